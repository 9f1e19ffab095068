"""Resolve host side (kernels/resolve.cl): the per-pixel outputs asked for
(`clraster.base.checks.RESOLVE_OUTPUTS`) made after the frame's last raster pass from its ids
and barycentrics and the scene's geometry already on the device (the pool positions the
vertex stage reads, `GeometryBuffers.positions`), one launch a frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ..arraypool import ArrayPool, page_aligned
from ..device import event_ms, kernel, program, shares_host_memory, wait
from ..drawlist import GeometryPool
from ..resolving import (
    OUTPUT_BITS,
    RESOLVE_SPAN,
    SHADE_SPAN,
    ResolveTables,
    ResolveView,
    ShadeSources,
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
#: kernels/resolve.cl SH_* flag bits
_SH_SMOOTH, _SH_TWO_SIDED, _SH_IDENTITY, _SH_SOURCES = 1, 2, 4, 8


@dataclass
class ResolveBuffers:
    """Scene → resolve boundary (shapes and dtypes: `clraster.pipeline.resolving`).

    Per scene (uploaded when the tables change): inst_base int32 (I,), inst_mesh int32
    (I,), mesh_fbase int32 (U,), face_verts int32 (F, 3), face_nrm float32 (F, 3), inst_nrm
    float64 (I, 9),
    vnormals float32 (V, 3) (on the first smooth output). Per frame: inst_model float64
    (I, 12), cam float64 (16,). The outputs are the caller's arrays (`ArrayPool`) under
    CL_MEM_USE_HOST_PTR buffers, as the raster's.
    """

    inst_base: GrowBuffer
    inst_mesh: GrowBuffer
    mesh_fbase: GrowBuffer
    face_verts: GrowBuffer
    face_nrm: GrowBuffer
    inst_nrm: GrowBuffer
    vnormals: GrowBuffer
    inst_model: GrowBuffer
    cam: GrowBuffer


@dataclass
class ShadeBuffers:
    """Scene → shading boundary (kernels/resolve.cl SHADE_ARGS; shapes and dtypes:
    `ResolveTables.buckets`, `inst_rows`, `shade_normal_mats`, `ShadeSources`). The face
    table, face normals and vertex normals are `ResolveBuffers`'. Per scene: inst_base
    int32 (I,), bucket int32 (B,), inst_row int32 (I,), inst_nrm float32 (I, 12); per colour
    sources: inst_src int32 (I, 8), colours float32 (N, 4), uvs float32 (M, 2), texels
    float32 (T, 4); per call (host buffers): inst_col float32 (I, 4), bad int32 (1,). On
    the first smooth call: face_vn int16 (F, 16) (`ResolveTables.face_vertex_normals`).
    """

    inst_base: GrowBuffer
    bucket: GrowBuffer
    inst_row: GrowBuffer
    inst_nrm: GrowBuffer
    inst_src: GrowBuffer
    colours: GrowBuffer
    uvs: GrowBuffer
    texels: GrowBuffer
    face_vn: GrowBuffer
    inst_col: GrowBuffer
    bad: GrowBuffer


@dataclass
class PendingResolve:
    """A resolve enqueued (`ResolveStage.enqueue`): its output arrays (name → array, written
    by the kernel), the buffers over them (in the kernel's argument order), its event.
    Keep it alive until a wait has seen the kernel complete."""

    outs: dict[str, np.ndarray]
    args: list[cl.Buffer]
    event: cl.Event


class ResolveFollow:
    """The frame's resolve enqueued right behind each raster launch (`StageChain.draw`'s
    ``follow``), so the wait for the raster covers it too: no host round trip (a wait, the
    host's resolve set-up, a second wait) between the last pass and the outputs. The
    latest enqueue is the one after the frame's last raster launch; an earlier one (a
    pass redrawn, or an earlier pass of a streamed frame) is kept alive until `result`,
    past the wait that saw it finish."""

    def __init__(self, stage: ResolveStage, geometry: GeometryBuffers, pool: GeometryPool,
                 tables: ResolveTables, view: ResolveView, width: int, height: int,
                 arrays: ArrayPool) -> None:
        self._stage, self._geometry, self._pool = stage, geometry, pool
        self._tables, self._view, self._size, self._arrays = tables, view, (width, height), arrays
        self._pending: PendingResolve | None = None
        self._after: Any = None   # the frame buffers the last enqueue read
        self._queue: cl.CommandQueue | None = None
        self._stale: list[PendingResolve] = []

    @property
    def view(self) -> ResolveView:
        """The view the outputs are made for."""
        return self._view

    def __call__(self, queue: cl.CommandQueue, out: Any, bins: Any) -> None:
        """Enqueue the resolve of ``out`` (a `RasterOutput` whose raster over the
        `BinBuffers` ``bins`` was just enqueued: where that raster skips a list that did
        not fit, so does the resolve)."""
        if self._pending is not None:
            self._stale.append(self._pending)
        bary = out.bufs[2] if out.bary is not None else None
        self._pending = self._stage.enqueue(queue, self._geometry, self._pool, self._tables,
                                            self._view, out.bufs[1], bary, *self._size,
                                            self._arrays, bins)
        self._after, self._queue = out, queue

    def result(self, out: Any) -> tuple[dict[str, np.ndarray], float] | None:
        """After the frame's last wait: the outputs (name → array) of the resolve enqueued
        after the last raster launch into ``out`` and its milliseconds, or None when none
        was (the caller resolves then)."""
        self._stale.clear()
        pending, self._pending = self._pending, None
        if pending is None or self._after is not out or self._queue is None:
            return None
        outs, ev = self._stage.collect(self._queue, pending)
        return outs, event_ms([ev])


class ResolveStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        opts = (*config.build_options(),
                *(f"-D{_DEFINES[n]}={bit}" for n, bit in OUTPUT_BITS.items()))
        prg = program(ctx, "resolve", opts)
        self.kernel = kernel(prg, "resolve_pixels")
        self.k_shade = kernel(prg, "shade_pixels")
        self.k_ssaa = kernel(prg, "shade_ssaa")
        self.k_seen = kernel(prg, "seen_instances")
        self.ctx = ctx
        self._shared = shares_host_memory(ctx)
        self.buffers = ResolveBuffers(*(GrowBuffer(ctx) for _ in range(7)),
                                      *(GrowBuffer(ctx, host=True) for _ in range(2)))
        self.shade_buffers = ShadeBuffers(
            *(GrowBuffer(ctx) for _ in range(9)),
            *(GrowBuffer(ctx, host=True) for _ in range(2)))
        self._tables: ResolveTables | None = None
        self._shade_tables: ResolveTables | None = None
        self._sources_key: object = None
        self._sources: ShadeSources | None = None
        self._smooth = False
        self._face_vn = False   # face_vn holds the shading tables' (a smooth call was made)

    def _upload_tables(self, queue: cl.CommandQueue, pool: GeometryPool,
                       tables: ResolveTables, smooth: bool) -> bool:
        """Upload ``tables`` (and the vertex normals, for ``smooth``) unless they are the
        ones on the device; True when something was copied (wait before the host arrays
        may go)."""
        b = self.buffers
        copied = False
        if tables is not self._tables:
            for gb, arr in ((b.inst_base, tables.inst_base), (b.inst_mesh, tables.inst_mesh),
                            (b.mesh_fbase, tables.mesh_fbase),
                            (b.face_verts, tables.face_verts),
                            (b.face_nrm, tables.face_normals),
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
        if self._upload_tables(queue, pool, tables, smooth):
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
                         b.inst_mesh.ensure(1), b.mesh_fbase.ensure(1), b.face_verts.ensure(1),
                         b.face_nrm.ensure(1),
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

    def _upload_shade(self, queue: cl.CommandQueue, pool: GeometryPool,
                      tables: ResolveTables, smooth: bool, sources: ShadeSources | None,
                      sources_key: object) -> bool:
        """Upload what the shading kernels read that changed: the scene's tables (once per
        `ResolveTables`: `_upload_tables` and the shading's own), the vertex normals (first
        smooth call), the colour sources (when ``sources_key`` changes). True when something
        was copied (the caller waits before the host arrays may go)."""
        sb = self.shade_buffers
        copied = self._upload_tables(queue, pool, tables, smooth)

        def put(gb: GrowBuffer, arr: np.ndarray, what: str) -> None:
            buf = gb.ensure(arr.nbytes, what)
            if arr.nbytes:
                cl.enqueue_copy(queue, buf, np.ascontiguousarray(arr), is_blocking=False)

        if tables is not self._shade_tables:
            bucket, _ = tables.buckets()
            for gb, arr in ((sb.inst_base, tables.inst_base), (sb.bucket, bucket),
                            (sb.inst_row, tables.inst_rows()),
                            (sb.inst_nrm, tables.shade_normal_mats())):
                put(gb, arr, "shading table")
            self._shade_tables, self._sources_key = tables, None
            self._face_vn = False
            copied = True
        if smooth and not self._face_vn:
            put(sb.face_vn, tables.face_vertex_normals(pool), "face vertex normal table")
            self._face_vn = copied = True
        if sources is not None and sources_key != self._sources_key:
            for gb, arr in ((sb.inst_src, sources.inst_src), (sb.colours, sources.colours),
                            (sb.uvs, sources.uvs), (sb.texels, sources.texels)):
                put(gb, arr, "colour source buffer")
            self._sources_key, self._sources = sources_key, sources
            copied = True
        return copied

    def _scene_args(self, tables: ResolveTables) -> tuple[Any, ...]:
        b, sb = self.buffers, self.shade_buffers
        _, shift = tables.buckets()
        return (sb.bucket.ensure(1), np.int32(shift), sb.inst_base.ensure(1),
                np.int32(tables.inst_base.size), sb.inst_row.ensure(1), b.face_verts.ensure(1),
                b.face_nrm.ensure(1), b.vnormals.ensure(1), sb.face_vn.ensure(1),
                sb.inst_nrm.ensure(1))

    def _frame_buffer(self, arr: np.ndarray, dtype: type) -> tuple[cl.Buffer, np.ndarray]:
        """A read-only device buffer over a frame array (in place on a CPU device)."""
        a: np.ndarray = np.ascontiguousarray(arr, dtype)
        flags = cl.mem_flags.READ_ONLY | (cl.mem_flags.USE_HOST_PTR if self._shared
                                          else cl.mem_flags.COPY_HOST_PTR)
        return cl.Buffer(self.ctx, flags, hostbuf=a), a

    def shade(self, queue: cl.CommandQueue, pool: GeometryPool, tables: ResolveTables,
              ids: np.ndarray, bary: np.ndarray | None, *, light: np.ndarray, ambient: float,
              two_sided: bool, inst_col: np.ndarray, sources: ShadeSources | None,
              sources_key: object, smooth: bool, identity: bool, max_id: int,
              background: np.ndarray, alpha: bool, k: int = 1,
              arrays: ArrayPool | None = None) -> tuple[np.ndarray | None, cl.Event]:
        """Shade a frame's ids int32 (k·H, k·W) (and barycentrics float32 (k·H, k·W, 3),
        for smooth shading and colour sources) on the device: uint8 (H, W, 3 | 4), as
        `clraster.output.shade` makes it (kernels/resolve.cl shade_pixels, shade_ssaa).

        ``inst_col``: float32 (I, 4) each instance's albedo before its colour sources
        (tint · texture factor, or the default albedo); ``sources``: the colour sources or
        None (kept on the device while ``sources_key`` is the same); ``identity``: light the
        table's normals without instance matrices (a Mesh); ``max_id``: the largest valid
        id. Returns (None, event) when the frame holds an id below −1 or above ``max_id``
        (the caller raises)."""
        sb = self.shade_buffers
        copied = self._upload_shade(queue, pool, tables, smooth, sources, sources_key)
        if copied:
            queue.finish()   # the host arrays may go: the copies are done
        sb.inst_col.write(queue, np.ascontiguousarray(inst_col, np.float32))
        sb.bad.write(queue, np.zeros(1, np.int32))
        fh, fw = ids.shape
        h, w = fh // k, fw // k
        ch = 4 if alpha else 3
        # page-aligned (the kernel's vector stores are aligned)
        out = (arrays.empty((h, w, ch), np.uint8) if arrays is not None
               else page_aligned(h * w * ch).reshape(h, w, ch))
        ids_buf, ids_arr = self._frame_buffer(ids, np.int32)
        need_bary = smooth or sources is not None
        bary_buf, bary_arr = (self._frame_buffer(bary, np.float32)
                              if need_bary and bary is not None else (ids_buf, ids_arr))
        flags = cl.mem_flags.WRITE_ONLY | cl.mem_flags.USE_HOST_PTR
        out_buf = cl.Buffer(self.ctx, flags, hostbuf=out)
        bits = ((_SH_SMOOTH if smooth else 0) | (_SH_TWO_SIDED if two_sided else 0)
                | (_SH_IDENTITY if identity else 0) | (_SH_SOURCES if sources is not None else 0))
        lw = np.zeros(1, cl.cltypes.float4)
        lw[0] = (light[0], light[1], light[2], ambient)
        src_args = ((sb.inst_src, sb.colours, sb.uvs, sb.texels) if sources is not None
                    else (sb.inst_col,) * 4)
        tail = (*self._scene_args(tables), sb.inst_col.ensure(1),
                *(g.ensure(1) for g in src_args), lw[0], np.int32(bits))
        bg = np.uint32(int(background[0]) | int(background[1]) << 8
                       | int(background[2]) << 16)
        n_out = h * w
        items = (max(-(-n_out // SHADE_SPAN), 1),)
        if k == 1:
            ev = self.k_shade(queue, items, (1,), ids_buf, bary_buf, np.int32(n_out),
                              np.int32(SHADE_SPAN), np.int32(max_id), bg, np.int32(ch),
                              sb.bad.ensure(4), out_buf, *tail)
        else:
            span = max(SHADE_SPAN // (k * k), 16)
            items = (max(-(-n_out // span), 1),)
            ev = self.k_ssaa(queue, items, (1,), ids_buf, bary_buf, np.int32(n_out),
                             np.int32(span), np.int32(w), np.int32(k), np.int32(max_id), bg,
                             np.int32(ch), sb.bad.ensure(4), out_buf, *tail)
        wait(queue, keep=(ids_buf, ids_arr, bary_buf, bary_arr, out_buf, out, self.buffers,
                          self.shade_buffers))
        if not self._shared:
            mapped, _ = cl.enqueue_map_buffer(queue, out_buf, cl.map_flags.READ, 0, out.shape,
                                              out.dtype, is_blocking=True)
            mapped.base.release(queue)
            queue.finish()
        if sb.bad.read(queue, np.int32, 1)[0]:
            return None, ev
        return out, ev

    def seen(self, queue: cl.CommandQueue, pool: GeometryPool, tables: ResolveTables,
             ids: np.ndarray, max_id: int) -> np.ndarray | None:
        """bool (I,): the instances with a pixel in ``ids`` (int32 (H, W)); None when an id
        is below −1 or above ``max_id``."""
        sb = self.shade_buffers
        if self._upload_shade(queue, pool, tables, False, None, None):
            queue.finish()
        n_inst = int(tables.inst_base.size)
        seen = np.zeros(max(n_inst, 1), np.uint8)
        flags = cl.mem_flags.READ_WRITE | (cl.mem_flags.USE_HOST_PTR if self._shared
                                           else cl.mem_flags.COPY_HOST_PTR)
        seen_buf = cl.Buffer(self.ctx, flags, hostbuf=seen)
        sb.bad.write(queue, np.zeros(1, np.int32))
        ids_buf, ids_arr = self._frame_buffer(ids, np.int32)
        npx = ids.size
        self.k_seen(queue, (max(-(-npx // SHADE_SPAN), 1),), (1,), ids_buf, np.int32(npx),
                    np.int32(SHADE_SPAN), np.int32(max_id), sb.bad.ensure(4), seen_buf,
                    *self._scene_args(tables)[:4])
        wait(queue, keep=(ids_buf, ids_arr, seen_buf, seen, self.shade_buffers))
        if not self._shared:
            cl.enqueue_copy(queue, seen, seen_buf)
        if sb.bad.read(queue, np.int32, 1)[0]:
            return None
        return seen[:n_inst].astype(bool)
