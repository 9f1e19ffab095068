"""Twin of kernels/resolve.cl: the per-pixel outputs of `clraster.base.checks.RESOLVE_OUTPUTS`
from a frame's ids and barycentrics and the scene's pool, vectorized over the covered pixels
(`clraster.pipeline.resolving` describes the inputs and the arithmetic). Every float64 sum is
written in the kernel's order, so for the same ids and barycentrics both give the same bits."""

from __future__ import annotations

import numpy as np

from ...output.surface import (
    affine_rows,
    blend_rows,
    dot_rows,
    mat3_rows,
    unit_rows,
)
from ..drawlist import GeometryPool
from ..resolving import ResolveTables, ResolveView

__all__ = ["resolve"]


def _f32(v: np.ndarray) -> np.ndarray:
    """float64 rows rounded to float32 and back (the kernel's round32)."""
    return v.astype(np.float32).astype(np.float64)


def resolve(pool: GeometryPool, tables: ResolveTables, view: ResolveView, ids: np.ndarray,
            bary: np.ndarray | None) -> dict[str, np.ndarray]:
    """The resolve outputs ``view.names`` of a frame: name → array, (H, W) or (H, W, 3)
    (mask bool; linear_depth, distance float32, inf on the background; points float64;
    normals float32; zeros on the background). ``ids`` int32 (H, W); ``bary`` float32
    (H, W, 3), needed by the outputs made from the surface point or smooth normals."""
    h, w = ids.shape
    names = view.names
    flat = np.asarray(ids).reshape(-1)
    sel = np.flatnonzero(flat >= 0)
    tid = flat[sel].astype(np.int64)
    out: dict[str, np.ndarray] = {}
    inst = np.searchsorted(tables.inst_base, tid, side="right") - 1
    row = tables.mesh_fbase[tables.inst_mesh[inst]].astype(np.int64) + (
        tid - tables.inst_base[inst])
    fv = tables.face_verts[row]
    b = None
    if bary is not None:
        b = np.asarray(bary, np.float32).reshape(-1, 3)[sel].astype(np.float64)

    def image(name: str, values: np.ndarray, dtype: type, fill: float) -> None:
        shape = (h, w) + values.shape[1:]
        img = np.full((h * w,) + values.shape[1:], fill, dtype)
        img[sel] = values
        out[name] = img.reshape(shape)

    if "mask" in names:
        out["mask"] = (flat >= 0).reshape(h, w)
    if any(n in names for n in ("linear_depth", "distance", "points")):
        assert b is not None, "the surface point needs the barycentrics"
        va, vb, vc = (pool.positions[fv[:, k]].astype(np.float64) for k in range(3))
        world = affine_rows(view.model[inst], blend_rows(b, va, vb, vc))
        cam = view.cam
        off = world - cam[3:6]
        along = dot_rows(off, cam[0:3])
        if "linear_depth" in names:
            image("linear_depth", along.astype(np.float32), np.float32, np.inf)
        if "distance" in names:
            d = along if cam[15] != 0.0 else np.sqrt(dot_rows(off, off))
            image("distance", d.astype(np.float32), np.float32, np.inf)
        if "points" in names:
            image("points", world, np.float64, 0.0)
    smooth = [n for n in ("smooth_normals", "smooth_camera_normals") if n in names]
    flat_n = [n for n in ("normals", "camera_normals") if n in names]
    if smooth or flat_n:
        fn = tables.face_normals[row].astype(np.float64)
        nm = tables.normal_mats[inst]
        cm = view.cam[6:15]
        normals = []
        if flat_n:
            normals.append(("normals", "camera_normals", fn))
        if smooth:
            assert b is not None, "smooth normals need the barycentrics"
            vn = tables.smooth_normals(pool)
            s = blend_rows(b, *(vn[fv[:, k]].astype(np.float64) for k in range(3)))
            weak = ~(np.sqrt(dot_rows(s, s)) >= 1e-6)
            s[weak] = fn[weak]
            normals.append(("smooth_normals", "smooth_camera_normals", s))
        for world_name, cam_name, n in normals:
            wn = _f32(unit_rows(mat3_rows(nm, n)))
            if world_name in names:
                image(world_name, wn.astype(np.float32), np.float32, 0.0)
            if cam_name in names:
                image(cam_name, unit_rows(mat3_rows(cm, wn)).astype(np.float32), np.float32,
                      0.0)
    return out
