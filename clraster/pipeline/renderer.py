"""The OpenCL renderer: the device backend of the frame driver (`clraster.pipeline.driver`), and the
public entrances that check a frame's options and convert its target once (`render`,
`render_many`)."""

from __future__ import annotations

import inspect
import os
import threading
from collections.abc import Iterable, Iterator, Sequence
from typing import Any, cast

import numpy as np
import pyopencl as cl

from ..base.checks import CameraLike, check_size
from ..base.config import RasterConfig
from ..output.frame import Frame
from ..world.camera import Camera
from ..world.inputs import Target, as_target
from ..world.mesh import Mesh
from ..world.scene import Scene
from ..world.views import ViewError, cameras_in_hand, frames
from .device import check_process, choose_context, describe_choice, event_ms
from .drawlist import GeometryPool, PlanCache
from .draws import FrameDraws
from .driver import FrameBuffers, FrameOptions, HiZ, check_options, render_frame
from .params import FrameParams, FrameTotals
from .resolving import ResolveTables, ResolveView, resolve_tables, shade_sources

# imported for its effect: it registers the device SSAO, FXAA and shadow passes with
# clraster.output.post, which render_shaded then uses
from .stages import post as _post_passes  # noqa: F401
from .stages.chain import StageChain
from .stages.pyramid import HizFollow, Pyramid, PyramidStage
from .stages.raster import RasterOutput, RasterStage
from .stages.resolve import ResolveFollow, ResolveStage
from .stages.shade import ShadeStage
from .twophase import OcclusionHistory

__all__ = ["Renderer", "check_render_kwargs", "check_render_options"]


class _OutputStages:
    """A renderer's resolve and shading stages, each built on first use (their programs
    and the scene's tables on the device), shared with its `Renderer.resized` renderers:
    both take the image size per call."""

    def __init__(self, context: cl.Context, config: RasterConfig) -> None:
        self.context, self.config = context, config
        self._resolver: ResolveStage | None = None
        self._shader: ShadeStage | None = None

    def resolver(self) -> ResolveStage:
        if self._resolver is None:
            self._resolver = ResolveStage(self.context, self.config)
        return self._resolver

    def shader(self) -> ShadeStage:
        if self._shader is None:
            self._shader = ShadeStage(self.resolver(), self.config)
        return self._shader


class Renderer:
    """Rasterizes meshes on an OpenCL device into depth, triangle-id and barycentric buffers.

    Args:
        width, height: image size in pixels, 1..16384.
        config: tunables (tile size, bin chunks); they never change the output.
        context: an OpenCL context; default `clraster.device.default_context()` (honours
            CLRASTER_DEVICE, then PYOPENCL_CTX, else the first CPU device that compiles,
            PoCL first).
        device: the device instead of a context: ``"pocl"``, ``"intel"``, ``"oclgrind"``,
            a case-insensitive part of a platform or device name, or a ``pyopencl.Device``;
            it takes precedence over CLRASTER_DEVICE and PYOPENCL_CTX
            (`clraster.pipeline.device.choose_context`). Not with ``context``. What was
            chosen and why: ``device_description``. The device never changes the output.

    Device buffers are kept and grown between frames; programs are built once per context
    and config. Frames are streamed: the draws go through the stage chain in consecutive
    batches bounded by ``config.batch_triangles`` (M) and ``config.batch_entries`` (E, bin
    entries and clipped pieces of a pass), all rasterized into the same frame buffers —
    the image and every count are those of one unbatched pass, whatever the budget
    (`clraster.pipeline.streaming`). So device memory is bounded by the budget and the image,
    never by the scene's triangle count::

        frame arrays   24·W·H bytes (depth, ids, barycentrics, overdraw; the caller's
                       NumPy arrays, used in place by a CPU device)
      + recycled       ≤ 48·W·H bytes of host memory of frames the caller has dropped,
                       kept to make the next frames' arrays without page faults
                       (`clraster.arraypool`: a frame's arrays are its own as long as
                       anything refers to them)
      + per pass       ≤ 153·M + 228·E bytes (609 MiB at the defaults; draws, setup
                       records, clipped pieces, bin entries; `StageChain.budget_bounds`
                       computes them, tests/test_budget_text.py checks these figures)
      + clipper        ≤ CLIP_SCRATCH_BYTES (64 MiB) of scratch rows for clipping a
                       pass's clipped triangles once (`clraster.base.config`)
      + per tile       (4·bin_chunks + 24)·T bytes, T = tiles of the image
      + per scene      the unique geometry (~17 bytes per vertex + 8 per triangle) and
                       96 bytes per instance (its matrix and depth rows) — not per drawn
                       triangle
      + pyramid        ≈ 5.3·W·H bytes (its levels, level 0 included) and 25 bytes per
                       tested cluster box, when occlusion culling is on

    A single draw (cluster) whose bin list alone exceeds E is still drawn, in a pass of its
    own; the buffers it grew are released after the frame, so memory returns to the bound.
    Frame buffers that cannot fit the device fail here, in the constructor, before
    anything is allocated. Many views of a target drawn in one pass (`render_many`, the
    batch paths) are drawn two at a time by default with a second renderer kept with this
    one (`view_partner`): as much again of the per-pass, per-tile and per-scene memory.

    Threads may share a Renderer: its frames are serialized by a lock (one per
    Renderer; use one Renderer per thread for parallel frames). It works only in the process
    that created it: after fork() a child must make its own, and only if its parent never
    used OpenCL (`clraster.device.ForkedProcessError` says why and what to do instead).
    """

    def __init__(self, width: int, height: int, *, config: RasterConfig | None = None,
                 context: cl.Context | None = None,
                 device: str | cl.Device | None = None) -> None:
        self.width, self.height = check_size(width, height)
        self.config = config or RasterConfig()
        if context is not None and device is not None:
            raise ValueError("give either context= or device=, not both")
        if context is not None:
            self.context, reason = context, "context= given"
        else:
            self.context, reason = choose_context(device)
        #: the device used and why, e.g. "Portable Computing Language / pthread-AMD EPYC
        #: (CLRASTER_DEVICE=pocl)"
        self.device_description = describe_choice(self.context, reason)
        self._pid = os.getpid()
        self._lock = threading.Lock()
        _check_frame_fits(self.context.devices[0], self.width, self.height, self.config)
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self.chain = StageChain(self.context, self.config)
        self.pyramid = PyramidStage(self.context, self.config)
        self._plans = PlanCache()   # the last target's scene and geometry pool
        self._history = OcclusionHistory()   # two-phase occlusion culling's memory
        self._pyramid: Pyramid | None = None   # the last one `_hiz` built (reset per frame)
        # the resolve and shading stages, built on first use (shared with `resized` ones)
        self._outputs = _OutputStages(self.context, self.config)
        self._partner: Renderer | None = None   # `view_partner`'s, made on first use
        self._partner_failed = False   # it ran out of memory once: views one at a time

    def resized(self, width: int, height: int, *, share_history: bool = True) -> Renderer:
        """A renderer of ``width`` × ``height`` on this one's device state: its queue, stage
        chain (the scene's geometry pool uploaded once, and the per-pass buffers, which each
        frame's parameters size), Hi-Z pyramid stage, resolve and shading stages (the
        scene's tables), plan cache (the scene's host geometry pool) and lock. So the scene
        is held once however many sizes are used (a viewer's render scales), and frames of
        all of them are serialized. Its frames are exactly a fresh renderer's of that size
        (and config).

        share_history: True (default): this renderer's occlusion history too — a view
        walked at changing sizes keeps phase 1's guess (last frame's visible clusters)
        current; visibility is per cluster and culling conservative whatever the history.
        False: a fresh one (a second view that must not disturb the first's).
        """
        r = Renderer(width, height, config=self.config, context=self.context)
        r.device_description = self.device_description
        r.queue, r.chain, r.pyramid = self.queue, self.chain, self.pyramid
        r._plans, r._lock, r._outputs = self._plans, self._lock, self._outputs
        if share_history:
            r._history = self._history
        return r

    def view_partner(self, target: Mesh | Scene, render_kwargs: dict[str, Any]
                     ) -> Renderer | None:
        """The renderer `clraster.views.frames` draws every other view of ``target`` with,
        two views in flight (`RasterConfig.views_in_flight`), or None where that is off or
        does not pay: occlusion culling on (each view's history must be the view before
        it), or a target of more than ``config.batch_triangles`` triangles (drawn in
        several passes: device-bound, and a second renderer would double the pass buffers
        and the scene's geometry on the device).

        The partner is this renderer's size, config and context, with its own queue,
        stages and lock, and this renderer's plan cache (the scene's host geometry pool,
        built once and only read by both); made on first use and kept with this renderer,
        so that later batches find the scene uploaded. Its frames are exactly this
        renderer's. It holds its own pass buffers and copy of the scene's geometry on the
        device (a one-pass target's: within the pass budget of the class docstring)."""
        if (self.config.views_in_flight < 2 or render_kwargs.get("occlusion")
                or target.n_faces > self.config.batch_triangles or self._partner_failed):
            return None
        with self._lock:   # (threads sharing this renderer make one partner)
            if self._partner is None:
                p = Renderer(self.width, self.height, config=self.config,
                             context=self.context)
                p.device_description = self.device_description
                p._plans = self._plans
                self._partner = p
            return self._partner

    def drop_view_partner(self) -> None:
        """Let go of the `view_partner` (its buffers go with it) and draw many views one
        at a time from now on: `clraster.views.frames` calls this when the partner runs out
        of memory, and renders that view with this renderer instead."""
        with self._lock:
            self._partner, self._partner_failed = None, True

    def render(self, target: Target, camera: CameraLike, *, cull: str = "back",
               frustum: bool = True, cones: bool = True, occlusion: bool = False,
               overdraw: bool = False, fates: bool = False, reversed_z: bool = False,
               clip_planes: Any = None, window: Any = None,
               outputs: Sequence[str] = ("depth", "ids", "bary")) -> Frame:
        """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`, or a ``trimesh.Trimesh``
        or ``trimesh.Scene``, converted once per object: `clraster.inputs.as_target`) seen
        by ``camera`` (a `clraster.Camera`, or any object with ``view_projection(width,
        height)``).

        Args:
            cull: "back" (drop faces that are clockwise in NDC, i.e. counter-clockwise is
                front, the OpenGL default), "front", or "none".
            frustum: cull instances and clusters against the view frustum through their
                BVHs first. Conservative: it never changes the image, only the work.
            cones: cull clusters whose normal cone faces away (with cull "back"/"front").
                Conservative too.
            occlusion: two-phase occlusion culling with a hierarchical depth pyramid: draw
                the clusters that were visible in this renderer's previous frame of the
                same scene (on a first frame: the nearest ones), build the pyramid, test
                every other cluster's box against it, draw those not occluded, and keep
                the visible set for the next frame. Conservative: same image.
            overdraw: also return ``frame.overdraw``, fragments tested per pixel (after
                the tile Hi-Z: `FrameStats.fragments_tested`).
            fates: also return ``frame.fates``, a `clraster.fates.ClusterFates`: the fate
                of every cluster of every instance (drawn, frustum-, cone- or
                occlusion-culled); its counts equal the stats' culling funnel.
            reversed_z: depth as reversed-Z, (1 − z/w)/2: 1 at the near plane, 0 at the far
                plane and where nothing was drawn (``frame.reversed_z`` says which). The
                depth test runs on it too, computed in double per triangle and stored in
                float32, whose precision near 0 keeps far depths distinct where window
                depth rounds to 1.0 (with near = 0.1, a float32 window depth cannot tell
                1,000 from 1,000.1 units; reversed-Z separates them). Ids and barycentrics
                are the same except where the finer far-depth test breaks ties differently.
            clip_planes: up to 8 world-space planes (a, b, c, d), array-like (K, 4), keeping
                the points with a·x + b·y + c·z + d >= 0, as OpenGL's gl_ClipDistance: the
                vertex stage computes each vertex's distances (in double, from its
                object-space position), setup rejects triangles wholly outside one plane
                and clips the others with Sutherland–Hodgman after the view volume (pieces
                keep the parent's id and barycentrics), and clusters wholly outside one
                plane are culled before anything is drawn (counted as frustum-culled).
                None or [] for none.
            window: a polygon in window pixels (x right, y down; an (N, 2) ring, concave
                allowed, or (exterior, holes); `clraster.clip2d.as_polygon`): only the pixel
                centres inside it are drawn (`clraster.window.window_mask`: vertices snap to
                1/256 px, centres on its boundary follow the top-left rule, so windows that
                tile the screen draw every pixel once). The image is the unwindowed image
                restricted to those pixels; tiles the window does not reach are not
                rasterized, and fragments at shut pixels of the others are tested but never
                pass (counted in fragments_tested, unless the tile Hi-Z skips their piece).
            outputs: which of "depth", "ids", "bary" to make. Without "bary" the
                barycentrics are not returned (``frame.barycentrics`` is None) and, unless
                an output below needs them, neither computed nor stored: 8 bytes per pixel
                instead of 20, for depth, visibility and occlusion users. Depth and ids
                are always made (the depth test needs both), and they are the same with
                or without "bary". Also, made on the device after the last pass by the
                resolve stage (kernels/resolve.cl) only when named, into
                ``frame.resolved`` (the `Frame` methods return them): "mask";
                "linear_depth", "distance" and "points" (from the exact surface point in
                float64: ids, float32 barycentrics and the scene's vertices; they need a
                camera with ``view`` and ``projection``); "normals", "smooth_normals",
                "camera_normals", "smooth_camera_normals" (face or interpolated vertex
                normals, world or OpenGL eye space). Conventions and precision:
                `clraster.pipeline.resolving`.

        Returns:
            A `Frame` (depth, triangle_id, barycentrics, stats); see its docstring for the
            conventions. For a Scene, triangle ids are ``scene.face_base[instance] + face``
            (`Scene.split_ids` splits them). Triangles with a NaN/Inf vertex are dropped
            and counted in ``stats.invalid``.
        """
        options = FrameOptions.make(
            self.width, self.height, camera, cull=cull, frustum=frustum, cones=cones,
            occlusion=occlusion, overdraw=overdraw, fates=fates, reversed_z=reversed_z,
            clip_planes=clip_planes, window=window, outputs=outputs)
        target = as_target(target)
        check_process(self._pid)
        with self._lock:
            return render_frame(self, target, camera, options)

    def render_many(self, target: Target, cameras: Iterable[Any] | str | os.PathLike,
                    **render_kwargs: Any) -> Iterator[Frame]:
        """Render ``target`` from each of ``cameras`` in order: a generator of Frames.

        Args:
            cameras: a list (any iterable, read lazily) of `clraster.Camera` objects, camera
                entry dicts, or objects with ``view_projection(width, height)``; or the path
                of a camera list file (JSON; format and checks in `clraster.views`).
            render_kwargs: `render`'s keywords (cull, frustum, cones, occlusion, overdraw,
                fates, outputs), the same for every view; unknown ones raise TypeError and
                bad values ValueError at once (`check_render_options`), not at a view.

        Each frame is exactly what ``render(target, camera, **render_kwargs)`` returns in a
        loop on this renderer (with occlusion=True, each view's history is the view before
        it). The scene's clusters, BVH and geometry pool and its upload to the device are
        kept across views; each frame has its own arrays. Views are drawn two at a time by
        this renderer and its `view_partner` where that pays (`RasterConfig.views_in_flight`;
        the frames still come in camera order). A broken camera raises
        `clraster.views.ViewError` naming its index (and field) when the generator reaches
        it; `clraster.batch.render_views` instead fails that view and goes on.
        """
        check_render_kwargs(self, render_kwargs)
        target = as_target(target)   # once, for every view
        if isinstance(cameras, (dict, Camera)):
            raise ValueError("cameras must be a list of cameras (or a camera list file), got "
                             f"one {type(cameras).__name__}; wrap it in a list")

        def gen() -> Iterator[Frame]:
            partner = (self.view_partner(target, render_kwargs)
                       if cameras_in_hand(cameras) else None)
            for _, item in frames(self, target, cameras, render_kwargs, partner):
                if isinstance(item, ViewError):
                    raise item
                yield item

        return gen()

    # -- the backend of `render_frame` ---------------------------------------------------

    def _clear(self, params: FrameParams, options: FrameOptions) -> RasterOutput:
        # cleared on the device
        return cast(RasterStage, self.chain.raster).clear(self.queue, params,
                                                         options.overdraw, options.bary)

    def _draw_pass(self, pool: GeometryPool, draws: FrameDraws, params: FrameParams,
                   totals: FrameTotals, into: RasterOutput | None, max_entries: int | None,
                   options: FrameOptions, follow: ResolveFollow | None = None
                   ) -> RasterOutput:
        return self.chain.draw(self.queue, pool, draws, params, totals, into=into,
                               overdraw=options.overdraw, max_entries=max_entries,
                               bary=options.bary, follow=follow)

    def _follow_resolve(self, pool: GeometryPool, tables: ResolveTables,
                        view: ResolveView) -> ResolveFollow:
        """The frame's resolve, to be enqueued behind its raster (`ResolveFollow`; made
        before the frame's first pass, while the queue is idle)."""
        return ResolveFollow(self._outputs.resolver(), self.queue, self.chain.geometry.buffers,
                             pool, tables, view, self.width, self.height,
                             cast(RasterStage, self.chain.raster).pool)

    def _hiz_step(self, params: FrameParams) -> HiZ:
        self._pyramid = None
        return _HizStep(self, params.zoff)

    def _buffers(self, out: RasterOutput) -> FrameBuffers:
        return out.depth, out.ids, out.bary, out.overdraw

    def _end_frame(self) -> None:
        self.chain.trim()   # an outsized pass's buffers go back to the budget's bound

    def _resolve(self, pool: GeometryPool, tables: ResolveTables, view: ResolveView,
                 out: RasterOutput) -> tuple[dict[str, np.ndarray], float]:
        geometry = self.chain.geometry
        geometry.upload_pool(self.queue, pool)   # (a frame with nothing drawn skipped it)
        bary = out.bufs[2] if out.bary is not None else None
        arrays, ev = self._outputs.resolver().run(
            self.queue, geometry.buffers, pool, tables, view, out.bufs[1], bary, self.width,
            self.height, cast(RasterStage, self.chain.raster).pool)
        return arrays, event_ms([ev])

    def shade_frame(self, frame: Frame, target: Any, *, smooth: bool, light: np.ndarray,
                    ambient: float, two_sided: bool, inst_col: np.ndarray,
                    sources: Any, sources_key: object, identity: bool, max_id: int,
                    background: np.ndarray, alpha: bool, k: int = 1) -> np.ndarray | None:
        """The image `clraster.output.shade` makes of ``frame`` (rendered from ``target``, a
        Mesh or Scene; k× the output size for render_shaded's ssaa), made on this
        renderer's device (kernels/shade.cl shade_pixels, shade_ssaa; arguments as
        `ShadeStage.shade`; ``sources``: per instance (vertex colours, face colours,
        texture) as `clraster.pipeline.resolving.shade_sources` takes them, or None, made
        into tables when ``sources_key`` differs from the last call's). None when the frame holds
        ids outside [−1, max_id]. The scene's tables are the resolve stage's, kept per
        geometry pool (this renderer's last target's, or made for ``target``)."""
        check_process(self._pid)
        with self._lock:
            res = self._outputs.shader()
            scene, pool = self._plans.scene_and_pool(target)
            tables = resolve_tables(pool, scene)
            src = None
            if sources is not None:
                src = (res._sources if sources_key == res._sources_key
                       and res._shade_tables is tables else shade_sources(tables, sources))
            img, _ = res.shade(
                self.queue, pool, tables, frame.triangle_id, frame.barycentrics, light=light,
                ambient=ambient, two_sided=two_sided, inst_col=inst_col, sources=src,
                sources_key=sources_key, smooth=smooth, identity=identity, max_id=max_id,
                background=background, alpha=alpha, k=k,
                arrays=cast(RasterStage, self.chain.raster).pool)
            return img

    def seen_instances(self, frame: Frame, target: Any, max_id: int) -> np.ndarray | None:
        """bool (I,): the instances of ``target`` with a pixel in ``frame`` (on the device);
        None when the frame holds ids outside [−1, max_id]."""
        check_process(self._pid)
        with self._lock:
            scene, pool = self._plans.scene_and_pool(target)
            return self._outputs.shader().seen(self.queue, pool, resolve_tables(pool, scene),
                                               frame.triangle_id, max_id)

    def _hiz(self, out: RasterOutput, rows: np.ndarray, vp32: np.ndarray, zoff: float = 0.5,
             same_depth: bool = False) -> tuple[np.ndarray, float]:
        """Pyramid of ``out``'s depth (key) buffer and the Hi-Z test of boxes ``rows``
        (float32 (6, K)) under ``vp32`` (float32 (16,)): `Occlusion` codes uint8 (K,) and
        device ms. zoff: the key's offset (`FrameParams.zoff`). same_depth: the depth
        buffer is the one of the previous call (nothing drawn since): its pyramid, still in
        the pyramid stage's buffer, is tested again instead of built again."""
        w, h = self.width, self.height
        pyr = self._pyramid
        if not same_depth or pyr is None:
            pyr = self._pyramid = self.pyramid.build(self.queue, out.bufs[0], w, h)
            events = list(pyr.events)
        else:
            events = []
        verdict, ev = self.pyramid.enqueue_test_rows(self.queue, pyr, rows, vp32, w, h, zoff)
        return verdict, event_ms([*events, ev] if ev else events)


class _HizStep:
    """The renderer's Hi-Z step of one frame (`two_phase`'s ``hiz``): called, the pyramid
    of the frame's depth and a test, waited for (`Renderer._hiz`); `follow`, the same
    enqueued behind a pass's raster instead (`HizFollow`)."""

    def __init__(self, renderer: Renderer, zoff: float) -> None:
        self._r, self._zoff = renderer, zoff

    def __call__(self, out: RasterOutput, rows: np.ndarray, vp32: np.ndarray,
                 same_depth: bool = False) -> tuple[np.ndarray, float]:
        return self._r._hiz(out, rows, vp32, self._zoff, same_depth)

    def follow(self, rows_fn: Any, vp32: np.ndarray) -> HizFollow:
        r = self._r

        def keep(pyr: Pyramid) -> None:   # a later test of the same depth tests it again
            r._pyramid = pyr

        return HizFollow(r.pyramid, rows_fn, vp32, r.width, r.height, self._zoff, keep)


def check_render_options(width: int, height: int, options: dict[str, Any]) -> None:
    """Check ``options`` (`Renderer.render`'s keywords, e.g. ``{"cull": "none"}``) once, as
    `Renderer.render` would for a ``width`` × ``height`` image, so that a batch of views
    refuses a bad value before its first view instead of failing every view with it.

    Raises:
        TypeError: a keyword `Renderer.render` does not take.
        ValueError: a bad value (cull not "back"/"front"/"none", a clip plane with a zero
            normal, a flag that is not a bool, a broken window polygon, ...), naming it.
    """
    sig = inspect.signature(Renderer.render)
    bound = sig.bind(None, None, None, **options)
    bound.apply_defaults()
    a = bound.arguments
    # the yes/no options are those whose default is a bool (a new one is checked too)
    flags = {name: a[name] for name, p in sig.parameters.items() if isinstance(p.default, bool)}
    check_options(width, height, a["cull"], a["clip_planes"], a["window"], a["outputs"], flags)


def check_render_kwargs(renderer: Any, render_kwargs: dict) -> None:
    """TypeError now (not at the first view) for keywords ``renderer.render`` does not take,
    and ValueError for values it would refuse on every view (``cull="sideways"``, a clip
    plane with a zero normal, ``reversed_z="yes"``...: `check_render_options`, the
    renderer's own checks, for ``renderer``'s width × height)."""
    try:
        inspect.signature(renderer.render).bind(None, None, **render_kwargs)
    except TypeError as exc:
        raise TypeError(f"render_many: {exc}") from None
    check_render_options(renderer.width, renderer.height, render_kwargs)


def _check_frame_fits(dev: cl.Device, width: int, height: int, config: RasterConfig) -> None:
    """Refuse an image whose frame buffers cannot fit ``dev``, before anything is allocated:
    the largest frame array (barycentrics, 12·W·H bytes) and the bin count buffer against
    the device's per-buffer limit, and all of them (depth, ids, barycentrics, overdraw:
    24·W·H, plus the per-tile buffers) against its global memory."""
    npx = width * height
    tiles_x, tiles_y = config.tiles(width, height)
    n_tiles = tiles_x * tiles_y
    limit, total = int(dev.max_mem_alloc_size), int(dev.global_mem_size)
    for nbytes, what, cap, unit in (
            (12 * npx, "barycentric buffer", limit, "per buffer"),
            (4 * config.bin_chunks * n_tiles, "bin count buffer", limit, "per buffer"),
            (24 * npx + (4 * config.bin_chunks + 24) * n_tiles,
             "set of frame buffers (depth, ids, barycentrics, overdraw, per-tile counts)",
             total, "in all")):
        if nbytes > cap:
            raise ValueError(f"{width}x{height} needs a {nbytes / 2**20:,.0f} MiB {what}; "
                             f"{dev.name} allocates at most {cap / 2**20:,.0f} MiB {unit}. "
                             "Render a smaller image (or split the view into several "
                             "cameras)")
