"""Device shading host side (kernels/shade.cl: `shade_pixels`, `shade_ssaa`,
`seen_instances`): the RGB(A)8 image `clraster.output.shade` makes from a frame's ids and
barycentrics, on the device, from the scene's tables that the resolve stage uploads
(`clraster.pipeline.stages.resolve.ResolveStage.upload_tables`) and the shading's own
(`ShadeBuffers`). The twin is the NumPy path of `clraster.output.shade`
(`clraster.pipeline.reference.shade` names it)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ..arraypool import ArrayPool, page_aligned
from ..device import kernel, program, shares_host_memory, wait
from ..drawlist import GeometryPool
from ..resolving import SHADE_SPAN, ResolveTables, ShadeSources
from ._buffers import GrowBuffer
from .resolve import ResolveStage

__all__ = ["ShadeBuffers", "ShadeStage"]

#: kernels/shade.cl SH_* flag bits
_SH_SMOOTH, _SH_TWO_SIDED, _SH_IDENTITY, _SH_SOURCES = 1, 2, 4, 8


@dataclass
class ShadeBuffers:
    """Scene → shading boundary (kernels/shade.cl SHADE_ARGS; shapes and dtypes:
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


class ShadeStage:
    """The shading kernels of one context, over ``resolve``'s tables (its buffers hold the
    face table, face normals and vertex normals the kernels read)."""

    def __init__(self, resolve: ResolveStage, config: RasterConfig) -> None:
        ctx = resolve.ctx
        prg = program(ctx, "shade", tuple(config.build_options()))
        self.k_shade = kernel(prg, "shade_pixels")
        self.k_ssaa = kernel(prg, "shade_ssaa")
        self.k_seen = kernel(prg, "seen_instances")
        self.ctx = ctx
        self.resolve = resolve
        self._shared = shares_host_memory(ctx)
        self.shade_buffers = ShadeBuffers(
            *(GrowBuffer(ctx) for _ in range(9)),
            *(GrowBuffer(ctx, host=True) for _ in range(2)))
        self._shade_tables: ResolveTables | None = None
        self._sources_key: object = None
        self._sources: ShadeSources | None = None
        self._face_vn = False   # face_vn holds the shading tables' (a smooth call was made)

    def _upload_shade(self, queue: cl.CommandQueue, pool: GeometryPool,
                      tables: ResolveTables, smooth: bool, sources: ShadeSources | None,
                      sources_key: object) -> bool:
        """Upload what the shading kernels read that changed: the scene's tables (once per
        `ResolveTables`: `ResolveStage.upload_tables` and the shading's own), the vertex
        normals (first smooth call), the colour sources (when ``sources_key`` changes). True
        when something was copied (the caller waits before the host arrays may go)."""
        sb = self.shade_buffers
        copied = self.resolve.upload_tables(queue, pool, tables, smooth)

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
        b, sb = self.resolve.buffers, self.shade_buffers
        _, shift = tables.buckets()
        return (sb.bucket.ensure(1), np.int32(shift), sb.inst_base.ensure(1),
                np.int32(tables.inst_base.size), sb.inst_row.ensure(1), b.face_rows.ensure(1),
                b.vnormals.ensure(1), sb.face_vn.ensure(1),
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
        `clraster.output.shade` makes it (kernels/shade.cl shade_pixels, shade_ssaa).

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
        wait(queue, keep=(ids_buf, ids_arr, bary_buf, bary_arr, out_buf, out,
                          self.resolve.buffers, self.shade_buffers))
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
