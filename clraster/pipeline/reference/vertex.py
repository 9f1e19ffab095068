"""NumPy twin of the vertex stage inside kernels/setup.cl (`draw_vertices`, `vertex_of`):
the same float32 operations in the same order, kept here as a vertex stream (each setup
work-item of the kernel makes its own draw's vertices in private memory)."""

from __future__ import annotations

import numpy as np

from ...base.layout import (
    DRAW_INSIDE,
    OC_GB_X_NEG,
    OC_GB_X_POS,
    OC_GB_Y_NEG,
    OC_GB_Y_POS,
    OC_INVALID,
    OC_NEEDS_CLIP,
    OC_W_NONPOS,
    OC_X_NEG,
    OC_X_POS,
    OC_Y_NEG,
    OC_Y_POS,
    OC_Z_NEG,
    OC_Z_POS,
    SUBPIXEL_ONE,
    WINVERT_DTYPE,
    WINXY_DTYPE,
)

F32 = np.float32


def viewport(c: np.ndarray, width: int, height: int) -> np.ndarray:
    """Viewport transform of clip positions c float32 (..., 4) with w > 0 (viewport_vertex in
    kernels/common.h). Returns WINVERT_DTYPE (...)."""
    hw, hh = F32(0.5) * F32(width), F32(0.5) * F32(height)
    out = np.zeros(c.shape[:-1], WINVERT_DTYPE)
    with np.errstate(all="ignore"):
        iw = F32(1) / c[..., 3]
        xn, yn, zn = c[..., 0] * iw, c[..., 1] * iw, c[..., 2] * iw
        xw = (xn + F32(1)) * hw
        yw = (F32(1) - yn) * hh
        out["x"] = np.rint(xw * F32(SUBPIXEL_ONE))
        out["y"] = np.rint(yw * F32(SUBPIXEL_ONE))
        out["z"] = zn * F32(0.5) + F32(0.5)
        out["iw"] = iw
    return out


def transform(vertices: np.ndarray, mvp: np.ndarray, kx: np.float32, ky: np.float32,
              width: int, height: int, inside: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object → clip space, outcodes and window positions.

    Args:
        vertices: float32 (N, 3). mvp: float32 row-major matrices, (16,) for all vertices or
            (N, 16) one per vertex; clip = M · [x y z 1]ᵀ. kx, ky: guard-band factors
            (config.guard_band_factors). inside: bool (N,) vertices of clusters inside the
            frustum by a margin, whose outcode tests are skipped (as the kernel does).

    Returns:
        clip float32 (N, 4), outcode uint16 (N,) (config.OC_* bits; a vertex whose clip
        position is not finite gets OC_INVALID alone) and win WINXY_DTYPE (N,): the
        viewport transform of vertices that need no clipping (zeros for the others).
    """
    v = np.asarray(vertices, np.float32)
    m = np.asarray(mvp, np.float32).reshape(-1, 16)
    m = m[0] if m.shape[0] == 1 else m.T  # (16,) scalars, or 16 rows of per-vertex values
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    clip = np.empty((v.shape[0], 4), np.float32)
    with np.errstate(all="ignore"):
        for r in range(4):  # ((m0·x + m1·y) + m2·z) + m3, no fused multiply-add
            clip[:, r] = ((m[4 * r] * x + m[4 * r + 1] * y) + m[4 * r + 2] * z) + m[4 * r + 3]
        cx, cy, cz, cw = clip.T
        zero = np.float32(0)
        oc = np.zeros(v.shape[0], np.uint16)
        for bit, d in ((OC_X_NEG, cx + cw), (OC_X_POS, cw - cx), (OC_Y_NEG, cy + cw),
                       (OC_Y_POS, cw - cy), (OC_Z_NEG, cz + cw), (OC_Z_POS, cw - cz),
                       (OC_GB_X_NEG, cx + kx * cw), (OC_GB_X_POS, kx * cw - cx),
                       (OC_GB_Y_NEG, cy + ky * cw), (OC_GB_Y_POS, ky * cw - cy)):
            oc |= np.where(d < zero, np.uint16(bit), np.uint16(0))
        oc |= np.where(cw > zero, np.uint16(0), np.uint16(OC_W_NONPOS))
    if inside is not None:
        oc[inside] = 0
    bad = ~np.all(np.isfinite(clip), axis=1)
    oc[bad] = OC_INVALID
    win = np.zeros(v.shape[0], WINXY_DTYPE)   # x, y alone, as setup.cl keeps them
    ok = (oc & (OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP)) == 0
    wv = viewport(clip[ok], width, height)
    win["x"][ok], win["y"][ok] = wv["x"], wv["y"]
    return clip, oc, win


def draw_vertices(pool, fd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame's vertex stream, as the kernel's work-items (draw, local vertex) see it.

    Returns pool vertex index int64 (N,), instance int64 (N,) and inside bool (N,) of each
    stream vertex, in stream order (draw.vert_base + local index).
    """
    d = fd.draws
    info = pool.clusters[d["cluster"]].astype(np.int64)
    nv = info[:, 3]
    owner = np.repeat(np.arange(d.size), nv)
    local = np.arange(owner.size) - np.repeat(d["vert_base"].astype(np.int64), nv)
    pv = pool.vert_ids[info[owner, 2] + local].astype(np.int64)
    return pv, d["instance"][owner].astype(np.int64), (d["flags"][owner] & DRAW_INSIDE) != 0


def transform_draws(pool, fd, kx: np.float32, ky: np.float32, width: int, height: int):
    """Vertex stage over a frame's draws (mirrors draw_vertices in kernels/setup.cl)."""
    pv, inst, inside = draw_vertices(pool, fd)
    return transform(pool.positions[pv], fd.mvps[inst], kx, ky, width, height, inside)
