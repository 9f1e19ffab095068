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

import hashlib
import threading
from typing import Any

import numpy as np

from ..base.layout import SUBPIXEL_BITS, SUBPIXEL_ONE
from .polygon import Polygon2D, as_polygon

__all__ = ["WINDOW_MAX_COORD", "WINDOW_PLANE_MARGIN", "window_clip_planes", "window_mask"]

#: Window coordinates must lie within ±2**20 px: the edge arithmetic in 24.8 fixed point then
#: stays far inside int64 (products below 2**58).
WINDOW_MAX_COORD = float(1 << 20)


#: Crossings (pixel row, edge) handled per step of `window_mask`: bounds its temporaries
#: (~100 bytes each) however many vertices or rows a window has.
_MASK_CHUNK = 1 << 20

_last_window: tuple[bytes, Polygon2D] | None = None
_last_lock = threading.Lock()


def _window_key(window: Any) -> bytes | None:
    """A digest of a window as given (its rings' float64 values and shapes, in the order
    `as_polygon` reads them), or None for a form it does not cover."""
    if isinstance(window, (tuple, list)) and len(window) == 2:
        try:
            ext = np.asarray(window[0], dtype=np.float64)
        except (ValueError, TypeError):
            return None
        if ext.ndim == 2:   # as_polygon's (exterior, holes) form
            if not isinstance(window[1], (tuple, list)):
                return None
            rings = [ext, *window[1]]
        else:
            rings = [window]
    else:
        rings = [window]
    h = hashlib.blake2b(digest_size=20)
    h.update(len(rings).to_bytes(8, "little"))
    for r in rings:
        try:
            a = np.ascontiguousarray(r, dtype=np.float64)
        except (ValueError, TypeError):
            return None
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.digest()


def _window_polygon(window: Any) -> Polygon2D:
    """`as_polygon(window)`, validated once for consecutive calls with the same window
    (equal values): one frame asks for the mask and then the culling planes, and a series
    of frames usually shares its window; validating 10⁶ vertices takes seconds. The key is
    a digest of the values, so a window changed in place is validated anew."""
    global _last_window
    if isinstance(window, Polygon2D):
        return window
    key = _window_key(window)
    with _last_lock:
        last = _last_window
    if key is not None and last is not None and last[0] == key:
        return last[1]
    poly = as_polygon(window)
    if key is not None:
        with _last_lock:
            _last_window = (key, poly)
    return poly


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
    from ..base.checks import view_projection
    from ..base.layout import USER_PLANES_MAX

    n = 0 if planes is None else planes.shape[0]
    extra = window_clip_planes(window, view_projection(camera, width, height), width,
                               height, USER_PLANES_MAX - n)
    return extra if extra.shape[0] else None


def window_mask(window: Any, width: int, height: int) -> np.ndarray:
    """bool (height, width): the pixel centres the window lets through (module docstring:
    24.8 snap, even-odd, top-left rule on the boundary).

    Cost: O(n log n) to validate n vertices (`clraster.clip2d.as_polygon`), then O(n + c)
    for the c (pixel row, edge) crossings, in bounded steps.

    Raises:
        ValueError: not a valid simple polygon (`clraster.clip2d.as_polygon`'s checks) or a
            coordinate beyond ±WINDOW_MAX_COORD pixels.
    """
    poly = _window_polygon(window)
    for r in poly.rings:
        if np.abs(r).max() > WINDOW_MAX_COORD:
            raise ValueError(f"window coordinates must lie within ±{WINDOW_MAX_COORD:.0f} "
                             "pixels")
    a, b = _snapped_edges(poly)
    half = SUBPIXEL_ONE // 2
    # edge k crosses row r's centre line py = 256 r + 128 iff (a.y > py) != (b.y > py), i.e.
    # min(a.y, b.y) <= py < max(a.y, b.y): rows r0 <= r < r1
    lo_y = np.minimum(a[:, 1], b[:, 1])
    hi_y = np.maximum(a[:, 1], b[:, 1])
    r0 = np.clip(-((half - lo_y) // SUBPIXEL_ONE), 0, height)
    r1 = np.clip(-((half - hi_y) // SUBPIXEL_ONE), 0, height)
    cnt = np.maximum(r1 - r0, 0)
    edges = np.nonzero(cnt)[0]
    cnt = cnt[edges]
    cum = np.cumsum(cnt)
    hist = np.zeros(height * (width + 1), np.int64)
    s = 0
    while s < len(edges):
        done = int(cum[s - 1]) if s else 0
        e = max(int(np.searchsorted(cum, done + _MASK_CHUNK, side="right")), s + 1)
        c = cnt[s:e]
        k = np.repeat(edges[s:e], c)
        rows = r0[k] + np.arange(len(k)) - np.repeat(np.cumsum(c) - c, c)
        py = (rows << SUBPIXEL_BITS) + half
        den = b[k, 1] - a[k, 1]
        num = a[k, 0] * den + (py - a[k, 1]) * (b[k, 0] - a[k, 0])     # x_c · den
        neg = den < 0
        num, den = np.where(neg, -num, num), np.where(neg, -den, den)
        # centres 256 i + 128 < num / den  ⟺  i < ceil((num − 128 den) / (256 den))
        n = -((-(num - half * den)) // (SUBPIXEL_ONE * den))
        n = np.clip(n, 0, width)
        hist += np.bincount(rows * (width + 1) + n, minlength=len(hist))
        s = e
    table = hist.reshape(height, width + 1)
    total = table.sum(axis=1, keepdims=True)
    le = np.cumsum(table, axis=1)[:, :width]         # crossings with n <= i (at or left of i)
    return ((total - le) & 1).astype(bool)


def _hull(points: np.ndarray, limit: int) -> np.ndarray | None:
    """Convex hull of (N, 2) float64 points, counter-clockwise in a y-up frame (so, with y
    down, clockwise on screen), no repeated or collinear points; None when it has more than
    ``limit`` vertices. Gift wrapping (Jarvis march): O(N) per hull vertex, so O(N · limit)
    in all, whatever N."""
    p = np.asarray(points, dtype=np.float64)
    low = np.nonzero(p[:, 1] == p[:, 1].min())[0]
    first = int(low[np.argmin(p[low, 0])])          # lowest, then leftmost: a hull vertex
    out = [first]
    heading = 0.0
    for _ in range(limit + 1):
        d = p - p[out[-1]]
        dist = np.hypot(d[:, 0], d[:, 1])
        # counter-clockwise turn from the current heading to each point; the next vertex
        # turns least (collinear ties: the farthest). Rounding misplaces points by far less
        # than WINDOW_PLANE_MARGIN.
        turn = np.mod(np.arctan2(d[:, 1], d[:, 0]) - heading, 2.0 * np.pi)
        turn[dist == 0.0] = np.inf
        best = turn.min()
        if not np.isfinite(best):
            break                                    # all points coincide
        near = np.nonzero(turn <= best + 1e-12)[0]
        nxt = int(near[np.argmax(dist[near])])
        if nxt == first:
            return p[out] if len(out) <= limit else None
        if nxt in out:
            return None     # rounding closed the walk elsewhere: not a hull to trust
        heading = float(np.arctan2(d[nxt, 1], d[nxt, 0]))
        out.append(nxt)
    return None if len(out) > limit else p[out]


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
    ext = _window_polygon(window).exterior
    hull = _hull(ext, free)
    if hull is None:
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
