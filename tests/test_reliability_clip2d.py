"""Reliability: polygon validation and polygon windows at 10⁵–10⁶ vertices
(clraster.clip.polygon, clraster.clip.sweep, clraster.clip.window).

Before, `as_polygon` tested every pair of edges (O(n²): 10⁴ vertices took 9 s, 4·10⁴ did not
finish in 2 minutes), `window_mask` built an (image rows × edges) table and the window's
convex hull was a Python loop over its vertices. Now validation takes its candidate pairs
of edges from sweeps over a segment tree plus a grid of edge ends (`sweep._candidate_pairs`,
O(n log n)) and the same exact pair predicates decide; the mask goes crossing by crossing in
bounded steps; the hull is a gift wrap that stops past the clip planes there is room for.

* Agreement: `as_polygon` raises exactly what the all-pairs check raised (same message) on
  families of random and adversarial rings and holes, with the sweep forced (the all-pairs
  shortcut for small polygons, `polygon._ALL_PAIRS`, off) and not. The old check is kept here
  verbatim as the reference (``_old_*``).
* Completeness: every pair of edges within the tolerance is a candidate, on random segment
  soups built to hit the sweep's cases (collinear, touching, near-misses at ±tol, needles).
* Scale: 10⁵-vertex polygons validate, and a single crossing or misplaced hole is found and
  named; the exact predicate sees O(n) pairs, not n².
* Windows: the mask and the hull are those of the old code; one validation serves a frame's
  mask and culling planes; a render through a 10⁵-vertex window (and, marked slow, a
  10⁶-vertex one at 640×480) is the unwindowed frame restricted to the mask.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from conftest import get_renderer, load_shared_mesh

from clraster import Camera
from clraster.clip import polygon as polygon_module
from clraster.clip import sweep as sweep_module
from clraster.clip import window as window_module
from clraster.clip.polygon import (
    Polygon2D,
    _clean_ring,
    _dedupe_ring,
    _is_ring_like,
    _perimeter,
    _ring_area,
    _tolerance,
    as_polygon,
)

window_mask, window_planes_for = window_module.window_mask, window_module.window_planes_for
window_clip_planes = window_module.window_clip_planes
WINDOW_MAX_COORD = window_module.WINDOW_MAX_COORD
SUBPIXEL_BITS, SUBPIXEL_ONE = window_module.SUBPIXEL_BITS, window_module.SUBPIXEL_ONE

FloatArray = npt.NDArray[np.float64]

# ---------------------------------------------------------------------------------------------
# The old all-pairs validation (clip2d before the sweep), verbatim but for the names: the
# reference the new one must agree with.
# ---------------------------------------------------------------------------------------------

_OLD_CHUNK = 1 << 21


def _old_normalise(exterior: Any, holes: Any = ()) -> tuple[FloatArray, list[FloatArray]]:
    """polygon._normalise with the old checks."""
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
            _old_check_ring_simple(r, tol, what, spikes=False)
            raise ValueError(f"{what} has zero area (its vertices are collinear or coincide); "
                             "a polygon needs at least 3 non-collinear vertices")
    ext = ext if _ring_area(ext) > 0 else ext[::-1]
    hs = [h if _ring_area(h) < 0 else h[::-1] for h in hs]
    for k, r in enumerate([ext, *hs]):
        _old_check_ring_simple(r, tol, "polygon exterior" if k == 0 else f"hole {k - 1}")
    _old_check_holes(ext, hs, tol)
    return ext, hs


def _old_check_ring_simple(ring: FloatArray, tol: float, what: str, spikes: bool = True) -> None:
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
    for rows, touch in _old_pairwise(a0, a1, a0, a1, tol, _old_segments_touch):
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


def _old_check_holes(ext: FloatArray, holes: list[FloatArray], tol: float) -> None:
    rings = [ext, *holes]
    names = ["the exterior"] + [f"hole {k}" for k in range(len(holes))]
    ends = [(r, np.roll(r, -1, axis=0)) for r in rings]
    for i in range(len(rings)):
        for j in range(i + 1, len(rings)):
            for _, bad in _old_pairwise(*ends[i], *ends[j], tol, _old_segments_cross_or_overlap):
                if bad.any():
                    raise ValueError(f"{names[j]} crosses or overlaps {names[i]}; holes must lie "
                                     "inside the exterior and may touch it or each other only "
                                     "at points")
    for k, h in enumerate(holes):
        if not _old_ring_inside(h, *ends[0], tol):
            raise ValueError(f"hole {k} lies outside the exterior; holes must be inside it")
        for m in range(len(holes)):
            if m != k and _old_ring_inside(h, *ends[m + 1], tol):
                raise ValueError(f"hole {k} lies inside hole {m}; nested holes are not a polygon "
                                 "(pass the island as a separate polygon)")


def _old_ring_inside(ring: FloatArray, e0: FloatArray, e1: FloatArray, tol: float) -> bool:
    """Whether a ring that does not cross the edges e0→e1 lies inside them (even-odd)."""
    mids = 0.5 * (ring + np.roll(ring, -1, axis=0))
    for p in (ring, mids):
        dist, _ = _old_point_segment(p, e0, e1)
        off = dist.min(axis=1) > tol
        if off.any():
            return bool(_old_inside_even_odd(p[off][:1], e0, e1)[0])
    return False  # every vertex and midpoint on the other ring: the same ring, not inside


# ---------------------------------------------------------------------------------------------
# Vectorised primitives
# ---------------------------------------------------------------------------------------------


def _old_pairwise(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray, tol: float,
              fn: Any) -> Iterator[tuple[npt.NDArray[np.intp], Any]]:
    """Yield ``(rows, fn(a0[rows], a1[rows], b0, b1, tol))`` over row blocks of the a-edges."""
    step = max(1, _OLD_CHUNK // max(1, len(b0)))
    for s in range(0, len(a0), step):
        rows = np.arange(s, min(s + step, len(a0)))
        yield rows, fn(a0[rows], a1[rows], b0, b1, tol)


def _old_side_distances(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray
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


def _old_sign(d: FloatArray, tol: float) -> npt.NDArray[np.int8]:
    return (np.int8(1) * (d > tol) - np.int8(1) * (d < -tol)).astype(np.int8)


def _old_proper(db0: FloatArray, db1: FloatArray, da0: FloatArray, da1: FloatArray,
            tol: float) -> npt.NDArray[np.bool_]:
    # Both pairs of endpoints strictly (beyond tol) on opposite sides: the segments cross at a
    # point at least tol away from all four endpoints. Everything else is a vertex-on-edge or
    # collinear case, handled through the nodes.
    return ((_old_sign(db0, tol) * _old_sign(db1, tol) == -1)
            & (_old_sign(da0, tol) * _old_sign(da1, tol) == -1))


def _old_point_segment(p: FloatArray, s0: FloatArray, s1: FloatArray
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


def _old_segments_touch(a0: FloatArray, a1: FloatArray, b0: FloatArray, b1: FloatArray,
                    tol: float) -> npt.NDArray[np.bool_]:
    """(n, m): the segments cross or come within tol of each other."""
    db0, db1, da0, da1 = _old_side_distances(a0, a1, b0, b1)
    near = _old_proper(db0, db1, da0, da1, tol)
    near |= _old_point_segment(b0, a0, a1)[0].T <= tol
    near |= _old_point_segment(b1, a0, a1)[0].T <= tol
    near |= _old_point_segment(a0, b0, b1)[0] <= tol
    near |= _old_point_segment(a1, b0, b1)[0] <= tol
    return near


def _old_segments_cross_or_overlap(a0: FloatArray, a1: FloatArray, b0: FloatArray,
                                   b1: FloatArray,
                               tol: float) -> npt.NDArray[np.bool_]:
    """(n, m): the segments cross properly or overlap collinearly over more than tol."""
    db0, db1, da0, da1 = _old_side_distances(a0, a1, b0, b1)
    bad = _old_proper(db0, db1, da0, da1, tol)
    r = a1 - a0
    lr = np.hypot(r[:, 0], r[:, 1])[:, None]
    u = r / lr
    s0 = ((b0[None, :, :] - a0[:, None, :]) * u[:, None, :]).sum(axis=2)
    s1 = ((b1[None, :, :] - a0[:, None, :]) * u[:, None, :]).sum(axis=2)
    overlap = np.minimum(lr, np.maximum(s0, s1)) - np.maximum(0.0, np.minimum(s0, s1))
    bad |= (np.abs(db0) <= tol) & (np.abs(db1) <= tol) & (overlap > tol)
    return bad


def _old_inside_even_odd(p: FloatArray, e0: FloatArray, e1: FloatArray) -> npt.NDArray[np.bool_]:
    """(P,) even-odd test of points against the closed edge set e0→e1 (half-open in y)."""
    out = np.zeros(len(p), dtype=bool)
    if len(p) == 0 or len(e0) == 0:
        return out
    step = max(1, _OLD_CHUNK // len(e0))
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


def _old_snapped_edges(poly: Polygon2D) -> tuple[np.ndarray, np.ndarray]:
    """All directed edges of the polygon's rings as int64 (E, 2) start and end points in
    24.8 fixed point (rint(x · 256), as triangle vertices snap)."""
    a, b = [], []
    for ring in poly.rings:
        q = np.rint(ring * SUBPIXEL_ONE).astype(np.int64)
        a.append(q)
        b.append(np.roll(q, -1, axis=0))
    return np.concatenate(a), np.concatenate(b)


def _old_window_mask(window: Any, width: int, height: int) -> np.ndarray:
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
    a, b = _old_snapped_edges(poly)
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


def _old_hull(points: np.ndarray) -> np.ndarray:
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


# ---------------------------------------------------------------------------------------------
# Families of rings and polygons (deterministic)
# ---------------------------------------------------------------------------------------------

def _star(rng: np.random.Generator, n: int, r0: float = 1.0, r1: float = 3.0,
          c: tuple[float, float] = (0.0, 0.0)) -> FloatArray:
    """A star-shaped (so simple) ring: n vertices at increasing angles, radii in [r0, r1]."""
    ang = (np.arange(n) + rng.uniform(0.1, 0.9, n)) * (2 * np.pi / n)
    r = rng.uniform(r0, r1, n)
    return np.stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)], axis=1)


def _offset_normal(a: FloatArray, b: FloatArray) -> FloatArray:
    d = b - a
    return np.array([-d[1], d[0]]) / math.hypot(d[0], d[1])


_TOLS = (0.0, 0.3, 0.9, 1.1, 3.0, -0.5, -0.9, -1.1, -3.0)   # offsets in units of tol


def _random_points(rng):
    return rng.uniform(-5, 5, (int(rng.integers(4, 10)), 2)), []


def _grid_walk(rng):
    # small integer coordinates: collinear overlaps, repeated vertices, vertices on edges
    return rng.integers(0, 4, (int(rng.integers(4, 10)), 2)).astype(float), []


def _vertex_near_edge(rng):
    ext = _star(rng, int(rng.integers(5, 15)))
    n = len(ext)
    k = int(rng.integers(n))
    m = int((k + rng.integers(2, n - 1)) % n)
    a, b = ext[m], ext[(m + 1) % n]
    ext[k] = a + rng.uniform() * (b - a) + rng.choice(_TOLS) * _tolerance(ext) * \
        _offset_normal(a, b)
    return ext, []


def _vertex_on_vertex(rng):
    ext = _star(rng, int(rng.integers(6, 14)))
    n = len(ext)
    k = int(rng.integers(n))
    m = int((k + rng.integers(2, n - 1)) % n)
    step = rng.normal(size=2)
    ext[m] = ext[k] + rng.choice([0.0, 0.5, 0.9, 1.5, 5.0]) * _tolerance(ext) * step / \
        np.hypot(*step)
    return ext, []


def _spike(rng):
    ext = _star(rng, int(rng.integers(5, 12)))
    n = len(ext)
    k = int(rng.integers(n))
    a, b = ext[k], ext[(k + 1) % n]
    q = a + rng.choice([0.3, 0.7, 1.5, -0.5]) * (b - a) + \
        rng.choice([0.0, 0.5, 3.0]) * _tolerance(ext) * _offset_normal(a, b)
    return np.insert(ext, k + 1, [b, q] if rng.random() < 0.5 else [q], axis=0), []


def _collinear(rng):
    # rectilinear rings on a grid whose edges run along each other (a slot cut into a
    # square, a comb whose teeth touch or overlap)
    w = int(rng.integers(3, 7))
    x = float(rng.integers(1, w))
    depth = float(rng.choice([1, 2, w, w + 1]))
    gap = float(rng.choice([0, 0, 1]))
    ring = [(0, 0), (x, 0), (x, depth), (x + gap, depth), (x + gap, 0), (w + gap, 0),
            (w + gap, w), (0, w)]
    return np.array(ring, float), []


def _big_star(rng):
    # above the all-pairs size: the sweep runs even unforced
    ext = _star(rng, int(rng.integers(100, 160)))
    if rng.random() < 0.7:
        n = len(ext)
        k = int(rng.integers(n))
        ext[k] = ext[int(rng.integers(n))] * rng.uniform(0.2, 1.3)
    return ext, []


def _grid_holes(rng):
    ext = np.array([(0, 0), (6, 0), (6, 6), (0, 6)], float)
    holes = []
    for _ in range(int(rng.integers(1, 4))):
        x, y = rng.integers(-1, 6, 2)
        w, h = rng.integers(1, 4, 2)
        holes.append(np.array([(x, y), (x + w, y), (x + w, y + h), (x, y + h)], float))
    return ext, holes


def _touching_holes(rng):
    ext = _star(rng, int(rng.integers(6, 14)), 4, 6)
    holes: list[FloatArray] = []
    for _ in range(int(rng.integers(1, 4))):
        h = rng.uniform(-3, 3, 2) + rng.uniform(-1.5, 1.5, (3, 2))
        if rng.random() < 0.5:    # a vertex on the exterior or on the previous hole
            tgt = ext if (not holes or rng.random() < 0.5) else holes[-1]
            i = int(rng.integers(len(tgt)))
            h[0] = tgt[i] + rng.choice([0.0, 0.5, rng.uniform()]) * (tgt[(i + 1) % len(tgt)]
                                                                      - tgt[i])
        holes.append(h)
    return ext, holes


def _diamond_holes(rng):
    ext = np.array([(0, 0), (8, 0), (8, 8), (0, 8)], float)
    holes = []
    for _ in range(int(rng.integers(1, 6))):
        cx, cy = rng.integers(1, 8, 2)
        r = int(rng.integers(1, 3))
        holes.append(np.array([(cx, cy - r), (cx + r, cy), (cx, cy + r), (cx - r, cy)], float))
    return ext, holes


def _placed_holes(rng):
    # holes nested in holes, outside the exterior, touching it within ±tol, inscribed in it
    kind = int(rng.integers(4))
    if kind == 0:
        return _star(rng, 12, 9, 10), [_star(rng, 8, 5, 6), _star(rng, 6, 1, 2)]
    if kind == 1:
        h = _star(rng, 6, 1, 3)
        return _star(rng, 9, 5, 6), [h, h + rng.uniform(-9, 9, 2)]
    ext = np.array([(0, 0), (10, 0), (10, 10), (0, 10)], float)
    if kind == 2:
        d = rng.choice(_TOLS) * _tolerance(ext)
        return ext, [np.array([(d, 5), (5, 3), (5, 7)], float)]
    return ext, [np.array([(5, 0), (10, 5), (5, 10), (0, 5)], float) * rng.choice([1, 0.5])]


FAMILIES = {f.__name__.lstrip("_"): f for f in (
    _random_points, _grid_walk, _vertex_near_edge, _vertex_on_vertex, _spike, _collinear,
    _big_star, _grid_holes, _touching_holes, _diamond_holes, _placed_holes)}


def _outcome(fn, ext, holes) -> str:
    try:
        fn(ext, holes)
    except ValueError as exc:
        return str(exc)
    return "valid"


# ---------------------------------------------------------------------------------------------
# Agreement with the all-pairs check
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sweep", [True, False], ids=["sweep", "auto"])
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_validation_agrees_with_the_all_pairs_check(family, sweep, monkeypatch):
    """Same verdict and same message (ring, edges, holes named) as the old check, case by
    case; each family yields valid and invalid polygons."""
    if sweep:
        monkeypatch.setattr(polygon_module, "_ALL_PAIRS", 0)
    rng = np.random.default_rng(sorted(FAMILIES).index(family))
    verdicts = set()
    for case in range(90):
        ext, holes = FAMILIES[family](rng)
        old = _outcome(_old_normalise, ext, holes)
        new = _outcome(lambda e, h: as_polygon((e, h)), ext, holes)
        assert new == old, (family, case, ext.tolist(), [h.tolist() for h in holes])
        verdicts.add(old == "valid")
    assert len(verdicts) == 2 or family in ("random_points",), verdicts


def _segment_soup(rng: np.random.Generator, n: int) -> tuple[FloatArray, FloatArray]:
    """Segments meant to stress the candidate search: grid segments (collinear, touching,
    crossing, vertical, horizontal), random ones, and copies of ends / needles placed within
    a few tol of other segments' ends or interiors on either side."""
    kind = rng.integers(0, 3, n)
    a = np.where(kind[:, None] == 0, rng.integers(0, 6, (n, 2)), rng.uniform(0, 6, (n, 2)))
    b = np.where(kind[:, None] == 0, rng.integers(0, 6, (n, 2)), rng.uniform(0, 6, (n, 2)))
    b[kind == 2, 0] = a[kind == 2, 0] + rng.uniform(-1e-3, 1e-3, int((kind == 2).sum()))
    a, b = a.astype(float), b.astype(float)
    same = np.all(a == b, axis=1)
    b[same] += 1.0
    tol = _tolerance(a, b)
    for k in rng.choice(n, n // 3, replace=False):
        m = int(rng.integers(n))
        if k == m:
            continue
        t = rng.choice([0.0, 1.0, rng.uniform()])
        p = a[m] + t * (b[m] - a[m])
        d = rng.normal(size=2)
        p = p + rng.choice(_TOLS) * tol * d / np.hypot(*d)
        if rng.random() < 0.5:      # an end of k near segment m
            a[k] = p
        else:                       # a steep needle beside p, not reaching p.x
            side = rng.choice([-1.0, 1.0]) * rng.choice([0.5, 0.9, 1.5]) * tol
            a[k] = p + [side, -2.0]
            b[k] = p + [side + rng.choice([0.0, 0.2]) * tol, 2.0]
    same = np.all(a == b, axis=1)
    b[same] += 1.0
    return a, b


def test_every_pair_within_tol_is_a_candidate():
    """The sweeps and the grid of ends miss no pair of segments that the old predicate
    finds within tol (whatever the segments: crossing, collinear, touching, needles)."""
    rng = np.random.default_rng(7)
    for case in range(60):
        a, b = _segment_soup(rng, int(rng.integers(20, 90)))
        tol = _tolerance(a, b)
        touch = _old_segments_touch(a, b, a, b, tol)
        np.fill_diagonal(touch, False)
        want = set(zip(*np.nonzero(np.triu(touch)), strict=True))
        got: set[tuple[int, int]] = set()
        for i, j, _ in sweep_module._candidate_pairs(a, b, tol, sweep_module._Ladders(a, b)):
            got.update(zip(np.minimum(i, j).tolist(), np.maximum(i, j).tolist(), strict=True))
        missed = {(int(i), int(j)) for i, j in want} - got
        assert not missed, (case, sorted(missed)[:5], a.tolist(), b.tolist())


# ---------------------------------------------------------------------------------------------
# Scale
# ---------------------------------------------------------------------------------------------

def _wavy_ring(n: int, seed: int = 0, c: tuple[float, float] = (0.0, 0.0), r: float = 200.0
               ) -> FloatArray:
    """A star-shaped (so simple) counter-clockwise ring of n vertices: a wavy circle."""
    rng = np.random.default_rng(seed)
    ang = (np.arange(n) + rng.uniform(0.1, 0.9, n)) * (2 * np.pi / n)
    rad = r * (1 + 0.15 * np.sin(7 * ang) + 0.04 * np.sin(61 * ang + 1) + 1e-3 * np.sin(
        997 * ang))
    return np.stack([c[0] + rad * np.cos(ang), c[1] + rad * np.sin(ang)], axis=1)


def _edge(ring: FloatArray, k: int) -> tuple[FloatArray, FloatArray]:
    return ring[k:k + 1], ring[(k + 1) % len(ring):(k + 1) % len(ring) + 1]


def test_a_1e5_vertex_ring_validates_and_a_crossing_in_it_is_named():
    n = 100_000
    ring = _wavy_ring(n)
    p = as_polygon(ring)
    np.testing.assert_array_equal(p.exterior, ring)       # already counter-clockwise, open
    # one vertex pulled across the ring: two edges cross the far side
    bad = ring.copy()
    bad[n // 3] = 1.2 * ring[n // 3 + n // 2]
    with pytest.raises(ValueError, match="intersects itself") as err:
        as_polygon(bad)
    e1, e2 = map(int, re.search(r"edges (\d+) and (\d+) meet", str(err.value)).groups())
    assert e2 > e1 + 1 and {e1, e2} & {n // 3 - 1, n // 3}
    tol = _tolerance(bad)
    assert _old_segments_touch(*_edge(bad, e1), *_edge(bad, e2), tol)[0, 0]


def test_a_1e5_vertex_polygon_with_holes_is_checked_like_a_small_one():
    ext = _wavy_ring(100_000, r=200.0)
    hole = _wavy_ring(20_000, seed=1, r=40.0)[::-1]             # clockwise
    # a thin triangle hanging from an exterior vertex (touching it at that one point)
    apex = ext[30_000]
    side = np.array([-apex[1], apex[0]]) / np.hypot(*apex)
    touch = np.array([apex, 0.9 * apex + 2 * side, 0.9 * apex - 2 * side])
    p = as_polygon((ext, [hole, touch]))
    assert len(p.holes) == 2
    assert p.area == pytest.approx(_ring_area(ext) - abs(_ring_area(hole))
                                   - abs(_ring_area(touch)))
    with pytest.raises(ValueError, match="hole 0 crosses or overlaps the exterior"):
        as_polygon((ext, [hole + [170.0, 0.0]]))
    with pytest.raises(ValueError, match="hole 1 lies outside the exterior"):
        as_polygon((ext, [hole, hole + [1000.0, 0.0]]))
    with pytest.raises(ValueError, match="hole 1 lies inside hole 0"):
        as_polygon((ext, [hole, 0.3 * hole]))


def test_validation_tests_linearly_many_pairs(monkeypatch):
    """The candidate pairs (all that the exact predicates may see) are O(n), not the n²/2
    pairs of the old check."""
    produced = []
    real = sweep_module._candidate_pairs

    def counting(*args):
        for i, j, work in real(*args):
            produced.append(len(i))
            yield i, j, work

    # validation looks it up in polygon's namespace
    monkeypatch.setattr(polygon_module, "_candidate_pairs", counting)
    n = 20_000
    as_polygon(_wavy_ring(n))
    assert n <= sum(produced) <= 20 * n    # at least each edge with a neighbour


# ---------------------------------------------------------------------------------------------
# Windows
# ---------------------------------------------------------------------------------------------

def _window_star(rng, n, cx, cy, r0, r1, snap):
    ring = _star(rng, n, r0, r1, (cx, cy))
    return np.rint(ring * snap) / snap if snap else ring


def test_window_mask_is_the_old_table_s():
    """Crossing by crossing in bounded steps gives the old (rows × edges) table's mask, bit
    for bit, on random windows (off screen, on pixel centres and grid lines, with holes) and
    on a 10⁵-vertex one."""
    rng = np.random.default_rng(11)
    w, h = 97, 71
    for case in range(150):
        snap = (0, 256, 2, 1)[case % 4]
        win: Any = _window_star(rng, int(rng.integers(3, 40)), rng.uniform(-20, 120),
                                rng.uniform(-20, 90), rng.uniform(1, 10), rng.uniform(10, 80),
                                snap)
        if case % 5 == 0:
            c = win.mean(axis=0)
            win = (win, [c + 0.2 * (win[::3][::-1] - c)])
        try:
            want = _old_window_mask(win, w, h)
        except ValueError as exc:
            with pytest.raises(ValueError, match=re.escape(str(exc))):
                window_mask(win, w, h)
            continue
        np.testing.assert_array_equal(window_mask(win, w, h), want, err_msg=f"case {case}")
    big = _wavy_ring(100_000, c=(48.0, 36.0), r=30.0)
    np.testing.assert_array_equal(window_mask(big, w, h), _old_window_mask(big, w, h))


def test_hull_is_the_monotone_chain_s_and_gives_up_past_the_limit():
    rng = np.random.default_rng(12)
    for case in range(200):
        pts = rng.uniform(-50, 50, (int(rng.integers(3, 60)), 2))
        if case % 2:
            pts = np.rint(pts / 10) * 10      # collinear and repeated points
        if len(np.unique(pts, axis=0)) < 3 or abs(_ring_area(_old_hull(pts))) == 0:
            continue
        old = _old_hull(pts)
        for limit in (3, 4, 8, 64):
            new = window_module._hull(pts, limit)
            if len(old) > limit:
                assert new is None, (case, limit)
                continue
            assert new is not None and len(new) == len(old), (case, limit)
            start = int(np.nonzero((new == old[0]).all(axis=1))[0][0])
            np.testing.assert_array_equal(np.roll(new, -start, axis=0), old)
    circle = _wavy_ring(1_000_000)
    assert window_module._hull(circle, 8) is None


def test_a_window_is_validated_once_for_its_mask_and_planes(monkeypatch):
    """A frame asks for the window's mask and then its culling planes: one validation (10⁶
    vertices take seconds). An equal window (a copy) needs none; a window changed in place
    is validated again."""
    calls = []
    real = window_module.as_polygon

    def counting(w):
        calls.append(1)
        return real(w)

    monkeypatch.setattr(window_module, "as_polygon", counting)
    win = _wavy_ring(5000, c=(48.0, 36.0), r=30.0)
    cam = Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=20.0)
    m = window_mask(win, 96, 72)
    window_planes_for(win, cam, 96, 72, None)
    assert len(calls) == 1
    np.testing.assert_array_equal(window_mask(win.copy(), 96, 72), m)
    assert len(calls) == 1
    win[10] = win[2500]                         # now it crosses itself
    with pytest.raises(ValueError, match="intersects itself"):
        window_mask(win, 96, 72)
    with pytest.raises(ValueError, match="intersects itself"):
        window_clip_planes(win, np.eye(4), 96, 72, 8)


def _spot_view(w, h):
    mesh = load_shared_mesh("spot.ply")
    lo, hi = mesh.bounds()
    return mesh, Camera.framing(lo, hi, direction=(0.4, 0.3, 1.0), aspect=w / h)


def _check_render_through(n: int, w: int, h: int) -> None:
    r = get_renderer(w, h)
    mesh, cam = _spot_view(w, h)
    full = r.render(mesh, cam)
    # a wavy disc over the middle of the image, n vertices
    win = _wavy_ring(n, c=(0.5 * w, 0.5 * h), r=0.3 * min(w, h))
    f = r.render(mesh, cam, window=win)
    m = window_mask(win, w, h)
    assert 0 < (m & (full.triangle_id >= 0)).sum() < (full.triangle_id >= 0).sum()
    np.testing.assert_array_equal(f.triangle_id, np.where(m, full.triangle_id, -1))
    np.testing.assert_array_equal(f.depth, np.where(m, full.depth, np.float32(1.0)))


def test_render_through_a_1e5_vertex_window():
    _check_render_through(100_000, 96, 72)


@pytest.mark.slow
def test_render_through_a_1e6_vertex_window_at_640x480():
    _check_render_through(1_000_000, 640, 480)

