"""NumPy twin of kernels/vertex.cl: the same float32 operations in the same order."""

from __future__ import annotations

import numpy as np

from ..config import (
    OC_GB_X_NEG,
    OC_GB_X_POS,
    OC_GB_Y_NEG,
    OC_GB_Y_POS,
    OC_INVALID,
    OC_X_NEG,
    OC_X_POS,
    OC_Y_NEG,
    OC_Y_POS,
    OC_Z_NEG,
    OC_Z_POS,
)


def transform(vertices: np.ndarray, mvp: np.ndarray, kx: np.float32, ky: np.float32
              ) -> tuple[np.ndarray, np.ndarray]:
    """Object → clip space and outcodes.

    Args:
        vertices: float32 (N, 3). mvp: float32 (4, 4) row-major, clip = mvp · [x y z 1]ᵀ.
        kx, ky: guard-band factors (config.guard_band_factors).

    Returns:
        clip float32 (N, 4) and outcode uint16 (N,) (config.OC_* bits; a vertex whose clip
        position is not finite gets OC_INVALID alone).
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
    bad = ~np.all(np.isfinite(clip), axis=1)
    oc[bad] = OC_INVALID
    return clip, oc
