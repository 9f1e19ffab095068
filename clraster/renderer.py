"""The OpenCL renderer: runs vertex → setup → bin → raster for one frame."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from .config import RasterConfig, guard_band_factors
from .device import default_context
from .frame import Frame, FrameStats
from .inputs import check_cull, check_mesh, check_size, mvp_matrix
from .stages._buffers import GrowBuffer
from .stages.bin import BinStage
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
        self._positions = GrowBuffer(self.context)
        self._faces = GrowBuffer(self.context)
        self._mesh = None

    def _upload(self, mesh) -> None:
        if self._mesh is mesh:
            return
        v, f = check_mesh(mesh)
        v, f = np.ascontiguousarray(v), np.ascontiguousarray(f)
        cl.enqueue_copy(self.queue, self._positions.ensure(v.nbytes), v)
        cl.enqueue_copy(self.queue, self._faces.ensure(f.nbytes), f)
        self._mesh = mesh

    def render(self, mesh, camera, *, cull: str = "back") -> Frame:
        """Render ``mesh`` (a `clraster.Mesh`) seen by ``camera``.

        Args:
            cull: "back" (drop faces that are clockwise in NDC, i.e. counter-clockwise is
                front, the OpenGL default), "front", or "none".

        Returns:
            A `Frame` (depth, triangle_id, barycentrics, stats); see its docstring for the
            conventions. Triangles with a NaN/Inf vertex are dropped and counted in
            ``stats.invalid``.
        """
        check_cull(cull)
        w, h = self.width, self.height
        mvp = mvp_matrix(camera, w, h)
        verts, faces = check_mesh(mesh)
        n, m = verts.shape[0], faces.shape[0]
        if m == 0:
            return Frame.empty(w, h)
        kx, ky = guard_band_factors(w, h)
        q = self.queue
        self._upload(mesh)
        ev_v = self.vertex.run(q, self._positions.buf, n, mvp, kx, ky, w, h)
        cb = self.vertex.buffers
        p, ev_s = self.setup.run(q, cb.clip.buf, cb.outcode.buf, cb.win.buf, self._faces.buf,
                                 m, w, h, cull, kx, ky)
        sb = self.setup.buffers
        e, ev_b = self.binning.run(q, sb.status.buf, sb.clip_count.buf, sb.clip_offset.buf,
                                   sb.pieces.buf, sb.clip_pieces.buf, m, w, h)
        bb = self.binning.buffers
        depth, ids, bary, tstats, ev_r = self.raster.run(
            q, sb.clip_bary.buf, bb.tile_start.buf, bb.entries.buf, w, h)
        status = np.empty(m, np.uint8)
        cl.enqueue_copy(q, status, sb.status.buf, is_blocking=True)
        stats = FrameStats.from_status(
            status, clip_pieces=p, binned_entries=e,
            fragments_tested=int(tstats[:, 0].sum()), fragments_passed=int(tstats[:, 1].sum()))
        stats.timings_ms = {
            "vertex": _ms([ev_v]), "setup": _ms(ev_s), "bin": _ms(ev_b), "raster": _ms([ev_r])}
        return Frame(depth, ids, bary, stats)


def _ms(events: list[cl.Event]) -> float:
    """Sum of device execution times of ``events`` in milliseconds."""
    return sum((ev.profile.end - ev.profile.start) for ev in events) * 1e-6
