"""Resolve host side (kernels/resolve.cl): the per-pixel outputs asked for
(`clraster.base.checks.RESOLVE_OUTPUTS`) made after the frame's last raster pass from its ids
and barycentrics and the scene's geometry already on the device (the pool positions the
vertex stage reads, `GeometryBuffers.positions`), one launch a frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from ...base.config import RasterConfig
from ..arraypool import ArrayPool
from ..device import kernel, program, shares_host_memory, wait
from ..drawlist import GeometryPool
from ..resolving import OUTPUT_BITS, RESOLVE_SPAN, ResolveTables, ResolveView
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
    shade: GrowBuffer
    tints: GrowBuffer


class ResolveStage:
    def __init__(self, ctx: cl.Context, config: RasterConfig) -> None:
        opts = (*config.build_options(),
                *(f"-D{_DEFINES[n]}={bit}" for n, bit in OUTPUT_BITS.items()))
        prg = program(ctx, "resolve", opts)
        self.kernel = kernel(prg, "resolve_pixels")
        self.k_shade = kernel(prg, "shade_pixels")
        self.ctx = ctx
        self.buffers = ResolveBuffers(*(GrowBuffer(ctx) for _ in range(7)),
                                      *(GrowBuffer(ctx, host=True) for _ in range(4)))
        self._tables: ResolveTables | None = None
        self._smooth = False

    def _upload_tables(self, queue: cl.CommandQueue, pool: GeometryPool,
                       tables: ResolveTables, smooth: bool) -> None:
        b = self.buffers
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
        if smooth and not self._smooth:
            vn = tables.smooth_normals(pool)
            buf = b.vnormals.ensure(vn.nbytes, "vertex normal buffer")
            if vn.nbytes:
                cl.enqueue_copy(queue, buf, vn, is_blocking=False)
            self._smooth = True
        queue.finish()   # the host arrays may go: the copies are done

    def run(self, queue: cl.CommandQueue, geometry: GeometryBuffers, pool: GeometryPool,
            tables: ResolveTables, view: ResolveView, ids: cl.Buffer, bary: cl.Buffer | None,
            width: int, height: int, arrays: ArrayPool) -> tuple[dict[str, np.ndarray],
                                                                  cl.Event]:
        """Make the outputs ``view.names`` of a frame whose ids (int32 (H, W)) and
        barycentrics (float32 (H, W, 3), or None when no output asked for needs them) are
        in the device buffers ``ids`` and ``bary``; ``geometry`` holds ``pool``'s
        positions (`GeometryStage.upload_pool`). Returns name → array (readable on return;
        shapes, dtypes, background values: `clraster.pipeline.reference.resolve.resolve`)
        and the kernel's event. Call while the queue is idle (after the frame's last pass)."""
        b = self.buffers
        smooth = any(n in view.names for n in ("smooth_normals", "smooth_camera_normals"))
        self._upload_tables(queue, pool, tables, smooth)
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
                         b.cam.ensure(1), *args)
        wait(queue, keep=(args, outs, self.buffers))
        if not shares_host_memory(self.ctx):
            for name, buf in zip(_IMAGES, args, strict=True):
                if name in outs:
                    mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0,
                                                      outs[name].shape, outs[name].dtype,
                                                      is_blocking=False)
                    mapped.base.release(queue)
            queue.finish()
        return outs, ev

    def shade(self, queue: cl.CommandQueue, pool: GeometryPool, tables: ResolveTables,
              ids: np.ndarray, bary: np.ndarray | None, *, light: np.ndarray, ambient: float,
              albedo: np.ndarray, two_sided: bool, tints: np.ndarray | None, smooth: bool,
              flat_raw: bool, background: np.ndarray, alpha: bool
              ) -> tuple[np.ndarray, cl.Event]:
        """Lambert-shade a frame's ids int32 (H, W) (and barycentrics float32 (H, W, 3),
        for ``smooth``) on the device: uint8 (H, W, 3 | 4), as `clraster.output.shade.shade`
        makes it for surfaces without colour sources (kernels/resolve.cl shade_pixels says
        how). ``tints``: float64 (I, 3) per-instance albedo, or None for ``albedo``;
        ``flat_raw``: light a Mesh's face normals as they are (no instance matrix)."""
        b = self.buffers
        self._upload_tables(queue, pool, tables, smooth)
        params = np.zeros(8)
        params[0:3], params[3], params[4:7] = light, ambient, albedo
        params[7] = 1.0 if two_sided else 0.0
        b.shade.write(queue, params)
        if tints is not None:
            b.tints.write(queue, np.ascontiguousarray(tints, np.float64))
        h, w = ids.shape
        ch = 4 if alpha else 3
        out = np.empty((h, w, ch), np.uint8)
        flags = cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR
        ro = cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR
        ids_buf = cl.Buffer(self.ctx, ro, hostbuf=np.ascontiguousarray(ids, np.int32))
        bary_buf = (cl.Buffer(self.ctx, ro, hostbuf=np.ascontiguousarray(bary, np.float32))
                    if smooth and bary is not None else ids_buf)
        out_buf = cl.Buffer(self.ctx, flags, hostbuf=out)
        npx = h * w
        ev = self.k_shade(queue, (max(-(-npx // RESOLVE_SPAN), 1),), (1,), ids_buf, bary_buf,
                          np.int32(npx), np.int32(RESOLVE_SPAN), b.inst_base.ensure(1),
                          np.int32(tables.inst_base.size), b.inst_mesh.ensure(1),
                          b.mesh_fbase.ensure(1), b.face_verts.ensure(1), b.face_nrm.ensure(1),
                          b.vnormals.ensure(1), b.inst_nrm.ensure(1), b.shade.ensure(1),
                          b.tints.ensure(1), np.int32(tints is not None), np.int32(smooth),
                          np.int32(flat_raw), np.int32(ch), np.uint8(background[0]),
                          np.uint8(background[1]), np.uint8(background[2]), out_buf)
        wait(queue, keep=(ids_buf, bary_buf, out_buf, out, self.buffers))
        if not shares_host_memory(self.ctx):
            mapped, _ = cl.enqueue_map_buffer(queue, out_buf, cl.map_flags.READ, 0, out.shape,
                                              out.dtype, is_blocking=True)
            mapped.base.release(queue)
            queue.finish()
        return out, ev
