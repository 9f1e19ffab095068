"""2-D polygon clipping: Sutherland–Hodgman for convex windows, Weiler–Atherton in general.

``clip_polygon(subject, window)`` returns the intersection ``subject ∩ window`` of two simple
polygons (with holes) as a list of polygons. Pure Python + NumPy, float64 throughout.

Conventions
-----------
* A polygon is a `Polygon2D`: ``exterior`` is an (N, 2) float64 ring, N ≥ 3, **counter-clockwise**
  (positive shoelace area in a y-up frame), **not closed** (the first vertex is not repeated);
  ``holes`` is a tuple of (M, 2) float64 rings, **clockwise**, also not closed. With these
  orientations the polygon's interior is on the *left* of every directed boundary edge, holes
  included — the property both algorithms below rely on. (In a y-down image frame the same
  arrays read as clockwise / counter-clockwise; nothing here depends on the axis direction
  except the words.)
* Inputs must be *simple*: no ring crosses or touches itself, holes lie inside the exterior and
  neither cross nor overlap it or each other (touching at isolated points is allowed, as in
  OGC/Shapely). `as_polygon` checks this and raises ``ValueError`` when it does not hold; what it
  does not check is holes that together cut the interior into pieces.
* Input rings may come in either orientation and may be closed (first vertex repeated); they
  are re-oriented and opened. A vertex closer than the tolerance (below) to the previous one is
  dropped; collinear vertices are kept.

Tolerance
---------
Geometry is float64 with one length tolerance per operation,
``tol = max(REL_TOL · extent, 64 · ε · max|coordinate|)``, where ``extent`` is the larger side
of the joint bounding box of the polygons involved, ``ε`` is float64's machine epsilon and
``REL_TOL = 1e-12``. (The second term only matters far from the origin, where the coordinates'
own rounding exceeds the first.) Points closer than ``tol`` are the same point; a vertex closer
than ``tol`` to an edge lies on it; a ring whose area is at most ``tol × perimeter`` (thinner
than the tolerance everywhere) has no area. Results therefore agree with exact arithmetic up
to about ``tol × perimeter`` in area. With small-integer coordinates (grids) every on-edge
and collinear decision comes out as in exact arithmetic (the errors are far below ``tol``).

Sutherland–Hodgman (`sutherland_hodgman`, `clip_ring_halfplane`)
-----------------------------------------------------------------
Sutherland & Hodgman (1974), "Reentrant polygon clipping": the subject ring is clipped
against the half-plane to the left of each window edge in turn. The window must be convex
(the intersection of those half-planes *is* the window) and the subject must have no holes.
The result is one ring. For a convex subject it is the exact intersection (a convex polygon).
For a concave subject whose intersection with the window has several pieces, the ring joins
the pieces by zero-width "bridges" running along the window's boundary: its area is right but
it is not a simple polygon and not a set of polygons. That is what the algorithm does, and
why `clip_polygon` only uses it where its result is exact.

Weiler–Atherton (`weiler_atherton`)
-----------------------------------
Weiler & Atherton (1977), "Hidden surface removal using polygon area sorting": walk both
boundaries, switching from one to the other at the intersection points where the subject's
boundary enters or leaves the window. This implementation makes the entering/leaving decision
per boundary *fragment* instead of per intersection point, which is what makes the degenerate
cases (collinear overlaps, vertices on edges, touching) come out right:

1. **Nodes.** Collect every vertex of both polygons (all rings, holes included) and every
   proper crossing of a subject edge with a window edge; points within ``tol`` merge into one
   node (a vertex wins over a computed crossing, so shared vertices keep their exact input
   coordinates). A node within ``tol`` of an edge's interior lies on that edge: this covers
   vertices on the other polygon's edges and both ends of every collinear overlap.
2. **Fragments.** Split every edge of both polygons at the nodes on it, into directed
   fragments between consecutive nodes.
3. **Classify** each fragment against the *other* polygon: a subject fragment with the same
   node pair as a window fragment is shared boundary, running in the same or in the opposite
   direction; any other fragment lies wholly inside or wholly outside the other polygon, and
   its midpoint decides which (even-odd rule over all the other polygon's rings).
4. **Keep** subject fragments inside the window, window fragments inside the subject, and
   shared fragments running the same way (once). Drop shared fragments running opposite ways:
   the interiors lie on opposite sides there, so such a piece only bounds a zero-area touch.
   The kept fragments are exactly the boundary of ``subject ∩ window``, interior on the left;
   the classic entering/leaving intersections are the nodes where the kept set passes from
   one polygon's boundary to the other's.
5. **Walk.** From each fragment's end continue with a kept fragment that starts there. Where
   several start at one node (polygons touching at a vertex, a hole touching the exterior),
   take the first one clockwise from the way back, so that the walk stays within one sector
   of the intersection's interior and rings never cross. A closed walk that passes a node
   twice is cut there into separate loops, so every ring is simple.
6. **Assemble.** Counter-clockwise rings are exteriors, clockwise rings are holes; each hole
   goes to the smallest exterior that contains it. Rings with no area (``tol`` rule above) are
   dropped.

Consequences: identical polygons give back the subject (same vertices, same order); one
polygon inside the other gives back the inner one with its holes; disjoint polygons, polygons
touching at a point, and polygons sharing only an edge give ``[]``. Output rings may have
collinear vertices where the two boundaries met. A hole of the result touching its exterior
or another hole at a point is kept as a hole (valid in the OGC sense), and a piece of the
result lying inside another piece's hole is a separate polygon. Outputs are pairwise
interior-disjoint; their order is deterministic but otherwise unspecified.

Cost: all edge pairs are tested at once with NumPy (O(n·m) memory in row chunks), so a few
hundred vertices per polygon take milliseconds. Input validation is O(n²) per polygon.

Limitation: in nearly degenerate configurations (an edge within a few ``tol`` of another but
not within ``tol``), the classification of the fragments around one node can disagree; the
walk then drops the open chain it cannot close and logs a warning (the area lost is of the
order of ``tol × length``). Exact inputs and generic inputs do not hit this.

Dispatch (`clip_polygon`)
-------------------------
``method="auto"`` runs Sutherland–Hodgman when both polygons are convex and hole-free (its
single ring is then exactly the intersection) and Weiler–Atherton otherwise; `auto_method`
says which one "auto" picks. ``method="sutherland-hodgman"`` or ``"weiler-atherton"`` forces
one (SH raises ``ValueError`` for a concave window or a subject with holes, and may return a
bridged ring for a concave subject, see above). `is_convex` is the convexity test used.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

__all__ = ["REL_TOL", "Polygon2D", "as_polygon", "auto_method", "clip_polygon",
           "clip_ring_halfplane", "is_convex", "sutherland_hodgman", "weiler_atherton"]

_log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

#: Relative length tolerance: ``tol = max(REL_TOL · extent, 64 · ε · max|coordinate|)``
#: (module docstring). Smaller makes nearly-touching inputs count as separate (and the
#: degenerate-configuration limitation likelier); larger merges features up to that size.
REL_TOL = 1e-12

_EPS = float(np.finfo(np.float64).eps)
# Pairwise NumPy work (edges × edges, points × edges) goes in row blocks of at most this many
# entries, so memory stays bounded (~16 MB per float64 temporary) for large polygons.
_CHUNK = 1 << 21

Method = Literal["auto", "sutherland-hodgman", "weiler-atherton"]


# ---------------------------------------------------------------------------------------------
# Polygon type and validation
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Polygon2D:
    """A simple polygon with holes, in float64.

    Attributes:
        exterior: (N, 2) float64, N ≥ 3, counter-clockwise, not closed (first vertex not
            repeated). Read-only.
        holes: tuple of (M, 2) float64 rings, M ≥ 3, each clockwise and not closed. Read-only.

    Constructing ``Polygon2D(exterior, holes)`` normalises and validates exactly like
    `as_polygon` (any orientation, closed or open rings, array-likes); it raises
    ``ValueError`` for a ring with fewer than 3 distinct vertices, non-finite coordinates, a
    shape other than (N, 2), zero area, self-intersection, or holes that cross or overlap the
    exterior or each other or lie outside it. Equality is identity (arrays do not compare as
    one bool); compare ``exterior``/``holes`` with NumPy.
    """

    exterior: FloatArray
    holes: tuple[FloatArray, ...] = ()

    def __post_init__(self) -> None:
        ext, holes = _normalise(self.exterior, self.holes)
        object.__setattr__(self, "exterior", ext)
        object.__setattr__(self, "holes", holes)

    @classmethod
    def _trusted(cls, exterior: FloatArray, holes: Sequence[FloatArray] = ()) -> Polygon2D:
        # Results of the clippers are correct by construction: skip the O(n²) validation.
        self = object.__new__(cls)
        object.__setattr__(self, "exterior", _frozen(exterior))
        object.__setattr__(self, "holes", tuple(_frozen(h) for h in holes))
        return self

    @property
    def rings(self) -> tuple[FloatArray, ...]:
        """``(exterior, *holes)``; interior on the left of every ring."""
        return (self.exterior, *self.holes)

    @property
    def area(self) -> float:
        """Area of the exterior minus the holes' areas (≥ 0)."""
        return _ring_area(self.exterior) + sum(_ring_area(h) for h in self.holes)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of the exterior."""
        lo = self.exterior.min(axis=0)
        hi = self.exterior.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def contains(self, points: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Which points lie in the polygon (inside the exterior, outside every hole).

        Args:
            points: (..., 2) array-like of x, y.

        Returns:
            bool array of shape ``points.shape[:-1]``. Even-odd rule over all rings (the same
            as nonzero winding for a valid polygon). Points exactly on the boundary get an
            unspecified but deterministic answer (half-open crossing test); use a tolerance of
            your own where that matters.
        """
        p = np.asarray(points, dtype=np.float64)
        if p.ndim == 0 or p.shape[-1] != 2:
            raise ValueError(f"points must have shape (..., 2), got {p.shape}")
        flat = p.reshape(-1, 2)
        e0, e1 = _edges(self.rings)
        return _inside_even_odd(flat, e0, e1).reshape(p.shape[:-1])


def as_polygon(obj: Any) -> Polygon2D:
    """Normalise a polygon given in any of the accepted forms to a `Polygon2D`.

    Args:
        obj: a `Polygon2D` (returned as is); an (N, 2) array-like ring (either orientation,
            closed or not; becomes the counter-clockwise exterior); or a pair
            ``(exterior, holes)`` with ``holes`` a sequence of (M, 2) rings (any orientation;
            holes become clockwise).

    Raises:
        ValueError: wrong shape, non-finite coordinates, fewer than 3 distinct vertices, zero
            area, a self-intersecting ring, or holes outside / crossing the exterior or each
            other. The message says which ring and what to do.
    """
    if isinstance(obj, Polygon2D):
        return obj
    if isinstance(obj, (tuple, list)) and len(obj) == 2 and _is_ring_like(obj[0]):
        return Polygon2D(obj[0], tuple(obj[1]))
    return Polygon2D(obj)


def _is_ring_like(x: Any) -> bool:
    try:
        return np.asarray(x, dtype=np.float64).ndim == 2
    except (ValueError, TypeError):
        return False


def _frozen(a: npt.ArrayLike) -> FloatArray:
    out = np.array(a, dtype=np.float64, order="C")
    out.setflags(write=False)
    return out


def _ring_area(ring: FloatArray) -> float:
    # Shoelace relative to the first vertex (less cancellation far from the origin).
    c = ring - ring[0]
    x, y = c[:, 0], c[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _perimeter(ring: FloatArray) -> float:
    d = np.roll(ring, -1, axis=0) - ring
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def _tolerance(*rings: FloatArray) -> float:
    pts = np.concatenate(rings)
    extent = float((pts.max(axis=0) - pts.min(axis=0)).max())
    return max(REL_TOL * extent, 64.0 * _EPS * float(np.abs(pts).max()))


def _clean_ring(ring: Any, what: str) -> FloatArray:
    try:
        r = np.array(ring, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{what} must be an (N, 2) array of x, y coordinates; could not read it "
                         f"as a float array ({exc})") from None
    if r.ndim != 2 or r.shape[1] != 2:
        raise ValueError(f"{what} must have shape (N, 2) (one x, y row per vertex), got shape "
                         f"{r.shape}; pass holes separately as (exterior, [hole, ...])")
    if not np.isfinite(r).all():
        bad = int(np.nonzero(~np.isfinite(r).all(axis=1))[0][0])
        raise ValueError(f"{what} has a non-finite coordinate (vertex {bad}: {r[bad].tolist()}); "
                         "remove or repair NaN/inf vertices first")
    if len(r) < 3:
        raise ValueError(f"{what} has {len(r)} vertices; a polygon needs at least 3")
    return r


def _dedupe_ring(r: FloatArray, tol: float, what: str) -> FloatArray:
    # vertices within tol of the previous one (including a closing copy of the first) are one
    # vertex at this tolerance; keeping both would make a zero-length edge
    r = _drop_close_repeats(r, tol)
    distinct = len(np.unique(r, axis=0))
    if distinct < 3 or len(r) < 3:
        raise ValueError(f"{what} has {min(distinct, len(r))} distinct vertices; a polygon needs "
                         "at least 3")
    return r


def _normalise(exterior: Any, holes: Any) -> tuple[FloatArray, tuple[FloatArray, ...]]:
    ext = _clean_ring(exterior, "polygon exterior")
    if _is_ring_like(holes):
        raise ValueError("holes must be a sequence of (M, 2) rings, got one (M, 2) array; "
                         "wrap it in a list: holes=[hole]")
    hs = [_clean_ring(h, f"hole {k}") for k, h in enumerate(holes)]
    tol = _tolerance(ext, *hs)
    ext = _dedupe_ring(ext, tol, "polygon exterior")
    hs = [_dedupe_ring(h, tol, f"hole {k}") for k, h in enumerate(hs)]
    rings = [ext, *hs]
    for k, r in enumerate(rings):
        what = "polygon exterior" if k == 0 else f"hole {k - 1}"
        area = _ring_area(r)
        if abs(area) <= tol * _perimeter(r):
            # a figure-eight has zero signed area too: name the real problem
            _check_ring_simple(r, tol, what, spikes=False)
            raise ValueError(f"{what} has zero area (its vertices are collinear or coincide); "
                             "a polygon needs at least 3 non-collinear vertices")
    ext = ext if _ring_area(ext) > 0 else ext[::-1]
    hs = [h if _ring_area(h) < 0 else h[::-1] for h in hs]
    for k, r in enumerate([ext, *hs]):
        _check_ring_simple(r, tol, "polygon exterior" if k == 0 else f"hole {k - 1}")
    _check_holes(ext, hs, tol)
    return _frozen(ext), tuple(_frozen(h) for h in hs)


def _check_ring_simple(ring: FloatArray, tol: float, what: str, spikes: bool = True) -> None:
    n = len(ring)
    a0, a1 = ring, np.roll(ring, -1, axis=0)
    # adjacent edges folding back onto each other (a zero-width spike)
    d = a1 - a0
    dn = np.roll(d, -1, axis=0)
    ln = np.hypot(d[:, 0], d[:, 1])
    off = np.abs(d[:, 0] * dn[:, 1] - d[:, 1] * dn[:, 0]) / ln
    back = (off <= tol) & ((d * dn).sum(axis=1) < 0)
    if spikes and back.any():
        k = int(np.nonzero(back)[0][0])
        raise ValueError(f"{what} folds back on itself at vertex {(k + 1) % n} "
                         f"({ring[(k + 1) % n].tolist()}): a zero-width spike; remove that vertex")
    if n < 4:
        return
    for rows, touch in _pairwise(a0, a1, a0, a1, tol, _segments_touch):
        i = rows[:, None]
        j = np.arange(n)[None, :]
        # non-adjacent pairs only (each once)
        nonadj = (j > i + 1) & ~((i == 0) & (j == n - 1))
        bad = touch & nonadj
        if bad.any():
            bi, bj = np.nonzero(bad)
            e1, e2 = int(i[bi[0], 0]), int(bj[0])
            raise ValueError(f"{what} intersects itself (edges {e1} and {e2} meet); pass a "
                             "simple polygon: split a self-intersecting outline into several "
                             "polygons, or describe holes as holes")


def _check_holes(ext: FloatArray, holes: list[FloatArray], tol: float) -> None:
    rings = [ext, *holes]
    names = ["the exterior"] + [f"hole {k}" for k in range(len(holes))]
    ends = [(r, np.roll(r, -1, axis=0)) for r in rings]
    for i in range(len(rings)):
        for j in range(i + 1, len(rings)):
            for _, bad in _pairwise(*ends[i], *ends[j], tol, _segments_cross_or_overlap):
                if bad.any():
                    raise ValueError(f"{names[j]} crosses or overlaps {names[i]}; holes must lie "
                                     "inside the exterior and may touch it or each other only "
                                     "at points")
    for k, h in enumerate(holes):
        if not _ring_inside(h, *ends[0], tol):
            raise ValueError(f"hole {k} lies outside the exterior; holes must be inside it")
        for m in range(len(holes)):
            if m != k and _ring_inside(h, *ends[m + 1], tol):
                raise ValueError(f"hole {k} lies inside hole {m}; nested holes are not a polygon "
                                 "(pass the island as a separate polygon)")


def _ring_inside(ring: FloatArray, e0: FloatArray, e1: FloatArray, tol: float) -> bool:
    """Whether a ring that does not cross the edges e0→e1 lies inside them (even-odd)."""
    mids = 0.5 * (ring + np.roll(ring, -1, axis=0))
    for p in (ring, mids):
        dist, _ = _point_segment(p, e0, e1)
        off = dist.min(axis=1) > tol
        if off.any():
            return bool(_inside_even_odd(p[off][:1], e0, e1)[0])
    return False  # every vertex and midpoint on the other ring: the same ring, not inside


# ---------------------------------------------------------------------------------------------
# Vectorised primitives
# ---------------------------------------------------------------------------------------------

def _edges(rings: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Start and end points, (E, 2) each, of the edges of all rings (edge k starts at vertex k)."""
    return (np.concatenate(rings),
            np.concatenate([np.roll(r, -1, axis=0) for r in rings]))


def _pairwise(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray, tol: float,
              fn: Any) -> Iterator[tuple[npt.NDArray[np.intp], Any]]:
    """Yield ``(rows, fn(a0[rows], a1[rows], b0, b1, tol))`` over row blocks of the a-edges."""
    step = max(1, _CHUNK // max(1, len(b0)))
    for s in range(0, len(a0), step):
        rows = np.arange(s, min(s + step, len(a0)))
        yield rows, fn(a0[rows], a1[rows], b0, b1, tol)


def _side_distances(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Signed distances, (n, m) each: of b0, b1 from the line of each a-edge and of a0, a1 from
    the line of each b-edge (positive on the left of the directed line)."""
    r = a1 - a0
    s = b1 - b0
    lr = np.hypot(r[:, 0], r[:, 1])[:, None]
    ls = np.hypot(s[:, 0], s[:, 1])[None, :]
    rx, ry = r[:, 0:1], r[:, 1:2]
    sx, sy = s[None, :, 0], s[None, :, 1]

    def from_a(p: FloatArray) -> FloatArray:
        return (rx * (p[None, :, 1] - a0[:, 1:2]) - ry * (p[None, :, 0] - a0[:, 0:1])) / lr

    def from_b(p: FloatArray) -> FloatArray:
        return (sx * (p[:, 1:2] - b0[None, :, 1]) - sy * (p[:, 0:1] - b0[None, :, 0])) / ls

    return from_a(b0), from_a(b1), from_b(a0), from_b(a1)


def _sign(d: FloatArray, tol: float) -> npt.NDArray[np.int8]:
    return (np.int8(1) * (d > tol) - np.int8(1) * (d < -tol)).astype(np.int8)


def _proper(db0: FloatArray, db1: FloatArray, da0: FloatArray, da1: FloatArray,
            tol: float) -> npt.NDArray[np.bool_]:
    # Both pairs of endpoints strictly (beyond tol) on opposite sides: the segments cross at a
    # point at least tol away from all four endpoints. Everything else is a vertex-on-edge or
    # collinear case, handled through the nodes.
    return (_sign(db0, tol) * _sign(db1, tol) == -1) & (_sign(da0, tol) * _sign(da1, tol) == -1)


def _point_segment(p: FloatArray, s0: FloatArray, s1: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:
    """Distance (P, E) of each point to each segment, and the unclamped projection parameter."""
    d = s1 - s0
    l2 = (d * d).sum(axis=1)
    l2 = np.where(l2 > 0, l2, 1.0)
    px = p[:, 0:1] - s0[None, :, 0]
    py = p[:, 1:2] - s0[None, :, 1]
    t = (px * d[None, :, 0] + py * d[None, :, 1]) / l2[None, :]
    tc = np.clip(t, 0.0, 1.0)
    return np.hypot(px - tc * d[None, :, 0], py - tc * d[None, :, 1]), t


def _segments_touch(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                    tol: float) -> npt.NDArray[np.bool_]:
    """(n, m): the segments cross or come within tol of each other."""
    db0, db1, da0, da1 = _side_distances(a0, a1, b0, b1)
    near = _proper(db0, db1, da0, da1, tol)
    near |= _point_segment(b0, a0, a1)[0].T <= tol
    near |= _point_segment(b1, a0, a1)[0].T <= tol
    near |= _point_segment(a0, b0, b1)[0] <= tol
    near |= _point_segment(a1, b0, b1)[0] <= tol
    return near


def _segments_cross_or_overlap(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                               tol: float) -> npt.NDArray[np.bool_]:
    """(n, m): the segments cross properly or overlap collinearly over more than tol."""
    db0, db1, da0, da1 = _side_distances(a0, a1, b0, b1)
    bad = _proper(db0, db1, da0, da1, tol)
    r = a1 - a0
    lr = np.hypot(r[:, 0], r[:, 1])[:, None]
    u = r / lr
    s0 = ((b0[None, :, :] - a0[:, None, :]) * u[:, None, :]).sum(axis=2)
    s1 = ((b1[None, :, :] - a0[:, None, :]) * u[:, None, :]).sum(axis=2)
    overlap = np.minimum(lr, np.maximum(s0, s1)) - np.maximum(0.0, np.minimum(s0, s1))
    bad |= (np.abs(db0) <= tol) & (np.abs(db1) <= tol) & (overlap > tol)
    return bad


def _inside_even_odd(p: FloatArray, e0: FloatArray, e1: FloatArray) -> npt.NDArray[np.bool_]:
    """(P,) even-odd test of points against the closed edge set e0→e1 (half-open in y)."""
    out = np.zeros(len(p), dtype=bool)
    if len(p) == 0 or len(e0) == 0:
        return out
    step = max(1, _CHUNK // len(e0))
    x0, y0 = e0[None, :, 0], e0[None, :, 1]
    x1, y1 = e1[None, :, 0], e1[None, :, 1]
    dy = np.where(y1 != y0, y1 - y0, 1.0)
    for s in range(0, len(p), step):
        px, py = p[s:s + step, 0:1], p[s:s + step, 1:2]
        straddle = (y0 > py) != (y1 > py)
        # only straddling edges count, where (py - y0) / dy is in [0, 1]; the others may
        # overflow harmlessly
        with np.errstate(over="ignore", invalid="ignore"):
            xi = x0 + (py - y0) / dy * (x1 - x0)
        out[s:s + step] = (np.count_nonzero(straddle & (px < xi), axis=1) & 1).astype(bool)
    return out


def is_convex(polygon: Any) -> bool:
    """Whether a polygon is convex: no holes and every vertex on or left of every edge's line
    (within the tolerance; collinear vertices allowed). ``polygon``: anything `as_polygon`
    accepts."""
    p = as_polygon(polygon)
    if p.holes:
        return False
    ring = p.exterior
    tol = _tolerance(ring)
    e0, e1 = ring, np.roll(ring, -1, axis=0)
    for _, d in _pairwise(e0, e1, ring, ring, tol, _left_distance):
        if (d < -tol).any():
            return False
    return True


def _left_distance(a0: FloatArray, a1: FloatArray, p: FloatArray, _p: FloatArray,
                   _tol: float) -> FloatArray:
    """(n, P) signed distance of each point from the line of each edge a0→a1 (left > 0)."""
    r = a1 - a0
    lr = np.hypot(r[:, 0], r[:, 1])[:, None]
    return (r[:, 0:1] * (p[None, :, 1] - a0[:, 1:2])
            - r[:, 1:2] * (p[None, :, 0] - a0[:, 0:1])) / lr


# ---------------------------------------------------------------------------------------------
# Sutherland–Hodgman
# ---------------------------------------------------------------------------------------------

def clip_ring_halfplane(ring: npt.ArrayLike, a: npt.ArrayLike, b: npt.ArrayLike,
                        tol: float = 0.0) -> FloatArray:
    """One Sutherland–Hodgman step: the part of a closed ring left of (or on) the line a→b.

    Args:
        ring: (N, 2) float64-convertible closed ring (not repeated at the end), any orientation.
        a, b: (2,) two distinct points; the kept half-plane is on the left of a→b
            (``cross(b - a, p - a) ≥ 0``), i.e. inside for a counter-clockwise convex window.
        tol: vertices within this distance of the line count as on it (kept, not split).

    Returns:
        (K, 2) float64 ring, K may be 0 (nothing left) and may be < 3 (a degenerate touch). The
        vertex order and orientation of ``ring`` are kept; crossing points are inserted where
        an edge passes strictly from one side to the other.
    """
    r = np.asarray(ring, dtype=np.float64).reshape(-1, 2)
    pa = np.asarray(a, dtype=np.float64).reshape(2)
    pb = np.asarray(b, dtype=np.float64).reshape(2)
    e = pb - pa
    length = math.hypot(float(e[0]), float(e[1]))
    if not length > 0:
        raise ValueError(f"clip line endpoints must differ, got a = b = {pa.tolist()}")
    if len(r) == 0:
        return r.copy()
    d = (e[0] * (r[:, 1] - pa[1]) - e[1] * (r[:, 0] - pa[0])) / length
    d[np.abs(d) <= tol] = 0.0
    dn = np.roll(d, -1)
    rn = np.roll(r, -1, axis=0)
    crossing = ((d < 0) & (dn > 0)) | ((d > 0) & (dn < 0))
    t = np.where(crossing, d / np.where(crossing, d - dn, 1.0), 0.0)
    x = r + t[:, None] * (rn - r)
    pts = np.stack([r, x], axis=1).reshape(-1, 2)
    keep = np.stack([d >= 0, crossing], axis=1).reshape(-1)
    return pts[keep]


def sutherland_hodgman(subject: Any, window: Any) -> Polygon2D | None:
    """Clip a hole-free polygon by a convex window (Sutherland–Hodgman).

    Args:
        subject: anything `as_polygon` accepts, without holes; convex or concave.
        window: anything `as_polygon` accepts; must be convex and hole-free.

    Returns:
        One `Polygon2D` (counter-clockwise exterior, no holes) or ``None`` when the intersection
        has no area. For a convex subject it is the exact intersection. For a concave subject
        whose intersection has several pieces it is one ring joining them by zero-width
        bridges along the window boundary: the area is right, but the ring is not simple (use
        `weiler_atherton` or `clip_polygon` for separate pieces).

    Raises:
        ValueError: the window is not convex or has holes, the subject has holes, or either
            input is invalid (`as_polygon`).
    """
    s = as_polygon(subject)
    w = as_polygon(window)
    if s.holes:
        raise ValueError("sutherland_hodgman clips a subject without holes; use "
                         "weiler_atherton or clip_polygon for a subject with holes")
    if not is_convex(w):
        raise ValueError("sutherland_hodgman needs a convex window without holes; use "
                         "weiler_atherton or clip_polygon for a concave window")
    tol = _tolerance(s.exterior, w.exterior)
    ring = s.exterior
    win = w.exterior
    for k in range(len(win)):
        ring = clip_ring_halfplane(ring, win[k], win[(k + 1) % len(win)], tol)
        if len(ring) == 0:
            return None
    ring = _drop_close_repeats(ring, tol)
    if len(ring) < 3 or _ring_area(ring) <= tol * _perimeter(ring):
        return None
    return Polygon2D._trusted(ring)


def _drop_close_repeats(ring: FloatArray, tol: float) -> FloatArray:
    while len(ring) > 1:
        d = np.roll(ring, -1, axis=0) - ring
        same = np.hypot(d[:, 0], d[:, 1]) <= tol
        if not same.any():
            break
        if same.all():
            return ring[:1]
        # drop the second vertex of the first close pair of each run, then look again
        drop = same & ~np.roll(same, 1)
        ring = ring[~np.roll(drop, 1)]
    return ring


# ---------------------------------------------------------------------------------------------
# Weiler–Atherton
# ---------------------------------------------------------------------------------------------

def weiler_atherton(subject: Any, window: Any) -> list[Polygon2D]:
    """Intersection of two simple polygons with holes (Weiler–Atherton, degenerate-safe).

    Args:
        subject, window: anything `as_polygon` accepts; convex or concave, with or without holes.

    Returns:
        list of `Polygon2D` (possibly empty): interior-disjoint simple polygons whose union is
        ``subject ∩ window`` (up to the tolerance in the module docstring); exteriors
        counter-clockwise, holes clockwise. Zero-area contacts (a shared point or edge) give
        nothing. The module docstring describes the algorithm and its degenerate cases.
    """
    a = as_polygon(subject)
    b = as_polygon(window)
    tol = _tolerance(*a.rings, *b.rings)
    alo, ahi = a.exterior.min(axis=0), a.exterior.max(axis=0)
    blo, bhi = b.exterior.min(axis=0), b.exterior.max(axis=0)
    if (alo > bhi + tol).any() or (blo > ahi + tol).any():
        return []

    ea0, ea1 = _edges(a.rings)
    eb0, eb1 = _edges(b.rings)
    na, nb = len(ea0), len(eb0)

    # 1. nodes: vertices of both polygons, then proper crossings; merged within tol
    crossings = [c for _, c in _pairwise(ea0, ea1, eb0, eb1, tol, _crossing_points)]
    pts = np.concatenate([ea0, eb0, *crossings])
    labels = _cluster(pts, tol)
    node_ids, node_of = np.unique(labels, return_inverse=True)
    nodes = pts[node_ids]  # vertices come first, so a merged node keeps a vertex's coordinates
    va, vb = node_of[:na], node_of[na:na + nb]

    # 2. fragments
    au, av = _split_edges(ea0, ea1, va, va[_next_in_ring(a.rings)], nodes, tol)
    bu, bv = _split_edges(eb0, eb1, vb, vb[_next_in_ring(b.rings)], nodes, tol)

    # 3./4. classify and keep
    k = np.int64(len(nodes))
    key_a, rev_a = au * k + av, av * k + au
    key_b, rev_b = bu * k + bv, bv * k + bu
    same_a = np.isin(key_a, key_b)
    opp_a = np.isin(rev_a, key_b)
    keep_a = same_a.copy()
    test_a = ~(same_a | opp_a)
    keep_a[test_a] = _inside_even_odd(0.5 * (nodes[au[test_a]] + nodes[av[test_a]]), eb0, eb1)
    test_b = ~(np.isin(key_b, key_a) | np.isin(rev_b, key_a))
    keep_b = np.zeros(len(bu), dtype=bool)
    keep_b[test_b] = _inside_even_odd(0.5 * (nodes[bu[test_b]] + nodes[bv[test_b]]), ea0, ea1)
    fu = np.concatenate([au[keep_a], bu[keep_b]])
    fv = np.concatenate([av[keep_a], bv[keep_b]])
    if len(fu) == 0:
        return []

    # 5. walk
    loops = [_split_at_repeats(fu[chain].tolist()) for chain in _walk(fu, fv, nodes)]

    # 6. assemble
    outers: list[FloatArray] = []
    holes: list[FloatArray] = []
    for loop in (lp for group in loops for lp in group):
        if len(loop) < 3:
            continue
        ring = nodes[loop]
        area = _ring_area(ring)
        if abs(area) <= tol * _perimeter(ring):
            continue
        (outers if area > 0 else holes).append(ring)
    return _assemble(outers, holes, tol)


def _next_in_ring(rings: Sequence[FloatArray]) -> npt.NDArray[np.intp]:
    """Index of the next vertex (the edge's end) in the concatenated rings."""
    out = []
    start = 0
    for r in rings:
        idx = np.arange(start, start + len(r))
        out.append(np.roll(idx, -1))
        start += len(r)
    return np.concatenate(out)


def _crossing_points(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                     tol: float) -> FloatArray:
    db0, db1, da0, da1 = _side_distances(a0, a1, b0, b1)
    i, j = np.nonzero(_proper(db0, db1, da0, da1, tol))
    # parameter along the a-edge from the signed distances of its endpoints to the b-line:
    # well conditioned, and in (0, 1) because the signs differ
    t = da0[i, j] / (da0[i, j] - da1[i, j])
    return a0[i] + t[:, None] * (a1[i] - a0[i])


def _cluster(p: FloatArray, tol: float) -> npt.NDArray[np.intp]:
    """Label each point with the smallest index of its cluster (points chained within tol)."""
    n = len(p)
    labels = np.arange(n)
    order = np.argsort(p[:, 0], kind="stable")
    xs = p[order, 0]
    hi = np.searchsorted(xs, xs + tol, side="right")
    counts = hi - np.arange(n) - 1
    total = int(counts.sum())
    if total == 0:
        return labels
    i_sorted = np.repeat(np.arange(n), counts)
    offset = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    i, j = order[i_sorted], order[i_sorted + 1 + offset]
    d = p[i] - p[j]
    close = np.hypot(d[:, 0], d[:, 1]) <= tol
    i, j = i[close], j[close]
    if len(i) == 0:
        return labels
    while True:
        m = np.minimum(labels[i], labels[j])
        new = labels.copy()
        np.minimum.at(new, i, m)
        np.minimum.at(new, j, m)
        new = new[new]
        if np.array_equal(new, labels):
            return labels
        labels = new


def _split_edges(e0: FloatArray, e1: FloatArray, start: npt.NDArray[np.intp],
                 end: npt.NDArray[np.intp], nodes: FloatArray, tol: float
                 ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Directed fragments (u, v) of the edges e0→e1 split at every node lying on them."""
    hit_node: list[npt.NDArray[np.intp]] = []
    hit_edge: list[npt.NDArray[np.intp]] = []
    hit_t: list[FloatArray] = []
    step = max(1, _CHUNK // max(1, len(e0)))
    for s in range(0, len(nodes), step):
        dist, t = _point_segment(nodes[s:s + step], e0, e1)
        ni, ei = np.nonzero(dist <= tol)
        ni = ni + s
        own = (ni == start[ei]) | (ni == end[ei])
        hit_node.append(ni[~own])
        hit_edge.append(ei[~own])
        hit_t.append(t[ni[~own] - s, ei[~own]])
    n = len(e0)
    edge_ids = np.arange(n)
    seq_node = np.concatenate([start, end, *hit_node])
    seq_edge = np.concatenate([edge_ids, edge_ids, *hit_edge])
    seq_t = np.concatenate([np.full(n, -np.inf), np.full(n, np.inf), *hit_t])
    order = np.lexsort((seq_t, seq_edge))
    seq_node, seq_edge = seq_node[order], seq_edge[order]
    same = seq_edge[:-1] == seq_edge[1:]
    u, v = seq_node[:-1][same], seq_node[1:][same]
    moving = u != v
    return u[moving].astype(np.int64), v[moving].astype(np.int64)


def _walk(fu: npt.NDArray[np.int64], fv: npt.NDArray[np.int64], nodes: FloatArray
          ) -> list[list[int]]:
    """Closed chains of fragment indices; at a node with several ways on, the first kept
    fragment clockwise from the way back (stays in one sector of the interior)."""
    f = len(fu)
    d = nodes[fv] - nodes[fu]
    ang_out = np.arctan2(d[:, 1], d[:, 0])
    ang_back = np.arctan2(-d[:, 1], -d[:, 0])
    k = len(nodes)
    cnt_out = np.bincount(fu, minlength=k)
    cnt_in = np.bincount(fv, minlength=k)
    by_out = np.argsort(fu, kind="stable")
    by_in = np.argsort(fv, kind="stable")
    first_out = np.concatenate([[0], np.cumsum(cnt_out)])
    first_in = np.concatenate([[0], np.cumsum(cnt_in)])
    nxt = np.full(f, -1, dtype=np.int64)
    simple = (cnt_out[fv] == 1) & (cnt_in[fv] == 1)
    nxt[simple] = by_out[first_out[fv[simple]]]
    two_pi = 2.0 * math.pi
    for node in np.nonzero((cnt_out > 1) | (cnt_in > 1))[0]:
        outs = by_out[first_out[node]:first_out[node + 1]]
        ins = by_in[first_in[node]:first_in[node + 1]]
        if len(outs) == 0 or len(ins) == 0:
            continue
        delta = np.mod(ang_back[ins][:, None] - ang_out[outs][None, :], two_pi)
        delta[delta <= 0.0] = two_pi
        used_in = np.zeros(len(ins), dtype=bool)
        used_out = np.zeros(len(outs), dtype=bool)
        # greedy by clockwise angle: in a consistent configuration each in-fragment's first
        # out-fragment clockwise is its own sector's, a bijection
        for flat in np.argsort(delta, axis=None, kind="stable"):
            ii, oo = divmod(int(flat), len(outs))
            if not used_in[ii] and not used_out[oo]:
                used_in[ii] = used_out[oo] = True
                nxt[ins[ii]] = outs[oo]
    visited = np.zeros(f, dtype=bool)
    chains: list[list[int]] = []
    broken = 0
    for f0 in range(f):
        if visited[f0]:
            continue
        chain = []
        cur = f0
        while cur != -1 and not visited[cur]:
            visited[cur] = True
            chain.append(cur)
            cur = int(nxt[cur])
        if cur == f0:
            chains.append(chain)
        else:
            broken += 1
    if broken:
        _log.warning("weiler_atherton: %d open boundary chain(s) dropped: the inputs are "
                     "degenerate within a few times the tolerance (see clraster.clip2d)", broken)
    return chains


def _split_at_repeats(seq: list[int]) -> list[list[int]]:
    """Cut a closed node walk into loops that visit no node twice."""
    loops: list[list[int]] = []
    stack: list[int] = []
    pos: dict[int, int] = {}
    for n in seq:
        if n in pos:
            i = pos[n]
            loops.append(stack[i:])
            for m in stack[i + 1:]:
                del pos[m]
            del stack[i + 1:]
        else:
            pos[n] = len(stack)
            stack.append(n)
    loops.append(stack)
    return loops


def _assemble(outers: list[FloatArray], holes: list[FloatArray], tol: float
              ) -> list[Polygon2D]:
    """Give each clockwise ring to the smallest counter-clockwise ring containing it."""
    areas = [_ring_area(r) for r in outers]
    edges = [_edges([r]) for r in outers]
    owned: list[list[FloatArray]] = [[] for _ in outers]
    orphans = 0
    for h in holes:
        best = -1
        for k, (e0, e1) in enumerate(edges):
            if (best < 0 or areas[k] < areas[best]) and _ring_inside(h, e0, e1, tol):
                best = k
        if best < 0:
            orphans += 1
        else:
            owned[best].append(h)
    if orphans:
        _log.warning("weiler_atherton: %d hole ring(s) outside every exterior dropped: the "
                     "inputs are degenerate within a few times the tolerance", orphans)
    return [Polygon2D._trusted(r, hs) for r, hs in zip(outers, owned, strict=True)]


# ---------------------------------------------------------------------------------------------
# Dispatch
# ---------------------------------------------------------------------------------------------

def auto_method(subject: Any, window: Any) -> Literal["sutherland-hodgman", "weiler-atherton"]:
    """The algorithm ``clip_polygon(..., method="auto")`` runs: Sutherland–Hodgman when both
    polygons are convex and hole-free (its one ring is then exactly the intersection),
    Weiler–Atherton otherwise."""
    if is_convex(window) and is_convex(subject):
        return "sutherland-hodgman"
    return "weiler-atherton"


def clip_polygon(subject: Any, window: Any, method: Method = "auto") -> list[Polygon2D]:
    """``subject ∩ window`` as a list of polygons.

    Args:
        subject, window: anything `as_polygon` accepts ((N, 2) ring, ``(exterior, holes)``,
            `Polygon2D`); simple, convex or concave, with or without holes.
        method: ``"auto"`` (see `auto_method`), ``"sutherland-hodgman"`` (convex hole-free
            window, hole-free subject; one ring, which for a concave subject may carry
            zero-width bridges) or ``"weiler-atherton"``.

    Returns:
        list of `Polygon2D`, possibly empty: exteriors counter-clockwise, holes clockwise,
        float64. With "auto" or "weiler-atherton" the polygons are simple and
        interior-disjoint; zero-area contacts give ``[]``.

    Raises:
        ValueError: an unknown method, invalid input (`as_polygon`), or inputs
            "sutherland-hodgman" cannot take.
    """
    if method not in ("auto", "sutherland-hodgman", "weiler-atherton"):
        raise ValueError(f"method must be 'auto', 'sutherland-hodgman' or 'weiler-atherton', "
                         f"got {method!r}")
    s = as_polygon(subject)
    w = as_polygon(window)
    chosen = auto_method(s, w) if method == "auto" else method
    if chosen == "sutherland-hodgman":
        out = sutherland_hodgman(s, w)
        return [] if out is None else [out]
    return weiler_atherton(s, w)
