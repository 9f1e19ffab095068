"""Growable device buffers: reused frame to frame, grown geometrically, released when a frame
needed more than the frame budget allows (`GrowBuffer.bound`, `trim`)."""

from __future__ import annotations

import pyopencl as cl

_MIN_BYTES = 256


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
    """

    def __init__(self, ctx: cl.Context, flags: int = cl.mem_flags.READ_WRITE) -> None:
        self.ctx = ctx
        self.flags = flags
        self.capacity = 0
        self.buf: cl.Buffer | None = None
        self.limit = int(ctx.devices[0].max_mem_alloc_size)
        self.bound: int | None = None

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
            self.buf = cl.Buffer(self.ctx, self.flags, cap)
            self.capacity = cap
        return self.buf

    def trim(self) -> None:
        """Release the buffer if it is larger than ``bound`` (the next `ensure` allocates
        what it asks for)."""
        if self.bound is not None and self.capacity > max(self.bound, _MIN_BYTES):
            self.buf = None
            self.capacity = 0
