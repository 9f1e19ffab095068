"""NumPy twin of kernels/vertex.cl: the same float32 operations in the same order."""

from __future__ import annotations

import numpy as np

from ..config import (
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
              width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Object → clip space and outcodes.

    Args:
        vertices: float32 (N, 3). mvp: float32 (4, 4) row-major, clip = mvp · [x y z 1]ᵀ.
        kx, ky: guard-band factors (config.guard_band_factors).

    Returns:
        clip float32 (N, 4), outcode uint16 (N,) (config.OC_* bits; a vertex whose clip
        position is not finite gets OC_INVALID alone) and win WINVERT_DTYPE (N,): the
        viewport transform of vertices that need no clipping (zeros for the others).
    """
    v = np.asarray(vertices, np.float32)
    m = np.asarray(mvp, np.float32)
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    clip = np.empty((v.shape[0], 4), np.float32)
    with np.errstate(all="ignore"):
        for r in range(4):  # ((m0·x + m1·y) + m2·z) + m3, no fused multiply-add
            clip[:, r] = ((m[r, 0] * x + m[r, 1] * y) + m[r, 2] * z) + m[r, 3]
        cx, cy, cz, cw = clip.T
        zero = np.float32(0)
        oc = np.zeros(v.shape[0], np.uint16)
        for bit, d in ((OC_X_NEG, cx + cw), (OC_X_POS, cw - cx), (OC_Y_NEG, cy + cw),
                       (OC_Y_POS, cw - cy), (OC_Z_NEG, cz + cw), (OC_Z_POS, cw - cz),
                       (OC_GB_X_NEG, cx + kx * cw), (OC_GB_X_POS, kx * cw - cx),
                       (OC_GB_Y_NEG, cy + ky * cw), (OC_GB_Y_POS, ky * cw - cy)):
            oc |= np.where(d < zero, np.uint16(bit), np.uint16(0))
        oc |= np.where(cw > zero, np.uint16(0), np.uint16(OC_W_NONPOS))
    bad = ~np.all(np.isfinite(clip), axis=1)
    oc[bad] = OC_INVALID
    win = np.zeros(v.shape[0], WINVERT_DTYPE)
    ok = (oc & (OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP)) == 0
    win[ok] = viewport(clip[ok], width, height)
    return clip, oc, win
