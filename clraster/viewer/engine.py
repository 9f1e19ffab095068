"""One viewer frame: the page's state in, a rendered, coloured and encoded picture out.

`ViewState` is everything the page controls (camera, mode, culling toggles, cut-away,
Hi-Z level, lossless stream); `Engine.frame` renders it on the OpenCL renderer with
frustum / cone / two-phase occlusion culling as toggled, colours it (`pictures`), adds the
third-person pane (`inspect.ThirdPerson`) and encodes both, returning a `Picture` whose
`header` carries the camera rendered (a look-at entry of `clraster.views`), the culling
funnel and the stage times.

Resolution while moving: a frame may be rendered at a lower scale (`SCALES`) when the
camera moved since the previous frame and the full scale's measured time (render + colour
+ encode, a moving average) exceeds the frame budget (`Engine.budget_ms`, 1000/25 ms by
default); the page draws it stretched. When the camera stops, the next frame is rendered at
full scale (`Engine.needs_refine`). A reduced frame still shows the *current* camera:
resolution drops, never freshness.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .inspect import ThirdPerson
from .pictures import (
    MODES,
    depth_pixels,
    encode,
    face_table,
    hiz_pixels,
    ids_pixels,
    overdraw_pixels,
    shaded_pixels,
)
from .scene import FlyCamera, ViewerScene

__all__ = ["INSET", "SCALES", "Engine", "Picture", "Rendered", "ViewState"]

#: Render scales tried while the camera moves, largest first (1.0 = the full size). At the
#: smallest ones a frame is mostly per-triangle and host work, not pixels; the last one
#: is the fallback when none fits the budget.
SCALES = (1.0, 0.75, 0.5, 0.375, 0.25)
#: The third-person pane's size as a fraction of the view's width and height.
INSET = 0.3
#: Weight of the newest frame in the per-scale moving average of frame times.
_EWMA = 0.3


@dataclass(frozen=True)
class ViewState:
    """What the page asks for. `camera`: the fly camera; `mode`: one of `pictures.MODES`;
    `frustum`, `cones`, `occlusion`: the culling toggles; `cut`: world height above which
    everything is cut away (None: no cut); `hiz_level`: the pyramid level of mode "hiz";
    `inset`: draw the third-person pane; `lossless`: PNG instead of JPEG; `seq`: the page's
    number for this camera (echoed in the frame's header)."""

    camera: FlyCamera
    mode: str = "shaded"
    frustum: bool = True
    cones: bool = True
    occlusion: bool = True
    cut: float | None = None
    hiz_level: int = 3
    inset: bool = True
    lossless: bool = False
    seq: int = 0


@dataclass
class Picture:
    """An encoded frame: `header` (JSON-able dict), `main` and `inset` image bytes
    (`inset` empty when the pane is off), and `fmt` ("jpeg" or "png")."""

    header: dict[str, Any]
    main: bytes
    inset: bytes
    fmt: str


@dataclass
class Rendered:
    """A rendered, not yet coloured frame (`Engine.render` → `Engine.finish`): the state,
    the scale, the `clraster.Camera` rendered, the `clraster.Frame` (depth, ids; fates
    when the pane or mode needs them; overdraw in mode "overdraw") and the render's
    milliseconds (scale choice included)."""

    state: ViewState
    scale: float
    camera: Any
    frame: Any
    render_ms: float


@dataclass
class _Timing:
    ms: dict[float, float] = field(default_factory=dict)

    def add(self, scale: float, ms: float) -> None:
        old = self.ms.get(scale)
        self.ms[scale] = ms if old is None else (1 - _EWMA) * old + _EWMA * ms


class Engine:
    """Renders `ViewState`s of one `ViewerScene` at ``width × height`` (full scale).
    Thread-safe: one `render` at a time and one `finish` at a time, each under its own
    lock, so a frame's finish may overlap the next frame's render; the renderers share one
    OpenCL context and one set of device buffers (`renderer`)."""

    def __init__(self, vs: ViewerScene, width: int, height: int, *, quality: int = 80,
                 budget_ms: float = 40.0, device: Any = None) -> None:
        from ..pipeline.device import choose_context

        self.vs = vs
        self.width, self.height = width, height
        self.quality = quality
        self.budget_ms = budget_ms
        self.context, _ = choose_context(device)
        self.table = face_table(vs.scene)
        self._renderers: dict[tuple[int, int], Any] = {}
        self._lines: dict[tuple[int, int], Any] = {}
        self._panes: dict[tuple[int, int], ThirdPerson] = {}
        self._lock = threading.Lock()          # one render at a time
        self._finish_lock = threading.Lock()   # one finish at a time (beside a render)
        self._make_lock = threading.Lock()     # renderers and panes made by either
        self._timing = _Timing()
        self._last: tuple[float, ...] | None = None   # the camera of the previous frame
        self.last_scale = 1.0

    # -- renderers ------------------------------------------------------------------------

    def renderer(self, w: int, h: int) -> Any:
        """The first-person `clraster.Renderer` of size w × h (made on first use, kept).
        Every size shares the full-size renderer's device state and occlusion history
        (`Renderer.resized`): one copy of the scene and one set of stage buffers, whatever
        the scales walked."""
        with self._make_lock:
            full = (self.width, self.height)
            if full not in self._renderers:
                self._renderers[full] = _renderer(self.context, *full)
            r = self._renderers.get((w, h))
            if r is None:
                r = self._renderers[(w, h)] = self._renderers[full].resized(w, h)
            return r

    def pane(self, w: int, h: int) -> ThirdPerson:
        """The third-person pane of size w × h. Its renderer shares the first-person one's
        device state but has its own occlusion history (the pane is not walked: it must not
        disturb the first-person history; it renders without occlusion culling anyway)."""
        from ..pipeline.lines import LineRenderer

        base = self.renderer(self.width, self.height)
        with self._make_lock:
            if (w, h) not in self._panes:
                lines = self._lines.get((w, h))
                if lines is None:
                    lines = self._lines[(w, h)] = LineRenderer(w, h, context=self.context)
                self._panes[(w, h)] = ThirdPerson(
                    vs=self.vs, renderer=base.resized(w, h, share_history=False), lines=lines)
            return self._panes[(w, h)]

    def inset_size(self) -> tuple[int, int]:
        return max(16, round(self.width * INSET)), max(16, round(self.height * INSET))

    # -- resolution -----------------------------------------------------------------------

    def choose_scale(self, state: ViewState) -> float:
        """The scale for `state`: 1.0 unless the camera moved since the last frame and the
        measured full-scale time is over budget; then the largest scale whose measured (or,
        unmeasured, pixel-proportional estimate of its) time fits."""
        key = _camera_key(state.camera)
        moving = self._last is not None and key != self._last
        if not moving or state.lossless:
            return 1.0
        full = self._timing.ms.get(1.0)
        if full is None or full <= self.budget_ms:
            return 1.0
        for s in SCALES[1:]:
            est = self._timing.ms.get(s, full * s * s)
            if est <= self.budget_ms:
                return s
        return SCALES[-1]

    def needs_refine(self, state: ViewState) -> bool:
        """True when the last frame was reduced and `state`'s camera has stopped there."""
        return self.last_scale != 1.0 and self._last == _camera_key(state.camera)

    # -- one frame ------------------------------------------------------------------------

    def frame(self, state: ViewState, scale: float | None = None) -> Picture:
        """Render, colour and encode `state` (at `scale`, default `choose_scale`):
        ``finish(render(state, scale))``."""
        return self.finish(self.render(state, scale))

    def render(self, state: ViewState, scale: float | None = None) -> Rendered:
        """The first half of `frame`: render `state` (at `scale`, default `choose_scale`).
        One render at a time (a lock); `finish` of the previous frame may run beside it on
        another thread (the server does so: the renderer releases the GIL while it waits
        for the device)."""
        if state.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {state.mode!r}")
        with self._lock:
            t0 = time.perf_counter()
            s = self.choose_scale(state) if scale is None else scale
            w, h = max(16, round(self.width * s)), max(16, round(self.height * s))
            cam = state.camera.camera()
            planes = None if state.cut is None else np.array([[0.0, -1.0, 0.0, state.cut]])
            frame = self.renderer(w, h).render(
                self.vs.scene, cam, frustum=state.frustum, cones=state.cones,
                occlusion=state.occlusion,
                fates=state.inset or state.mode == "fates",   # the pane's colours
                overdraw=state.mode == "overdraw", clip_planes=planes,
                outputs=("depth", "ids"))
            self._last = _camera_key(state.camera)
            self.last_scale = s
            return Rendered(state, s, cam, frame, (time.perf_counter() - t0) * 1e3)

    def finish(self, r: Rendered) -> Picture:
        """The second half of `frame`: colour `r`'s frame for its mode, draw the pane and
        encode both. One finish at a time (a lock of its own, so it may overlap the next
        `render`)."""
        with self._finish_lock:
            t0 = time.perf_counter()
            pic = self._finish(r)
            total = r.render_ms + (time.perf_counter() - t0) * 1e3
            self._timing.add(r.scale, total)
            pic.header["frame_ms"] = total
            return pic

    def _finish(self, r: Rendered) -> Picture:
        state, s, cam, frame = r.state, r.scale, r.camera, r.frame
        h, w = frame.triangle_id.shape
        t1 = time.perf_counter()
        proj = cam.projection(w, h)
        near, far = state.camera.near, state.camera.far
        info: dict[str, Any] = {}
        fp_vp = cam.view_projection(self.width, self.height)
        pane_size = self.inset_size()
        if state.mode == "shaded":
            main = shaded_pixels(frame.triangle_id, self.table)
        elif state.mode == "depth":
            main = depth_pixels(frame.depth, proj, near, far)
        elif state.mode == "overdraw":
            main = overdraw_pixels(frame.overdraw)
        elif state.mode == "hiz":
            main, info["hiz_level"] = hiz_pixels(frame.depth, state.hiz_level, proj, near, far)
        elif state.mode == "ids":
            main = ids_pixels(frame.triangle_id)
        else:   # fates: the outside view large, the first-person picture in the pane
            main, info["third_person"] = self.pane(w, h).picture(
                frame.fates, fp_vp, state.camera.eye[1], state.cut)
        inset_px = None
        if state.inset:
            if state.mode == "fates":
                iw, ih = pane_size
                ys = (np.arange(ih) * h) // ih
                xs = (np.arange(iw) * w) // iw
                inset_px = shaded_pixels(frame.triangle_id[ys[:, None], xs[None, :]],
                                         self.table)
            else:
                inset_px, info["third_person"] = self.pane(*pane_size).picture(
                    frame.fates, fp_vp, state.camera.eye[1], state.cut)
        colour_ms = (time.perf_counter() - t1) * 1e3
        t2 = time.perf_counter()
        fmt = "png" if state.lossless else "jpeg"
        main_bytes = encode(main, fmt, self.quality)
        inset_bytes = b"" if inset_px is None else encode(inset_px, fmt, self.quality)
        encode_ms = (time.perf_counter() - t2) * 1e3
        st = frame.stats
        header = {
            "seq": state.seq, "mode": state.mode, "width": w, "height": h, "scale": s,
            "fmt": fmt, "camera": state.camera.entry(),
            "yaw": state.camera.yaw, "pitch": state.camera.pitch,
            "options": {"frustum": state.frustum, "cones": state.cones,
                        "occlusion": state.occlusion, "cut": state.cut},
            "funnel": st.counts(),
            "fates": {f.name.lower(): n for f, n in frame.fates.counts().items()}
            if frame.fates is not None else {},
            "times_ms": {**{k: round(v, 3) for k, v in st.timings_ms.items()},
                         "render": round(r.render_ms, 3), "colour": round(colour_ms, 3),
                         "encode": round(encode_ms, 3)},
            "main_bytes": len(main_bytes), "inset_bytes": len(inset_bytes), **info,
        }
        return Picture(header, main_bytes, inset_bytes, fmt)

    def screenshot(self, state: ViewState) -> Picture:
        """`state` at full scale as a lossless PNG, without the pane."""
        return self.frame(replace(state, lossless=True, inset=False), 1.0)


def _renderer(context: Any, w: int, h: int) -> Any:
    """The full-size `clraster.Renderer`; every other size is its `Renderer.resized` (one
    copy of the scene and of the stage buffers, whatever the scales walked: a renderer per
    render scale held its own — ~450 MiB each for the 10M plant, the pool on the host and
    on the device and stage buffers grown to a pass — and a walk that reached every scale
    and the pane grew by ~1.8 GiB; tests/test_viewer.py checks the frames)."""
    from ..pipeline.renderer import Renderer

    return Renderer(w, h, context=context)


def _camera_key(c: FlyCamera) -> tuple[float, ...]:
    return (*c.eye, c.yaw, c.pitch)

