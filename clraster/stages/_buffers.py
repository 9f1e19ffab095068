"""Growable device buffers: reused frame to frame, grown geometrically, never shrunk."""

from __future__ import annotations

import pyopencl as cl

_MIN_BYTES = 256


class GrowBuffer:
    """A device buffer that is at least as large as the last request.

    ``ensure(nbytes)`` reallocates (contents are lost) only when the request exceeds the
    capacity, then to max(request, 1.5 × capacity), so a sequence of growing frames costs
    O(log n) allocations.
    """

    def __init__(self, ctx: cl.Context, flags: int = cl.mem_flags.READ_WRITE) -> None:
        self.ctx = ctx
        self.flags = flags
        self.capacity = 0
        self.buf: cl.Buffer | None = None
        self.limit = int(ctx.devices[0].max_mem_alloc_size)

    def ensure(self, nbytes: int, what: str = "buffer") -> cl.Buffer:
        nbytes = max(int(nbytes), _MIN_BYTES)
        if nbytes > self.limit:
            raise MemoryError(
                f"this frame needs a {nbytes / 2**20:,.0f} MiB {what}; the OpenCL device "
                f"allocates at most {self.limit / 2**20:,.0f} MiB per buffer. Render a "
                "smaller image or fewer triangles per draw (or raise PoCL's limit with "
                "POCL_MEMORY_LIMIT)")
        if self.buf is None or nbytes > self.capacity:
            cap = min(max(nbytes, int(self.capacity * 1.5)), self.limit)
            self.buf = cl.Buffer(self.ctx, self.flags, cap)
            self.capacity = cap
        return self.buf
