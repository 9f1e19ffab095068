"""2-D polygons: the `Polygon2D` type, `as_polygon`, and their validation.

Polygons as `clraster.clip.clip2d` clips them (and `clraster.clip.window` draws through
them). Pure Python + NumPy, float64 throughout.

Conventions
-----------
* A polygon is a `Polygon2D`: ``exterior`` is an (N, 2) float64 ring, N ≥ 3, **counter-clockwise**
  (positive shoelace area in a y-up frame), **not closed** (the first vertex is not repeated);
  ``holes`` is a tuple of (M, 2) float64 rings, **clockwise**, also not closed. With these
  orientations the polygon's interior is on the *left* of every directed boundary edge, holes
  included — the property both clipping algorithms (`clraster.clip.clip2d`) rely on. (In a
  y-down image frame the same arrays read as clockwise / counter-clockwise; nothing here
  depends on the axis direction except the words.)
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

Validation (`as_polygon`)
-------------------------
Which pairs of edges break the rules is decided by the same exact predicates as an all-pairs
check would use, with the same results and messages (each ring: no zero-width spike, no two
non-adjacent edges within ``tol``; two rings: no proper crossing, no collinear overlap longer
than ``tol``). Only the pairs they see differ: a superset of every pair of edges within
``tol`` of each other, found in O(n log n) for n edges in all (plus the number of pairs
found, which is O(n) for a valid polygon: each edge's neighbours and the few it touches)
by the sweeps of `clraster.clip.sweep` (its docstring says how).

Holes are then placed with one point each (off the other rings) and the parity of the
crossings of a vertical ray (counted in the same tree, O(log n) per hole). A badly tangled
input (a self-intersecting outline of n vertices has up to ~n² close pairs) stops after
O(n) pairs once a fault is found; then the edges named are a crossing pair, not necessarily
the first. Polygons of at most 96 edges take every pair (the sweeps' fixed cost dominates).
Measured on 2 cores: 10⁵ vertices ~1 s, 10⁶ ~10 s for a smooth outline; a dense zigzag
(hundreds of edges over every x) is slower by a log factor and larger constants.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from .sweep import _CHUNK, _above, _candidate_pairs, _Ladders

__all__ = ["REL_TOL", "Polygon2D", "as_polygon"]

FloatArray = npt.NDArray[np.float64]

#: Relative length tolerance: ``tol = max(REL_TOL · extent, 64 · ε · max|coordinate|)``
#: (module docstring). Smaller makes nearly-touching inputs count as separate (and the
#: degenerate-configuration limitation likelier); larger merges features up to that size.
REL_TOL = 1e-12

_EPS = float(np.finfo(np.float64).eps)
# Validation of polygons with at most this many edges in all tests every pair of edges.
_ALL_PAIRS = 96


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



def _drop_close_repeats(ring: FloatArray, tol: float) -> FloatArray:
    """The ring without vertices within tol of the previous one (cyclically)."""
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
# Vectorised primitives
# ---------------------------------------------------------------------------------------------

def _edges(rings: Sequence[FloatArray]) -> tuple[FloatArray, FloatArray]:
    """Start and end points, (E, 2) each, of the edges of all rings (edge k starts at vertex k)."""
    return (np.concatenate(rings),
            np.concatenate([np.roll(r, -1, axis=0) for r in rings]))


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
