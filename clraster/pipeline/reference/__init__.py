"""The NumPy twin of the OpenCL pipeline.

Each module mirrors one kernel file with the same inputs, outputs, integer rules and float32
operation order (vertex ↔ the vertices kernels/setup.cl makes per draw, setup ↔ setup.cl,
bin ↔ bin.cl, raster ↔ raster.cl, pyramid ↔ pyramid.cl, query ↔ query.cl), so for the same
input it produces the same triangle ids and depths. It is the test oracle and the benchmark
baseline, vectorized throughout (no per-pixel Python loops).

`render` draws one frame; `Renderer` keeps what the OpenCL `clraster.Renderer` keeps between
frames (the scene of a bare Mesh, the occlusion-culling history). Both are backends of the one
frame driver (`clraster.pipeline.driver.render_frame`), so with ``occlusion=True`` a sequence
of frames follows the same two-phase schedule (`clraster.pipeline.twophase`) as the OpenCL
path, through the same code. The twin imports only the lower layers (config, layout, the
driver, boxes, params...), never the OpenCL side.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...base.checks import CameraLike, check_size
from ...base.config import RasterConfig
from ...output.frame import Frame
from ...world.inputs import Target, as_target
from ..drawlist import GeometryPool, PlanCache
from ..draws import FrameDraws
from ..driver import FrameBuffers, FrameOptions, HiZ, render_frame
from ..params import BinBudgetExceeded, FrameParams, FrameTotals
from ..resolving import ResolveTables, ResolveView
from ..streaming import stream_draws
from ..twophase import OcclusionHistory
from . import bin as bin_
from . import pyramid as pyramid_
from . import raster as raster_
from . import resolve as resolve_
from . import setup as setup_
from . import vertex as vertex_

__all__ = ["Renderer", "render"]

#: The twin's frame buffers between passes: depth float32 (H, W), ids int32 (H, W),
#: barycentrics float32 (H, W, 3).
Images = tuple[np.ndarray, np.ndarray, np.ndarray]


class Renderer:
    """The twin with a memory across frames, as `clraster.Renderer` has one: it keeps the
    scene made from a bare Mesh and its geometry pool (so repeated frames of one target are
    frames of the same scene), and the visibility history of two-phase occlusion culling
    (`clraster.pipeline.twophase.OcclusionHistory`), so a sequence of ``render(...,
    occlusion=True)`` calls runs the OpenCL renderer's schedule frame for frame and gives
    the same frames and occlusion counts as one `clraster.Renderer` fed the same sequence.

    Args:
        width, height: image size in pixels. config: tile size used by binning (it never
            changes the image).
    """

    def __init__(self, width: int, height: int, *, config: RasterConfig | None = None) -> None:
        self.width, self.height = check_size(width, height)
        self.config = config or RasterConfig()
        self._plans = PlanCache()
        self._history = OcclusionHistory()

    @property
    def history(self) -> OcclusionHistory:
        """The visibility history of two-phase occlusion culling."""
        return self._history

    def render(self, target: Target, camera: CameraLike, *, cull: str = "back",
               frustum: bool = True, cones: bool = True, occlusion: bool = False,
               reversed_z: bool = False, clip_planes: Any = None, window: Any = None,
               outputs: Sequence[str] = ("depth", "ids", "bary")) -> Frame:
        """Render ``target`` (Mesh or Scene, or a trimesh Trimesh or Scene); arguments and
        outputs as `clraster.Renderer.render` (no overdraw or fates; the resolve outputs
        made by the twin of kernels/resolve.cl, `clraster.pipeline.reference.resolve`)."""
        options = FrameOptions.make(
            self.width, self.height, camera, cull=cull, frustum=frustum, cones=cones,
            occlusion=occlusion, reversed_z=reversed_z, clip_planes=clip_planes,
            window=window, outputs=outputs)
        return render_frame(self, as_target(target), camera, options)

    # -- the backend of `render_frame` ---------------------------------------------------

    def _clear(self, params: FrameParams, options: FrameOptions) -> Images:
        # (barycentrics: fresh zero pages, free until touched; dropped without "bary")
        f = Frame.empty(self.width, self.height)
        return f.depth, f.triangle_id, f.need_barycentrics()

    def _draw_pass(self, pool: GeometryPool, draws: FrameDraws, params: FrameParams,
                   totals: FrameTotals, into: Images | None, max_entries: int | None,
                   options: FrameOptions, follow: Any = None) -> Images:
        # (no _follow_resolve: the twin resolves after the frame, follow is None)
        return _one_pass(pool, draws, params, self.config, totals, into, max_entries)

    def _hiz_step(self, params: FrameParams) -> HiZ:
        return _hiz(self.width, self.height, params.zoff)

    def _buffers(self, out: Images) -> FrameBuffers:
        return out[0], out[1], out[2], None

    def _end_frame(self) -> None:
        pass

    def _resolve(self, pool: GeometryPool, tables: ResolveTables, view: ResolveView,
                 out: Images) -> tuple[dict[str, np.ndarray], float]:
        t0 = time.perf_counter()
        arrays = resolve_.resolve(pool, tables, view, out[1], out[2])
        return arrays, (time.perf_counter() - t0) * 1e3


def render(target: Target, camera: CameraLike, width: int, height: int, *,
           cull: str = "back", frustum: bool = True, cones: bool = True,
           occlusion: bool = False, config: RasterConfig | None = None,
           reversed_z: bool = False, clip_planes: Any = None, window: Any = None) -> Frame:
    """Render ``target`` (Mesh or Scene, or a trimesh Trimesh or Scene) with the NumPy
    twin; same arguments and outputs as `Renderer.render` (the same culling code decides
    what is drawn).

    ``config`` only matters for the tile size used by binning; like on the device, it never
    changes the image. ``occlusion``: two-phase occlusion culling with the OpenCL renderer's
    schedule (`clraster.pipeline.twophase`); this function keeps no history, so it renders what a
    fresh `clraster.Renderer`'s first frame does (the nearest clusters first). For the
    frames after that, keep a `Renderer` (this module's) across calls.
    """
    return Renderer(width, height, config=config).render(
        target, camera, cull=cull, frustum=frustum, cones=cones, occlusion=occlusion,
        reversed_z=reversed_z, clip_planes=clip_planes, window=window)


def draw_pass(pool, fd: FrameDraws, params: FrameParams, config: RasterConfig,
              totals: FrameTotals, into: Images | None = None) -> Images:
    """The twin's stage chain over the draws ``fd`` of ``pool``: vertex → setup → bin →
    raster (its vertex stream, made by `vertex.transform_draws`, is what each setup
    work-item of kernels/setup.cl makes for its draw) into ``into`` (an earlier pass's
    images, not modified; None: clear), streamed in batches within ``config``'s budget by
    the renderer's own batching function (`clraster.pipeline.streaming.stream_draws`), so
    the twin's memory per pass is bounded like the device's and it runs the same passes.
    Adds the counts and host times to ``totals``; returns the new images."""

    def one_pass(batch: FrameDraws, max_entries: int | None, into: Images | None
                 ) -> Images:
        return _one_pass(pool, batch, params, config, totals, into, max_entries)

    return stream_draws(fd, config.batch_triangles, config.batch_entries, one_pass, into)


def _one_pass(pool, fd: FrameDraws, params: FrameParams, config: RasterConfig,
              totals: FrameTotals, into: Images | None, max_entries: int | None) -> Images:
    """One pass of the twin's stage chain, as `clraster.pipeline.stages.chain.StageChain.draw`
    (``max_entries``: over it, in clipped pieces or bin entries,
    `clraster.pipeline.params.BinBudgetExceeded` is raised and nothing is counted)."""
    w, h = params.width, params.height
    if fd.n_tris == 0:
        if into is not None:
            return into
        return (np.ones((h, w), np.float32), np.full((h, w), -1, np.int32),
                np.zeros((h, w, 3), np.float32))
    t0 = time.perf_counter()
    clip, oc, win = vertex_.transform_draws(pool, fd, params.kx, params.ky, w, h)
    tri_verts, ids = setup_.draw_triangles(pool, fd)
    st = setup_.setup(clip, oc, win, tri_verts, ids, w, h, params.cull, params.kx, params.ky,
                      setup_.object_clip(pool, fd, params.reversed_z),
                      setup_.draw_mirrored(pool, fd), params.reversed_z,
                      setup_.user_distances(pool, fd), fd.uclip)
    t2 = time.perf_counter()
    if max_entries is not None and st.clip_pieces.size > max_entries:
        raise BinBudgetExceeded(st.clip_pieces.size, max_entries)
    order = bin_.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = bin_.bin_pieces(allp, order, w, h, config, max_entries)
    t3 = time.perf_counter()
    depth, ids_img, bary, tested, passed = raster_.raster(st.clip_bary, tile_start, entries,
                                                          w, h, config, into=into,
                                                          window=params.window)
    t4 = time.perf_counter()
    totals.add_status(st.status)
    totals.clip_pieces += int(st.clip_pieces.size)
    totals.binned_entries += int(entries.size)
    totals.fragments_tested += tested
    totals.fragments_passed += passed
    # (the vertex transform is part of setup, as in kernels/setup.cl)
    for stage, ms in (("setup", t2 - t0), ("bin", t3 - t2), ("raster", t4 - t3)):
        totals.add_time(stage, ms * 1e3)
    return depth, ids_img, bary


def _hiz(width: int, height: int, zoff: float = 0.5):
    """The twin's Hi-Z step for `clraster.pipeline.twophase.two_phase`: the NumPy pyramid of the
    images' depth (key) buffer and the NumPy box test (twins of kernels/pyramid.cl); zoff:
    the key's offset (`FrameParams.zoff`). With same_depth, the pyramid of the previous
    call is tested again (the renderer's `_hiz`)."""
    last: list = []

    def hiz(images: Images, rows: np.ndarray, vp32: np.ndarray, same_depth: bool = False
            ) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        if not same_depth or not last:
            last[:] = [pyramid_.build(images[0])]
        verdict = pyramid_.test_boxes(last[0], rows[:3].T, rows[3:].T, vp32.reshape(4, 4),
                                      width, height, zoff)
        return verdict, (time.perf_counter() - t0) * 1e3

    return hiz
