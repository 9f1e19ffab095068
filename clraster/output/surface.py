"""The per-pixel float64 arithmetic of the visible surface, written once in the order
kernels/resolve.cl computes it: the host outputs (`clraster.output.outputs`), the shading
normals (`clraster.output.shade.pixel_normals`) and the resolve stage's NumPy twin
(`clraster.pipeline.reference.resolve`) all call these, so a frame's device-made outputs and
the same outputs computed on the host are the same bits. Each function takes rows (K, 3)
float64 and sums in a written order (no BLAS, whose order and fused multiply-adds vary)."""

from __future__ import annotations

import numpy as np

__all__ = ["affine_rows", "blend_rows", "cross_rows", "dot_rows", "mat3_rows", "unit_rows"]

_DBL_MAX = np.finfo(np.float64).max


def blend_rows(b: np.ndarray, a: np.ndarray, bb: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3): ``(b0·a + b1·bb) + b2·c`` per row and component, ``b`` (K, 3) weights (the
    barycentric blend of a face's three corners, kernel blend3)."""
    return (b[:, 0:1] * a + b[:, 1:2] * bb) + b[:, 2:3] * c


def dot_rows(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K,): ``(u0·v0 + u1·v1) + u2·v2`` per row (``u`` or ``v`` may be one (3,) vector)."""
    u = np.broadcast_to(u, np.broadcast_shapes(np.shape(u), np.shape(v)))
    v = np.broadcast_to(v, u.shape)
    return (u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]) + u[..., 2] * v[..., 2]


def cross_rows(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 3): u × v per row, as `numpy.cross` writes it."""
    return np.stack([u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
                     u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                     u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]], axis=1)


def unit_rows(v: np.ndarray) -> np.ndarray:
    """(K, 3): the rows of ``v`` times the reciprocal of their length ``sqrt((x² + y²) +
    z²)``; zero rows where the length is zero or not finite (a degenerate face: kernel
    unit3)."""
    length = np.sqrt(dot_rows(v, v))
    ok = (length > 0.0) & (length <= _DBL_MAX)
    out = np.zeros_like(v)
    out[ok] = v[ok] * (1.0 / length[ok])[:, None]
    return out


def mat3_rows(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 3): row-major 3 × 3 matrices ``m`` ((K, 9) per row, or one (9,)) times the rows
    of ``v``, each component ``(m0·x + m1·y) + m2·z`` (kernel mat3)."""
    m = np.broadcast_to(m, (v.shape[0], 9))
    return np.stack([(m[:, 3 * r] * v[:, 0] + m[:, 3 * r + 1] * v[:, 1])
                     + m[:, 3 * r + 2] * v[:, 2] for r in range(3)], axis=1)


def affine_rows(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 3): row-major 3 × 4 affine matrices ``m`` ((K, 12), or one (12,)) applied to the
    points ``v``, each component ``((m0·x + m1·y) + m2·z) + m3`` (common.h MAT_ROW)."""
    m = np.broadcast_to(m, (v.shape[0], 12))
    return np.stack([((m[:, 4 * r] * v[:, 0] + m[:, 4 * r + 1] * v[:, 1])
                      + m[:, 4 * r + 2] * v[:, 2]) + m[:, 4 * r + 3] for r in range(3)],
                    axis=1)
