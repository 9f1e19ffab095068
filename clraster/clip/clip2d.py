"""2-D polygon clipping: Sutherland–Hodgman for convex windows, Weiler–Atherton in general.

``clip_polygon(subject, window)`` returns the intersection ``subject ∩ window`` of two simple
polygons (with holes) as a list of polygons. Pure Python + NumPy, float64 throughout.

Polygons
--------
Inputs are anything `as_polygon` accepts, outputs are `Polygon2D`; both live in
`clraster.clip.polygon` (and are importable from here), whose docstring pins the conventions
both algorithms rely on (exterior counter-clockwise, holes clockwise, rings not closed, so
the interior is on the *left* of every directed boundary edge; inputs simple) and the one
length tolerance per operation, ``tol = max(REL_TOL · extent, 64 · ε · max|coordinate|)``:
points closer than ``tol`` are the same point, a vertex closer than ``tol`` to an edge lies
on it, a ring whose area is at most ``tol × perimeter`` has no area.

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
hundred vertices per polygon take milliseconds. Input validation is O(n log n)
(`clraster.clip.polygon`).

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
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from .polygon import (
    REL_TOL,
    Polygon2D,
    _drop_close_repeats,
    _edges,
    _inside_even_odd,
    _perimeter,
    _point_segment,
    _proper,
    _ring_area,
    _ring_inside,
    _tolerance,
    as_polygon,
)
from .sweep import _CHUNK

__all__ = ["REL_TOL", "Polygon2D", "as_polygon", "auto_method", "clip_polygon",
           "clip_ring_halfplane", "is_convex", "sutherland_hodgman", "weiler_atherton"]

#: named by the module's public path (users' logging settings name it)
_log = logging.getLogger("clraster.clip2d")

FloatArray = npt.NDArray[np.float64]

Method = Literal["auto", "sutherland-hodgman", "weiler-atherton"]


# ---------------------------------------------------------------------------------------------
# Vectorised primitives (pairs of edge sets)
# ---------------------------------------------------------------------------------------------

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
