"""Polygon windows: which pixel centres a 2-D window (lens mask, portal, non-rectangular
viewport) lets through, by the same rules the rasterizer uses for triangles.

``window_mask(window, width, height)`` → bool (H, W). The window is any polygon
`clraster.clip2d.as_polygon` accepts (an (N, 2) ring, concave allowed, or (exterior, holes)),
in window pixels: x to the right, y down, pixel (i, j) sampled at its centre (i + 0.5,
j + 0.5), exactly as triangles are.

Rule. Window vertices snap to 1/256 pixel (24.8 fixed point, like triangle vertices). A pixel
centre P is inside iff the point P + (ε, ε²), for an infinitesimal ε > 0, lies inside the
polygon (even-odd over all its rings). Off the boundary that is plain point-in-polygon; on it,
the nudge to the right and (second order) down is the top-left rule of D3D11: a centre on a
left edge (interior to its right) or on a top edge (horizontal, interior below) is inside, on
a right or bottom edge outside. Since the nudged point never lies on a boundary, two windows
that tile the screen (sharing their common edges exactly) let every pixel centre through
exactly once, as two triangles sharing an edge cover it once.

Computed exactly in integers, per pixel row: the edges crossing the nudged row are those with
(a.y > P.y) != (b.y > P.y) (integers, so the ε² only decides equality), and a crossing lies
to the right of the nudged point iff its x at P.y is > P.x strictly; the count of crossings
to the right of each centre comes from one histogram per row.

`Renderer.render(..., window=...)` uses the mask: fragments are tested only against pixels
the window lets through, so the image is the unwindowed image restricted to them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .clip2d import Polygon2D, as_polygon
from .layout import SUBPIXEL_BITS, SUBPIXEL_ONE

__all__ = ["WINDOW_MAX_COORD", "window_mask"]

#: Window coordinates must lie within ±2**20 px: the edge arithmetic in 24.8 fixed point then
#: stays far inside int64 (products below 2**58).
WINDOW_MAX_COORD = float(1 << 20)


def _snapped_edges(poly: Polygon2D) -> tuple[np.ndarray, np.ndarray]:
    """All directed edges of the polygon's rings as int64 (E, 2) start and end points in
    24.8 fixed point (rint(x · 256), as triangle vertices snap)."""
    a, b = [], []
    for ring in poly.rings:
        q = np.rint(ring * SUBPIXEL_ONE).astype(np.int64)
        a.append(q)
        b.append(np.roll(q, -1, axis=0))
    return np.concatenate(a), np.concatenate(b)


def window_mask(window: Any, width: int, height: int) -> np.ndarray:
    """bool (height, width): the pixel centres the window lets through (module docstring:
    24.8 snap, even-odd, top-left rule on the boundary).

    Raises:
        ValueError: not a valid simple polygon (`clraster.clip2d.as_polygon`'s checks) or a
            coordinate beyond ±WINDOW_MAX_COORD pixels.
    """
    poly = as_polygon(window)
    for r in poly.rings:
        if np.abs(r).max() > WINDOW_MAX_COORD:
            raise ValueError(f"window coordinates must lie within ±{WINDOW_MAX_COORD:.0f} "
                             "pixels")
    a, b = _snapped_edges(poly)
    half = SUBPIXEL_ONE // 2
    py = (np.arange(height, dtype=np.int64) << SUBPIXEL_BITS) + half        # (H,)
    ay, by = a[None, :, 1], b[None, :, 1]
    cross = (ay > py[:, None]) != (by > py[:, None])                          # (H, E)
    rows, k = np.nonzero(cross)
    den = b[k, 1] - a[k, 1]
    num = a[k, 0] * den + (py[rows] - a[k, 1]) * (b[k, 0] - a[k, 0])          # x_c · den
    neg = den < 0
    num, den = np.where(neg, -num, num), np.where(neg, -den, den)
    # centres 256 i + 128 < num / den  ⟺  i < ceil((num − 128 den) / (256 den))
    n = -((-(num - half * den)) // (SUBPIXEL_ONE * den))
    n = np.clip(n, 0, width)
    hist = np.zeros((height, width + 1), np.int64)
    np.add.at(hist, (rows, n), 1)
    total = hist.sum(axis=1, keepdims=True)
    le = np.cumsum(hist, axis=1)[:, :width]          # crossings with n <= i (at or left of i)
    return ((total - le) & 1).astype(bool)

