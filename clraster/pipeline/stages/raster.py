"""Tile raster host side (kernels/raster.cl): one work-item per segment of a row of tiles
(`segments`)."""

from __future__ import annotations

import math
import mmap
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import pyopencl as cl

from ...base.config import CLEAR_SHARES, SEG_PIXELS, RasterConfig
from ..arraypool import ArrayPool
from ..device import device_busy, kernel, program, shares_host_memory, wait
from ..params import FrameParams
from ._buffers import GrowBuffer
from .bin import BinBuffers
from .setup import SetupBuffers


def zeros_array(shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """A zero-filled page-aligned array in fresh anonymous memory: the OS maps its pages as
    zeros on first touch, so the parts never written cost nothing (the barycentrics of a
    cleared frame). Not for arrays a kernel then writes all over: faulting fresh pages
    inside the raster kernel made spot at 1080p 1.23x slower than reused memory."""
    n = math.prod(int(s) for s in shape)   # (np.prod of a small tuple: ~10 µs here)
    mm = mmap.mmap(-1, max(n * np.dtype(dtype).itemsize, 1))
    return np.frombuffer(mm, dtype, count=n).reshape(shape)


def segments(params: FrameParams, tile_log2: int) -> int:
    """Work-items of the raster kernel: rows of tiles × segments of each row, a segment
    being the whole tiles of about `SEG_PIXELS` pixels (config; at least one tile: 255
    work-items at 1920x1080 with 64 px tiles). The kernel reads the segments per row back
    from its global size."""
    seg_tiles = max(1, SEG_PIXELS >> tile_log2)
    return params.tiles_y * -(-params.tiles_x // seg_tiles)


@dataclass
class FrameBuffers:
    """Raster outputs, H × W image, T tiles.

    The image outputs are the caller's own NumPy arrays (from `pool`, whose memory is reused
    only once the caller has dropped them: `clraster.arraypool`), wrapped per frame as
    CL_MEM_USE_HOST_PTR buffers: on a CPU device the kernel writes straight into them, which
    saves copying ~20 bytes per pixel back (a third of the frame time of a small scene at
    1080p). seg_stats: int64 (S, 2) fragments tested / passed per segment of a row of
    tiles (`segments`). window: uint8 (H, W) the polygon window's mask of this frame
    (`clraster.window`), when it has one.
    """

    seg_stats: GrowBuffer
    window: GrowBuffer


class RasterStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        prog = program(ctx, "raster", config.build_options())
        self.kernel = kernel(prog, "raster_tiles")
        self._clear_kernel = kernel(prog, "clear_frame")
        #: work-items of `clear`: a few contiguous shares per compute unit, so a core that
        #: the host's thread holds for a moment leaves its shares to the others
        self._clear_items = CLEAR_SHARES * ctx.devices[0].max_compute_units
        self.config = config
        self.buffers = FrameBuffers(GrowBuffer(ctx, host=True), GrowBuffer(ctx))
        self._window_src: np.ndarray | None = None
        self.ctx = ctx
        #: memory of dropped frames' arrays, reused for new ones (at most two frames'
        #: worth is kept: `run` raises the bound to the image size)
        self.pool = ArrayPool(0)

    def clear(self, queue: cl.CommandQueue, params: FrameParams, overdraw: bool = False,
              bary: bool = True) -> RasterOutput:
        """Fresh outputs holding the cleared frame (depth 1.0, id −1, barycentrics and
        overdraw 0), complete and readable on return: depth and ids (and overdraw) written
        by `clear_frame` in contiguous shares, the barycentrics fresh zero pages
        (`zeros_array`) that nothing touches until a later pass draws. An empty frame at
        1080p: 16.6 MB written on the device instead of 41 MB on the host."""
        width, height = params.width, params.height
        self.pool.max_bytes = max(self.pool.max_bytes, 2 * 24 * width * height)
        into = RasterOutput.allocate(self.ctx, width, height, overdraw, False, self.pool)
        ev = self._clear_kernel(queue, (self._clear_items,), (1,), *into.bufs[:2],
                                into.bufs[-1] if overdraw else into.bufs[1],
                                np.int32(overdraw), np.int32(width * height))
        if bary:   # (made while the kernel runs: it does not touch them)
            into.bary = zeros_array((height, width, 3), np.float32)
            into.bufs.insert(2, cl.Buffer(self.ctx, cl.mem_flags.READ_WRITE
                                          | cl.mem_flags.USE_HOST_PTR, hostbuf=into.bary))
        if device_busy():
            # an interrupted frame's work still runs ahead of the clear: wait interruptibly
            wait(queue, keep=(into,))
        else:
            # one C call, not `wait`'s interruptible hand-over (its waiter thread's wake-ups):
            # a clear is a few ms at most (16.6 MB at 1080p)
            queue.finish()
            if ev.command_execution_status < 0:   # a failed clear raises, as `wait` does
                ev.wait()
        into.sync(queue)
        return into

    def _window(self, queue: cl.CommandQueue, params: FrameParams) -> tuple[cl.Buffer, np.int32]:
        """The window mask buffer (uint8 (H, W), `FrameParams.window`) and the kernel's
        use_window flag; uploaded once per frame (the passes of a frame share it)."""
        w = params.window
        if w is None:
            return self.buffers.window.ensure(1), np.int32(0)
        if self._window_src is not w:
            buf = self.buffers.window.ensure(w.nbytes)
            cl.enqueue_copy(queue, buf, w, is_blocking=True)
            self._window_src = w
        return cast(cl.Buffer, self.buffers.window.buf), np.int32(1)

    def run(self, queue: cl.CommandQueue, setup: SetupBuffers, bins: BinBuffers,
            params: FrameParams, *, into: RasterOutput | None = None,
            overdraw: bool = False, bary: bool = True
            ) -> tuple[RasterOutput, np.ndarray, cl.Event]:
        """Rasterize the binned pieces (bins, complete: not pending; the parent
        barycentrics of clipped pieces come from setup.clip_bary).

        Args:
            into: outputs of an earlier pass over the same image to continue from (its
                depth and ids take part in the depth test; pixels nobody beats keep their
                values) — used by two-phase occlusion culling. None: start from clear.
            overdraw: also count fragments tested per pixel (after the tile Hi-Z,
                RasterConfig.tile_hiz).
            bary: also compute and write barycentrics (new outputs only; ``into`` has
                them or not as it was allocated).

        Returns:
            the outputs (complete and readable on return), segment stats (S, 2) int64
            (fragments tested / passed per segment of a row of tiles) and the profiling
            event.
        """
        out, load = self.outputs(params, into, overdraw, bary)
        self.prepare(queue, params)
        ev = self.launch(queue, setup, bins, params, out, load)
        self.wait(queue, out)
        rstats = self.finish(queue, params, out)
        return out, rstats, ev

    def outputs(self, params: FrameParams, into: RasterOutput | None, overdraw: bool,
                bary: bool) -> tuple[RasterOutput, bool]:
        """The outputs a pass draws into and whether it loads them (`run`'s ``into``,
        ``overdraw`` and ``bary``): ``into`` itself, or fresh uninitialised arrays that
        the raster kernel fills completely."""
        if into is None:
            width, height = params.width, params.height
            self.pool.max_bytes = max(self.pool.max_bytes, 2 * 24 * width * height)
            return RasterOutput.allocate(self.ctx, width, height, overdraw, bary,
                                         self.pool), False
        if overdraw and into.overdraw is None:
            raise ValueError("overdraw was not counted in the earlier pass")
        return into, True

    def launch(self, queue: cl.CommandQueue, setup: SetupBuffers, bins: BinBuffers,
               params: FrameParams, out: RasterOutput, load: bool) -> cl.Event:
        """Enqueue the raster kernel over ``bins`` into ``out`` (``load``: continue from
        its contents, see `run`); it draws nothing when the bin list did not fit the
        entry buffer (bins.cap, `BinStage.run` with defer). Returns its event; `wait`
        waits for it, then `finish` makes the outputs readable. Call `prepare` first,
        while the queue is idle."""
        width, height = params.width, params.height
        want = out.overdraw is not None
        want_bary = out.bary is not None
        # an output not wanted gets another buffer as its (untouched) argument; overdraw,
        # when present, is the last buffer
        n = segments(params, self.config.tile_log2)
        return self.kernel(queue, (n,), (1,), setup.clip_bary.buf,
                           bins.tile_start.buf, bins.entries.buf,
                           np.int32(width), np.int32(height), np.int32(params.tiles_x),
                           *out.bufs[:2], out.bufs[2] if want_bary else out.bufs[1],
                           self.buffers.seg_stats.ensure(16 * n),
                           np.int32(load), np.int32(want),
                           out.bufs[-1] if want else out.bufs[1], np.int32(want_bary),
                           *self._window(queue, params), bins.summary.buf, np.int32(bins.cap),
                           np.int32(self.config.tile_hiz))

    def prepare(self, queue: cl.CommandQueue, params: FrameParams) -> None:
        """Upload the frame's window mask, if it has a new one, before the pass's first
        kernel: a host-to-device write enqueued behind running kernels (the setup and bin
        stages of a deferred pass) blocks the calling thread with the GIL held
        (docs/ARCHITECTURE.md)."""
        self._window(queue, params)

    def wait(self, queue: cl.CommandQueue, out: RasterOutput, keep: Any = None) -> None:
        """Wait (interruptibly, `device.wait`) for what is enqueued, ``out`` (and ``keep``:
        what was enqueued behind the raster) kept alive should the wait be interrupted
        (and the stage's own buffers: seg_stats)."""
        wait(queue, keep=(out, self.buffers, keep))

    def finish(self, queue: cl.CommandQueue, params: FrameParams,
               out: RasterOutput) -> np.ndarray:
        """After `wait`: make ``out`` readable. Returns the segment stats (S, 2) int64
        (see `run`)."""
        # the caller waited first: a non-blocking read enqueued behind the running raster
        # kept the GIL for the whole kernel (~200 ms of a big frame during which no other
        # Python thread ran)
        out.sync(queue)
        n = segments(params, self.config.tile_log2)
        return self.buffers.seg_stats.read(queue, np.int64, 2 * n).reshape(n, 2)


@dataclass
class RasterOutput:
    """The image outputs as the caller's NumPy arrays and the CL_MEM_USE_HOST_PTR buffers
    over them. depth float32 (H, W), ids int32 (H, W), bary float32 (H, W, 3) or None (not
    asked for), overdraw int32 (H, W) or None. bufs: one buffer per array present, in
    that order (depth, ids, then bary and overdraw when present)."""

    depth: np.ndarray
    ids: np.ndarray
    bary: np.ndarray | None
    overdraw: np.ndarray | None
    bufs: list[cl.Buffer]
    #: the device writes into the arrays themselves (`clraster.device.shares_host_memory`)
    shared: bool = False

    @classmethod
    def allocate(cls, ctx: cl.Context, width: int, height: int, overdraw: bool,
                 bary: bool = True, pool: ArrayPool | None = None) -> RasterOutput:
        """Uninitialised page-aligned arrays (from ``pool``, else a pool of their own) and
        the buffers over them."""
        pool = pool or ArrayPool(0)
        arrs = [pool.empty((height, width), np.float32), pool.empty((height, width), np.int32)]
        if bary:
            arrs.append(pool.empty((height, width, 3), np.float32))
        if overdraw:
            arrs.append(pool.empty((height, width), np.int32))
        flags = cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR
        bufs = [cl.Buffer(ctx, flags, hostbuf=a) for a in arrs]
        return cls(arrs[0], arrs[1], arrs[2] if bary else None,
                   arrs[-1] if overdraw else None, bufs, shares_host_memory(ctx))

    def arrays(self) -> list[np.ndarray]:
        """The arrays present, in the order of ``bufs``."""
        return [a for a in (self.depth, self.ids, self.bary, self.overdraw) if a is not None]

    def sync(self, queue: cl.CommandQueue) -> None:
        """Make the kernels' writes visible in the arrays, after a wait that saw them
        complete. map/unmap is the OpenCL way for USE_HOST_PTR buffers; a device that
        works in the arrays themselves (``shared``) needs nothing: there the maps copied
        nothing and cost a command each (six, and a finish, ~0.17 ms a pass on spot at
        1080p)."""
        if self.shared:
            return
        # enqueued without blocking, then one finish: each blocking map was a round trip
        for a, b in zip(self.arrays(), self.bufs, strict=True):
            mapped, _ = cl.enqueue_map_buffer(queue, b, cl.map_flags.READ, 0, a.shape, a.dtype,
                                              is_blocking=False)
            mapped.base.release(queue)
        queue.finish()
