"""Growable device buffers: reused frame to frame, grown geometrically, released when a frame
needed more than the frame budget allows (`GrowBuffer.bound`, `trim`)."""

from __future__ import annotations

import ctypes
import functools
import mmap
import sys

import numpy as np
import pyopencl as cl

from ..arraypool import page_aligned
from ..device import shares_host_memory

_MIN_BYTES = 256

#: Transparent huge pages for the big stage buffers (`advise_huge_pages`): the x86-64 and
#: arm64 (4 KiB base pages) huge page size; buffers of at least two of them are advised.
_HUGE = 2 << 20
_QUEUE_ATTR = "_clraster_advice_queue"


@functools.cache
def _madvise():
    """libc's madvise and MADV_HUGEPAGE, or None where there are none (not Linux); looked
    up on first use (the process's own symbols: no ldconfig run at import)."""
    if not sys.platform.startswith("linux") or not hasattr(mmap, "MADV_HUGEPAGE"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).madvise
    except (OSError, AttributeError):
        return None
    fn.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    fn.restype = ctypes.c_int
    return fn, mmap.MADV_HUGEPAGE


def advise_huge_pages(ctx: cl.Context, buf: cl.Buffer, nbytes: int) -> bool:
    """Ask Linux to back the 2 MiB-aligned part of ``buf``'s memory with transparent huge
    pages (madvise MADV_HUGEPAGE), where the device works in host memory (PoCL's CPU
    drivers, `clraster.device.shares_host_memory`). Returns whether advice was given.

    Why: a frame walks ~160 MB of stage buffers (the dragon at 1080p: the vertex stream,
    setup's records at triangle slots, bin entries scattered to tiles) in 4 KiB pages,
    some 40,000 of them against a TLB of ~2,000 entries, so most accesses to a new page
    walked the page tables, and after other work had evicted those from the caches
    (the benchmark harness runs a NumPy twin frame and an llvmpipe frame between two
    clraster frames) each walk went to DRAM. With the advice, dragon 1080p frames with
    cold caches 0.94x (bench/proc_ab.py --evict 2000). Machines whose
    /sys/kernel/mm/transparent_hugepage/enabled is "madvise" (Debian's default) give huge
    pages only to advised memory; "always" gives them anyway, "never" ignores the advice.

    The buffer stays PoCL's (its lifetime is OpenCL's, in-flight commands included): its
    host address comes from a map on a queue of this module's own, made once per
    context, and the advice only changes how pages not yet touched are backed. With
    Linux's default `defrag` setting the first touch of an advised buffer may wait while
    the kernel compacts memory for a huge page: a cost of the frames that grow a buffer,
    not of the frames that reuse it."""
    if nbytes < 2 * _HUGE or _madvise() is None or not shares_host_memory(ctx):
        return False
    queue = getattr(ctx, _QUEUE_ATTR, None)
    try:
        if queue is None:
            queue = cl.CommandQueue(ctx)
            setattr(ctx, _QUEUE_ATTR, queue)
        mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, (nbytes,),
                                          np.dtype(np.uint8))
        addr = mapped.ctypes.data
        mapped.base.release(queue)
        queue.finish()
    except cl.Error:
        return False
    lo = -(-addr // _HUGE) * _HUGE
    hi = (addr + nbytes) // _HUGE * _HUGE
    fn, advice = _madvise()
    return hi > lo and fn(lo, hi - lo, advice) == 0


class GrowBuffer:
    """A device buffer that is at least as large as the last request.

    ``ensure(nbytes)`` reallocates (contents are lost) only when the request exceeds the
    capacity, then to max(request, 1.5 × capacity), so a sequence of growing frames costs
    O(log n) allocations.

    ``bound`` (bytes, or None): what the frame budget (`clraster.RasterConfig.batch_*`)
    lets this buffer need in one pass. Geometric growth never goes past it (a request
    beyond it — a single draw whose bin list is over the budget — gets exactly its size),
    and `trim` releases a buffer left larger than it, so after an outsized pass the
    renderer's memory returns to the budget's bound.

    ``host=True`` (small buffers of results the host reads after a wait: counts, flags):
    where the device works in host memory itself (`clraster.device.shares_host_memory`),
    the buffer is a CL_MEM_USE_HOST_PTR buffer over a page-aligned array of its own, so
    `read` and `write` are plain memory accesses instead of commands; elsewhere they are
    blocking reads and queued writes. In host mode the array is this object's: `write`,
    and an `ensure` or `trim` that reallocates, only while no enqueued command uses the
    buffer, and keep the owner alive while one may (`clraster.device.wait`'s ``keep``,
    `clraster.device.abandon`).
    """

    def __init__(self, ctx: cl.Context, flags: int = cl.mem_flags.READ_WRITE,
                 host: bool = False) -> None:
        self.ctx = ctx
        self.flags = flags
        self.capacity = 0
        self.buf: cl.Buffer | None = None
        self.limit = int(ctx.devices[0].max_mem_alloc_size)
        self.bound: int | None = None
        self.host = host and shares_host_memory(ctx)
        self._mem: np.ndarray | None = None   # the host array behind buf (host mode)

    def ensure(self, nbytes: int, what: str = "buffer") -> cl.Buffer:
        nbytes = max(int(nbytes), _MIN_BYTES)
        if nbytes > self.limit:
            raise MemoryError(
                f"this frame needs a {nbytes / 2**20:,.0f} MiB {what}; the OpenCL device "
                f"allocates at most {self.limit / 2**20:,.0f} MiB per buffer. Render a "
                "smaller image, lower RasterConfig's batch_triangles / batch_entries (the "
                "per-pass budget), or raise PoCL's limit with POCL_MEMORY_LIMIT")
        if self.buf is None or nbytes > self.capacity:
            cap = max(nbytes, int(self.capacity * 1.5))
            if self.bound is not None:
                cap = min(cap, max(nbytes, self.bound))
            cap = min(cap, self.limit)
            self.buf = None   # let the old allocation go before the new one is made
            if self.host:
                self._mem = page_aligned(cap)
                self.buf = cl.Buffer(self.ctx, self.flags | cl.mem_flags.USE_HOST_PTR,
                                     hostbuf=self._mem)
            else:
                self.buf = cl.Buffer(self.ctx, self.flags, cap)
                advise_huge_pages(self.ctx, self.buf, cap)
            self.capacity = cap
        return self.buf

    def read(self, queue: cl.CommandQueue, dtype: type | np.dtype, count: int) -> np.ndarray:
        """The first ``count`` items of ``dtype``, copied; call after a wait that saw the
        commands writing them complete (`clraster.device.wait`). In host mode a copy of
        the array, else a blocking read."""
        dt = np.dtype(dtype)
        if self._mem is not None:
            return self._mem[:count * dt.itemsize].view(dt).copy()
        out = np.empty(count, dt)
        assert self.buf is not None, "read before ensure"
        cl.enqueue_copy(queue, out, self.buf)
        return out

    def write(self, queue: cl.CommandQueue, arr: np.ndarray) -> None:
        """Put ``arr`` at the start of the buffer (ensured large enough), while no enqueued
        command uses it: in host mode a copy into the array, else a queued write."""
        arr = np.ascontiguousarray(arr)
        buf = self.ensure(arr.nbytes)
        if self._mem is not None:
            self._mem[:arr.nbytes] = arr.reshape(-1).view(np.uint8)
        else:   # (pyopencl keeps arr alive until the write is done)
            cl.enqueue_copy(queue, buf, arr, is_blocking=False)

    def trim(self) -> None:
        """Release the buffer if it is larger than ``bound`` (the next `ensure` allocates
        what it asks for)."""
        if self.bound is not None and self.capacity > max(self.bound, _MIN_BYTES):
            self.buf = None
            self._mem = None
            self.capacity = 0
