"""Line segments host side (kernels/lines.cl): setup, depth pass, id pass.

Three launches of one work-item per segment: line_setup (transform, clip, snap), line_depth
(pass 1: per-pixel atomic_min of the depth bits, fragment counts) and line_id (pass 2:
atomic_min of the segment index among the fragments at the minimum depth). The result does
not depend on how the work-items are scheduled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ...base.config import LINES_LOCAL, RasterConfig
from ...base.layout import LINE_DTYPE, ZMIN_CLEAR
from ..device import kernel, program
from ..features import local_size
from ._buffers import GrowBuffer

_CLEAR = np.array([ZMIN_CLEAR], np.uint32)  # ZMIN_CLEAR == IDMIN_CLEAR: both resolve buffers


@dataclass
class LineBuffers:
    """Device buffers, N segments, H × W image.

    positions: float32 (N, 2, 3) world endpoints. mvp: float32 (16,) row-major matrix.
    records: LINE_DTYPE (N,) set-up segments (clraster.base.layout.LINE_DTYPE, 32 bytes).
    counts: int32 (N, 2) fragments / fragments passed per segment.
    depth_in: float32 (H, W) input depth buffer (4 bytes when none is given).
    zmin: uint32 (H, W) minimum depth bits per pixel (0xFFFFFFFF: none).
    idmin: uint32 (H, W) minimum segment index at that depth (0xFFFFFFFF: none).
    """

    positions: GrowBuffer
    mvp: GrowBuffer
    records: GrowBuffer
    counts: GrowBuffer
    depth_in: GrowBuffer
    zmin: GrowBuffer
    idmin: GrowBuffer


class LineStage:
    def __init__(self, ctx: cl.Context) -> None:
        prg = program(ctx, "lines", RasterConfig().build_options())
        self.k_setup = kernel(prg, "line_setup")
        self.k_depth = kernel(prg, "line_depth")
        self.k_id = kernel(prg, "line_id")
        self.local = min(local_size(k, ctx.devices[0], LINES_LOCAL)
                         for k in (self.k_setup, self.k_depth, self.k_id))
        ro = cl.mem_flags.READ_ONLY
        self.buffers = LineBuffers(GrowBuffer(ctx, ro), GrowBuffer(ctx, ro), GrowBuffer(ctx),
                                   GrowBuffer(ctx), GrowBuffer(ctx, ro), GrowBuffer(ctx),
                                   GrowBuffer(ctx))

    def run(self, queue: cl.CommandQueue, segments: np.ndarray, mvp: np.ndarray, width: int,
            height: int, depth: np.ndarray | None, bias: np.float32
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
        """Draw float32 (N, 2, 3) ``segments`` (N ≥ 1) with the float32 (4, 4) matrix; blocking.

        Returns line_id int32 (H, W), depth float32 (H, W), status int32 (N,) (LS_*),
        fragments and fragments passed.
        """
        n = segments.shape[0]
        npix = width * height
        b = self.buffers
        pos = b.positions.ensure(segments.nbytes, "segment buffer")
        mbuf = b.mvp.ensure(64)
        rec = b.records.ensure(LINE_DTYPE.itemsize * n, "segment setup buffer")
        counts = b.counts.ensure(8 * n, "segment count buffer")
        zmin = b.zmin.ensure(4 * npix, "depth resolve buffer")
        idmin = b.idmin.ensure(4 * npix, "id resolve buffer")
        dbuf = b.depth_in.ensure(4 * npix if depth is not None else 4, "depth buffer")
        cl.enqueue_copy(queue, pos, segments, is_blocking=False)
        cl.enqueue_copy(queue, mbuf, mvp, is_blocking=False)
        if depth is not None:
            cl.enqueue_copy(queue, dbuf, depth, is_blocking=False)
        cl.enqueue_fill_buffer(queue, zmin, _CLEAR, 0, 4 * npix)
        cl.enqueue_fill_buffer(queue, idmin, _CLEAR, 0, 4 * npix)
        gsize = ((n + self.local - 1) // self.local * self.local,)
        lsize = (self.local,)
        w, h, nn = np.int32(width), np.int32(height), np.uint32(n)
        has = np.int32(depth is not None)
        self.k_setup(queue, gsize, lsize, pos, nn, mbuf, w, h, rec)
        self.k_depth(queue, gsize, lsize, rec, nn, w, h, dbuf, has, np.float32(bias), zmin,
                     counts)
        self.k_id(queue, gsize, lsize, rec, nn, w, h, dbuf, has, np.float32(bias), zmin, idmin)
        recs = np.empty(n, LINE_DTYPE)
        cnt = np.empty((n, 2), np.int32)
        zb = np.empty((height, width), np.uint32)
        ib = np.empty((height, width), np.uint32)
        cl.enqueue_copy(queue, recs, rec, is_blocking=False)
        cl.enqueue_copy(queue, cnt, counts, is_blocking=False)
        cl.enqueue_copy(queue, zb, zmin, is_blocking=False)
        cl.enqueue_copy(queue, ib, idmin, is_blocking=True)
        hit = ib != 0xFFFFFFFF
        line_id = np.where(hit, ib, 0).astype(np.int32)
        line_id[~hit] = -1
        depth_out = np.where(hit, zb, np.float32(1).view(np.uint32)).view(np.float32)
        frags = int(cnt[:, 0].sum(dtype=np.int64))
        passed = int(cnt[:, 1].sum(dtype=np.int64))
        return line_id, depth_out, recs["status"].copy(), frags, passed
