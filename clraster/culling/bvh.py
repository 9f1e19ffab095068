"""A bounding volume hierarchy over axis-aligned boxes, culled against planes (the frustum's
and user clip planes).

:class:`BVH` is a binary tree stored in flat arrays and built level by level with NumPy:
every node splits its items at the median of their box centroids along the axis where the
centroids spread most (so the tree is balanced: depth ``ceil(log2(K / leaf_size))``). Cost
O(K log K): the items are sorted once per axis, and each level partitions those orders
stably in O(K).

Culling is a level-synchronous traversal with plane masks: every (query, node) pair of the
frontier is classified against the planes still set in its P-bit mask (bit k = "plane k is
still crossed higher up: test it here"); a node inside plane k clears bit k for its whole
subtree, a node outside any plane is dropped with its subtree, a node inside every plane
makes all its items INSIDE without further tests, and a leaf that is still intersecting
tests its items one by one. P is the number of plane rows, at most `MAX_PLANES` = 14: the 6
frustum planes (masks 0..63, as `ALL_PLANES`) and up to 8 user clip planes appended after
them (bits 6..13; :mod:`clraster.culling.cull` passes them so that a node wholly on a user plane's
removed side is culled in the same traversal). The traversal returns uint16 masks; inside,
and from `check_mask` and the classifiers, a mask has the narrowest dtype for P planes
(uint8 up to 8: the frustum's 6 cost what they always did).

Plane classification (also used by :mod:`clraster.culling.frustum` and
:mod:`clraster.culling.cull`): a plane is a row (a, b, c, d) whose value
``a·x + b·y + c·z + d`` is >= 0 inside. With a relative margin μ and a per-plane *scale* row
s >= 0 (the magnitude of the terms the renderer adds up in float32 when it evaluates that
plane; see :func:`clraster.culling.frustum.frustum_plane_scales`), a volume with coordinate
magnitudes <= m (per axis) is

* inside plane k iff ``min over the volume of plane_k >= μ_in · (s_k[:3]·m + s_k[3])``,
* outside plane k iff ``max over the volume of plane_k < −μ_out · (s_k[:3]·m + s_k[3])``,

so both answers hold with room to spare for float32 rounding in clip space. μ_in and μ_out
are one float for every plane, or one per plane (float64 (P,)): user clip planes are
evaluated in float64 by the vertex stage and take a much smaller margin than the frustum's
(`clraster.culling.cull.CLIP_PLANE_MARGIN`), with scale rows ``|plane|``. Boxes use the
n-vertex / p-vertex (the corner that minimizes / maximizes the plane), spheres centre ± r·|n|.
NaN bounds compare false both ways: they are never culled and never INSIDE.

Public API beyond the tree, for the frustum and draw-list code: the classification
primitives (`box_extremes`, `sphere_extremes`, `classify_extremes`, `dense_rows`,
`dense_row_states`, `box_magnitudes`, and `plane_table` / `box_extremes_table` for one
plane set per box), the argument checks they share (`check_planes`,
`check_mask`; boxes: `clraster.base.checks.check_boxes`) and two index helpers
(`concat_ranges`, `argsort_distinct`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, ClassVar, cast

import numpy as np
import numpy.typing as npt

from ..base.checks import check_boxes

__all__ = [
    "ALL_PLANES", "BVH", "DEFAULT_MARGIN", "INSIDE", "INTERSECTING", "MAX_PLANES", "OUTSIDE",
    "Visibility",
    "argsort_distinct", "box_extremes", "box_extremes_table", "box_magnitudes", "check_mask",
    "check_planes", "classify_extremes", "classify_one", "concat_ranges", "dense_row_states",
    "dense_rows",
    "plane_table", "sphere_extremes",
]


class Visibility(IntEnum):
    """Classification of a bounding volume against the frustum."""

    INSIDE = 0  #: inside every plane (by the inside margin): clip tests may be skipped
    INTERSECTING = 1  #: neither: may cross a plane
    OUTSIDE = 2  #: outside some plane (by the outside margin): cannot touch the frustum


#: The `Visibility` values as plain ints, for comparisons with uint8 state arrays.
INSIDE, INTERSECTING, OUTSIDE = 0, 1, 2
#: Default relative margin for INSIDE and OUTSIDE (see the module docstring and
#: :mod:`clraster.culling.frustum`): 1e-5 of the float32 term magnitude, about 170× float32's unit
#: roundoff and >10× the error of evaluating a plane through an object and a view matrix.
DEFAULT_MARGIN = 1e-5
#: Mask with all 6 frustum plane bits set (test every frustum plane).
ALL_PLANES = np.uint8(63)
#: Most plane rows one classification or traversal takes: the 6 frustum planes and up to 8
#: user clip planes (`clraster.base.layout.USER_PLANES_MAX`); masks are then uint16.
MAX_PLANES = 14


def _mask_dtype(k: int) -> type[np.unsignedinteger]:
    """The narrowest mask dtype for k planes: uint8 up to 8 (the frustum's 6), else uint16."""
    return np.uint8 if k <= 8 else np.uint16


def _mask_table(k: int) -> np.ndarray:
    """bool (k, 2**k), read-only: [j, m] = bit j of mask m is set. Cached per k: a gather
    from it is the fastest way to expand masks into per-plane flags (2**14 columns at most,
    229 KB)."""
    t = _MASK_TABLES.get(k)
    if t is None:
        t = (np.arange(1 << k, dtype=np.int64)[None, :] >> np.arange(k)[:, None]) & 1 != 0
        t.flags.writeable = False
        _MASK_TABLES[k] = t
    return t


def _weights(k: int) -> np.ndarray:
    """Plane bit weights for k planes, (k,) in `_mask_dtype(k)`."""
    w = _WEIGHTS.get(k)
    if w is None:
        w = (1 << np.arange(k)).astype(_mask_dtype(k))
        w.flags.writeable = False
        _WEIGHTS[k] = w
    return w


_MASK_TABLES: dict[int, np.ndarray] = {}
_WEIGHTS: dict[int, np.ndarray] = {}
_mask_table(6)  # the frustum's: built at import, as the 6-plane table always was
_weights(6)


def _per_plane(margin: float | npt.ArrayLike, k: int, ndim: int) -> float | np.ndarray:
    """A margin as a float, or a per-plane float64 (k,) array shaped (k, 1, ...) to
    broadcast against plane-major (k, *S) arrays of `ndim` dimensions."""
    if isinstance(margin, (float, int)):
        return margin
    m = np.asarray(margin, np.float64)
    if m.ndim == 0:
        return float(m)
    if m.shape != (k,):
        raise ValueError(f"per-plane margins must have shape ({k},), got {m.shape}")
    return m.reshape((k,) + (1,) * (ndim - 1))


# -- plane classification primitives ----------------------------------------------------
#
# Plane-major layout: the per-plane values of F volumes are (P, F) arrays, so the reductions
# over the planes run along the first axis (row operations, fast in NumPy; a reduction
# along a length-P last axis is not).


def classify_extremes(dmin: np.ndarray, dmax: np.ndarray, mterm: np.ndarray,
                      mask: np.ndarray, inside_margin: float | np.ndarray,
                      outside_margin: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States and reduced masks from the plane values' extremes over each volume.

    dmin, dmax, mterm: float64 (P, *S) plane-major, P <= `MAX_PLANES` (min and max of each
    plane over each volume, and its margin term: `box_extremes` / `sphere_extremes`); mask:
    unsigned plane masks < 2**P (bit k = test plane k; uint8 for the 6 frustum planes,
    uint16 with user planes) broadcastable to S; inside_margin, outside_margin: floats, or
    float64 (P,) one per plane. Returns (state uint8, mask) of shape S (broadcast with the
    mask's; the mask keeps the input's dtype, widened to uint16 if P > 8): state is a
    `Visibility` value (OUTSIDE if some tested plane has ``dmax < −outside_margin ·
    mterm``), and the mask loses the bits of the planes with ``dmin >= inside_margin ·
    mterm``; INSIDE iff no bit remains. NaN compares false both ways, so NaN volumes stay
    INTERSECTING.
    """
    k = dmin.shape[0]
    active = np.take(_mask_table(k), mask, axis=1)  # (P, *mask.shape)
    out = dmax < mterm * -_per_plane(outside_margin, k, dmax.ndim)
    out &= active
    outside = out.any(axis=0)
    inside = dmin >= mterm * _per_plane(inside_margin, k, dmin.ndim)
    inside &= active
    weights = _weights(k).reshape((k,) + (1,) * (inside.ndim - 1))
    inside_bits = (inside.view(np.uint8) * weights).sum(axis=0, dtype=weights.dtype)
    # inside ⊆ active, so XOR clears exactly those bits; unlike `mask & ~bits` it cannot
    # clear high bits of a uint16 mask through a uint8 complement
    new_mask = mask ^ inside_bits
    state = (new_mask != 0).view(np.uint8)  # INTERSECTING (1) or INSIDE (0)
    state[outside] = OUTSIDE
    return state, new_mask


def classify_one(dmin: np.ndarray, dmax: np.ndarray, mterm: np.ndarray, mask: int,
                 inside_margin: float | np.ndarray, outside_margin: float | np.ndarray
                 ) -> tuple[int, int]:
    """`classify_extremes` of a single volume, in plain Python floats: dmin, dmax, mterm
    float64 (P, 1) (`box_extremes` of one box), ``mask`` an int < 2**P; margins as there.
    Returns (state, new mask) as ints. The same float64 products and comparisons per plane
    (a Python float is an IEEE double), so the same answers, NaN included; NumPy's
    per-call overhead was most of the time of one box (~27 µs against ~3)."""
    k = dmin.shape[0]
    lo, hi, m = dmin[:, 0].tolist(), dmax[:, 0].tolist(), mterm[:, 0].tolist()
    mi, mo = ([float(u)] * k if isinstance(u, (float, int))
              else np.broadcast_to(np.asarray(u, np.float64), (k,)).tolist()
              for u in (inside_margin, outside_margin))
    outside = False
    bits = 0
    for j in range(k):
        if (mask >> j) & 1:
            outside |= hi[j] < m[j] * -mo[j]
            if lo[j] >= m[j] * mi[j]:
                bits |= 1 << j
    new_mask = mask ^ bits
    return (OUTSIDE if outside else INTERSECTING if new_mask else INSIDE), new_mask


def plane_table(planes: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(11P, Q) per-query rows for `box_extremes_table`, for planes and scales (Q, P, 4):
    n⁺ (3×P, axis-major), n⁻ (3×P), d (P), scale xyz (3×P), scale w (P)."""
    n = np.moveaxis(planes[..., :3], -1, 0)  # (3, Q, P) → rows j, columns (q, k)
    q = planes.shape[0]

    def rows(a: np.ndarray) -> np.ndarray:  # (..., Q, P) → (... · P, Q)
        return np.moveaxis(a, -2, -1).reshape(-1, q)

    return np.concatenate([rows(np.maximum(n, 0.0)), rows(np.minimum(n, 0.0)),
                           rows(planes[..., 3]), rows(np.moveaxis(scales[..., :3], -1, 0)),
                           rows(scales[..., 3])], axis=0)


def box_extremes(planes: np.ndarray, scales: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 mag: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Min and max of each plane over each box, and the margin term: float64 (P, F) each.

    planes, scales: float64 (P, 4) shared by all boxes. lo, hi, mag: float64 (3, F)
    coordinate-major (box corners and per-axis margin magnitudes). Feed the result to
    `classify_extremes`.
    """
    n = planes[:, :3]
    npos = np.maximum(n, 0.0)
    nneg = np.minimum(n, 0.0)
    d = planes[:, 3:4]
    dmin = npos @ lo + nneg @ hi + d
    dmax = npos @ hi + nneg @ lo + d
    mterm = scales[:, :3] @ mag + scales[:, 3:4]
    return dmin, dmax, mterm


def box_extremes_table(table: np.ndarray, lo: np.ndarray, hi: np.ndarray, mag: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`box_extremes` with one plane set per box: table (11K, F) from `plane_table`
    (gathered per box), lo, hi, mag (3, F)."""
    f = lo.shape[1]
    k = table.shape[0] // 11
    npos = table[0:3 * k].reshape(3, k, f)
    nneg = table[3 * k:6 * k].reshape(3, k, f)
    d = table[6 * k:7 * k]
    s3 = table[7 * k:10 * k].reshape(3, k, f)
    lo3, hi3, mag3 = lo[:, None, :], hi[:, None, :], mag[:, None, :]
    dmin = d + (npos * lo3).sum(axis=0) + (nneg * hi3).sum(axis=0)
    dmax = d + (npos * hi3).sum(axis=0) + (nneg * lo3).sum(axis=0)
    mterm = table[10 * k:11 * k] + (s3 * mag3).sum(axis=0)
    return dmin, dmax, mterm


def sphere_extremes(planes: np.ndarray, scales: np.ndarray, centers: np.ndarray,
                    radii: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Like `box_extremes` for spheres (centre ± r·|n|): planes, scales float64 (P, 4),
    centers float64 (K, 3), radii float64 (K,); float64 (P, K) results. The margin
    magnitude of a sphere is ``|centre| + r`` per axis."""
    n = planes[:, :3]
    dist = n @ centers.T + planes[:, 3:4]
    reach = np.linalg.norm(n, axis=1)[:, None] * radii[None, :]
    mag = (np.abs(centers) + radii[:, None]).T
    mterm = scales[:, :3] @ mag + scales[:, 3:4]
    return dist - reach, dist + reach, mterm


def dense_rows(lo: np.ndarray, hi: np.ndarray, mag: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The right-hand sides of `dense_row_states`' products for boxes lo, hi, mag (K, 3):
    float64 (7, K) [lo; hi; 1], (7, K) [hi; lo; 1] and (4, K) [mag; 1]. They depend on the
    boxes only, so a BVH keeps them (`BVH.dense_rows`)."""
    one = np.ones((1, lo.shape[0]))
    return (np.vstack([lo.T, hi.T, one]), np.vstack([hi.T, lo.T, one]),
            np.vstack([mag.T, one]))


def dense_row_states(planes: np.ndarray, scales: np.ndarray, masks: np.ndarray,
                     rows: tuple[np.ndarray, np.ndarray, np.ndarray], *,
                     inside_margin: float | np.ndarray, outside_margin: float | np.ndarray):
    """Classify every box against every plane set: states uint8 and masks (the masks'
    dtype, see `classify_extremes`), (Q, N) each.

    planes, scales: (Q, P, 4), P <= `MAX_PLANES` planes per set; masks: (Q,) unsigned,
    < 2**P; rows: the N boxes' `dense_rows`; margins: floats or float64 (P,). Three
    matrix products of (PQ, 7) by (7, N) (plane value at the n-vertex, at the p-vertex,
    margin term), so it pays for small N and many plane sets, where a per-(query, node)
    traversal would gather planes for every pair.
    """
    lohi, hilo, mag1 = rows
    n_q, n_p, n_k = planes.shape[0], planes.shape[1], lohi.shape[1]
    n = planes[..., :3]
    w = np.concatenate([np.maximum(n, 0.0), np.minimum(n, 0.0), planes[..., 3:]], axis=-1)
    w = np.ascontiguousarray(np.swapaxes(w, 0, 1)).reshape(n_p * n_q, 7)  # rows (k, q)
    sc = np.ascontiguousarray(np.swapaxes(scales, 0, 1)).reshape(n_p * n_q, 4)
    shape = (n_p, n_q, n_k)
    dmin = (w @ lohi).reshape(shape)
    dmax = (w @ hilo).reshape(shape)
    mterm = (sc @ mag1).reshape(shape)
    return classify_extremes(dmin, dmax, mterm, masks[:, None], inside_margin, outside_margin)


def check_planes(planes: npt.ArrayLike, scales: npt.ArrayLike | None,
                 batch: bool, max_planes: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Validated (planes, scales), float64 (P, 4), or (Q, P, 4) when `batch`; scales
    default to ``abs(planes)``. P is 6 (the frustum planes) unless `max_planes` (<=
    `MAX_PLANES`) allows 1..max_planes rows (the frustum's 6 and user clip planes after
    them). Raises ValueError on a wrong shape."""
    p = np.asarray(planes, dtype=np.float64)
    ndim = 3 if batch else 2
    if max_planes == 6:
        ok = p.ndim == ndim and p.shape[-2:] == (6, 4)
        shape = "(Q, 6, 4)" if batch else "(6, 4)"
        rows = "left, right, bottom, top, near, far rows a, b, c, d"
    else:
        ok = p.ndim == ndim and p.shape[-1] == 4 and 1 <= p.shape[-2] <= max_planes
        shape = (f"(Q, P, 4), 1 <= P <= {max_planes}" if batch
                 else f"(P, 4), 1 <= P <= {max_planes}")
        rows = "rows a, b, c, d: the 6 frustum planes, then any user clip planes"
    if not ok:
        raise ValueError(f"planes must have shape {shape} ({rows}), got shape {p.shape}")
    if scales is None:
        s = np.abs(p)
    else:
        s = np.asarray(scales, dtype=np.float64)
        if s.shape != p.shape:
            raise ValueError(f"scales must have the planes' shape {p.shape}, got {s.shape}")
    return p, s


def check_mask(mask: npt.ArrayLike | None, n: int, n_planes: int = 6) -> np.ndarray:
    """Plane masks for `n_planes` planes (P, default the frustum's 6) as (n,) uint8 when
    P <= 8, else uint16: None → all P bits (63 for 6); a scalar is broadcast. Raises
    ValueError unless it is an integer scalar or (n,) array with values in 0..2**P − 1."""
    top = (1 << n_planes) - 1
    dt = _mask_dtype(n_planes)
    if mask is None:
        return np.full(n, top, dt)
    m = np.asarray(mask)
    if m.ndim == 0:
        m = np.full(n, m)
    if m.shape != (n,) or m.dtype.kind not in "iu" or (m.size and (m.min() < 0
                                                                    or m.max() > top)):
        raise ValueError(f"mask must be a scalar or ({n},) array of {n_planes}-bit plane "
                         f"masks in 0..{top}, got {m.dtype} {m.shape}")
    return m.astype(dt)



def box_magnitudes(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """float64 (K, 3): largest |coordinate| per axis over each box (its margin magnitude),
    for boxes lo, hi float64 (K, 3)."""
    return np.maximum(np.abs(lo), np.abs(hi))


# -- the tree ---------------------------------------------------------------------------

def concat_ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of arange(s, s + c) for each (s, c): int64 (counts.sum(),).

    starts, counts: integer (R,), counts >= 0. Used to expand node / instance runs into
    item positions without a Python loop."""
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offs = np.cumsum(counts) - counts
    return np.repeat(starts - offs, counts) + np.arange(total)


@dataclass(frozen=True)
class BVH:
    """A binary BVH over K axis-aligned boxes, in flat arrays (all read-only).

    Node 0 is the root (no nodes when K = 0). Node n covers the items
    ``order[first[n] : first[n] + count[n]]``; its children are ``left[n]`` and
    ``left[n] + 1``, or ``left[n] == −1`` for a leaf (<= leaf_size items). Nodes are stored
    level by level.

    Attributes:
        n_items: K.
        leaf_size: most items per leaf.
        order: int32 (K,): item indices in leaf order.
        node_min, node_max: float64 (N, 3): node boxes (union of their items' boxes).
        node_mag: float64 (N, 3): per-axis max of the items' margin magnitudes.
        first, count, left: int32 (N,).
        item_min, item_max, item_mag: float64 (K, 3), by item index.
    """

    n_items: int
    leaf_size: int
    order: np.ndarray
    node_min: np.ndarray
    node_max: np.ndarray
    node_mag: np.ndarray
    first: np.ndarray
    count: np.ndarray
    left: np.ndarray
    item_min: np.ndarray
    item_max: np.ndarray
    item_mag: np.ndarray
    if TYPE_CHECKING:   # set in __post_init__, not dataclass fields
        _nodes9: ClassVar[np.ndarray]
        _items9: ClassVar[np.ndarray]
        _dense_rows: ClassVar[tuple[np.ndarray, np.ndarray, np.ndarray] | None]

    def __post_init__(self) -> None:
        # Gather-friendly copies, coordinate-major (9, n): rows min xyz, max xyz, mag xyz;
        # nodes by index, items in leaf order (a leaf's items are one contiguous run).
        nodes = np.ascontiguousarray(np.hstack([self.node_min, self.node_max,
                                                self.node_mag]).T)
        items = np.ascontiguousarray(np.hstack([self.item_min, self.item_max,
                                                self.item_mag])[self.order].T)
        nodes.flags.writeable = False
        items.flags.writeable = False
        object.__setattr__(self, "_nodes9", nodes)
        object.__setattr__(self, "_items9", items)
        object.__setattr__(self, "_dense_rows", None)

    @property
    def dense_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`dense_rows` of the items (by item index), made on first use and kept."""
        if self._dense_rows is None:
            rows = dense_rows(self.item_min, self.item_max, self.item_mag)
            for r in rows:
                r.flags.writeable = False
            object.__setattr__(self, "_dense_rows", rows)
        return cast("tuple[np.ndarray, np.ndarray, np.ndarray]", self._dense_rows)

    @property
    def n_nodes(self) -> int:
        return int(self.first.size)

    @classmethod
    def build(cls, mins: npt.ArrayLike, maxs: npt.ArrayLike, leaf_size: int = 4,
              mags: npt.ArrayLike | None = None) -> BVH:
        """Build over the boxes ``[mins[k], maxs[k]]``.

        Args:
            mins, maxs: (K, 3) finite, ``mins <= maxs``; zero-size boxes are fine.
            leaf_size: most items per leaf, >= 1.
            mags: (K, 3) per-axis coordinate magnitudes used for the margins (default: the
                boxes' own, ``max(|min|, |max|)``); pass larger ones when the renderer's
                arithmetic sees larger numbers than the boxes' coordinates (e.g. instance
                boxes: magnitudes before the object → world transform).

        Raises:
            ValueError: wrong shapes, NaN/Inf, ``mins > maxs`` or a bad leaf_size.
        """
        lo, hi = check_boxes(mins, maxs)
        if isinstance(leaf_size, bool) or not isinstance(leaf_size, (int, np.integer)) \
                or leaf_size < 1:
            raise ValueError(f"leaf_size must be a positive integer, got {leaf_size!r}")
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise ValueError("BVH boxes must be finite; keep unbounded items out of the tree "
                             "and treat them as INTERSECTING")
        if np.any(lo > hi):
            k = int(np.flatnonzero((lo > hi).any(axis=1))[0])
            raise ValueError(f"box {k} has mins > maxs ({lo[k].tolist()} vs "
                             f"{hi[k].tolist()})")
        mag = box_magnitudes(lo, hi) if mags is None else np.asarray(mags, np.float64)
        if mag.shape != lo.shape:
            raise ValueError(f"mags must have shape {lo.shape}, got {mag.shape}")
        k_items = lo.shape[0]
        leaf_size = int(leaf_size)
        if k_items == 0:
            z = np.zeros((0, 3))
            e = np.zeros(0, np.int32)
            return _freeze(cls(0, leaf_size, e, z, z.copy(), z.copy(), e.copy(), e.copy(),
                               e.copy(), lo.copy(), hi.copy(), mag.copy()))

        cen = (lo + hi) * 0.5
        orders = np.ascontiguousarray(np.argsort(cen, axis=0, kind="stable").T)  # (3, K)
        axes = np.arange(3)[:, None]
        goes_left = np.zeros(k_items, dtype=bool)
        start = np.zeros(1, np.int64)
        cnt = np.array([k_items], np.int64)
        firsts, counts, lefts = [], [], []
        base = 0
        while True:
            split = cnt > leaf_size
            left = np.full(cnt.size, -1, np.int64)
            firsts.append(start)
            counts.append(cnt)
            lefts.append(left)
            if not split.any():
                break
            s_start, s_cnt = start[split], cnt[split]
            n_split = s_start.size
            last = s_start + s_cnt - 1
            extent = cen[orders[:, last], axes] - cen[orders[:, s_start], axes]  # (3, S)
            axis = np.argmax(extent, axis=0)
            half = s_cnt // 2
            mid = s_start + half
            # Items of the left halves (in the chosen axis' order) go left.
            pos = concat_ranges(s_start, half)
            goes_left[orders[np.repeat(axis, half), pos]] = True
            # Stable partition of every axis order within each split segment.
            all_pos = concat_ranges(s_start, s_cnt)
            seg = np.repeat(np.arange(n_split), s_cnt)
            seg_begin = np.cumsum(s_cnt) - s_cnt  # index in all_pos of each segment start
            for a in range(3):
                items = orders[a, all_pos]
                flag = goes_left[items]
                cl = np.cumsum(flag)
                cr = np.cumsum(~flag)
                rank_l = cl - 1 - (cl - flag)[seg_begin][seg]
                rank_r = cr - 1 - (cr - ~flag)[seg_begin][seg]
                new_pos = np.where(flag, s_start[seg] + rank_l, mid[seg] + rank_r)
                orders[a, new_pos] = items
            goes_left[orders[0, all_pos]] = False
            left[split] = base + cnt.size + 2 * np.arange(n_split)
            base += cnt.size
            start = np.stack([s_start, mid], axis=1).ravel()
            cnt = np.stack([half, s_cnt - half], axis=1).ravel()

        first = np.concatenate(firsts)
        count = np.concatenate(counts)
        left = np.concatenate(lefts)
        order = orders[0]
        n_nodes = first.size
        node_min = np.empty((n_nodes, 3))
        node_max = np.empty((n_nodes, 3))
        node_mag = np.empty((n_nodes, 3))
        leaves = np.flatnonzero(left < 0)
        leaves = leaves[np.argsort(first[leaves])]  # leaves partition 0..K-1
        starts = first[leaves]
        node_min[leaves] = np.minimum.reduceat(lo[order], starts, axis=0)
        node_max[leaves] = np.maximum.reduceat(hi[order], starts, axis=0)
        node_mag[leaves] = np.maximum.reduceat(mag[order], starts, axis=0)
        level_ends = np.cumsum([c.size for c in counts])
        for lv in range(len(counts) - 1, -1, -1):  # bottom-up: parents from children
            ids = np.arange(level_ends[lv] - counts[lv].size, level_ends[lv])
            ids = ids[left[ids] >= 0]
            if ids.size:
                c0, c1 = left[ids], left[ids] + 1
                node_min[ids] = np.minimum(node_min[c0], node_min[c1])
                node_max[ids] = np.maximum(node_max[c0], node_max[c1])
                node_mag[ids] = np.maximum(node_mag[c0], node_mag[c1])
        return _freeze(cls(k_items, leaf_size, order.astype(np.int32), node_min, node_max,
                           node_mag, first.astype(np.int32), count.astype(np.int32),
                           left.astype(np.int32), lo.copy(), hi.copy(), mag.copy()))

    # -- culling --------------------------------------------------------------------------

    def cull(self, planes: npt.ArrayLike, scales: npt.ArrayLike | None = None, *,
             mask: int | None = None, inside_margin: float | npt.ArrayLike = DEFAULT_MARGIN,
             outside_margin: float | npt.ArrayLike = DEFAULT_MARGIN, return_mask: bool = False):
        """Items not outside the planes, with their state.

        Args:
            planes: (P, 4) plane rows (>= 0 inside), 1 <= P <= `MAX_PLANES`: e.g. the 6 of
                `clraster.culling.frustum.frustum_planes`, then any user clip planes.
            scales: (P, 4) margin scales (default ``abs(planes)``).
            mask: planes to test (bit k = plane k), 0..2**P − 1 (default all P; 63 for the
                6 frustum planes).
            inside_margin, outside_margin: relative margins (see the module docstring): a
                float, or float64 (P,) one per plane.
            return_mask: also return each item's remaining plane mask (bits of the planes
                it may still cross; 0 for INSIDE items).

        Returns:
            (items int32 (D,), state uint8 (D,)) sorted by item index — OUTSIDE items are
            left out, the others are `Visibility.INSIDE` (every bit cleared) or
            `INTERSECTING` — and the masks uint16 (D,) if `return_mask`. Equal to
            classifying every item box on its own against the P planes (for the 6 frustum
            planes :func:`clraster.culling.frustum.classify_aabbs`; same margins), minus the
            OUTSIDE ones.
        """
        p, s = check_planes(planes, scales, batch=False, max_planes=MAX_PLANES)
        m = check_mask(mask, 1, p.shape[0])
        _, items, state, masks = self.cull_batch(p[None], s[None], m, inside_margin=inside_margin,
                                                 outside_margin=outside_margin)
        return (items, state, masks) if return_mask else (items, state)

    def cull_batch(self, planes: np.ndarray, scales: np.ndarray | None = None,
                   masks: npt.ArrayLike | None = None, *,
                   inside_margin: float | npt.ArrayLike = DEFAULT_MARGIN,
                   outside_margin: float | npt.ArrayLike = DEFAULT_MARGIN):
        """Cull the tree against Q plane sets at once (e.g. one per instance of a mesh).

        Args:
            planes, scales: (Q, P, 4) plane rows and margin scales, 1 <= P <=
                `MAX_PLANES` (the 6 frustum planes, then up to 8 user clip planes; scales
                default ``abs(planes)``).
            masks: (Q,) starting plane masks, integers in 0..2**P − 1 (default all P bits;
                63 for the 6 frustum planes). A query's node pairs are tested only against
                the planes still set in their masks.
            inside_margin, outside_margin: floats, or float64 (P,) one per plane.

        Returns:
            (query int32, item int32, state uint8, mask uint16), all (D,), sorted by
            (query, item); OUTSIDE pairs left out. A pair is INSIDE iff no bit of its mask
            remains (so with user planes appended, INSIDE means inside them too).
        """
        p, s = check_planes(planes, scales, batch=True, max_planes=MAX_PLANES)
        n_q, n_p = p.shape[0], p.shape[1]
        # the frontier keeps the narrowest mask dtype (uint8 for the frustum's 6 planes:
        # the common case stays as fast as before); the result is widened to uint16
        qmask = check_mask(masks, n_q, n_p)
        mu_in = _per_plane(inside_margin, n_p, 1)
        mu_out = _per_plane(outside_margin, n_p, 1)
        empty = (np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.uint8),
                 np.zeros(0, np.uint16))
        if self.n_items == 0 or n_q == 0:
            return empty
        single = n_q == 1
        table = None if single else plane_table(p, s)
        out_q, out_item, out_state, out_mask = [], [], [], []
        fq = np.arange(n_q)
        fn = np.zeros(n_q, np.int64)
        fm = qmask
        while fq.size:
            data = np.take(self._nodes9, fn, axis=1)
            lo, hi, mag = data[0:3], data[3:6], data[6:9]
            if single:
                ext = box_extremes(p[0], s[0], lo, hi, mag)
            else:
                ext = box_extremes_table(np.take(cast(np.ndarray, table), fq, axis=1), lo, hi,
                                         mag)
            state, nmask = classify_extremes(*ext, fm, mu_in, mu_out)
            inside = state == INSIDE
            if inside.any():  # every item of the node is inside: no further tests
                pos = concat_ranges(self.first[fn[inside]].astype(np.int64),
                              self.count[fn[inside]].astype(np.int64))
                n_each = self.count[fn[inside]]
                out_q.append(np.repeat(fq[inside], n_each))
                out_item.append(np.take(self.order, pos))
                out_state.append(np.zeros(pos.size, np.uint8))
                out_mask.append(np.zeros(pos.size, qmask.dtype))
            inter = state == INTERSECTING
            child = self.left[fn]
            leaf = inter & (child < 0)
            if leaf.any():  # test the leaf's items one by one, with the reduced mask
                n_each = self.count[fn[leaf]].astype(np.int64)
                pos = concat_ranges(self.first[fn[leaf]].astype(np.int64), n_each)
                items = np.take(self.order, pos)
                iq = np.repeat(fq[leaf], n_each)
                im = np.repeat(nmask[leaf], n_each)
                data = np.take(self._items9, pos, axis=1)
                lo_i, hi_i, mag_i = data[0:3], data[3:6], data[6:9]
                if single:
                    ext = box_extremes(p[0], s[0], lo_i, hi_i, mag_i)
                else:
                    ext = box_extremes_table(np.take(cast(np.ndarray, table), iq, axis=1),
                                             lo_i, hi_i, mag_i)
                ist, imask = classify_extremes(*ext, im, mu_in, mu_out)
                keep = ist != OUTSIDE
                out_q.append(iq[keep])
                out_item.append(items[keep])
                out_state.append(ist[keep])
                out_mask.append(imask[keep])
            go = inter & (child >= 0)
            fq = np.repeat(fq[go], 2)
            fn = np.stack([child[go], child[go] + 1], axis=1).ravel().astype(np.int64)
            fm = np.repeat(nmask[go], 2)
        if not out_q:
            return empty
        q = np.concatenate(out_q).astype(np.int64)
        item = np.concatenate(out_item).astype(np.int64)
        st = np.concatenate(out_state)
        mk = np.concatenate(out_mask)
        order = argsort_distinct(q * self.n_items + item, n_q * self.n_items)
        return (q[order].astype(np.int32), item[order].astype(np.int32), st[order],
                mk[order].astype(np.uint16))


def argsort_distinct(keys: np.ndarray, key_range: int) -> np.ndarray:
    """Permutation (int64 (N,)) sorting distinct non-negative int64 `keys` (N,) < key_range.

    Scatters into a dense bitmap when the range is small relative to the key count
    (O(range), no comparison sort), else arg-sorts.
    """
    if keys.size and key_range <= 16 * keys.size + 4096:
        slot = np.full(key_range, -1, np.int64)
        slot[keys] = np.arange(keys.size)
        out = slot[slot >= 0]
        return out
    return np.argsort(keys, kind="stable")


def _freeze(b: BVH) -> BVH:
    for value in vars(b).values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return b
