"""Vertex stage host side: object → clip space (float4), outcodes and window positions of
every vertex of this frame's draws (kernels/vertex.cl)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ...base.layout import CLUSTER_MAX, VERTEX_LANES, WINXY_DTYPE
from ..device import kernel, program
from ..features import local_size
from ..params import FrameParams
from ._buffers import GrowBuffer
from .geometry import GeometryBuffers


@dataclass
class ClipBuffers:
    """Vertex → setup boundary, N = vertices in this frame's vertex stream.

    clip: float32 (N, 4) clip-space positions. outcode: uint16 (N,) outcode bits
    (config.OC_*: 6 frustum bits, 4 guard-band bits, invalid, w <= 0).
    win: WINXY_DTYPE (N,) snapped window x, y of the vertices that need no clipping.
    ucode: uint8 (N,) user clip plane bits (bit k: outside user plane k; 0 without planes).
    n_verts: N of the last run. (The double clip positions setup's value planes and clipper
    take are made by setup itself, for the corners it needs: kernels/setup.cl CLIP_IN.)
    """

    clip: GrowBuffer
    outcode: GrowBuffer
    win: GrowBuffer
    ucode: GrowBuffer
    n_verts: int = 0


class VertexStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        self.kernel = kernel(program(ctx, "vertex", config.build_options()), "vertex_transform")
        # one work-group per draw (kernels/vertex.cl): a device that cannot is refused here
        local_size(self.kernel, ctx.devices[0], CLUSTER_MAX // VERTEX_LANES, exact=True)
        self.buffers = ClipBuffers(*(GrowBuffer(ctx) for _ in range(4)))  # type: ignore[arg-type]  # one GrowBuffer per buffer field

    def run(self, queue: cl.CommandQueue, geo: GeometryBuffers, params: FrameParams
            ) -> tuple[ClipBuffers, list[cl.Event]]:
        """Transform the vertices of the uploaded draws (geo) into a vertex stream of
        ``geo.n_verts`` entries. Returns the buffers and the profiling events."""
        b = self.buffers
        n_draws, n_verts = geo.n_draws, geo.n_verts
        group = CLUSTER_MAX // VERTEX_LANES   # work-items per draw (kernels/vertex.cl)
        ev = self.kernel(queue, (max(n_draws, 1) * group,), (group,),
                         geo.positions.buf, geo.clusters.buf, geo.draws.buf,
                         np.uint32(n_draws), geo.mvps.buf, np.float32(params.kx),
                         np.float32(params.ky), np.int32(params.width), np.int32(params.height),
                         b.clip.ensure(16 * n_verts), b.outcode.ensure(2 * n_verts),
                         b.win.ensure(WINXY_DTYPE.itemsize * n_verts), geo.uplanes.buf,
                         np.int32(geo.n_user), b.ucode.ensure(n_verts))
        b.n_verts = n_verts
        return b, [ev]
