"""Device copies of the geometry pool (per scene) and of the per-frame draw records."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ...base.layout import DRAW_INSIDE, DRAW_NO_CLIP
from ..drawlist import GeometryPool
from ..draws import FrameDraws
from ._buffers import GrowBuffer


@dataclass
class GeometryBuffers:
    """Scene → setup boundary (see drawlist.GeometryPool for shapes and dtypes).

    positions, clusters, local_tris, face_ids: the pool, uploaded once per scene (not its
    vert_ids: the kernels read a cluster's positions in place, so the pool must store them
    in cluster order, vert_ids the identity — `GeometryStage.upload_pool` checks it).
    draws: DRAW_DTYPE (D,), mvps: float32 (I, 16), mvps64: float64 (I, 16) and zrows:
    float64 (I, 4), uplanes: float64 (I, K, 4) (draws.FrameDraws), uploaded for every
    pass. n_user: K, the user clip planes of the draws uploaded last; uclip: the bits of
    those that clip (`FrameDraws.uclip`).
    n_draws, n_tris: D and the size of the triangle stream of the draws uploaded last
    (draws.FrameDraws). may_clip: whether setup can clip any of their triangles: False when
    every draw is inside the frustum by a margin (DRAW_INSIDE: setup's vertices get no clip
    bits there) or inside the near and far planes and the
    guard band by one (DRAW_NO_CLIP, the host's test), and no user plane clips (uclip 0),
    so that setup need not wait to learn that none was clipped (`SetupStage.run`).
    host_clip_test: may_clip is False thanks to DRAW_NO_CLIP draws (the host's test, which
    `SetupStage.check_unclipped` checks after the pass).
    """

    positions: GrowBuffer
    clusters: GrowBuffer
    local_tris: GrowBuffer
    face_ids: GrowBuffer
    draws: GrowBuffer
    mvps: GrowBuffer
    mvps64: GrowBuffer
    zrows: GrowBuffer
    uplanes: GrowBuffer
    n_draws: int = 0
    n_user: int = 0
    uclip: int = 0
    n_tris: int = 0
    may_clip: bool = True
    host_clip_test: bool = False


class GeometryStage:
    def __init__(self, ctx: cl.Context) -> None:
        # the pool's buffers, then the per-pass records, written by the host (`upload_frame`)
        self.buffers = GeometryBuffers(*(GrowBuffer(ctx) for _ in range(4)),  # type: ignore[arg-type]  # one GrowBuffer per buffer field
                                       *(GrowBuffer(ctx, host=True) for _ in range(5)))
        self._pool: GeometryPool | None = None

    def upload_pool(self, queue: cl.CommandQueue, pool: GeometryPool) -> None:
        if pool is self._pool:
            return
        b = self.buffers
        vids = np.asarray(pool.vert_ids)
        if not np.array_equal(vids, np.arange(vids.shape[0], dtype=vids.dtype)):
            raise ValueError("the geometry pool must store its positions in cluster order "
                             "(vert_ids the identity): the kernels read them in place")
        for gb, arr in ((b.positions, pool.positions), (b.clusters, pool.clusters),
                        (b.local_tris, pool.local_tris), (b.face_ids, pool.face_ids)):
            buf = gb.ensure(arr.nbytes, "geometry buffer")
            if arr.nbytes:
                cl.enqueue_copy(queue, buf, np.ascontiguousarray(arr), is_blocking=False)
        queue.finish()
        self._pool = pool

    def upload_frame(self, queue: cl.CommandQueue, fd: FrameDraws) -> GeometryBuffers:
        """Upload the draw records of ``fd`` (a frame's draws, or any subset of them);
        returns the buffers, the setup stage's input. Call while no enqueued
        command uses them: every pass waits for its raster before the next one uploads,
        and after one ended by an exception `StageChain` waits for what it left running.
        Where the device works in host memory (`GrowBuffer` host mode) the records are
        copied into the buffers' own arrays; five blocking writes were five commands,
        ~0.2 ms a pass before the first kernel could start."""
        b = self.buffers
        for gb, arr in ((b.draws, fd.draws), (b.mvps, fd.mvps), (b.mvps64, fd.mvps64),
                        (b.zrows, fd.zrows), (b.uplanes, fd.uplanes)):
            gb.ensure(arr.nbytes)
            if arr.nbytes:
                gb.write(queue, arr)
        b.n_draws, b.n_tris = int(fd.draws.shape[0]), fd.n_tris
        b.n_user, b.uclip = fd.n_user, fd.uclip
        flags = fd.draws["flags"]
        unclipped = (flags & (DRAW_INSIDE | DRAW_NO_CLIP)) != 0
        b.may_clip = bool((fd.n_user > 0 and fd.uclip != 0) or not unclipped.all())
        b.host_clip_test = not b.may_clip and bool(((flags & DRAW_NO_CLIP) != 0).any())
        return b
