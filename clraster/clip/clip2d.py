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
hundred vertices per polygon take milliseconds. Input validation is O(n log n) (below).

Limitation: in nearly degenerate configurations (an edge within a few ``tol`` of another but
not within ``tol``), the classification of the fragments around one node can disagree; the
walk then drops the open chain it cannot close and logs a warning (the area lost is of the
order of ``tol × length``). Exact inputs and generic inputs do not hit this.

Validation (`as_polygon`)
-------------------------
Which pairs of edges break the rules is decided by the same exact predicates as an all-pairs
check would use, with the same results and messages (each ring: no zero-width spike, no two
non-adjacent edges within ``tol``; two rings: no proper crossing, no collinear overlap longer
than ``tol``). Only the pairs they see differ: a superset of every pair of edges within
``tol`` of each other, found in O(n log n) for n edges in all (plus the number of pairs
found, which is O(n) for a valid polygon: each edge's neighbours and the few it touches):

* an x-sweep (`_Ladders`): a segment tree over the edges' end x-coordinates; each edge is
  stored at the O(log n) nodes whose slab it spans (sorted by y there, in blocks where edges
  cross or touch), and each edge is located, by bisection, in the nodes whose slab holds one
  of its ends. It yields every intersecting pair and every edge passing within 2·tol in y of
  an end at that end's x;
* a y-sweep (the same, x and y swapped, steep edges only) for edges steeper than 45° near an
  end, and a grid of cells 3·tol wide for ends near each other: an edge within tol of an end
  p that spans neither p.x nor p.y has an end within (1 + √2)·tol of p.

Holes are then placed with one point each (off the other rings) and the parity of the
crossings of a vertical ray (counted in the same tree, O(log n) per hole). A badly tangled
input (a self-intersecting outline of n vertices has up to ~n² close pairs) stops after
O(n) pairs once a fault is found; then the edges named are a crossing pair, not necessarily
the first. Polygons of at most 96 edges take every pair (the sweeps' fixed cost dominates).
Measured on 2 cores: 10⁵ vertices ~1 s, 10⁶ ~10 s for a smooth outline; a dense zigzag
(hundreds of edges over every x) is slower by a log factor and larger constants.

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

#: named by the module's public path (users' logging settings name it)
_log = logging.getLogger("clraster.clip2d")

FloatArray = npt.NDArray[np.float64]

#: Relative length tolerance: ``tol = max(REL_TOL · extent, 64 · ε · max|coordinate|)``
#: (module docstring). Smaller makes nearly-touching inputs count as separate (and the
#: degenerate-configuration limitation likelier); larger merges features up to that size.
REL_TOL = 1e-12

_EPS = float(np.finfo(np.float64).eps)
# Sweep ladders (`_Ladders`) of at most this many edges are scanned whole rather than searched.
_SCAN = 8
# Validation of polygons with at most this many edges in all tests every pair of edges.
_ALL_PAIRS = 96
# Pairwise NumPy work (edges × edges, points × edges) goes in row blocks of at most this many
# entries, so memory stays bounded (~16 MB per float64 temporary) for large polygons.
_CHUNK = 1 << 21

Method = Literal["auto", "sutherland-hodgman", "weiler-atherton"]
#: Candidate pairs of edges in chunks: (edge ids, edge ids, how many pairs were looked at).
_PairChunks = Iterator[tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], int]]


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
        # Results of the clippers are correct by construction: skip the validation.
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
    _check_rings([ext, *hs], ["polygon exterior"] + [f"hole {k}" for k in range(len(hs))], tol)
    return _frozen(ext), tuple(_frozen(h) for h in hs)


def _check_rings(rings: Sequence[FloatArray], names: Sequence[str], tol: float,
                 spikes: bool = True) -> None:
    """Raise ValueError unless the rings form a valid polygon (exterior first, then holes).

    In order: each ring has no zero-width spike (``spikes``) and no two non-adjacent edges
    within ``tol`` of each other (`_pair_touch`); no edges of two different rings cross or
    overlap (`_pair_cross_or_overlap`); every hole lies inside the exterior and outside the
    other holes. The messages name the first offending ring (and edges) in the same order
    as an all-pairs check would.

    Cost O(n log n) for n edges in all (plus the number of edge pairs within ``tol``, which
    is O(n) for a valid polygon): `_candidate_pairs` gives a superset of every pair within
    ``tol`` and only those pairs meet the exact predicates.
    """
    e0, e1 = _edges(rings)
    sizes = np.array([len(r) for r in rings])
    first = np.concatenate([[0], np.cumsum(sizes)])
    ring_of = np.repeat(np.arange(len(rings)), sizes)
    idx = np.arange(len(e0))
    nxt = np.where(idx + 1 == first[ring_of + 1], first[ring_of], idx + 1)
    prv = np.where(idx == first[ring_of], first[ring_of + 1] - 1, idx - 1)

    # few edges: every pair is a candidate (the sweep's fixed cost would dominate)
    xsweep = _Ladders(e0, e1) if len(e0) > _ALL_PAIRS else None
    self_hit: dict[int, tuple[int, int]] = {}
    cross_hit: tuple[int, int] | None = None
    unclean: list[tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]] = []
    # a tangled input (a self-intersecting outline) can have ~n² pairs within tol: once a
    # fault is found, stop after looking at this many pairs
    looked = 0
    budget = 32 * len(e0) + 4 * _CHUNK
    lo = np.minimum(e0, e1) - 2.0 * tol
    hi = np.maximum(e0, e1) + 2.0 * tol
    pairs = (_candidate_pairs(e0, e1, tol, xsweep) if xsweep is not None
             else iter([(*np.triu_indices(len(e0), 1), len(e0) ** 2 // 2)]))
    for i, j, work in pairs:
        looked += work
        # distinct, not sharing a vertex, boxes within 2 tol (cheap filters first)
        keep = (i != j) & (j != nxt[i]) & (j != prv[i])
        keep &= ((lo[i] <= hi[j]) & (lo[j] <= hi[i])).all(axis=1)
        i, j = i[keep], j[keep]
        same = ring_of[i] == ring_of[j]
        si, sj = np.minimum(i[same], j[same]), np.maximum(i[same], j[same])
        bad = _pair_touch(e0[si], e1[si], e0[sj], e1[sj], tol)
        if bad.any():
            r = ring_of[si[bad]]
            a, b = si[bad] - first[r], sj[bad] - first[r]
            o = np.lexsort((b, a, r))
            r, a, b = r[o], a[o], b[o]
            head = np.nonzero(np.concatenate([[True], r[1:] != r[:-1]]))[0]
            for rk, ak, bk in zip(r[head].tolist(), a[head].tolist(), b[head].tolist(),
                                  strict=True):
                if rk not in self_hit or (ak, bk) < self_hit[rk]:
                    self_hit[rk] = (ak, bk)
        # cross-ring pairs: the lower ring's edge first (as the all-pairs check orders them)
        ci, cj = i[~same], j[~same]
        swap = ring_of[ci] > ring_of[cj]
        ci, cj = np.where(swap, cj, ci), np.where(swap, ci, cj)
        bad = _pair_cross_or_overlap(e0[ci], e1[ci], e0[cj], e1[cj], tol)
        if bad.any():
            ri, rj = ring_of[ci[bad]], ring_of[cj[bad]]
            k = int(np.lexsort((rj, ri))[0])
            pair = (int(ri[k]), int(rj[k]))
            cross_hit = pair if cross_hit is None else min(cross_hit, pair)
        unclean.append(_unclean_points(e0, e1, ci, cj, nxt, tol))
        if (self_hit or cross_hit is not None) and looked > budget:
            break  # a badly tangled input: report what was found so far
    for k, ring in enumerate(rings):
        if spikes:
            _check_spikes(ring, tol, names[k])
        if k in self_hit:
            a, b = self_hit[k]
            raise ValueError(f"{names[k]} intersects itself (edges {a} and {b} meet); pass a "
                             "simple polygon: split a self-intersecting outline into several "
                             "polygons, or describe holes as holes")
    if cross_hit is not None:
        a, b = cross_hit
        raise ValueError(f"{_ring_name(b)} crosses or overlaps {_ring_name(a)}; holes must lie "
                         "inside the exterior and may touch it or each other only at points")
    if len(rings) > 1:
        _check_containment(rings, e0, e1, first, ring_of, xsweep, unclean, tol)


def _ring_name(k: int) -> str:
    return "the exterior" if k == 0 else f"hole {k - 1}"


def _check_spikes(ring: FloatArray, tol: float, what: str) -> None:
    """Adjacent edges folding back onto each other (a zero-width spike)."""
    n = len(ring)
    d = np.roll(ring, -1, axis=0) - ring
    dn = np.roll(d, -1, axis=0)
    ln = np.hypot(d[:, 0], d[:, 1])
    off = np.abs(d[:, 0] * dn[:, 1] - d[:, 1] * dn[:, 0]) / ln
    back = (off <= tol) & ((d * dn).sum(axis=1) < 0)
    if back.any():
        k = int(np.nonzero(back)[0][0])
        raise ValueError(f"{what} folds back on itself at vertex {(k + 1) % n} "
                         f"({ring[(k + 1) % n].tolist()}): a zero-width spike; remove that vertex")


def _check_ring_simple(ring: FloatArray, tol: float, what: str, spikes: bool = True) -> None:
    """One ring: no zero-width spike (``spikes``), no two non-adjacent edges within ``tol``."""
    _check_rings([ring], [what], tol, spikes=spikes)


def _unclean_points(e0: FloatArray, e1: FloatArray, ci: npt.NDArray[np.intp],
                    cj: npt.NDArray[np.intp], nxt: npt.NDArray[np.intp], tol: float
                    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """Vertices and edge midpoints within tol of an edge of another ring, from the candidate
    pairs (ci, cj) of edges of different rings: (vertex ids, edge ids whose midpoint) —
    vertex k starts edge k. Every such point lies on an edge of a candidate pair."""
    verts, mids = [], []
    for a, b in ((ci, cj), (cj, ci)):
        for p, ids in ((e0[a], a), (e1[a], nxt[a])):
            verts.append(ids[_pair_point_segment(p, e0[b], e1[b]) <= tol])
        m = 0.5 * (e0[a] + e1[a])
        mids.append(a[_pair_point_segment(m, e0[b], e1[b]) <= tol])
    return np.concatenate(verts), np.concatenate(mids)


def _check_containment(rings: Sequence[FloatArray], e0: FloatArray, e1: FloatArray,
                       first: npt.NDArray[np.intp], ring_of: npt.NDArray[np.intp],
                       xsweep: _Ladders | None, unclean: list[tuple[npt.NDArray[np.intp],
                                                             npt.NDArray[np.intp]]],
                       tol: float) -> None:
    """Every hole inside the exterior and outside the other holes, given that no two rings
    cross or overlap (so one point of a hole off the other rings decides for all of it).

    One representative point per hole (its first vertex, else first edge midpoint, farther
    than tol from every other ring): the hole is placed right iff the vertical ray up from
    that point crosses the other rings' edges an odd number of times (inside the exterior
    and no hole; an even count means outside the exterior or inside a hole, and then the
    per-ring counts of that one point say which). Counting uses the sweep's ladders: O(log n)
    per point."""
    n = len(e0)
    bad_v = np.zeros(n, dtype=bool)
    bad_m = np.zeros(n, dtype=bool)
    for v, m in unclean:
        bad_v[v] = True
        bad_m[m] = True
    reps: list[FloatArray] = []
    hole_ids: list[int] = []
    for k in range(1, len(rings)):
        s, e = int(first[k]), int(first[k + 1])
        ring = rings[k]
        ok = np.nonzero(~bad_v[s:e])[0]
        if len(ok):
            reps.append(ring[ok[0]])
        else:
            ok = np.nonzero(~bad_m[s:e])[0]
            if not len(ok):
                _check_hole_fallback(rings, k, tol)
                continue
            reps.append(0.5 * (ring[ok[0]] + ring[(ok[0] + 1) % len(ring)]))
        hole_ids.append(k)
    if not hole_ids:
        return
    p = np.array(reps)
    if xsweep is not None:
        total = xsweep.count_above(p[:, 0], p[:, 1])
    else:
        total = np.array([int(_above(e0, e1, x, y).sum()) for x, y in p])
    for q, k in enumerate(hole_ids):
        s, e = int(first[k]), int(first[k + 1])
        own = int(_above(e0[s:e], e1[s:e], p[q, 0], p[q, 1]).sum())
        if (int(total[q]) - own) % 2 == 0:
            counts = np.bincount(ring_of[_above(e0, e1, p[q, 0], p[q, 1])],
                                 minlength=len(rings))
            _raise_placement(k, counts)


def _raise_placement(k: int, counts: npt.NDArray[np.intp]) -> None:
    """Hole ``k`` (ring index) is misplaced; ``counts``: ray crossings per ring of a point of
    it off the other rings."""
    if counts[0] % 2 == 0:
        raise ValueError(f"hole {k - 1} lies outside the exterior; holes must be inside it")
    for m in range(1, len(counts)):
        if m != k and counts[m] % 2 == 1:
            raise ValueError(f"hole {k - 1} lies inside hole {m - 1}; nested holes are not a "
                             "polygon (pass the island as a separate polygon)")
    raise ValueError(f"hole {k - 1} is misplaced; holes must lie inside the exterior and "
                     "outside each other")


def _check_hole_fallback(rings: Sequence[FloatArray], k: int, tol: float) -> None:
    """Placement of a hole every vertex and edge midpoint of which touches another ring:
    decide against each ring separately, as `_ring_inside` does (quadratic, but only for
    such degenerate holes)."""
    h = rings[k]
    ext = rings[0]
    if not _ring_inside(h, ext, np.roll(ext, -1, axis=0), tol):
        raise ValueError(f"hole {k - 1} lies outside the exterior; holes must be inside it")
    for m in range(1, len(rings)):
        if m != k and _ring_inside(h, rings[m], np.roll(rings[m], -1, axis=0), tol):
            raise ValueError(f"hole {k - 1} lies inside hole {m - 1}; nested holes are not a "
                             "polygon (pass the island as a separate polygon)")


def _above(e0: FloatArray, e1: FloatArray, px: float, py: float) -> npt.NDArray[np.bool_]:
    """Which edges the vertical ray up from (px, py) crosses: xl <= px < xr (half-open, so a
    vertex on the ray counts once) and the edge's y at px (`_y_at`) above py."""
    swap = e1[:, 0] < e0[:, 0]
    xl = np.where(swap, e1[:, 0], e0[:, 0])
    xr = np.where(swap, e0[:, 0], e1[:, 0])
    yl = np.where(swap, e1[:, 1], e0[:, 1])
    yr = np.where(swap, e0[:, 1], e1[:, 1])
    span = (xl <= px) & (px < xr)
    out = np.zeros(len(e0), dtype=bool)
    out[span] = _y_at(xl[span], yl[span], xr[span], yr[span], np.full(int(span.sum()), px)) > py
    return out


def _y_at(xl: FloatArray, yl: FloatArray, xr: FloatArray, yr: FloatArray,
          x: FloatArray) -> FloatArray:
    """y of the non-vertical segments (xl, yl)–(xr, yr), xl < xr, at x in [xl, xr]: exact at
    both ends (so edges meeting at a vertex agree there), no overflow for steep ones."""
    return np.where(x == xr, yr, yl + (x - xl) / (xr - xl) * (yr - yl))


class _Ladders:
    """Segment tree over the x-coordinates of the edges' ends (a static sweep line).

    The elementary slabs lie between consecutive distinct end x-coordinates; tree node
    (level l, j) covers slabs [j·2^l, (j+1)·2^l). Each non-vertical edge is stored at the
    O(log n) nodes whose slab it spans and whose parent's it does not (its canonical nodes);
    the edges at a node, a *ladder*, are sorted by their y at the slab's middle. Within a
    slab, non-crossing edges keep their order, so the ladder is sorted at every x of it;
    where edges cross or touch inside a slab (a self-intersection, or rings touching), the
    ladder is cut into *blocks*: maximal runs whose members are strictly above all earlier
    and strictly below all later ones at both slab ends (hence everywhere in the slab), and a
    search that lands in a block takes all of it. So a binary search over a ladder finds
    every edge of it near a point, whether the edges cross or not.

    Every pair of segments at distance 0 has, for some node, both in its ladder (then the
    same block) or one in it and the other with an end strictly inside the node's slab (then
    the other's piece in the slab lies between the two positions `pairs` finds for it).
    """

    def __init__(self, p0: FloatArray, p1: FloatArray,
                 rungs: npt.NDArray[np.bool_] | None = None) -> None:
        """Ladders of the edges p0[k]→p1[k] selected by ``rungs`` (default: all non-vertical
        ones; vertical edges are never stored)."""
        swap = p1[:, 0] < p0[:, 0]
        self.xl = np.where(swap, p1[:, 0], p0[:, 0])
        self.yl = np.where(swap, p1[:, 1], p0[:, 1])
        self.xr = np.where(swap, p0[:, 0], p1[:, 0])
        self.yr = np.where(swap, p0[:, 1], p1[:, 1])
        self.vertical = self.xl == self.xr
        self.x, rank = np.unique(np.concatenate([self.xl, self.xr]), return_inverse=True)
        self.nleaf = max(len(self.x) - 1, 0)
        self.ra, self.rb = rank[:len(p0)], rank[len(p0):]
        self.nlev = max(1, (self.nleaf - 1).bit_length() + 1) if self.nleaf else 0
        sizes = [(self.nleaf + (1 << lv) - 1) >> lv for lv in range(self.nlev)]
        self.level_off = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]).astype(np.int64)
        self.top = 0        # levels above `top` hold no edges: queries stop there
        nodes = int(self.level_off[-1])

        # canonical nodes of each non-vertical edge ([ra, rb) in slab units)
        ent_e, ent_l, ent_j = [], [], []
        ids = np.nonzero(~self.vertical if rungs is None else rungs & ~self.vertical)[0]
        lo, hi = self.ra[ids].copy(), self.rb[ids].copy()
        for lv in range(self.nlev):
            act = lo < hi
            if not act.any():
                break
            take = act & (lo & 1 == 1)
            ent_e.append(ids[take])
            ent_j.append(lo[take])
            ent_l.append(np.full(int(take.sum()), lv))
            lo[take] += 1
            take = act & (hi & 1 == 1)
            hi[take] -= 1
            ent_e.append(ids[take])
            ent_j.append(hi[take])
            ent_l.append(np.full(int(take.sum()), lv))
            lo >>= 1
            hi >>= 1
        edge = np.concatenate(ent_e) if ent_e else np.zeros(0, np.int64)
        lev = np.concatenate(ent_l) if ent_l else np.zeros(0, np.int64)
        self.top = int(lev.max()) + 1 if len(lev) else 0
        j = np.concatenate(ent_j) if ent_j else np.zeros(0, np.int64)
        node = self.level_off[lev] + j
        order = np.argsort(node, kind="stable")
        edge, node, lev, j = edge[order], node[order], lev[order], j[order]
        m = len(node)
        self.start = np.concatenate([[0], np.cumsum(np.bincount(node, minlength=nodes))])
        size = np.diff(self.start)[node]
        pos = np.arange(m)
        # a short ladder (<= _SCAN edges) is scanned whole: one block, in any order
        self.block_lo = self.start[node]
        self.block_hi = self.start[node + 1] - 1
        big = np.nonzero(size > _SCAN)[0]
        if len(big):
            # longer ones sorted by y at the slab's middle, then cut into blocks: between k
            # and k+1 iff everything up to k is strictly below everything after it at the
            # slab's left end, middle and right end. Where each edge is strictly below the
            # next at all three (the usual case) that holds; ladders with ties or inversions
            # get the exact test (prefix maximum below suffix minimum of ranks at each end).
            left, right = self._slab(lev[big], j[big])
            eb, nb = edge[big], node[big]
            y_m = self.y(eb, 0.5 * left + 0.5 * right)
            o = np.lexsort((y_m, nb))
            eb, nb, y_m, left, right = eb[o], nb[o], y_m[o], left[o], right[o]
            edge[big] = eb
            y_l, y_r = self.y(eb, left), self.y(eb, right)
            newnode = nb[1:] != nb[:-1]
            cut = newnode | ((y_m[:-1] < y_m[1:]) & (y_l[:-1] < y_l[1:]) & (y_r[:-1] < y_r[1:]))
            if not cut.all():
                bad = np.zeros(nodes, dtype=bool)
                bad[nb[:-1][~cut]] = True
                sel = np.nonzero(bad[nb])[0]
                sub = _exact_cuts(nb[sel], y_l[sel], y_m[sel], y_r[sel])
                inner = sel[1:] == sel[:-1] + 1
                cut[sel[:-1][inner]] = sub[inner]
            p = pos[big]
            starts = np.concatenate([[True], cut])
            ends = np.concatenate([cut, [True]])
            self.block_lo[big] = p[np.maximum.accumulate(np.where(starts, np.arange(len(p)), 0))]
            self.block_hi[big] = p[np.minimum.accumulate(
                np.where(ends, np.arange(len(p)), len(p) - 1)[::-1])[::-1]]
        self.edge = edge
        self.slab_l, self.slab_r = self._slab(lev, j)
        # the rungs' ends in ladder order, for the searches and scans (one gather per step)
        self.seg = np.stack([self.xl[edge], self.yl[edge], self.xr[edge], self.yr[edge]], axis=1)

    def _slab(self, lev: npt.NDArray[np.int64], j: npt.NDArray[np.int64]
              ) -> tuple[FloatArray, FloatArray]:
        return (self.x[j << lev],
                self.x[np.minimum((j + 1) << lev, self.nleaf)])

    def y(self, edge: npt.NDArray[np.intp], x: FloatArray) -> FloatArray:
        """y of non-vertical edges at x (`_y_at`)."""
        return _y_at(self.xl[edge], self.yl[edge], self.xr[edge], self.yr[edge], x)

    def _search(self, s: npt.NDArray[np.int64], e: npt.NDArray[np.int64], x: FloatArray,
                y: FloatArray, strict: bool) -> npt.NDArray[np.int64]:
        """Bisection per query in ladder positions [s, e): the first one whose edge at x is
        >= y (> y with ``strict``), as if the ladder were sorted at x (a transition point of
        the comparison, in general)."""
        lo, hi = s.copy(), e.copy()
        act = np.nonzero(lo < hi)[0]
        while len(act):
            mid = (lo[act] + hi[act]) >> 1
            g = self.seg[mid]
            v = _y_at(g[:, 0], g[:, 1], g[:, 2], g[:, 3], x[act])
            go_left = v > y[act] if strict else v >= y[act]
            hi[act[go_left]] = mid[go_left]
            lo[act[~go_left]] = mid[~go_left] + 1
            act = act[lo[act] < hi[act]]
        return lo

    def _window(self, s: npt.NDArray[np.int64], e: npt.NDArray[np.int64], x: FloatArray,
                y0: FloatArray, y1: FloatArray
                ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Inclusive ladder ranges [lo, hi] holding every edge whose y at x may lie in
        [y0, y1] (whole blocks; the ones strictly outside are below / above all of it)."""
        a = self._search(s, e, x, y0, strict=False)
        b = self._gallop(a, e, x, y1)
        return self._expand_lo(a, s), self._expand_hi(b, e)

    def _gallop(self, a: npt.NDArray[np.int64], e: npt.NDArray[np.int64], x: FloatArray,
                y: FloatArray) -> npt.NDArray[np.int64]:
        """`_search` (strict) in [a, e) where the answer is usually at or just after a
        (windows are a few tol wide): probe a, a+1, a+3, … then bisect the last step."""
        lo, hi = a.copy(), e.copy()
        step = np.ones(len(a), dtype=np.int64)
        act = np.nonzero(lo < hi)[0]
        while len(act):
            at = np.minimum(lo[act] + step[act] - 1, hi[act] - 1)
            g = self.seg[at]
            above = _y_at(g[:, 0], g[:, 1], g[:, 2], g[:, 3], x[act]) > y[act]
            hi[act[above]] = at[above]
            lo[act[~above]] = at[~above] + 1
            step[act] *= 2
            act = act[~above]
            act = act[lo[act] < hi[act]]
        return self._search(lo, hi, x, y, strict=True)

    def _expand_lo(self, a: npt.NDArray[np.int64], s: npt.NDArray[np.int64]
                   ) -> npt.NDArray[np.int64]:
        """Lower end of a range from a transition a (edge a-1 below, edge a not): edge a-1's
        block when it has other members (their order may differ from the search's)."""
        k = np.clip(a - 1, 0, max(len(self.edge) - 1, 0))
        alone = (self.block_lo[k] == k) & (self.block_hi[k] == k)
        return np.where((a > s) & ~alone, self.block_lo[k], a)

    def _expand_hi(self, b: npt.NDArray[np.int64], e: npt.NDArray[np.int64]
                   ) -> npt.NDArray[np.int64]:
        """Upper end (inclusive) of a range from a transition b (edge b above, b-1 not)."""
        k = np.clip(b, 0, max(len(self.edge) - 1, 0))
        alone = (self.block_lo[k] == k) & (self.block_hi[k] == k)
        return np.where((b < e) & ~alone, self.block_hi[k], b - 1)

    def _query_nodes(self, leaves: npt.NDArray[np.int64], lv: int
                     ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.int64]]:
        """(query row, node j at level lv) for the distinct non-empty ancestors at level lv of
        each row's leaves (an (n, k) array, -1 for none)."""
        jj = np.where(leaves >= 0, leaves >> lv, -1)
        dup = np.zeros(jj.shape, dtype=bool)
        for c in range(1, jj.shape[1]):
            dup[:, c] = (jj[:, :c] == jj[:, c:c + 1]).any(axis=1)
        row, col = np.nonzero((jj >= 0) & ~dup)
        j = jj[row, col]
        node = self.level_off[lv] + j
        keep = self.start[node + 1] > self.start[node]
        return row[keep], j[keep]

    def pairs(self, delta: float, pieces: bool = True) -> _PairChunks:
        """Candidate pairs (edge, edge), in chunks (`_PairChunks`), with repeats.

        With ``pieces``: every pair of edges that intersect, and every edge paired with every
        non-vertical edge that spans the x of one of its ends p, extends from there to the
        same side as it, and passes within ``delta`` of p.y there. Without: only the latter
        (the ends alone, no crossings), which is what the y-sweep is for.

        How: both edges in one ladder block; else each edge is a query at every node whose
        slab holds one of its ends (the ancestors of the slabs it covers at its ends; a
        vertical edge, both slabs beside its x): the ladder range between the edge's
        positions at the two ends of its piece in the slab, each widened by ``delta``. An
        edge that intersects a ladder edge either has an end strictly inside that slab or
        shares a ladder with it (its canonical nodes and the ladder's lie on one path).
        """
        if not len(self.edge):
            return
        if pieces:
            # two edges of one block (a short ladder is one block) that meet in the slab:
            # their order at its left end is not strictly the one at its right end
            pos = np.arange(len(self.edge))
            for u, w in _expand(pos, pos + 1, self.block_hi, pos):
                gu, gw = self.seg[u], self.seg[w]
                x_l, x_r = self.slab_l[u], self.slab_r[u]
                d_l = (_y_at(gu[:, 0], gu[:, 1], gu[:, 2], gu[:, 3], x_l)
                       - _y_at(gw[:, 0], gw[:, 1], gw[:, 2], gw[:, 3], x_l))
                d_r = (_y_at(gu[:, 0], gu[:, 1], gu[:, 2], gu[:, 3], x_r)
                       - _y_at(gw[:, 0], gw[:, 1], gw[:, 2], gw[:, 3], x_r))
                meet = ~(((d_l > 0) & (d_r > 0)) | ((d_l < 0) & (d_r < 0)))
                yield self.edge[u[meet]], self.edge[w[meet]], len(u)
        ids = np.arange(len(self.xl))
        vert = self.vertical
        ra, rb = self.ra, self.rb
        if pieces:
            owner = ids
            leaves = np.stack([np.where(vert, ra - 1, ra), np.where(vert, ra, rb - 1)], axis=1)
            x0, x1 = self.xl, self.xr
            y0, y1 = self.yl, self.yr
        else:
            owner = np.concatenate([ids, ids])
            leaves = np.concatenate([np.stack([np.where(vert, ra - 1, ra), ra], axis=1),
                                     np.stack([np.where(vert, rb, rb - 1), rb - 1], axis=1)])
            x0 = x1 = np.concatenate([self.xl, self.xr])
            y0 = y1 = np.concatenate([self.yl, self.yr])
        leaves = np.where((leaves >= 0) & (leaves < self.nleaf), leaves, -1)
        point = x0 == x1            # a vertical edge or a lone end: a y-range at one x
        ylo, yhi = np.minimum(y0, y1), np.maximum(y0, y1)
        for lv in range(self.top):
            row, j = self._query_nodes(leaves, lv)
            if not len(row):
                continue
            node = self.level_off[lv] + j
            s, e = self.start[node], self.start[node + 1]
            left, right = self._slab(np.full(len(j), lv), j)
            cl = np.maximum(left, x0[row])
            cr = np.minimum(right, x1[row])
            y_cl, y_cr = ylo[row], yhi[row]
            piece = ~point[row]
            y_cl[piece] = self.y(owner[row[piece]], cl[piece])
            y_cr[piece] = self.y(owner[row[piece]], cr[piece])
            # short ladders: test every edge of it (no search, no blocks needed)
            small = e - s <= _SCAN
            if small.any():
                q = np.nonzero(small)[0]
                for which, k in _expand(q, s[q], e[q] - 1, np.arange(len(self.edge))):
                    g = self.seg[k]
                    v1 = _y_at(g[:, 0], g[:, 1], g[:, 2], g[:, 3], cl[which])
                    v2 = _y_at(g[:, 0], g[:, 1], g[:, 2], g[:, 3], cr[which])
                    below = (v1 < y_cl[which] - delta) & (v2 < y_cr[which] - delta)
                    above = (v1 > y_cl[which] + delta) & (v2 > y_cr[which] + delta)
                    keep = ~(below | above)
                    yield owner[row[which[keep]]], self.edge[k[keep]], len(k)
            q = np.nonzero(~small)[0]
            if len(q):
                lo1, hi1 = self._window(s[q], e[q], cl[q], y_cl[q] - delta, y_cl[q] + delta)
                lo2, hi2 = self._window(s[q], e[q], cr[q], y_cr[q] - delta, y_cr[q] + delta)
                for i, j in _expand(owner[row[q]], np.minimum(lo1, lo2), np.maximum(hi1, hi2),
                                    self.edge):
                    yield i, j, len(i)

    def count_above(self, px: FloatArray, py: FloatArray) -> npt.NDArray[np.int64]:
        """Per point, how many non-vertical edges with xl <= px < xr have their y at px
        (`_y_at`) above py: the crossings of the vertical ray up from it."""
        out = np.zeros(len(px), dtype=np.int64)
        if not len(self.edge):
            return out
        leaf = np.searchsorted(self.x, px, side="right") - 1
        inside = np.nonzero((leaf >= 0) & (leaf < self.nleaf))[0]
        for lv in range(self.top):
            row, j = self._query_nodes(leaf[inside, None], lv)
            q = inside[row]
            node = self.level_off[lv] + j
            s, e = self.start[node], self.start[node + 1]
            x, y = px[q], py[q]
            b = self._search(s, e, x, y, strict=True)
            lo, hi = self._expand_lo(b, s), self._expand_hi(b, e)
            np.add.at(out, q, e - 1 - hi)
            # the block(s) the search landed in: count exactly
            cnt = np.maximum(hi - lo + 1, 0)
            which = np.repeat(np.arange(len(q)), cnt)
            at = lo[which] + _ramp(cnt)
            above = self.y(self.edge[at], x[which]) > y[which]
            np.add.at(out, q[which[above]], 1)
        return out


def _exact_cuts(node: npt.NDArray[np.int64], y_l: FloatArray, y_m: FloatArray,
                y_r: FloatArray) -> npt.NDArray[np.bool_]:
    """For ladders (grouped by node, sorted by y_m within): whether everything up to entry k
    is strictly below everything after it (same node) at all three x, for each k."""
    m = len(node)
    pos = np.arange(m)
    newnode = node[1:] != node[:-1]
    rank_m = _tie_rank(node, y_m, pos)
    ok = newnode | (rank_m[:-1] < rank_m[1:])
    for yv in (y_l, y_r):
        o = np.lexsort((yv, node))
        r = np.empty(m, dtype=np.int64)
        r[o] = _tie_rank(node[o], yv[o], pos)
        pmax = np.maximum.accumulate(r)
        smin = np.minimum.accumulate(r[::-1])[::-1]
        ok &= newnode | (pmax[:-1] < smin[1:])
    return ok


def _tie_rank(group: npt.NDArray[np.int64], v: FloatArray, pos: npt.NDArray[np.int64]
              ) -> npt.NDArray[np.int64]:
    """For a sequence sorted by (group, v): each entry's position of the first entry equal to
    it (same group and value), so equal values share a rank and ranks grow across groups."""
    new = np.ones(len(v), dtype=bool)
    new[1:] = (group[1:] != group[:-1]) | (v[1:] != v[:-1])
    return np.maximum.accumulate(np.where(new, pos, 0))


def _ramp(cnt: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """0, 1, …, cnt[0]-1, 0, 1, …, cnt[1]-1, …"""
    total = int(cnt.sum())
    return np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)


def _expand(owner: npt.NDArray[np.intp], lo: npt.NDArray[np.int64], hi: npt.NDArray[np.int64],
            target: npt.NDArray[np.intp]
            ) -> Iterator[tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]]:
    """Pairs (owner[q], target[k]) for k in [lo[q], hi[q]], in chunks of about _CHUNK."""
    cnt = np.maximum(hi - lo + 1, 0)
    cum = np.cumsum(cnt)
    a = 0
    while a < len(cnt):
        b = int(np.searchsorted(cum, (cum[a - 1] if a else 0) + _CHUNK, side="right"))
        b = max(b, a + 1)
        c = cnt[a:b]
        which = np.repeat(np.arange(a, b), c)
        if len(which):
            yield owner[which], target[lo[which] + _ramp(c)]
        a = b


def _grid_pairs(p0: FloatArray, p1: FloatArray, radius: float) -> _PairChunks:
    """Edge pairs with ends within ``radius`` of each other (and a few farther): the ends
    sorted by column (x in steps of ``radius``), then y; each end against the ends after it
    in its column and those in the next column, with y within ``radius``."""
    pts = np.concatenate([p0, p1])
    owner = np.concatenate([np.arange(len(p0)), np.arange(len(p0))])
    col = np.floor((pts[:, 0] - pts[:, 0].min()) / radius).astype(np.int64)
    order = np.lexsort((pts[:, 1], col))
    col, y = col[order], pts[order, 1]
    n = len(col)
    ucol, first = np.unique(col, return_index=True)
    bounds = np.concatenate([first, [n]])
    which = np.repeat(np.arange(len(ucol)), np.diff(bounds))
    pos = np.arange(n)
    # the same column: the ends after this one up to y + radius
    hi = _bisect(y, pos + 1, bounds[which + 1], y + radius, strict=True)
    ranges = [(pos + 1, hi - 1)]
    # the next column, if it is the adjacent one
    nxt = np.minimum(which + 1, len(ucol) - 1)
    there = (which + 1 < len(ucol)) & (ucol[nxt] == col + 1)
    s = np.where(there, bounds[nxt], 0)
    e = np.where(there, bounds[nxt + 1], 0)
    lo = _bisect(y, s, e, y - radius, strict=False)
    ranges.append((lo, _bisect(y, lo, e, y + radius, strict=True) - 1))
    for lo, hi in ranges:
        for i, k in _expand(pos, lo, hi, pos):
            d = pts[order[i]] - pts[order[k]]
            near = np.hypot(d[:, 0], d[:, 1]) <= radius
            yield owner[order[i[near]]], owner[order[k[near]]], len(i)


def _bisect(v: FloatArray, s: npt.NDArray[np.int64], e: npt.NDArray[np.int64],
            target: FloatArray, strict: bool) -> npt.NDArray[np.int64]:
    """Per query, the first index in [s, e) of the ascending run v[s:e] with v >= target
    (> target with ``strict``); e if none."""
    lo, hi = s.copy(), e.copy()
    act = np.nonzero(lo < hi)[0]
    while len(act):
        mid = (lo[act] + hi[act]) >> 1
        left = v[mid] > target[act] if strict else v[mid] >= target[act]
        hi[act[left]] = mid[left]
        lo[act[~left]] = mid[~left] + 1
        act = act[lo[act] < hi[act]]
    return lo


def _candidate_pairs(e0: FloatArray, e1: FloatArray, tol: float, xsweep: _Ladders
                     ) -> _PairChunks:
    """Edge pairs (i, j), in chunks, unordered, with repeats and pairs of adjacent edges: a
    superset of every pair of edges (e0[i], e1[i]), (e0[j], e1[j]) within ``tol``.

    Why it is complete: two edges within tol either intersect, or an end p of one lies within
    tol of the other, e. Intersecting pairs come from the x-sweep (`_Ladders`; a vertical
    edge there is a query at its x, and two vertical edges overlapping have an end of one on
    the other). For the end p: if e is at most 45° from horizontal and spans p.x, its y at
    p.x is within √2·tol of p.y (x-sweep window of 2·tol); if steeper and it spans p.y, the
    same holds in the y-sweep (x and y swapped); otherwise e lies in one quadrant around p
    and one of its ends is within (1 + √2)·tol of p (grid of radius 3·tol).

    Cost: O(n log n) for n edges, plus the number of pairs produced; for a valid polygon
    that is O(n) (each edge meets its neighbours and the few edges it touches).
    """
    yield from _grid_pairs(e0, e1, 3.0 * tol)
    yield from xsweep.pairs(2.0 * tol)
    d = np.abs(e1 - e0)
    steep = d[:, 1] > d[:, 0]
    if steep.any():
        yield from _Ladders(e0[:, ::-1], e1[:, ::-1], rungs=steep).pairs(2.0 * tol,
                                                                        pieces=False)


def _pair_side_distances(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray
                         ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """`_side_distances` for pairs of edges (row k of a with row k of b), same arithmetic."""
    r = a1 - a0
    s = b1 - b0
    lr = np.hypot(r[:, 0], r[:, 1])
    ls = np.hypot(s[:, 0], s[:, 1])

    def from_a(p: FloatArray) -> FloatArray:
        return (r[:, 0] * (p[:, 1] - a0[:, 1]) - r[:, 1] * (p[:, 0] - a0[:, 0])) / lr

    def from_b(p: FloatArray) -> FloatArray:
        return (s[:, 0] * (p[:, 1] - b0[:, 1]) - s[:, 1] * (p[:, 0] - b0[:, 0])) / ls

    return from_a(b0), from_a(b1), from_b(a0), from_b(a1)


def _pair_point_segment(p: FloatArray, s0: FloatArray, s1: FloatArray) -> FloatArray:
    """Distance of point k to segment k (`_point_segment` row by row, same arithmetic)."""
    d = s1 - s0
    l2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    l2 = np.where(l2 > 0, l2, 1.0)
    px = p[:, 0] - s0[:, 0]
    py = p[:, 1] - s0[:, 1]
    t = (px * d[:, 0] + py * d[:, 1]) / l2
    tc = np.clip(t, 0.0, 1.0)
    return np.hypot(px - tc * d[:, 0], py - tc * d[:, 1])


def _pair_touch(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                tol: float) -> npt.NDArray[np.bool_]:
    """Per pair: the segments cross or come within tol of each other."""
    db0, db1, da0, da1 = _pair_side_distances(a0, a1, b0, b1)
    near = _proper(db0, db1, da0, da1, tol)
    near |= _pair_point_segment(b0, a0, a1) <= tol
    near |= _pair_point_segment(b1, a0, a1) <= tol
    near |= _pair_point_segment(a0, b0, b1) <= tol
    near |= _pair_point_segment(a1, b0, b1) <= tol
    return near


def _pair_cross_or_overlap(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                           tol: float) -> npt.NDArray[np.bool_]:
    """Per pair: the segments cross properly or overlap collinearly over more than tol
    (measured along a)."""
    db0, db1, da0, da1 = _pair_side_distances(a0, a1, b0, b1)
    bad = _proper(db0, db1, da0, da1, tol)
    r = a1 - a0
    lr = np.hypot(r[:, 0], r[:, 1])
    u = r / lr[:, None]
    s0 = (b0[:, 0] - a0[:, 0]) * u[:, 0] + (b0[:, 1] - a0[:, 1]) * u[:, 1]
    s1 = (b1[:, 0] - a0[:, 0]) * u[:, 0] + (b1[:, 1] - a0[:, 1]) * u[:, 1]
    overlap = np.minimum(lr, np.maximum(s0, s1)) - np.maximum(0.0, np.minimum(s0, s1))
    bad |= (np.abs(db0) <= tol) & (np.abs(db1) <= tol) & (overlap > tol)
    return bad


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
