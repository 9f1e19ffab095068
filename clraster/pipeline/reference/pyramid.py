"""NumPy twin of kernels/pyramid.cl: the depth pyramid and the conservative box test.

`build` is bit-identical to the kernel (a maximum is exact; ties and signed zeros resolve
the same way because both pick with ``a > b ? a : b`` in the same order). `test_boxes` does
the kernel's float32 operations in the kernel's order, vectorized over boxes and looping over
the 8 corners, so both give the same answer for every box.
"""

from __future__ import annotations

import numpy as np

# Error-model constants of kernels/pyramid.cl (see the comments there for the derivation).
from ...base.layout import HIZ_DEPTH_SLACK, HIZ_EPS, HIZ_PIXEL_SLACK
from ..boxes import Occlusion

F32 = np.float32


def _farther(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.where(a > b, a, b)


def reduce_level(level: np.ndarray) -> np.ndarray:
    """The next level: texel (i, j) = max of texels (2i|2i+1, 2j|2j+1), clamped at the edge."""
    h, w = level.shape
    xa = np.arange(0, w, 2)
    xb = np.minimum(xa + 1, w - 1)
    ya = np.arange(0, h, 2)
    yb = np.minimum(ya + 1, h - 1)
    ra, rb = level[ya], level[yb]
    return _farther(_farther(ra[:, xa], ra[:, xb]), _farther(rb[:, xa], rb[:, xb]))


def build(depth: np.ndarray) -> list[np.ndarray]:
    """All pyramid levels of a float32 (H, W) depth buffer: level 0 (a copy) first, down to
    (1, 1). Every texel of level L is the maximum depth over its footprint, the level-0
    pixels [i·2^L, min((i+1)·2^L, W)) × [j·2^L, min((j+1)·2^L, H))."""
    d = np.asarray(depth)
    if d.dtype != np.float32 or d.ndim != 2 or d.size == 0:
        raise ValueError(f"depth must be a non-empty float32 (H, W) array, got {d.dtype} "
                         f"{d.shape}")
    levels = [d.copy()]
    while levels[-1].shape != (1, 1):
        levels.append(reduce_level(levels[-1]))
    return levels


def test_boxes(levels: list[np.ndarray], mins: np.ndarray, maxs: np.ndarray,
               view_proj: np.ndarray, width: int, height: int, zoff: float = 0.5
               ) -> np.ndarray:
    """Twin of hiz_test_boxes: uint8 (K,) `Occlusion` codes for world-space boxes.

    Args:
        levels: the pyramid (`build`) of the depth buffer, level 0 (H, W) first.
        mins, maxs: (K, 3) box corners (float32). view_proj: (4, 4) row-major float32
            world → clip matrix. width, height: the image size (level 0's shape).
        zoff: the depth buffer's key offset (0.5: window depth; -0.5: minus reversed-Z
            depth, `clraster.pipeline.params.FrameParams.zoff`).

    See kernels/pyramid.cl for the rules; every float operation here is float32, in the
    kernel's order.
    """
    lo = np.asarray(mins, F32)
    hi = np.asarray(maxs, F32)
    if lo.ndim != 2 or lo.shape[1] != 3 or lo.shape != hi.shape:
        raise ValueError(f"box mins and maxs must both be (K, 3), got {lo.shape} and "
                         f"{hi.shape}")
    if levels[0].shape != (height, width):
        raise ValueError(f"level 0 is {levels[0].shape}, expected ({height}, {width})")
    m = np.asarray(view_proj, F32).reshape(16)
    am = np.abs(m)
    k_n = lo.shape[0]
    inf = F32(np.inf)
    zero = F32(0)

    def row(mm, r, x, y, z):
        return ((mm[4 * r] * x + mm[4 * r + 1] * y) + mm[4 * r + 2] * z) + mm[4 * r + 3]

    with np.errstate(all="ignore"):
        # one error bound per box, from the componentwise largest |corner|
        ax = np.fmax(np.abs(lo[:, 0]), np.abs(hi[:, 0]))
        ay = np.fmax(np.abs(lo[:, 1]), np.abs(hi[:, 1]))
        az = np.fmax(np.abs(lo[:, 2]), np.abs(hi[:, 2]))
        ex, ey, ez, ew = (HIZ_EPS * row(am, r, ax, ay, az) for r in range(4))
        exw, eyw, ezw = ex + ew, ey + ew, ez + ew
        bad = np.zeros(k_n, bool)
        for v in (ex, ey, ez, ew, exw, eyw, ezw):
            bad |= ~(np.abs(v) < inf)
        out_and = np.full(k_n, 63, np.uint32)
        cross = np.zeros(k_n, bool)
        xl = np.full(k_n, inf)
        xh = np.full(k_n, -inf)
        yl = np.full(k_n, inf)
        yh = np.full(k_n, -inf)
        zl = np.full(k_n, inf)
        for k in range(8):
            px = hi[:, 0] if k & 1 else lo[:, 0]
            py = hi[:, 1] if k & 2 else lo[:, 1]
            pz = hi[:, 2] if k & 4 else lo[:, 2]
            cx, cy, cz, cw = (row(m, r, px, py, pz) for r in range(4))
            for v in (cx, cy, cz, cw):
                bad |= ~(np.abs(v) < inf)
            o = np.zeros(k_n, np.uint32)
            for bit, dist, e in ((1, cx + cw, exw), (2, cw - cx, exw), (4, cy + cw, eyw),
                                 (8, cw - cy, eyw), (16, cz + cw, ezw), (32, cw - cz, ezw)):
                o |= np.where(dist < -e, np.uint32(bit), np.uint32(0))
            out_and &= o
            wl, wh = cw - ew, cw + ew
            cross |= ~(wl > zero) | (cz + cw < zero)
            qx, rx, qy, ry, qz = cx - ex, cx + ex, cy - ey, cy + ey, cz - ez
            v = qx / np.where(qx >= zero, wh, wl)
            xl = np.where(v < xl, v, xl)
            v = rx / np.where(rx >= zero, wl, wh)
            xh = np.where(v > xh, v, xh)
            v = qy / np.where(qy >= zero, wh, wl)
            yl = np.where(v < yl, v, yl)
            v = ry / np.where(ry >= zero, wl, wh)
            yh = np.where(v > yh, v, yh)
            v = qz / np.where(qz >= zero, wh, wl)
            zl = np.where(v < zl, v, zl)

    res = np.full(k_n, Occlusion.VISIBLE, np.uint8)
    res[~bad & (out_and != 0)] = Occlusion.VIEW_CULLED
    todo = np.nonzero(~bad & (out_and == 0) & ~cross)[0]
    if todo.size == 0:
        return res
    xl, xh, yl, yh, zl = xl[todo], xh[todo], yl[todo], yh[todo], zl[todo]
    one, half = F32(1), F32(0.5)
    hw, hh = half * F32(width), half * F32(height)
    fw, fh = F32(width), F32(height)

    def clamp(v, top):
        return np.minimum(np.maximum(v, F32(-1)), top)

    x0 = np.maximum(np.ceil(clamp(((xl + one) * hw - HIZ_PIXEL_SLACK) - half, fw)), 0)
    x1 = np.minimum(np.floor(clamp(((xh + one) * hw + HIZ_PIXEL_SLACK) - half, fw)), width - 1)
    y0 = np.maximum(np.ceil(clamp(((one - yh) * hh - HIZ_PIXEL_SLACK) - half, fh)), 0)
    y1 = np.minimum(np.floor(clamp(((one - yl) * hh + HIZ_PIXEL_SLACK) - half, fh)),
                    height - 1)
    x0, x1, y0, y1 = (a.astype(np.int64) for a in (x0, x1, y0, y1))
    empty = (x0 > x1) | (y0 > y1)
    res[todo[empty]] = Occlusion.OCCLUDED
    keep = ~empty
    todo, x0, x1, y0, y1, zl = todo[keep], x0[keep], x1[keep], y0[keep], y1[keep], zl[keep]
    # the level by its definition (the kernel uses a closed form; the tests compare them)
    n_levels = len(levels)
    lev = np.zeros(todo.size, np.int64)
    for _ in range(n_levels):
        wide = (((x1 >> lev) - (x0 >> lev)) > 1) | (((y1 >> lev) - (y0 >> lev)) > 1)
        lev += (lev + 1 < n_levels) & wide
    zmax = np.empty(todo.size, F32)
    for L in np.unique(lev):
        s = lev == L
        p = levels[L]
        tx0, tx1, ty0, ty1 = x0[s] >> L, x1[s] >> L, y0[s] >> L, y1[s] >> L
        zmax[s] = _farther(_farther(p[ty0, tx0], p[ty0, tx1]),
                           _farther(p[ty1, tx0], p[ty1, tx1]))
    dnear = (zl * half + F32(zoff)) - HIZ_DEPTH_SLACK
    res[todo] = np.where(dnear > zmax, Occlusion.OCCLUDED, Occlusion.VISIBLE)
    return res
