"""Exact occlusion queries, host side (kernels/query.cl).

The boxes (clraster.pipeline.boxes.box_geometry: 12 triangles per box, clusters of 10 boxes
drawn in box order) go through this stage's own `StageChain` of geometry, setup (with the
vertex transform; cull "none") and binning stages — the same kernels and programs as the
renderer's, separate buffers, so a query never disturbs a renderer's state — and then one
work-item per tile walks the tile's list read-only against the depth buffer (query_tiles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ..boxes import BoxGeometry
from ..device import event_ms, kernel, program
from ..draws import FrameDraws
from ..params import FrameParams, FrameTotals
from ._buffers import GrowBuffer
from .chain import StageChain


@dataclass
class QueryBuffers:
    """Query outputs, K boxes: samples uint32 (K,) per-box counters (a box covers at most
    W·H ≤ 2**28 pixels); order_error int32 (1,) set when a tile list is not in box order."""

    samples: GrowBuffer
    order_error: GrowBuffer


class QueryStage:
    """Draws boxes through setup → bin (its own `StageChain`) and counts their
    passing samples."""

    def __init__(self, ctx: cl.Context, config: RasterConfig | None = None) -> None:
        self.config = config or RasterConfig()
        self.kernel = kernel(program(ctx, "query", self.config.build_options()),
                                "query_tiles")
        self.chain = StageChain(ctx, self.config, raster=False)
        self.buffers = QueryBuffers(GrowBuffer(ctx), GrowBuffer(ctx))

    def run(self, queue: cl.CommandQueue, pool: BoxGeometry, fd: FrameDraws, n_boxes: int,
            depth_buf: cl.Buffer, width: int, height: int
            ) -> tuple[np.ndarray, dict[str, float]]:
        """Count samples passed for the ``n_boxes`` boxes of (pool, fd) — from
        `clraster.pipeline.boxes.box_geometry` — against the float32 (H, W) depth buffer
        ``depth_buf``; blocking.

        Returns int64 (n_boxes,) counts and the device milliseconds per stage (setup, bin,
        query).
        """
        params = FrameParams.make(width, height, self.config, "none")
        totals = FrameTotals()
        bins = self.chain.bin(queue, pool, fd, params, totals)
        b = self.buffers
        samples = b.samples.ensure(4 * n_boxes)
        flag = b.order_error.ensure(4)
        zero = np.zeros(1, np.uint32)
        ev_f = [cl.enqueue_fill_buffer(queue, samples, zero, 0, 4 * n_boxes),
                cl.enqueue_fill_buffer(queue, flag, zero, 0, 4)]
        ev_q = self.kernel(queue, (params.n_tiles,), (1,), bins.tile_start.buf,
                           bins.entries.buf, np.int32(width), np.int32(height),
                           np.int32(params.tiles_x), depth_buf, samples, flag)
        totals.add_events("query", ev_f + [ev_q])
        out = np.empty(n_boxes, np.uint32)
        err = np.zeros(1, np.int32)
        cl.enqueue_copy(queue, out, samples, is_blocking=False)
        cl.enqueue_copy(queue, err, flag, is_blocking=True)
        if err[0]:
            raise RuntimeError("occlusion query: a tile list is not in box order; the box "
                               "geometry must be drawn box after box (a bug in clraster)")
        totals.settle(event_ms)   # the blocking read above waited for everything before it
        return out.astype(np.int64), totals.timings_ms
