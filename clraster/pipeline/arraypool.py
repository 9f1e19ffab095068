"""Recycled host memory for the arrays a renderer returns (plain NumPy; imports nothing of
clraster).

Why: a 1920x1080 frame is 41 MB of new arrays (depth, ids, barycentrics), and fresh memory
is paid for in page faults when it is first written — measured here at ~4 µs a fault, 6 ms
for two new 8 MB arrays, and at 3840x2160 (arrays over glibc's 32 MB mmap ceiling, so never
reused by malloc) 500-1100 faults a frame. Whether malloc reuses a freed block depends on
sizes and on the order of frees, so the cost came and went with the caller's loop.

Ownership: every array handed out belongs to its caller alone, for as long as the caller
(or any view, slice or copy-free reshape of it) holds it. Its block comes back to the pool
only when the last reference is gone — the arrays' base is a small lease object that
NumPy keeps alive through every view, whose ``__del__`` returns the block — so a frame kept
from many views never shares memory with another. Nothing is ever written into a block
that anyone can still see. The pool keeps at most ``max_bytes`` of free blocks (blocks
beyond that go back to the allocator), so an idle renderer holds a bounded amount.
"""

from __future__ import annotations

import math
import threading

import numpy as np

_PAGE = 4096


def page_aligned(nbytes: int) -> np.ndarray:
    """An uninitialised uint8 array of ``nbytes`` aligned to a page, so an OpenCL CPU device
    can use its memory directly (CL_MEM_USE_HOST_PTR)."""
    raw = np.empty(nbytes + _PAGE, np.uint8)
    off = (-raw.ctypes.data) % _PAGE
    return raw[off:off + nbytes]


class _Lease:
    """The base of the arrays over one pooled block; returns the block when collected."""

    __slots__ = ("__array_interface__", "_block", "_pool")

    def __init__(self, pool: ArrayPool, block: tuple[np.ndarray, int], shape: tuple[int, ...],
                 dtype: np.dtype) -> None:
        self._pool = pool
        self._block = block
        self.__array_interface__ = {"data": (block[1], False), "shape": shape,
                                    "typestr": dtype.str, "version": 3}

    def __del__(self) -> None:
        try:
            self._pool._give_back(self._block)
        except Exception:   # interpreter shutdown: nothing to give back to
            pass


class ArrayPool:
    """Page-aligned NumPy arrays whose memory is reused once their users drop them.

    Args:
        max_bytes: free blocks kept for reuse, at most (bytes).
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        # free blocks by size, each with its address (``block.ctypes.data`` cost ~1.6 µs
        # a call here, so it is read once per block)
        self._free: dict[int, list[tuple[np.ndarray, int]]] = {}
        self._free_bytes = 0
        self._lock = threading.Lock()

    def empty(self, shape: tuple[int, ...], dtype: type | np.dtype) -> np.ndarray:
        """An uninitialised, writeable, page-aligned C-contiguous array of ``shape`` and
        ``dtype``, owned by the caller (see the module docstring)."""
        dt = np.dtype(dtype)
        shape = tuple(int(s) for s in shape)
        # math.prod of the Python ints: np.prod of a small tuple cost ~10 µs here (~0.1 µs)
        nbytes = max(math.prod(shape) * dt.itemsize, 1)
        with self._lock:
            blocks = self._free.get(nbytes)
            block = blocks.pop() if blocks else None
            if block is not None:
                self._free_bytes -= nbytes
        if block is None:
            mem = page_aligned(nbytes)
            block = (mem, mem.ctypes.data)
        return np.asarray(_Lease(self, block, shape, dt))

    @property
    def free_bytes(self) -> int:
        """Bytes of free blocks held now."""
        return self._free_bytes

    def _give_back(self, block: tuple[np.ndarray, int]) -> None:
        nbytes = block[0].nbytes
        with self._lock:
            if self._free_bytes + nbytes <= self.max_bytes:
                self._free.setdefault(nbytes, []).append(block)
                self._free_bytes += nbytes
