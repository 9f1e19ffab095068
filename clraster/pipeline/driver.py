"""One frame, written once for both renderers: the table of contents of the pipeline.

`render_frame` runs a frame: plan it (object culling and the draw layout, `plan_frame`), make
its `FrameParams`, draw it as a stream of bounded passes (`stream_draws`) — or, with occlusion
culling, the two phases around a depth pyramid (`two_phase`) — and return the `Frame`. The
OpenCL renderer (`clraster.renderer.Renderer`) and the NumPy twin
(`clraster.reference.Renderer`) are its backends (`Backend`): each supplies only what differs
— one pass of its stage chain, its Hi-Z step, its cleared frame, its frame buffers — so the
twin runs the very schedule it exists to check, as niagara runs its early and late passes
from one body.

`FrameOptions.make` checks a frame's options once, for both renderers, before anything is
planned.

After the last pass, the per-pixel outputs asked for beyond depth, ids and barycentrics
(`clraster.base.checks.RESOLVE_OUTPUTS`: mask, metric depth, points, normals) are made by
the backend's resolve step from the frame buffers and the scene's geometry
(`clraster.pipeline.resolving`), only when asked for; the frame carries them
(`Frame.resolved`).
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

from ..base.checks import (
    RESOLVE_OUTPUTS,
    CameraLike,
    check_clip_planes,
    check_cull,
    check_flag,
    check_render_outputs,
)
from ..base.config import RasterConfig
from ..clip.window import window_mask, window_planes_for
from ..culling.fates import ClusterFates
from ..output.frame import Frame, FrameStats
from ..world.mesh import Mesh
from ..world.scene import Scene
from .drawlist import GeometryPool, PlanCache, plan_frame
from .draws import FrameDraws
from .params import FrameParams, FrameTotals, finish_depth
from .resolving import (
    NEED_BARY,
    ResolveTables,
    ResolveView,
    check_resolve_camera,
    resolve_tables,
    resolve_view,
)
from .streaming import stream_draws
from .twophase import OcclusionHistory, two_phase

__all__ = ["Backend", "FrameBuffers", "FrameOptions", "HiZ", "check_options", "render_frame"]

#: A backend's frame buffers between passes (its own type: device buffers, NumPy arrays).
Out = TypeVar("Out")
#: What a frame returns of a backend's buffers: the depth key (float32 (H, W), turned into
#: the frame's depth in place by `finish_depth`), ids int32 (H, W), barycentrics float32
#: (H, W, 3) or None, overdraw int32 (H, W) or None.
FrameBuffers = tuple[np.ndarray, np.ndarray, "np.ndarray | None", "np.ndarray | None"]
#: The Hi-Z step of a frame, as `two_phase` calls it: (buffers, boxes float32 (6, K),
#: view-projection float32 (16,), same_depth=False) → (`Occlusion` codes uint8 (K,), ms).
HiZ = Callable[..., tuple[np.ndarray, float]]


@dataclass(frozen=True)
class FrameOptions:
    """A frame's options, checked (`make`): the keywords of `Renderer.render`.

    clip_planes: float64 (K, 4) world-space user clip planes, or None. window: bool (H, W)
    mask of the pixels a polygon window lets through (`window_mask`), or None. cull_planes:
    float64 (K', 4) planes bounding that window for this camera (`window_planes_for`): they
    cull and reject, never clip. bary: whether barycentrics are made (asked for in
    ``outputs``, or needed by a resolve output); keep_bary: whether the frame returns them.
    resolve: the resolve outputs asked for (`clraster.base.checks.RESOLVE_OUTPUTS`), in
    ``outputs``' order."""

    cull: str = "back"
    frustum: bool = True
    cones: bool = True
    occlusion: bool = False
    overdraw: bool = False
    fates: bool = False
    reversed_z: bool = False
    bary: bool = True
    clip_planes: np.ndarray | None = None
    window: np.ndarray | None = None
    cull_planes: np.ndarray | None = None
    keep_bary: bool = True
    resolve: tuple[str, ...] = ()
    axes: Any = None   # the camera's `camera_axes` where a resolve output needs them

    @classmethod
    def make(cls, width: int, height: int, camera: CameraLike, *, cull: Any = "back",
             frustum: Any = True, cones: Any = True, occlusion: Any = False,
             overdraw: Any = False, fates: Any = False, reversed_z: Any = False,
             clip_planes: Any = None, window: Any = None,
             outputs: Any = ("depth", "ids", "bary")) -> FrameOptions:
        """Check `Renderer.render`'s options for a ``width`` × ``height`` frame seen by
        ``camera`` (ValueError naming a bad one, `check_options`; a resolve output that
        needs the camera's view with a camera that has none, `check_resolve_camera`) and
        make the window's culling planes for that camera."""
        flags = {"frustum": frustum, "cones": cones, "occlusion": occlusion,
                 "overdraw": overdraw, "fates": fates, "reversed_z": reversed_z}
        planes, mask, names = check_options(width, height, cull, clip_planes, window, outputs,
                                            flags)
        resolve = tuple(n for n in names if n in RESOLVE_OUTPUTS)
        axes = check_resolve_camera(resolve, camera, width, height)
        keep = "bary" in names
        cull_planes = None
        if window is not None:   # planes that cut the work outside the window's mask
            cull_planes = window_planes_for(window, camera, width, height, planes)
        return cls(cull, bool(frustum), bool(cones), bool(occlusion), bool(overdraw),
                   bool(fates), bool(reversed_z), keep or any(n in NEED_BARY for n in resolve),
                   planes, mask, cull_planes, keep, resolve, axes)


def check_options(width: int, height: int, cull: Any, clip_planes: Any, window: Any,
                  outputs: Any, flags: dict[str, Any]
                  ) -> tuple[np.ndarray | None, np.ndarray | None, tuple[str, ...]]:
    """The checks made on a frame's options, whatever the camera: (clip planes float64
    (K, 4) or None, window mask bool (height, width) or None, the output names asked for).
    ValueError naming the option otherwise."""
    check_cull(cull)
    planes = check_clip_planes(clip_planes)
    mask = None if window is None else window_mask(window, width, height)
    for name, value in flags.items():
        check_flag(value, name)
    return planes, mask, check_render_outputs(outputs)


class Backend(Protocol[Out]):
    """What a renderer gives `render_frame`: its image size and config, what it keeps
    between frames (the last target's scene and geometry pool, the occlusion history), and
    the steps that differ between the OpenCL device and the NumPy twin."""

    width: int
    height: int
    config: RasterConfig
    _plans: PlanCache
    _history: OcclusionHistory

    def _clear(self, params: FrameParams, options: FrameOptions) -> Out:
        """Frame buffers with nothing drawn."""
        ...

    def _draw_pass(self, pool: GeometryPool, draws: FrameDraws, params: FrameParams,
                   totals: FrameTotals, into: Out | None, max_entries: int | None,
                   options: FrameOptions, follow: Any = None) -> Out:
        """One pass of the stage chain over ``draws`` into ``into`` (None: cleared
        buffers), adding its counts and times to ``totals``; `BinBudgetExceeded` before
        anything is drawn when its bin list would hold more than ``max_entries``.
        ``follow``: what the backend's optional ``_follow_resolve`` made (None for a
        backend without it)."""
        ...

    def _hiz_step(self, params: FrameParams) -> HiZ:
        """The Hi-Z step of this frame for `two_phase`."""
        ...

    def _buffers(self, out: Out) -> FrameBuffers:
        """The frame's arrays in ``out``."""
        ...

    def _end_frame(self) -> None:
        """After the passes of a frame, even a failed one."""
        ...

    def _resolve(self, pool: GeometryPool, tables: ResolveTables, view: ResolveView,
                 out: Out) -> tuple[dict[str, np.ndarray], float]:
        """The resolve outputs ``view.names`` of the finished frame buffers ``out`` (name →
        array, `clraster.pipeline.reference.resolve.resolve` gives shapes and dtypes) and
        the milliseconds it took."""
        ...


def render_frame(backend: Backend[Out], target: Mesh | Scene, camera: CameraLike,
                 options: FrameOptions) -> Frame:
    """Render ``target`` seen by ``camera`` with ``backend``'s stages (module docstring).
    ``target`` is a Mesh or a Scene (`clraster.inputs.as_target` made it one at the
    public entrance); ``options`` were checked by `FrameOptions.make`."""
    o = options
    w, h, config = backend.width, backend.height, backend.config
    t0 = time.perf_counter()
    plan = plan_frame(target, camera, w, h, cull=o.cull, frustum=o.frustum, cones=o.cones,
                      cache=backend._plans, keep_cone_culled=o.fates,
                      clip_planes=o.clip_planes, cull_planes=o.cull_planes)
    # the draw records: all of them now, or, with occlusion culling, those of each phase
    # when it is drawn (two_phase, which also culls the clusters: it may test only some of
    # them, hierarchically)
    empty = not o.occlusion and plan.empty
    fd = plan.frame if not o.occlusion and not empty else None
    t_cull = (time.perf_counter() - t0) * 1e3
    counts = dict(plan.draw_list.counts) if not o.occlusion else {}
    params = FrameParams.make(w, h, config, o.cull, o.reversed_z, o.window)
    if empty:
        # nothing in view: the cleared frame
        out = backend._clear(params, o)
        stats = FrameStats.from_counts(counts, np.zeros(0, np.uint8))
        return _frame(backend._buffers(out), stats,
                      ClusterFates.from_plan(plan) if o.fates else None, o,
                      _resolve(backend, plan, camera, o, out, stats.timings_ms), backend)
    totals = FrameTotals(timings_ms={"cull (host)": t_cull})
    occluded = None
    # a backend that can enqueue the resolve behind the raster (the OpenCL renderer) does,
    # for a frame drawn in one pass: a frame over the triangle budget is not tried, and a
    # second pass (the entry budget) turns it off, the frame then resolving after its passes
    follow = None
    follow_make = getattr(backend, "_follow_resolve", None)
    if (o.resolve and fd is not None and follow_make is not None
            and fd.n_tris <= config.batch_triangles):
        follow = follow_make(plan.pool, *_resolve_inputs(backend, plan, camera, o))

    def draw(draws: FrameDraws, into: Out | None, after: Any = None) -> Out:
        # a frame (or an occlusion phase) as a stream of bounded passes; ``after``: what to
        # enqueue behind the rasters instead of the resolve (`twophase`: phase 1's Hi-Z)
        then = follow if after is None else after

        def one_pass(batch: FrameDraws, max_entries: int | None, into: Out | None) -> Out:
            return backend._draw_pass(plan.pool, batch, params, totals, into, max_entries, o,
                                      then)

        return stream_draws(draws, config.batch_triangles, config.batch_entries, one_pass,
                            into)

    try:
        if fd is not None:
            out = draw(fd, None)
        else:
            res = two_phase(plan, backend._history, draw, backend._hiz_step(params), totals,
                            counts, group_clusters=config.occlusion_groups)
            out = res.out
            # (listed only for fates: the hierarchical schedule counts hidden groups
            # without listing their clusters)
            occluded = res.occluded_keys if o.fates else None
    finally:
        backend._end_frame()
    resolved = _resolve(backend, plan, camera, o, out, totals.timings_ms, follow)
    return _frame(backend._buffers(out), totals.stats(counts),
                  ClusterFates.from_plan(plan, occluded) if o.fates else None, o, resolved,
                  backend)


def _resolve_inputs(backend: Backend[Out], plan: Any, camera: CameraLike, o: FrameOptions
                    ) -> tuple[ResolveTables, ResolveView]:
    tables = resolve_tables(plan.pool, plan.scene)
    view = resolve_view(plan.pool, plan.scene, camera, backend.width, backend.height,
                        o.resolve, o.axes)
    return tables, view


def _resolve(backend: Backend[Out], plan: Any, camera: CameraLike, o: FrameOptions, out: Out,
             timings_ms: dict[str, float], follow: Any = None
             ) -> tuple[dict[str, np.ndarray], ResolveView | None]:
    """The resolve outputs asked for (none: nothing runs) and the view they were made for;
    their time goes to ``timings_ms["resolve"]``. ``follow``: the backend's resolve
    enqueued behind the raster (its `_follow_resolve`), used when it followed the frame's
    last raster launch."""
    if not o.resolve:
        return {}, None
    made = None if follow is None else follow.result(out)
    if made is not None:
        arrays, ms = made
        view = follow.view
    else:
        tables, view = _resolve_inputs(backend, plan, camera, o)
        arrays, ms = backend._resolve(plan.pool, tables, view, out)
    timings_ms["resolve"] = timings_ms.get("resolve", 0.0) + ms
    return arrays, view


def _frame(buffers: FrameBuffers, stats: FrameStats, fates: ClusterFates | None,
           o: FrameOptions, resolved: tuple[dict[str, np.ndarray], ResolveView | None],
           backend: Any = None) -> Frame:
    depth, ids, bary, overdraw = buffers
    # a backend that shades on its device (the OpenCL renderer's `shade_frame`), weakly
    source = weakref.ref(backend) if hasattr(backend, "shade_frame") else None
    arrays, view = resolved
    cam = (None if view is None or view.view is None or view.projection is None
           else (view.view, view.projection))
    return Frame(finish_depth(depth, ids, o.reversed_z), ids, bary if o.keep_bary else None,
                 stats, overdraw=overdraw, fates=fates, reversed_z=o.reversed_z,
                 resolved=arrays, resolved_camera=cam, source=source)
