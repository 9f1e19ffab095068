"""Candidate pairs of edges for polygon validation (`clraster.clip.polygon`): a superset of
every pair of edges within ``tol`` of each other, found in O(n log n) for n edges in all (plus
the number of pairs found, which is O(n) for a valid polygon: each edge's neighbours and the
few it touches), instead of the n² pairs an all-pairs check looks at. The exact pair
predicates stay with the validation; this module only says which pairs they need to see.

Algorithm (`_candidate_pairs`):

* an x-sweep (`_Ladders`): a segment tree over the edges' end x-coordinates; each edge is
  stored at the O(log n) nodes whose slab it spans (sorted by y there, in blocks where edges
  cross or touch), and each edge is located, by bisection, in the nodes whose slab holds one
  of its ends. It yields every intersecting pair and every edge passing within 2·tol in y of
  an end at that end's x;
* a y-sweep (the same, x and y swapped, steep edges only) for edges steeper than 45° near an
  end, and a grid of cells 3·tol wide for ends near each other (`_grid_pairs`): an edge
  within tol of an end p that spans neither p.x nor p.y has an end within (1 + √2)·tol of p.

The same tree counts the crossings of a vertical ray up from a point in O(log n)
(`_Ladders.count_above`; `_above` is the direct test for a few edges), which is how
validation places holes. Pure NumPy, all work in bounded chunks (`_CHUNK`); imports nothing
of clraster.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

# Sweep ladders (`_Ladders`) of at most this many edges are scanned whole rather than searched.
_SCAN = 8
# Pairwise NumPy work (edges × edges, points × edges) goes in row blocks of at most this many
# entries, so memory stays bounded (~16 MB per float64 temporary) for large polygons.
_CHUNK = 1 << 21

#: Candidate pairs of edges in chunks: (edge ids, edge ids, how many pairs were looked at).
_PairChunks = Iterator[tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], int]]


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
