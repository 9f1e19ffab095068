"""Depth pyramid (Hi-Z) and the conservative box occlusion test, host side (kernels/pyramid.cl).

Level 0 is the W × H depth buffer; level k+1 is ceil(w_k/2) × ceil(h_k/2), each texel the
farthest (max) depth of the ≤ 2×2 level-k texels it covers (indices clamped at the last
row/column), down to 1 × 1. Texel (i, j) of level L therefore covers exactly the level-0
pixels [i·2^L, min((i+1)·2^L, W)) × [j·2^L, min((j+1)·2^L, H)) and bounds the farthest
depth under them; pixel (x, y) sits under texel (x >> L, y >> L) at every level.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyopencl as cl

from ...base.checks import check_boxes
from ...base.config import HIZ_TEST_LOCAL, RasterConfig

# PYR_LOG2: levels made per launch of pyramid_reduce (kernels/pyramid.cl)
from ...base.layout import PYR_LOG2, level_shapes
from ..device import event_ms, kernel, program
from ..features import local_size
from ._buffers import GrowBuffer

#: Boxes per test call: the kernel indexes its (6, K) box array with int32.
MAX_TEST_BOXES = 1 << 28


def level_table(width: int, height: int) -> np.ndarray:
    """int32 (n_levels, 4) rows (offset in floats, width, height, 0): the kernels' table."""
    shapes = level_shapes(width, height)
    t = np.zeros((len(shapes), 4), np.int32)
    off = 0
    for k, (h, w) in enumerate(shapes):
        t[k] = (off, w, h, 0)
        off += w * h
    return t


@dataclass
class Pyramid:
    """A built depth pyramid on the device.

    buffer: float32, every level row-major, concatenated; level k starts at
        ``offsets[k]`` floats and has shape ``shapes[k]`` = (h_k, w_k). Level 0 is a copy of
        the depth buffer it was built from.
    table: int32 (n_levels, 4) device copy of `level_table` (what the test kernel reads).
    width, height: level-0 size. events: the build's profiling events.

    The buffer belongs to the `PyramidStage` that built it and is overwritten by its next
    `build`; read or test before building again.
    """

    buffer: cl.Buffer
    table: cl.Buffer
    width: int
    height: int
    shapes: tuple[tuple[int, int], ...]
    offsets: tuple[int, ...]
    events: list[cl.Event] = field(default_factory=list)

    @property
    def n_levels(self) -> int:
        return len(self.shapes)

    def read(self, queue: cl.CommandQueue) -> list[np.ndarray]:
        """All levels as float32 arrays, level 0 (H, W) first, down to (1, 1)."""
        total = self.offsets[-1] + self.shapes[-1][0] * self.shapes[-1][1]
        flat = np.empty(total, np.float32)
        cl.enqueue_copy(queue, flat, self.buffer, is_blocking=True)
        return [flat[o:o + h * w].reshape(h, w).copy()
                for o, (h, w) in zip(self.offsets, self.shapes, strict=True)]


@dataclass
class PyramidBuffers:
    """Buffers of the pyramid and of the box test, reused between calls.

    levels: float32 (sum of level sizes,) the pyramid. table: int32 (n_levels, 4).
    boxes: float32 (6, K8) rows min.x, min.y, min.z, max.x, max.y, max.z, K8 = K rounded
    up to a multiple of 8 (the test kernel does 8 boxes per work-item in float8 lanes).
    view_proj: float32 (16,). result: uint8 (K8,).
    """

    levels: GrowBuffer
    table: GrowBuffer
    boxes: GrowBuffer
    view_proj: GrowBuffer
    result: GrowBuffer


class PyramidStage:
    """Builds depth pyramids and tests boxes against them (kernels/pyramid.cl)."""

    def __init__(self, ctx: cl.Context, config: RasterConfig | None = None) -> None:
        prg = program(ctx, "pyramid", (config or RasterConfig()).build_options())
        self.k_reduce = kernel(prg, "pyramid_reduce")
        self.k_test = kernel(prg, "hiz_test_boxes")
        self.test_local = local_size(self.k_test, ctx.devices[0], HIZ_TEST_LOCAL)
        # boxes, view_proj and result go between host and device every test: host mode
        # (`GrowBuffer`), where the device works in host memory no command each
        self.buffers = PyramidBuffers(GrowBuffer(ctx), GrowBuffer(ctx),
                                      *(GrowBuffer(ctx, host=True) for _ in range(3)))
        self._table_key: tuple[int, int] | None = None
        self._table_buf: cl.Buffer | None = None

    def build(self, queue: cl.CommandQueue, depth_buf: cl.Buffer, width: int,
              height: int) -> Pyramid:
        """Build the pyramid of the float32 (H, W) row-major depth buffer ``depth_buf``.

        Enqueues ceil((n_levels − 1) / 6) launches (2 at 1920×1080) and returns without
        waiting; the returned `Pyramid` is complete once its events are (anything enqueued
        after it on ``queue`` sees it complete: the queue is in order).
        """
        table = level_table(width, height)
        b = self.buffers
        total = int(table[-1, 0]) + int(table[-1, 1]) * int(table[-1, 2])
        pyr = b.levels.ensure(4 * total, "depth pyramid")
        tbuf = b.table.ensure(table.nbytes)
        if self._table_key != (width, height) or b.table.buf is not self._table_buf:
            cl.enqueue_copy(queue, tbuf, table, is_blocking=True)
            self._table_key = (width, height)
            self._table_buf = b.table.buf
        events = []
        n_levels = table.shape[0]
        src = 0
        if n_levels == 1:   # 1 × 1: level 0 only, still copied into the pyramid
            events.append(cl.enqueue_copy(queue, pyr, depth_buf, byte_count=4))
        while src < n_levels - 1:
            n_make = min(PYR_LOG2, n_levels - 1 - src)
            nb = 1 << n_make
            ws, hs = int(table[src, 1]), int(table[src, 2])
            bx, by = -(-ws // nb), -(-hs // nb)
            events.append(self.k_reduce(queue, (bx * by,), (1,), depth_buf, pyr, tbuf,
                                        np.int32(src), np.int32(n_make), np.int32(bx),
                                        np.int32(bx * by)))
            src += n_make
        shapes = tuple((int(h), int(w)) for _, w, h, _ in table)
        return Pyramid(pyr, tbuf, int(width), int(height), shapes,
                       tuple(int(o) for o in table[:, 0]), events)

    def test_boxes(self, queue: cl.CommandQueue, pyramid: Pyramid, mins: np.ndarray,
                   maxs: np.ndarray, view_proj: np.ndarray, width: int, height: int
                   ) -> np.ndarray:
        """Classify world-space boxes against ``pyramid``; blocking.

        Args:
            mins, maxs: (K, 3) box corners (converted to float32; any order per axis works,
                the 8 corners are the same).
            view_proj: (4, 4) or (16,) row-major world → clip matrix (converted to float32),
                clip = VP · [p, 1]; the one the depth buffer was rendered with for the test
                to mean anything.
            width, height: image size; must be the pyramid's.

        Returns:
            uint8 (K,) `clraster.occlusion.Occlusion` codes: VISIBLE 0, OCCLUDED 1 (no sample
            of anything inside the box can pass LESS against the depth buffer, or the box
            covers no pixel centre), VIEW_CULLED 2 (outside one frustum plane). Boxes
            crossing the near plane, or with non-finite corners, are VISIBLE.
        """
        res, _ev = self.enqueue_test(queue, pyramid, mins, maxs, view_proj, width, height)
        return res

    def enqueue_test(self, queue: cl.CommandQueue, pyramid: Pyramid, mins: np.ndarray,
                     maxs: np.ndarray, view_proj: np.ndarray, width: int, height: int
                     ) -> tuple[np.ndarray, cl.Event | None]:
        """`test_boxes`, also returning the kernel's profiling event (None when K = 0)."""
        if (int(width), int(height)) != (pyramid.width, pyramid.height):
            raise ValueError(f"the pyramid is {pyramid.width}x{pyramid.height}, not "
                             f"{width}x{height}")
        lo, hi, vp = check_test_inputs(mins, maxs, view_proj)
        return self.enqueue_test_rows(queue, pyramid, np.vstack([lo.T, hi.T]), vp, width,
                                      height)

    def enqueue_test_rows(self, queue: cl.CommandQueue, pyramid: Pyramid, rows: np.ndarray,
                          vp: np.ndarray, width: int, height: int, zoff: float = 0.5
                          ) -> tuple[np.ndarray, cl.Event | None]:
        """`enqueue_test` with the boxes already in the kernel's layout: float32 (6, K)
        rows min x, y, z, max x, y, z; vp float32 (16,) row-major. For callers that keep
        their boxes that way (the renderer's occlusion culling, every frame). zoff: the
        pyramid's depth key (`clraster.pipeline.params.FrameParams.zoff`; 0.5 = window depth)."""
        k = rows.shape[1]
        if k == 0:
            return np.empty(0, np.uint8), None
        ev = self.launch_test_rows(queue, pyramid, rows, vp, width, height, zoff)
        # Waited for in one C call, not interruptibly (device.wait): the build and the test
        # take a few ms, and an interrupted wait would leave them running on the frame's
        # depth and this stage's host-mode buffers (`GrowBuffer`) after the caller lets go.
        queue.finish()
        return self.test_result(queue, k), ev

    def launch_test_rows(self, queue: cl.CommandQueue, pyramid: Pyramid, rows: np.ndarray,
                         vp: np.ndarray, width: int, height: int, zoff: float = 0.5
                         ) -> cl.Event:
        """`enqueue_test_rows`' inputs written and its test enqueued (K > 0 boxes), without
        waiting: after a wait that covers it, `test_result` (K) reads the verdicts. No other
        test may be launched on this stage before then (they share its host-mode
        buffers)."""
        k = rows.shape[1]
        if k > MAX_TEST_BOXES:
            raise ValueError(f"{k:,} boxes in one call; at most {MAX_TEST_BOXES:,} (split "
                             "the list)")
        b = self.buffers
        n_pad = -(-k // 8) * 8
        if (n_pad == k and rows.shape[0] == 6 and rows.dtype == np.float32
                and rows.flags.c_contiguous):
            soa = rows   # already the kernel's layout (two_phase pads its gathers)
        else:
            soa = np.zeros((6, n_pad), np.float32)   # rows min.xyz, max.xyz
            soa[:, :k] = rows
        bbox = b.boxes.ensure(soa.nbytes, "box buffer")
        bvp, bres = b.view_proj.ensure(64), b.result.ensure(n_pad)
        # (no pending command uses these two: a test's result is read, after a wait, before
        # the next test is launched)
        b.boxes.write(queue, soa)
        b.view_proj.write(queue, vp)
        n_wi = n_pad // 8
        gsize = -(-n_wi // self.test_local) * self.test_local
        return self.k_test(queue, (gsize,), (self.test_local,), bbox, np.int32(n_pad), bvp,
                           np.int32(width), np.int32(height), pyramid.buffer, pyramid.table,
                           np.int32(pyramid.n_levels), np.float32(zoff), bres)

    def test_result(self, queue: cl.CommandQueue, k: int) -> np.ndarray:
        """The verdicts uint8 (K,) of the last test launched, once a wait covered it."""
        return self.buffers.result.read(queue, np.uint8, k)


class HizFollow:
    """A depth pyramid and a Hi-Z test enqueued right behind the raster launch of a pass
    (`StageChain.draw`'s ``follow``), so the pass's wait covers them: two-phase occlusion
    culling's test of phase 1 (`clraster.pipeline.twophase`), with no host round trip
    (the wait's wake-up, the frame's bookkeeping, the boxes' gather, a second wait)
    between the raster and the test, the device idle meanwhile.

    ``rows_fn()`` gives the boxes (float32 (6, K'), K' a multiple of 8, K' > 0: the
    test's layout, `enqueue_test_rows`), called once, at the first launch, so their gather
    runs while the raster does. A pass drawn again (its bin list did not fit, ``redraw``)
    enqueues both again behind the second raster; a second pass of the phase (a phase the
    budget streams) turns it off: `result` is then None and the caller tests after the
    phase. ``on_build(pyramid)``: told of each pyramid built (the renderer keeps the last,
    for tests of the same depth later in the frame)."""

    def __init__(self, stage: PyramidStage, rows_fn: Callable[[], np.ndarray],
                 vp32: np.ndarray, width: int, height: int, zoff: float,
                 on_build: Callable[[Pyramid], None]) -> None:
        self._stage, self._rows_fn, self._vp32 = stage, rows_fn, vp32
        self._size, self._zoff, self._on_build = (width, height), zoff, on_build
        self._rows: np.ndarray | None = None
        self._launched: tuple[cl.CommandQueue, list[cl.Event]] | None = None
        self._passes = 0
        self._off = False

    def __call__(self, queue: cl.CommandQueue, out: Any, bins: Any, redraw: bool) -> None:
        """Enqueue the pyramid of ``out``'s depth (a `RasterOutput` whose raster was just
        enqueued) and the test of the boxes against it."""
        if not redraw:
            self._passes += 1
            self._off |= self._passes > 1
        if self._off:
            self._launched = None
            return
        if self._rows is None:
            self._rows = self._rows_fn()
        w, h = self._size
        pyr = self._stage.build(queue, out.bufs[0], w, h)
        self._on_build(pyr)
        ev = self._stage.launch_test_rows(queue, pyr, self._rows, self._vp32, w, h,
                                          self._zoff)
        self._launched = (queue, [*pyr.events, ev])

    def result(self) -> tuple[np.ndarray, float] | None:
        """After the wait that followed the pass: the verdicts uint8 (K',) and the device
        milliseconds of the pyramid and test, or None (turned off, or never launched)."""
        if self._launched is None or self._off or self._rows is None:
            return None
        queue, events = self._launched
        return self._stage.test_result(queue, self._rows.shape[1]), event_ms(events)


def check_test_inputs(mins, maxs, view_proj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated contiguous float32 (K, 3), (K, 3) and (16,) copies of the test inputs."""
    lo, hi = check_boxes(mins, maxs, np.float32)
    vp = np.ascontiguousarray(np.asarray(view_proj, np.float32).reshape(-1))
    if vp.shape != (16,):
        raise ValueError(f"view_proj must be a (4, 4) matrix, got {vp.size} values")
    return lo, hi, vp
