"""Triangle setup host side (kernels/setup.cl): the draws' vertices (object → clip space,
outcodes, window positions: the vertex stage, made by each draw's work-item), status per
triangle, setup records (pieces) for unclipped survivors; the clipped triangles listed,
then clipped once into scratch rows → scan → moved to their places (or, where those rows
would pass CLIP_SCRATCH_BYTES, count → scan → write)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import pyopencl as cl

from ...base.config import CLIP_SCRATCH_BYTES, SCAN_CHUNKS, RasterConfig
from ...base.layout import PIECE_DTYPE
from ..device import kernel, program, wait
from ..features import local_size
from ..params import BinBudgetExceeded, FrameParams
from ._buffers import GrowBuffer
from .geometry import GeometryBuffers


@dataclass
class SetupBuffers:
    """Setup → binning boundary, M = triangles in this frame's triangle stream (the draws'
    triangles, draw after draw), P = clipped pieces.

    pieces: PIECE_DTYPE (M,), slot t valid iff status[t] == ST_RASTER.
    status: uint8 (M,) config.ST_* per triangle.
    clip_count: int32 (M,) surviving pieces per clipped triangle, written only where
    status[t] == ST_CLIPPED (undefined elsewhere: read it through status).
    clip_offset: int32 (M,) exclusive scan of the clipped triangles' piece counts (the
    others count 0), written only when some triangle is clipped.
    clip_total: int32 (1,) P.
    clip_pieces: PIECE_DTYPE (P,) in submission order. clip_bary: float32 (P, 3, 3) parent
    barycentrics of each clipped piece's vertices.
    clip_list: int32 (M, 2) (draw, local triangle) of each clipped triangle, the first
    C = the count setup_triangles leaves in `SetupStage.n_clipped` entries valid, in no fixed
    order: the clipper's kernels run over these alone.
    tile1: int32 (M,) what binning needs of each slot without reading its 96-byte record
    (kernels/common.h TILE1_*): the one tile of a piece whose pixel box lies in one tile,
    the top-left tile and tile mask of one over at most 2 × 2 tiles, −1 nothing to bin,
    −2 pieces to walk (clipped triangles, pieces over more tiles).
    n_tris, n_clip_pieces: M and P of the last run.
    """

    pieces: GrowBuffer
    status: GrowBuffer
    clip_count: GrowBuffer
    clip_offset: GrowBuffer
    clip_total: GrowBuffer
    clip_pieces: GrowBuffer
    clip_bary: GrowBuffer
    tile1: GrowBuffer
    clip_list: GrowBuffer
    n_tris: int = 0
    n_clip_pieces: int = 0


class SetupStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        prg = program(ctx, "setup", config.build_options())
        self.k_setup = kernel(prg, "setup_triangles")
        self.k_clipped = kernel(prg, "setup_clipped")
        self.k_count = kernel(prg, "setup_count_clipped")
        self.k_scratch = kernel(prg, "setup_clip_scratch")
        self.k_place = kernel(prg, "setup_clip_place")
        # one work-group per draw (setup_triangles: one work-item, the draw's triangles
        # SETUP_LANES at a time)
        local_size(self.k_setup, ctx.devices[0], 1, exact=True)
        # (the clipper's kernels: work-groups of one, a listed clipped triangle each)
        self.k_partials = kernel(prg, "scan_partials")
        self.k_offsets = kernel(prg, "scan_offsets")
        self.buffers = SetupBuffers(*(GrowBuffer(ctx) for _ in range(9)))  # type: ignore[arg-type]  # one GrowBuffer per buffer field
        self.buffers.clip_total = GrowBuffer(ctx, host=True)   # read after a wait
        self.partial = GrowBuffer(ctx)
        # setup_clip_scratch's pieces and parent barycentrics, `bound` rows per clipped
        # triangle, before setup_clip_place moves them (at most CLIP_SCRATCH_BYTES in all)
        self.scratch = GrowBuffer(ctx)
        self.scratch_bary = GrowBuffer(ctx)
        #: triangles ST_CLIPPED (setup_triangles), the length of `SetupBuffers.clip_list`
        self.n_clipped = GrowBuffer(ctx, host=True)

    def prepare(self, queue: cl.CommandQueue) -> None:
        """Zero the count of clipped triangles `run` reads; call before the pass's first kernel,
        while the queue is idle. (As a command enqueued behind a running kernel, this
        host-to-device write blocked the calling thread, GIL held, until that kernel was
        done: ~15 ms of a 3.5M-triangle frame in which no other Python thread ran,
        tests/test_processes.py. In host mode it is a plain store.)"""
        self.n_clipped.write(queue, np.zeros(1, np.int32))

    def check_unclipped(self, queue: cl.CommandQueue, geo: GeometryBuffers) -> None:
        """After the pass's wait: where `run` did not wait for the clip count because of
        the host's clip test (``geo``'s draws all DRAW_INSIDE or DRAW_NO_CLIP, some of them
        the latter), check that setup found no triangle to clip.
        The host's tests are conservative by a margin, so this never fires; if it did, the
        triangles to clip were dropped from the image, and that must not pass silently.
        (A read of host memory where the device shares it.)"""
        # (draws all DRAW_INSIDE have no clip bits at all: setup skips their vertices'
        # outcode tests, so there is nothing to check, and no read on a discrete device)
        if not geo.host_clip_test or not geo.n_tris:
            return
        if int(self.n_clipped.read(queue, np.int32, 1)[0]):
            raise RuntimeError(
                "internal error: setup clipped triangles of draws the host had found to need "
                "no clipping (DRAW_INSIDE / DRAW_NO_CLIP), so the image lacks them. Please "
                "report it with the camera and mesh; RasterConfig is not the cause")

    def run(self, queue: cl.CommandQueue, geo: GeometryBuffers, params: FrameParams,
            max_pieces: int | None = None) -> tuple[SetupBuffers, list[cl.Event]]:
        """Transform the vertices of the uploaded draws (geo) and set up their
        ``geo.n_tris`` triangles. Returns the buffers (n_clip_pieces = P) and the profiling
        events. ``max_pieces``: when P > max_pieces, raise
        `clraster.pipeline.params.BinBudgetExceeded` (P) before the clipped pieces are sized or
        written (a streamed frame splits the pass; None: no limit)."""
        b = self.buffers
        rec = PIECE_DTYPE.itemsize
        n_draws, m = geo.n_draws, geo.n_tris
        kx, ky = params.kx, params.ky
        # the pool and the float32 matrices (the vertices), the user planes (their codes
        # and the clipper's distances, common.h user_dist), and the float64 matrices and
        # depth rows (the double positions of the value planes and the clipper's inputs,
        # kernels/setup.cl CLIP_IN)
        draw_args = (geo.draws.buf, np.uint32(n_draws), geo.clusters.buf, geo.local_tris.buf,
                     geo.face_ids.buf, geo.positions.buf, geo.mvps64.buf,
                     geo.zrows.buf, geo.uplanes.buf, np.int32(geo.n_user), np.uint32(geo.uclip),
                     geo.mvps.buf)
        size = np.int32(params.width), np.int32(params.height)
        # setup_triangles: one work-item per draw; the clipper's kernels: one per clipped
        # triangle (its list, clip_list)
        n_clipped = cast(cl.Buffer, self.n_clipped.buf)   # zeroed by `prepare`
        ev = [self.k_setup(queue, (max(n_draws, 1),), (1,), *draw_args, *size,
                           np.int32(params.cull_mode), np.float32(kx), np.float32(ky),
                           np.int32(params.reversed_z), b.pieces.ensure(rec * m, "setup buffer"),
                           b.status.ensure(m),
                           np.int32(params.tiles_x), b.tile1.ensure(4 * m), n_clipped,
                           b.clip_count.ensure(4 * max(m, 1)),
                           b.clip_list.ensure(8 * max(m, 1)))]
        # Most passes clip nothing: then the clipper's count, the scan and their launches
        # are skipped; the wait here replaces the one after the scan. When no triangle can
        # be clipped (geo.may_clip: every draw inside the frustum by a margin, no clipping
        # user plane; a framed mesh) there is nothing to wait for: binning is enqueued
        # behind setup at once, saving the device's idle time between the two.
        if geo.may_clip:
            wait(queue)   # interruptibly, with the GIL free (device.wait)
            total = self.n_clipped.read(queue, np.int32, 1)
        else:
            total = np.zeros(1, np.int32)
        # bin's arguments (read for clipped slots only); clip_count is written by k_scratch
        # or k_count (setup_triangles zeroes the clipped slots' first)
        b.clip_offset.ensure(4 * max(m, 1))
        n_clip = int(total[0])
        clip_args = (*draw_args, *size, np.float32(kx), np.float32(ky),
                     np.int32(params.reversed_z), b.clip_list.buf, np.int32(n_clip))
        # the clipper once into scratch rows of `bound` pieces (then moved to their places)
        # where those fit CLIP_SCRATCH_BYTES, else twice: counting, then writing in place
        bound = 1 + 6 + int(geo.uclip).bit_count()   # pieces of one triangle at most
        once = n_clip * bound * (rec + 36) <= CLIP_SCRATCH_BYTES
        if m and n_clip:
            if once:
                ev.append(self.k_scratch(queue, (n_clip,), (1,), *clip_args, np.int32(bound),
                                         b.clip_count.buf,
                                         self.scratch.ensure(rec * bound * n_clip),
                                         self.scratch_bary.ensure(36 * bound * n_clip)))
            else:
                ev.append(self.k_count(queue, (n_clip,), (1,), *clip_args, b.clip_count.buf))
            chunks = np.uint32(min(SCAN_CHUNKS, m))
            part = self.partial.ensure(4 * SCAN_CHUNKS)
            ev.append(self.k_partials(queue, (int(chunks),), (1,), b.status.buf,
                                      b.clip_count.buf,
                                      np.uint32(m), chunks, part))
            ev.append(self.k_offsets(queue, (int(chunks),), (1,), b.status.buf,
                                     b.clip_count.buf,
                                     np.uint32(m), chunks, part, b.clip_offset.ensure(4 * m),
                                     b.clip_total.ensure(4)))
            wait(queue)
            total = b.clip_total.read(queue, np.int32, 1)
        else:
            total[0] = 0
        p = int(total[0])
        if max_pieces is not None and p > max_pieces:
            raise BinBudgetExceeded(p, max_pieces, ev)
        if p and once:
            ev.append(self.k_place(queue, (n_clip,), (1,), b.clip_list.buf, np.int32(n_clip),
                                   np.int32(bound), geo.draws.buf, b.clip_count.buf,
                                   b.clip_offset.buf, self.scratch.buf, self.scratch_bary.buf,
                                   b.clip_pieces.ensure(rec * p), b.clip_bary.ensure(36 * p)))
        elif p:
            ev.append(self.k_clipped(queue, (n_clip,), (1,), *clip_args, b.clip_count.buf,
                                     b.clip_offset.buf, b.clip_pieces.ensure(rec * p),
                                     b.clip_bary.ensure(36 * p)))
        else:  # the kernels still need valid buffer arguments downstream
            b.clip_pieces.ensure(rec)
            b.clip_bary.ensure(36)
        b.n_tris, b.n_clip_pieces = m, p
        return b, ev
