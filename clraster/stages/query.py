"""Exact occlusion queries, host side (kernels/query.cl).

The boxes (reference.query.box_geometry: 12 triangles per box, clusters of 10 boxes drawn in
box order) go through this stage's own copies of the renderer's geometry, vertex, setup
(cull "none") and binning stages — the same kernels and programs, separate buffers, so a
query never disturbs a renderer's state — and then one work-item per tile walks the tile's
list read-only against the depth buffer (query_tiles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ..config import RasterConfig, guard_band_factors
from ..device import program
from ..drawlist import FrameDraws
from ._buffers import GrowBuffer
from .bin import BinStage
from .geometry import GeometryStage
from .setup import SetupStage
from .vertex import VertexStage


@dataclass
class QueryBuffers:
    """Query outputs, K boxes: samples uint32 (K,) per-box counters (a box covers at most
    W·H ≤ 2**28 pixels); order_error int32 (1,) set when a tile list is not in box order."""

    samples: GrowBuffer
    order_error: GrowBuffer


class QueryStage:
    """Draws boxes through vertex → setup → bin and counts their passing samples."""

    def __init__(self, ctx: cl.Context, config: RasterConfig | None = None) -> None:
        self.config = config or RasterConfig()
        self.kernel = cl.Kernel(program(ctx, "query", self.config.build_options()),
                                "query_tiles")
        self.geometry = GeometryStage(ctx)
        self.vertex = VertexStage(ctx, self.config)
        self.setup = SetupStage(ctx, self.config)
        self.binning = BinStage(ctx, self.config)
        self.buffers = QueryBuffers(GrowBuffer(ctx), GrowBuffer(ctx))

    def run(self, queue: cl.CommandQueue, pool, fd: FrameDraws, n_boxes: int,
            depth_buf: cl.Buffer, width: int, height: int
            ) -> tuple[np.ndarray, dict[str, list[cl.Event]]]:
        """Count samples passed for the ``n_boxes`` boxes of (pool, fd) — from
        `clraster.reference.query.box_geometry` — against the float32 (H, W) depth buffer
        ``depth_buf``; blocking.

        Returns int64 (n_boxes,) counts and the profiling events per stage.
        """
        kx, ky = guard_band_factors(width, height)
        n_draws, m = fd.draws.shape[0], fd.n_tris
        self.geometry.upload_pool(queue, pool)
        self.geometry.upload_frame(queue, fd)
        geo = self.geometry.buffers
        ev_v = self.vertex.run(queue, geo, n_draws, fd.n_verts, kx, ky, width, height)
        cb = self.vertex.buffers
        _p, ev_s = self.setup.run(queue, cb.clip.buf, cb.outcode.buf, cb.win.buf, geo, n_draws,
                                  m, width, height, "none", kx, ky)
        sb = self.setup.buffers
        _e, ev_b = self.binning.run(queue, sb.status.buf, sb.clip_count.buf,
                                    sb.clip_offset.buf, sb.pieces.buf, sb.clip_pieces.buf, m,
                                    width, height)
        bb = self.binning.buffers
        b = self.buffers
        samples = b.samples.ensure(4 * n_boxes)
        flag = b.order_error.ensure(4)
        zero = np.zeros(1, np.uint32)
        ev_f = [cl.enqueue_fill_buffer(queue, samples, zero, 0, 4 * n_boxes),
                cl.enqueue_fill_buffer(queue, flag, zero, 0, 4)]
        tiles_x, tiles_y = self.config.tiles(width, height)
        ev_q = self.kernel(queue, (tiles_x * tiles_y,), (1,), bb.tile_start.buf,
                           bb.entries.buf, np.int32(width), np.int32(height),
                           np.int32(tiles_x), depth_buf, samples, flag)
        out = np.empty(n_boxes, np.uint32)
        err = np.zeros(1, np.int32)
        cl.enqueue_copy(queue, out, samples, is_blocking=False)
        cl.enqueue_copy(queue, err, flag, is_blocking=True)
        if err[0]:
            raise RuntimeError("occlusion query: a tile list is not in box order; the box "
                               "geometry must be drawn box after box (a bug in clraster)")
        return out.astype(np.int64), {"vertex": [ev_v], "setup": ev_s, "bin": ev_b,
                                      "query": ev_f + [ev_q]}
