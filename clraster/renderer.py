"""The OpenCL renderer: cull → vertex → setup → bin → raster for one frame."""

from __future__ import annotations

import time

import numpy as np
import pyopencl as cl

from .config import RasterConfig, guard_band_factors
from .device import default_context
from .drawlist import PlanCache, plan_frame
from .frame import Frame, FrameStats
from .inputs import check_cull, check_size
from .stages.bin import BinStage
from .stages.geometry import GeometryStage
from .stages.raster import RasterStage
from .stages.setup import SetupStage
from .stages.vertex import VertexStage


class Renderer:
    """Rasterizes meshes on an OpenCL device into depth, triangle-id and barycentric buffers.

    Args:
        width, height: image size in pixels, 1..16384.
        config: tunables (tile size, bin chunks); they never change the output.
        context: an OpenCL context; default `clraster.device.default_context()` (honours
            PYOPENCL_CTX, else the first PoCL CPU device).

    Device buffers are kept and grown between frames; programs are built once per context
    and config. A Renderer is not thread-safe; use one per thread.
    """

    def __init__(self, width: int, height: int, *, config: RasterConfig | None = None,
                 context: cl.Context | None = None) -> None:
        self.width, self.height = check_size(width, height)
        self.config = config or RasterConfig()
        self.context = context or default_context()
        dev = self.context.devices[0]
        need = 12 * self.width * self.height
        if need > dev.max_mem_alloc_size:
            raise ValueError(f"{self.width}x{self.height} needs a {need / 2**20:.0f} MiB "
                             f"barycentric buffer; {dev.name} allocates at most "
                             f"{dev.max_mem_alloc_size / 2**20:.0f} MiB per buffer")
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE)
        self.vertex = VertexStage(self.context, self.config)
        self.setup = SetupStage(self.context, self.config)
        self.binning = BinStage(self.context, self.config)
        self.raster = RasterStage(self.context, self.config)
        self.geometry = GeometryStage(self.context)
        self._plans = PlanCache()

    def render(self, target, camera, *, cull: str = "back", frustum: bool = True,
               cones: bool = True) -> Frame:
        """Render ``target`` (a `clraster.Mesh` or `clraster.Scene`) seen by ``camera``.

        Args:
            cull: "back" (drop faces that are clockwise in NDC, i.e. counter-clockwise is
                front, the OpenGL default), "front", or "none".
            frustum: cull instances and clusters against the view frustum through their
                BVHs first. Conservative: it never changes the image, only the work.
            cones: cull clusters whose normal cone faces away (with cull "back"/"front").
                Conservative too.

        Returns:
            A `Frame` (depth, triangle_id, barycentrics, stats); see its docstring for the
            conventions. For a Scene, triangle ids are ``scene.face_base[instance] + face``
            (`Scene.split_ids` splits them). Triangles with a NaN/Inf vertex are dropped
            and counted in ``stats.invalid``.
        """
        check_cull(cull)
        w, h = self.width, self.height
        t0 = time.perf_counter()
        plan = plan_frame(target, camera, w, h, cull=cull, frustum=frustum, cones=cones,
                          cache=self._plans)
        fd = plan.frame
        t_cull = (time.perf_counter() - t0) * 1e3
        n_draws, m = fd.draws.shape[0], fd.n_tris
        counts = plan.draw_list.counts
        if m == 0:
            return Frame.empty(w, h, FrameStats.from_counts(counts, np.zeros(0, np.uint8)))
        kx, ky = guard_band_factors(w, h)
        q = self.queue
        self.geometry.upload_pool(q, plan.pool)
        self.geometry.upload_frame(q, fd)
        geo = self.geometry.buffers
        ev_v = self.vertex.run(q, geo, n_draws, fd.n_verts, kx, ky, w, h)
        cb = self.vertex.buffers
        p, ev_s = self.setup.run(q, cb.clip.buf, cb.outcode.buf, cb.win.buf, geo, n_draws, m,
                                 w, h, cull, kx, ky)
        sb = self.setup.buffers
        e, ev_b = self.binning.run(q, sb.status.buf, sb.clip_count.buf, sb.clip_offset.buf,
                                   sb.pieces.buf, sb.clip_pieces.buf, m, w, h)
        bb = self.binning.buffers
        depth, ids, bary, tstats, ev_r = self.raster.run(
            q, sb.clip_bary.buf, bb.tile_start.buf, bb.entries.buf, w, h)
        status = np.empty(m, np.uint8)
        cl.enqueue_copy(q, status, sb.status.buf, is_blocking=True)
        stats = FrameStats.from_counts(
            counts, status, clip_pieces=p, binned_entries=e,
            fragments_tested=int(tstats[:, 0].sum()), fragments_passed=int(tstats[:, 1].sum()))
        stats.timings_ms = {"cull (host)": t_cull, "vertex": _ms([ev_v]), "setup": _ms(ev_s),
                            "bin": _ms(ev_b), "raster": _ms([ev_r])}
        return Frame(depth, ids, bary, stats)


def _ms(events: list[cl.Event]) -> float:
    """Sum of device execution times of ``events`` in milliseconds."""
    return sum((ev.profile.end - ev.profile.start) for ev in events) * 1e-6
