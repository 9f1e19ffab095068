"""Triangle setup host side (kernels/setup.cl): status per triangle, setup records (pieces)
for unclipped survivors, then count → scan → write for clipped triangles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
from pyopencl.scan import GenericScanKernel

from ..config import CULL_MODES, PIECE_DTYPE, RasterConfig
from ..device import program
from ._buffers import GrowBuffer


@dataclass
class SetupBuffers:
    """Setup → binning boundary, M = number of triangles, P = clipped pieces.

    pieces: PIECE_DTYPE (M,), slot t valid iff status[t] == ST_RASTER.
    status: uint8 (M,) config.ST_* per triangle.
    clip_count: int32 (M,) surviving pieces per clipped triangle (0 otherwise).
    clip_offset: int32 (M,) exclusive scan of clip_count.
    clip_total: int32 (1,) P.
    clip_pieces: PIECE_DTYPE (P,) in submission order. clip_bary: float32 (P, 3, 3) parent
    barycentrics of each clipped piece's vertices.
    """

    pieces: GrowBuffer
    status: GrowBuffer
    clip_count: GrowBuffer
    clip_offset: GrowBuffer
    clip_total: GrowBuffer
    clip_pieces: GrowBuffer
    clip_bary: GrowBuffer


class SetupStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        prg = program(ctx, "setup", config.build_options())
        self.k_setup = cl.Kernel(prg, "setup_triangles")
        self.k_clipped = cl.Kernel(prg, "setup_clipped")
        self.scan = GenericScanKernel(
            ctx, np.int32,
            arguments="__global const int *cnt, __global int *off, __global int *total, "
                      "const int n",
            input_expr="cnt[i]", scan_expr="a+b", neutral="0",
            output_statement="off[i] = prev_item; if (i + 1 == n) total[0] = item;")
        self.buffers = SetupBuffers(*(GrowBuffer(ctx) for _ in range(7)))

    def run(self, queue: cl.CommandQueue, clip: cl.Buffer, outcode: cl.Buffer,
            win: cl.Buffer, faces: cl.Buffer, m: int, width: int, height: int, cull: str,
            kx: np.float32, ky: np.float32) -> tuple[int, list[cl.Event]]:
        """Run setup for ``m`` triangles. Returns (P = clipped pieces, profiling events)."""
        b = self.buffers
        rec = PIECE_DTYPE.itemsize
        args = (clip, outcode, win, faces, np.uint32(m), np.int32(width), np.int32(height),
                np.int32(CULL_MODES[cull]), np.float32(kx), np.float32(ky))
        gsize = (max(m, 1),)
        ev = [self.k_setup(queue, gsize, None, *args, b.pieces.ensure(rec * m),
                           b.status.ensure(m), b.clip_count.ensure(4 * m))]
        total = np.zeros(1, np.int32)
        if m:
            cnt = cla.Array(queue, (m,), np.int32, data=b.clip_count.buf)
            off = cla.Array(queue, (m,), np.int32, data=b.clip_offset.ensure(4 * m))
            tot = cla.Array(queue, (1,), np.int32, data=b.clip_total.ensure(4))
            ev.append(self.scan(cnt, off, tot, np.int32(m), size=m, queue=queue))
            cl.enqueue_copy(queue, total, b.clip_total.buf)
        p = int(total[0])
        if p:
            ev.append(self.k_clipped(queue, gsize, None, *args, b.clip_count.buf,
                                     b.clip_offset.buf, b.clip_pieces.ensure(rec * p),
                                     b.clip_bary.ensure(36 * p)))
        else:  # the kernels still need valid buffer arguments downstream
            b.clip_pieces.ensure(rec)
            b.clip_bary.ensure(36)
        return p, ev
