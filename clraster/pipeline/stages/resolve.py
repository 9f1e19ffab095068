"""Resolve host side (kernels/resolve.cl): the per-pixel outputs asked for
(`clraster.base.checks.RESOLVE_OUTPUTS`) made after the frame's last raster pass from its ids
and barycentrics and the scene's geometry already on the device (the pool positions setup
reads, `GeometryBuffers.positions`), one launch a frame (two where a pass is
drawn again, `ResolveFollow`). Device shading
(`clraster.pipeline.stages.shade`) reads the tables this stage uploads."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ..arraypool import ArrayPool
from ..device import event_ms, kernel, program, shares_host_memory, wait
from ..drawlist import GeometryPool
from ..resolving import (
    OUTPUT_BITS,
    RESOLVE_SPAN,
    ResolveTables,
    ResolveView,
)
from ._buffers import GrowBuffer
from .geometry import GeometryBuffers

#: the kernel's names of the `want` bits (-D options)
_DEFINES = {"mask": "RS_MASK", "linear_depth": "RS_LINEAR", "distance": "RS_DISTANCE",
            "points": "RS_POINTS", "normals": "RS_NORMALS", "smooth_normals": "RS_SMOOTH",
            "camera_normals": "RS_CAM_NORMALS", "smooth_camera_normals": "RS_CAM_SMOOTH"}
#: output → (dtype, components per pixel), in the kernel's argument order
_IMAGES = {"mask": (np.bool_, 1), "linear_depth": (np.float32, 1), "distance": (np.float32, 1),
           "points": (np.float64, 3), "normals": (np.float32, 3),
           "smooth_normals": (np.float32, 3), "camera_normals": (np.float32, 3),
           "smooth_camera_normals": (np.float32, 3)}


@dataclass
class ResolveBuffers:
    """Scene → resolve boundary (shapes and dtypes: `clraster.pipeline.resolving`).

    Per scene (uploaded when the tables change): inst_base int32 (I,), inst_mesh int32
    (I,), mesh_fbase int32 (U,), face_rows int32 (F, FACE_ROW_WORDS) (`ResolveTables.face_rows`:
    each face's vertices and normal in one row), inst_nrm float64 (I, 9),
    vnormals float32 (V, 3) (on the first smooth output). Per frame: inst_model float64
    (I, 12), cam float64 (16,). The outputs are the caller's arrays (`ArrayPool`) under
    CL_MEM_USE_HOST_PTR buffers, as the raster's.
    """

    inst_base: GrowBuffer
    inst_mesh: GrowBuffer
    mesh_fbase: GrowBuffer
    face_rows: GrowBuffer
    inst_nrm: GrowBuffer
    vnormals: GrowBuffer
    inst_model: GrowBuffer
    cam: GrowBuffer


@dataclass
class PendingResolve:
    """A resolve enqueued (`ResolveStage.enqueue`): its output arrays (name → array, written
    by the kernel), the buffers over them (in the kernel's argument order), its event.
    Keep it alive until a wait has seen the kernel complete."""

    outs: dict[str, np.ndarray]
    args: list[cl.Buffer]
    event: cl.Event


class ResolveFollow:
    """The frame's resolve enqueued right behind the raster launch of a frame drawn in one
    pass (`StageChain.draw`'s ``follow``), so the wait for the raster covers it too: no
    host round trip (a wait, the host's resolve set-up, a second wait) between the last
    pass and the outputs.

    Made before the frame's first pass, while the queue is idle: the scene's tables are
    uploaded then, so a call between a raster launch and its wait only allocates the
    outputs and enqueues. A pass drawn again (its bin list did not fit, ``redraw``)
    enqueues it again behind the second raster; the first one skipped with its raster
    (the kernel reads the same bin summary). A second pass of the frame (a frame the
    budget streams) turns it off: `result` is then None and the caller resolves once,
    after the frame."""

    def __init__(self, stage: ResolveStage, queue: cl.CommandQueue, geometry: GeometryBuffers,
                 pool: GeometryPool, tables: ResolveTables, view: ResolveView, width: int,
                 height: int, arrays: ArrayPool) -> None:
        self._stage, self._geometry, self._pool = stage, geometry, pool
        self._tables, self._view, self._size, self._arrays = tables, view, (width, height), arrays
        smooth = any(n in view.names for n in ("smooth_normals", "smooth_camera_normals"))
        if stage.upload_tables(queue, pool, tables, smooth):
            queue.finish()   # the host arrays may go: the copies are done (nothing else runs)
        self._pending: PendingResolve | None = None
        self._after: Any = None   # the frame buffers the last enqueue read
        self._queue: cl.CommandQueue | None = None
        self._passes = 0
        self._off = False

    @property
    def view(self) -> ResolveView:
        """The view the outputs are made for."""
        return self._view

    def __call__(self, queue: cl.CommandQueue, out: Any, bins: Any, redraw: bool) -> None:
        """Enqueue the resolve of ``out`` (a `RasterOutput` whose raster over the
        `BinBuffers` ``bins`` was just enqueued: where that raster skips a list that did
        not fit, so does the resolve). ``redraw``: the same pass drawn again. An earlier
        enqueue is dropped: the wait after its raster saw it complete."""
        if not redraw:
            self._passes += 1
            self._off |= self._passes > 1
        self._pending = None
        if self._off:
            return
        bary = out.bufs[2] if out.bary is not None else None
        self._pending = self._stage.enqueue(queue, self._geometry, self._pool, self._tables,
                                            self._view, out.bufs[1], bary, *self._size,
                                            self._arrays, bins)
        self._after, self._queue = out, queue

    def result(self, out: Any) -> tuple[dict[str, np.ndarray], float] | None:
        """After the frame's last wait: the outputs (name → array) of the resolve enqueued
        after the last raster launch into ``out`` and its milliseconds, or None when none
        was (the caller resolves then)."""
        pending, self._pending = self._pending, None
        if pending is None or self._off or self._after is not out or self._queue is None:
            return None
        outs, ev = self._stage.collect(self._queue, pending)
        return outs, event_ms([ev])


class ResolveStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        opts = (*config.build_options(),
                *(f"-D{_DEFINES[n]}={bit}" for n, bit in OUTPUT_BITS.items()))
        self.kernel = kernel(program(ctx, "resolve", opts), "resolve_pixels")
        self.ctx = ctx
        self._shared = shares_host_memory(ctx)
        self.buffers = ResolveBuffers(*(GrowBuffer(ctx) for _ in range(6)),
                                      *(GrowBuffer(ctx, host=True) for _ in range(2)))
        self._tables: ResolveTables | None = None
        self._smooth = False

    def upload_tables(self, queue: cl.CommandQueue, pool: GeometryPool,
                       tables: ResolveTables, smooth: bool) -> bool:
        """Upload ``tables`` (and the vertex normals, for ``smooth``) unless they are the
        ones on the device; True when something was copied (wait before the host arrays
        may go)."""
        b = self.buffers
        copied = False
        if tables is not self._tables:
            for gb, arr in ((b.inst_base, tables.inst_base), (b.inst_mesh, tables.inst_mesh),
                            (b.mesh_fbase, tables.mesh_fbase),
                            (b.face_rows, tables.face_rows()),
                            (b.inst_nrm, tables.normal_mats)):
                buf = gb.ensure(arr.nbytes, "resolve table")
                if arr.nbytes:
                    cl.enqueue_copy(queue, buf, np.ascontiguousarray(arr), is_blocking=False)
            self._tables, self._smooth = tables, False
            copied = True
        if smooth and not self._smooth:
            vn = tables.smooth_normals(pool)
            buf = b.vnormals.ensure(vn.nbytes, "vertex normal buffer")
            if vn.nbytes:
                cl.enqueue_copy(queue, buf, vn, is_blocking=False)
            self._smooth = copied = True
        return copied

    def run(self, queue: cl.CommandQueue, geometry: GeometryBuffers, pool: GeometryPool,
            tables: ResolveTables, view: ResolveView, ids: cl.Buffer, bary: cl.Buffer | None,
            width: int, height: int, arrays: ArrayPool) -> tuple[dict[str, np.ndarray],
                                                                  cl.Event]:
        """Make the outputs ``view.names`` of a frame whose ids (int32 (H, W)) and
        barycentrics (float32 (H, W, 3), or None when no output asked for needs them) are
        in the device buffers ``ids`` and ``bary``; ``geometry`` holds ``pool``'s
        positions (`GeometryStage.upload_pool`). Returns name → array (readable on return;
        shapes, dtypes, background values: `clraster.pipeline.reference.resolve.resolve`)
        and the kernel's event. Call while the queue is idle (after the frame's last pass):
        `enqueue`, a wait, `collect`."""
        pending = self.enqueue(queue, geometry, pool, tables, view, ids, bary, width, height,
                               arrays)
        wait(queue, keep=(pending, self.buffers))
        return self.collect(queue, pending)

    def enqueue(self, queue: cl.CommandQueue, geometry: GeometryBuffers, pool: GeometryPool,
                tables: ResolveTables, view: ResolveView, ids: cl.Buffer,
                bary: cl.Buffer | None, width: int, height: int, arrays: ArrayPool,
                bins: Any = None) -> PendingResolve:
        """`run`'s kernel enqueued behind whatever is on the queue (the frame's raster:
        `ResolveFollow`), its output arrays allocated; wait for the queue (keeping the
        result and this stage's buffers alive), then `collect`. ``bins``: the
        `BinBuffers` of the raster just enqueued, whose skip (a bin list that did not fit)
        the kernel repeats; None after the frame."""
        b = self.buffers
        smooth = any(n in view.names for n in ("smooth_normals", "smooth_camera_normals"))
        if self.upload_tables(queue, pool, tables, smooth):
            queue.finish()   # the host arrays may go: the copies are done
        b.inst_model.write(queue, view.model)
        b.cam.write(queue, view.cam)
        npx = width * height
        outs: dict[str, np.ndarray] = {}
        flags = cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR
        args: list[cl.Buffer] = []
        for name, (dtype, comps) in _IMAGES.items():
            if name in view.names:
                shape = (height, width) if comps == 1 else (height, width, comps)
                arr = arrays.empty(shape, dtype)
                outs[name] = arr
                args.append(cl.Buffer(self.ctx, flags, hostbuf=arr))
            else:   # not written: any buffer
                args.append(ids)
        positions = geometry.positions.ensure(1)
        vnormals = b.vnormals.ensure(1)
        n_items = -(-npx // RESOLVE_SPAN)
        ev = self.kernel(queue, (max(n_items, 1),), (1,), ids, bary if bary is not None else ids,
                         np.int32(npx), np.int32(RESOLVE_SPAN), np.int32(view.want),
                         b.inst_base.ensure(1), np.int32(tables.inst_base.size),
                         b.inst_mesh.ensure(1), b.mesh_fbase.ensure(1), b.face_rows.ensure(1),
                         positions, vnormals, b.inst_model.ensure(1), b.inst_nrm.ensure(1),
                         b.cam.ensure(1), *args,
                         bins.summary.buf if bins is not None else ids,
                         np.int32(bins.cap if bins is not None else -1))
        return PendingResolve(outs, args, ev)

    def collect(self, queue: cl.CommandQueue, pending: PendingResolve
                ) -> tuple[dict[str, np.ndarray], cl.Event]:
        """After the wait that followed `enqueue`: the outputs (made readable where the
        device does not work in host memory) and the kernel's event."""
        if not shares_host_memory(self.ctx):
            for name, buf in zip(_IMAGES, pending.args, strict=True):
                if name in pending.outs:
                    out = pending.outs[name]
                    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0,
                                                      out.shape, out.dtype, is_blocking=False)
                    mapped.base.release(queue)
            queue.finish()
        return pending.outs, pending.event
