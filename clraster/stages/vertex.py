"""Vertex stage host side: object → clip space (float4) and outcodes (kernels/vertex.cl)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pyopencl as cl

from ..config import RasterConfig
from ..device import program
from ._buffers import GrowBuffer


@dataclass
class ClipBuffers:
    """Vertex → setup boundary, N = number of vertices.

    clip: float32 (N, 4) clip-space positions. outcode: uint16 (N,) outcode bits
    (config.OC_*: 6 frustum bits, 4 guard-band bits, invalid, w <= 0).
    win: WINVERT_DTYPE (N,) viewport transform of the vertices that need no clipping.
    """

    clip: GrowBuffer
    outcode: GrowBuffer
    win: GrowBuffer
    mvp: cl.Buffer = field(repr=False)


class VertexStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        self.kernel = cl.Kernel(program(ctx, "vertex", config.build_options()), "vertex_transform")
        self.buffers = ClipBuffers(GrowBuffer(ctx), GrowBuffer(ctx), GrowBuffer(ctx),
                                   cl.Buffer(ctx, cl.mem_flags.READ_ONLY, 64))

    def run(self, queue: cl.CommandQueue, positions: cl.Buffer, n: int, mvp: np.ndarray,
            kx: np.float32, ky: np.float32, width: int, height: int) -> cl.Event:
        """Transform ``n`` float32 xyz positions by the row-major float32 (4, 4) ``mvp``."""
        b = self.buffers
        clip = b.clip.ensure(16 * n)
        oc = b.outcode.ensure(2 * n)
        cl.enqueue_copy(queue, b.mvp, np.ascontiguousarray(mvp, np.float32), is_blocking=False)
        return self.kernel(queue, (max(n, 1),), None, positions, np.uint32(n), b.mvp,
                           np.float32(kx), np.float32(ky), np.int32(width), np.int32(height),
                           clip, oc, b.win.ensure(16 * n))
