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

__all__ = ["WINDOW_MAX_COORD", "WINDOW_PLANE_MARGIN", "window_clip_planes", "window_mask"]

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


def window_planes_for(window: Any, camera: Any, width: int, height: int,
                      planes: np.ndarray | None) -> np.ndarray | None:
    """The window's bounding planes (`window_clip_planes`) in the slots the user clip
    planes ``planes`` (checked, or None) leave of USER_PLANES_MAX, or None: both renderers
    cull clusters and reject triangles wholly outside them, but never clip with them (a
    clipped piece's new vertices snap, which would move coverage inside the window)."""
    from .inputs import view_projection
    from .layout import USER_PLANES_MAX

    n = 0 if planes is None else planes.shape[0]
    extra = window_clip_planes(window, view_projection(camera, width, height), width,
                               height, USER_PLANES_MAX - n)
    return extra if extra.shape[0] else None


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



def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (Andrew's monotone chain) of (N, 2) float64 points, counter-clockwise in
    a y-up frame (so, with y down, clockwise on screen), no repeated or collinear points."""
    p = np.unique(points, axis=0)
    if p.shape[0] < 3:
        return p

    def half(pts):
        out: list[np.ndarray] = []
        for q in pts:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(p), half(p[::-1])
    return np.array(lower[:-1] + upper[:-1])


#: How far (pixels) the window's clip planes lie outside its convex hull: geometric clipping
#: only saves work, so it must never remove a pixel centre the mask lets through; a pixel is
#: far more than the 1/512-px snap of the pieces' new vertices.
WINDOW_PLANE_MARGIN = 1.0


def window_clip_planes(window: Any, view_proj: np.ndarray, width: int, height: int,
                       free: int) -> np.ndarray:
    """World-space clip planes (float64 (K, 4), K <= ``free``) bounding what a window can
    show: the edges of its convex hull moved out by WINDOW_PLANE_MARGIN px (its bounding
    box's 4 edges if the hull has more than ``free``; none if fewer than 4 are free), as
    planes through the eye. With them the renderer culls clusters and rejects triangles
    wholly outside the window before binning (the user clip plane path, reject only), so
    what the window cannot show is neither binned nor rasterized; the mask decides which
    pixel centres are drawn, exactly.

    A screen-space half-plane n·(x_w, y_w) + c >= 0 with x_w = (x/w + 1)·W/2 and
    y_w = (1 − y/w)·H/2 is, times w > 0, the clip-space plane (n_x W/2, −n_y H/2, 0,
    n_x W/2 + n_y H/2 + c), and in world space that row times view_proj.
    """
    if free < 4:
        return np.zeros((0, 4))
    ext = as_polygon(window).exterior
    hull = _hull(ext)
    if hull.shape[0] > free:
        lo, hi = ext.min(axis=0), ext.max(axis=0)
        hull = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    a, b = hull, np.roll(hull, -1, axis=0)
    d = b - a
    # counter-clockwise in the (x, y) numbers: the inside is to the left, normal (−dy, dx)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = -np.einsum("ij,ij->i", n, a) + WINDOW_PLANE_MARGIN
    hw, hh = 0.5 * width, 0.5 * height
    clip = np.stack([n[:, 0] * hw, -n[:, 1] * hh, np.zeros(len(n)),
                     n[:, 0] * hw + n[:, 1] * hh + c], axis=1)
    return clip @ np.asarray(view_proj, np.float64)
