"""Object culling on the host: frustum planes, bounding-volume tests, draw lists.

Step 1 of the pipeline (DESIGN.md): instances and clusters are classified against the six
frustum planes of the view-projection matrix, and clusters that face away are removed with
their normal cones. The result is a :class:`DrawList` of (instance, cluster) pairs for the
renderer.

Frustum culling has two levels. Top: a BVH over the instances' world boxes; an instance
OUTSIDE is dropped with all its clusters, one INSIDE makes all its clusters INSIDE with no
further test, one INTERSECTING passes on the planes it still crosses (its plane mask).
Below, an intersecting instance's clusters are tested against those planes only, by one of
three equivalent-in-spirit, all-conservative paths chosen by mesh size:

* big meshes (> `DENSE_PAIRS` instance × cluster pairs): the mesh's cluster BVH (built once
  per mesh, object space), traversed for all of the mesh's intersecting instances at once
  with each instance's planes moved to object space;
* medium meshes: every cluster box against each instance's object-space planes (three
  matrix products, no traversal);
* small meshes (<= `FLAT_CLUSTERS` clusters, the many-instances case): every (instance,
  cluster) box precomputed once in world space (the exact box around the transformed
  cluster box) and tested against the world planes, all instances at once.

Frustum planes (Gribb & Hartmann, "Fast extraction of viewing frustum planes from the
world-view-projection matrix", 2001): with rows r0..r3 of VP, a point p is inside iff
−w <= x, y, z <= w for (x, y, z, w) = VP·[p, 1], i.e. iff the six planes
r3 + r0, r3 − r0, r3 + r1, r3 − r1, r3 + r2, r3 − r2 (left, right, bottom, top, near, far)
are all >= 0 at p. For an object transform M the same planes in object space are the rows
times M (plane·(M·p) = (plane·M)·p), so no bounding volume is ever transformed: boxes and
spheres are tested where they were computed, which stays exact under any affine M
(non-uniform scale included).

Margins. The renderer evaluates those inequalities in float32. A plane row's value at p is a
sum of products whose magnitude is at most ``scale · [|p|, 1]`` with ``scale = |r3| + |ri|``
(elementwise; in object space ``(|r3| + |ri|) @ |M|``, which also covers evaluating
``VP @ (M @ p)`` in two steps); its float32 rounding error is a small multiple of 2**−24
times that. INSIDE therefore requires every plane value to be >= ``inside_margin`` (default
1e-5, ~170× float32's unit roundoff) times that magnitude over the whole volume, and
OUTSIDE requires some plane value to stay below −``outside_margin`` times it: what the
culler calls INSIDE passes every clip test in float32 too, and what it removes fails one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .bvh import (
    ALL_PLANES,
    BVH,
    DEFAULT_MARGIN,
    INSIDE,
    INTERSECTING,
    OUTSIDE,
    Visibility,
    _box_extremes,
    _check_boxes,
    _check_mask,
    _check_planes,
    _decide,
    _ranges,
    _sort_keys,
    _sphere_extremes,
    box_magnitudes,
    dense_row_states,
)
from .clusters import ClusteredMesh, clusters_of, cone_kernel, cone_table
from .config import CULL_MODES
from .mesh import Mesh
from .scene import Scene

__all__ = [
    "COUNT_NAMES", "DEFAULT_CONE_MARGIN", "DEFAULT_MARGIN", "PLANE_NAMES", "DrawList",
    "Visibility", "build_draw_list",
    "classify_aabbs", "classify_spheres", "eye_from_view_proj", "frustum_plane_scales",
    "frustum_planes", "view_proj_flips",
]

#: Cone-culling margin in radians: a culled cluster's triangles are all seen at least this
#: far from edge-on (in world space).
DEFAULT_CONE_MARGIN = 1e-3

PLANE_NAMES = ("left", "right", "bottom", "top", "near", "far")


# -- matrices and planes ----------------------------------------------------------------

def _check_vp(view_proj: npt.ArrayLike) -> np.ndarray:
    try:
        vp = np.array(view_proj, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"view_proj must be a 4×4 real matrix; could not convert "
                         f"{type(view_proj).__name__} ({exc})") from exc
    if vp.shape != (4, 4):
        raise ValueError(f"view_proj must have shape (4, 4), got shape {vp.shape}")
    if not np.all(np.isfinite(vp)):
        raise ValueError("view_proj contains NaN or Inf")
    return vp


def _raw_planes(vp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalized Gribb–Hartmann rows (6, 4) and their magnitude rows (6, 4)."""
    r = vp
    a = np.abs(vp)
    raw = np.stack([r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[3] + r[2],
                    r[3] - r[2]])
    mag = np.stack([a[3] + a[0], a[3] + a[0], a[3] + a[1], a[3] + a[1], a[3] + a[2],
                    a[3] + a[2]])
    return raw, mag


def _normalize(raw: np.ndarray, mag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Divide plane rows (..., 6, 4) and their scales by the normal length. A plane with a
    zero normal (e.g. an infinitely far plane: constant sign everywhere) is divided by
    |d| instead, so its value is ±1 (or 0 if it is identically zero)."""
    n = np.linalg.norm(raw[..., :3], axis=-1)
    n = np.where(n > 0.0, n, np.abs(raw[..., 3]))
    n = np.where(n > 0.0, n, 1.0)[..., None]
    return raw / n, mag / n


def frustum_planes(view_proj: npt.ArrayLike) -> np.ndarray:
    """The six frustum planes of an OpenGL-style view-projection matrix.

    Args:
        view_proj: (4, 4) world → clip for column vectors; a point p is inside iff
            −w <= x, y, z <= w for (x, y, z, w) = view_proj @ [p, 1].

    Returns:
        float64 (6, 4): rows (a, b, c, d) for left, right, bottom, top, near, far, each
        scaled so that (a, b, c) is a unit vector and ``a·x + b·y + c·z + d`` is the signed
        distance of (x, y, z) to the plane, >= 0 inside. A plane whose normal is zero (an
        infinitely distant far plane) is scaled to ``(0, 0, 0, ±1)``.
    """
    planes, _ = _normalize(*_raw_planes(_check_vp(view_proj)))
    return planes


def frustum_plane_scales(view_proj: npt.ArrayLike,
                         transform: npt.ArrayLike | None = None) -> np.ndarray:
    """Margin scales (6, 4) of the planes of ``view_proj @ transform``.

    Row k bounds the magnitude of the float32 terms of plane k: its value at p is off by a
    small multiple of 2**−24 · ``scales[k] · [|x|, |y|, |z|, 1]`` at most (see the module
    docstring). Scaled like `frustum_planes` of ``view_proj @ transform``.
    """
    vp = _check_vp(view_proj)
    raw, mag = _raw_planes(vp)
    if transform is not None:
        m = _check_vp(transform)
        raw, mag = raw @ m, mag @ np.abs(m)
    return _normalize(raw, mag)[1]


def _cofactor_eye(vp: np.ndarray) -> np.ndarray:
    """c with c·q = det([x; y; w; q]) for the x, y, w rows of vp: their null vector."""
    p3 = vp[[0, 1, 3]]
    c = np.empty(4)
    for j in range(4):
        cols = [k for k in range(4) if k != j]
        c[j] = (-1.0) ** (3 + j) * np.linalg.det(p3[:, cols])
    return c


def _eye_and_flip(vp: np.ndarray) -> tuple[np.ndarray, bool]:
    c = _cofactor_eye(vp)
    scale = float(np.prod(np.linalg.norm(vp[[0, 1, 3]], axis=1)))
    if not np.linalg.norm(c) > 1e-12 * scale:
        raise ValueError("view_proj has linearly dependent x, y and w rows: it has no eye "
                         "point or viewing direction (a degenerate projection)")
    if abs(c[3]) > 1e-12 * np.linalg.norm(c):
        return np.append(c[:3] / c[3], 1.0), bool(c[3] > 0.0)
    d = c[:3] / np.linalg.norm(c[:3])
    return np.append(d, 0.0), bool(np.dot(vp[2, :3], d) < 0.0)


def eye_from_view_proj(view_proj: npt.ArrayLike) -> np.ndarray:
    """The homogeneous eye of a view-projection matrix, float64 (4,).

    The eye is the null vector of the x, y and w rows of VP (every point on a line through
    it projects to the same pixel). Perspective: ``(ex, ey, ez, 1)``, the eye point.
    Orthographic (w row constant): ``(dx, dy, dz, 0)`` with d the unit viewing direction,
    signed so that a face with normal n is clockwise in NDC (culled by cull="back") iff
    ``dot(n, d) > 0``.

    For a perspective eye e, a face with normal n through point p is clockwise in NDC iff
    ``dot(n, p − e) > 0`` — unless the projection mirrors (`view_proj_flips`), which swaps
    the two. (Derivation: det([x; y; w] of the three clip vertices) = −c_w·dot(n, e − p)
    where c = the cofactor vector of the x, y, w rows and e = c[:3] / c_w; its sign is the
    NDC orientation when all w > 0, and c_w < 0 for an unmirrored camera.)

    Raises:
        ValueError: not a finite (4, 4) matrix, or its x, y, w rows are linearly dependent.
    """
    return _eye_and_flip(_check_vp(view_proj))[0]


def view_proj_flips(view_proj: npt.ArrayLike) -> bool:
    """Whether the projection mirrors the image: faces that point towards the eye come out
    clockwise in NDC. Perspective: the cofactor c_w = det of the x, y, w rows' 3×3 part is
    > 0 (it is < 0 for look_at + perspective). Orthographic: the viewing direction points
    towards decreasing depth. Cone culling is disabled for such projections.

    Raises:
        ValueError: as `eye_from_view_proj`.
    """
    return _eye_and_flip(_check_vp(view_proj))[1]


# -- single-level classification --------------------------------------------------------

def classify_spheres(planes: npt.ArrayLike, centers: npt.ArrayLike, radii: npt.ArrayLike,
                     mask: npt.ArrayLike | None = None, *, scales: npt.ArrayLike | None = None,
                     inside_margin: float = DEFAULT_MARGIN,
                     outside_margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Classify K spheres against 6 planes.

    Args:
        planes: (6, 4) plane rows, >= 0 inside (e.g. `frustum_planes`).
        centers: (K, 3); radii: (K,) >= 0.
        mask: uint8 scalar or (K,): bit k set = test plane k (default all 63); a clear bit
            means the sphere is already known to be inside plane k.
        scales: (6, 4) margin scales (default ``abs(planes)``; `frustum_plane_scales` gives
            the renderer's float32 scales).
        inside_margin, outside_margin: relative margins (see the module docstring). With
            both 0 the test is exact: INSIDE iff the closed sphere is inside every tested
            plane, OUTSIDE iff it is strictly outside one.

    Returns:
        (state uint8 (K,) of `Visibility` values, mask uint8 (K,)): the input mask with the
        bits of the planes the sphere is inside (by the margin) cleared. A sphere is OUTSIDE
        if it is outside some tested plane, INSIDE if no bit remains, else INTERSECTING.
        NaN inputs are INTERSECTING.
    """
    p, s = _check_planes(planes, scales, batch=False)
    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(radii, dtype=np.float64).reshape(-1)
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"radii must have shape ({c.shape[0]},) to match centers, got "
                         f"{np.shape(radii)}")
    if np.any(r < 0):
        raise ValueError("radii must be >= 0")
    m = _check_mask(mask, c.shape[0])
    with np.errstate(invalid="ignore", over="ignore"):
        return _decide(*_sphere_extremes(p, s, c, r), m, inside_margin, outside_margin)


def classify_aabbs(planes: npt.ArrayLike, mins: npt.ArrayLike, maxs: npt.ArrayLike,
                   mask: npt.ArrayLike | None = None, *, scales: npt.ArrayLike | None = None,
                   mags: npt.ArrayLike | None = None, inside_margin: float = DEFAULT_MARGIN,
                   outside_margin: float = DEFAULT_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """Classify K axis-aligned boxes against 6 planes (n-vertex / p-vertex test).

    Same arguments and results as `classify_spheres`, with boxes ``[mins[k], maxs[k]]``
    (K, 3) and optional margin magnitudes `mags` (K, 3) (default ``max(|mins|, |maxs|)``).
    Infinite bounds are clipped to ±1e300 (so an infinite box is never culled).
    """
    p, s = _check_planes(planes, scales, batch=False)
    lo, hi = _check_boxes(mins, maxs)
    lo = np.clip(lo, -1e300, 1e300)
    hi = np.clip(hi, -1e300, 1e300)
    mag = box_magnitudes(lo, hi) if mags is None else np.asarray(mags, np.float64)
    m = _check_mask(mask, lo.shape[0])
    with np.errstate(invalid="ignore", over="ignore"):
        return _decide(*_box_extremes(p, s, lo.T, hi.T, mag.T), m, inside_margin,
                       outside_margin)


# -- draw lists -------------------------------------------------------------------------

COUNT_NAMES = (
    "instances_total", "instances_frustum_culled", "instances_empty",
    "clusters_total", "clusters_frustum_culled", "clusters_cone_culled", "clusters_drawn",
    "triangles_total", "triangles_frustum_culled", "triangles_cone_culled", "triangles_drawn",
)


@dataclass
class DrawList:
    """The clusters to draw for one view, in draw order.

    Pairs are sorted by instance (scene order), then cluster index: the order never depends
    on what was culled, so depth ties resolve the same way with culling on or off.

    Attributes:
        instance: int32 (D,): instance index in the scene.
        cluster: int32 (D,): cluster index in that instance's `ClusteredMesh`
            (`clusters_of(mesh, max_triangles, max_vertices)`).
        inside: bool (D,): the cluster is INSIDE the frustum by the margin: for the matrix
            ``VP @ transform`` of its instance, every vertex of every triangle satisfies
            −w < x, y, z < w (so w > 0) with room for float32 rounding — per-triangle
            frustum tests and clipping (trivial reject, near/far, guard band) may be skipped
            for it. False means "may cross a plane" (and always with frustum=False).
        counts: the partition of the scene into culled and drawn parts:
            instances_total (= scene.n_instances), instances_empty (no face: skipped),
            instances_frustum_culled (whole instance OUTSIDE at the top level);
            clusters_total (over non-empty instances) = clusters_frustum_culled
            + clusters_cone_culled + clusters_drawn; the same for triangles_*
            (triangles_total = scene.n_faces), counted exactly by cluster sizes.
        timings_ms: host time per step: "prepare" (clusterizing / BVH builds done by this
            call; 0 when cached), "instances", "clusters", "cones", "order", "total".
        cone_culled: int32 (P, 2) (instance, cluster) pairs removed by the normal-cone test,
            in no particular order, when asked for (``keep_cone_culled=True``); else None.
            The frustum-culled pairs are the rest: neither drawn nor cone-culled.
    """

    instance: np.ndarray
    cluster: np.ndarray
    inside: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)
    cone_culled: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.instance.size)


class _MeshCull:
    """Per-mesh culling data (built once per mesh and cluster limits)."""

    __slots__ = ("cm", "bvh", "bvh_ids", "unbounded", "tri_count", "cones", "can_cone")

    def __init__(self, cm: ClusteredMesh) -> None:
        self.cm = cm
        bounded = cm.bounded
        ids = np.flatnonzero(bounded)
        self.bvh_ids = ids.astype(np.int32)
        self.unbounded = np.flatnonzero(~bounded).astype(np.int32)
        self.bvh = BVH.build(cm.aabb_min[ids].astype(np.float64),
                             cm.aabb_max[ids].astype(np.float64), leaf_size=CLUSTER_LEAF_SIZE)
        self.tri_count = np.diff(cm.tri_offset).astype(np.int64)
        self.cones = cone_table(cm.cone_apex.astype(np.float64),
                                cm.cone_axis.astype(np.float64),
                                cm.cone_cutoff.astype(np.float64), cm.sphere.astype(np.float64))
        self.can_cone = bool((cm.cone_cutoff <= 1.0).any())


class _SceneCull:
    """Per-scene culling data (rebuilt when the scene changes)."""

    def __init__(self, scene: Scene, meshes: list[_MeshCull]) -> None:
        n = scene.n_instances
        self.n = n
        self.meshes = meshes  # per instance
        self.nonempty = ~scene.empty
        self.bounded = scene.bounded
        t = scene.transforms()
        self.m = t
        self.minv = np.linalg.inv(t) if n else np.zeros((0, 4, 4))
        self.abs_m = np.abs(t)
        lin = t[:, :3, :3]
        self.det_neg = np.linalg.det(lin) < 0.0 if n else np.zeros(0, bool)
        sv = np.linalg.svd(lin, compute_uv=False) if n else np.zeros((0, 3))
        self.cond = sv[:, 0] / sv[:, -1] if n else np.zeros(0)
        n_clusters = np.array([mc.cm.n_clusters for mc in meshes], np.int64)
        self.n_clusters = np.where(self.nonempty, n_clusters, 0)
        self.cluster_base = np.cumsum(self.n_clusters) - self.n_clusters
        self.clusters_total = int(self.n_clusters.sum())
        self.tri_total = int(scene.n_faces)
        # Top level: world boxes of bounded instances; margin magnitudes before the object
        # transform, |M| @ [max |object coordinate|, 1], bound what float32 sees.
        ids = np.flatnonzero(self.bounded)
        self.inst_ids = ids
        self.unbounded_ids = np.flatnonzero(self.nonempty & ~self.bounded)
        lo_w, hi_w = scene.world_aabbs()
        lo_o, hi_o = scene.object_aabbs()
        obj_mag = np.append(box_magnitudes(lo_o[ids], hi_o[ids]), np.ones((ids.size, 1)), 1)
        mags = np.einsum("ijk,ik->ij", self.abs_m[ids], obj_mag)[:, :3]
        self.inst_bvh = BVH.build(lo_w[ids], hi_w[ids], mags=mags)
        # Unique meshes: cluster tables concatenated (global cluster g = mesh_base + c).
        uniq: dict[int, int] = {}
        for mc in meshes:
            uniq.setdefault(id(mc), len(uniq))
        umesh = list({id(mc): mc for mc in meshes}.values())
        self.inst_umesh = np.array([uniq[id(mc)] for mc in meshes], np.int64)
        sizes = np.array([mc.cm.n_clusters for mc in umesh], np.int64)
        self.mesh_base = np.cumsum(sizes) - sizes
        self.g_tri = np.concatenate([mc.tri_count for mc in umesh]) if umesh \
            else np.zeros(0, np.int64)
        self.g_cones = np.concatenate([mc.cones for mc in umesh], axis=1) if umesh \
            else np.zeros((9, 0))
        self.g_can_cone = self.g_cones[7] < 1.0
        # Flat path: bounded instances of small meshes, every (instance, cluster) pair with
        # its cluster box moved to world space (centre M·c, half-extent |M|·e: the exact box
        # around the transformed box), tested against the world planes all at once.
        flat = self.bounded & (self.n_clusters <= FLAT_CLUSTERS)
        if int(self.n_clusters[flat].sum()) > FLAT_MAX_PAIRS:
            flat[:] = False
        self.flat_ids = np.flatnonzero(flat)
        fc = self.n_clusters[self.flat_ids]
        self.flat_start = np.cumsum(fc) - fc
        self.flat_count = fc
        pi = np.repeat(self.flat_ids, fc)
        pc = _ranges(self.flat_start, fc) - np.repeat(self.flat_start, fc)
        self.flat_inst = pi.astype(np.int32)
        self.flat_cl = pc.astype(np.int32)
        self.flat_g = (self.mesh_base[self.inst_umesh[pi]] + pc).astype(np.int32)
        self.flat_boxes = np.empty((9, pi.size))
        lo_c = np.concatenate([mc.cm.aabb_min for mc in umesh]).astype(np.float64) if umesh \
            else np.zeros((0, 3))
        hi_c = np.concatenate([mc.cm.aabb_max for mc in umesh]).astype(np.float64) if umesh \
            else np.zeros((0, 3))
        for p0 in range(0, pi.size, 1 << 16):  # bounded temporaries
            sl = slice(p0, p0 + (1 << 16))
            g, lin, am = self.flat_g[sl], self.m[pi[sl]], self.abs_m[pi[sl]]
            centre = (lo_c[g] + hi_c[g]) * 0.5
            half = (hi_c[g] - lo_c[g]) * 0.5
            cw = np.einsum("pij,pj->pi", lin[:, :3, :3], centre) + lin[:, :3, 3]
            hw = np.einsum("pij,pj->pi", am[:, :3, :3], half)
            magw = np.einsum("pij,pj->pi", am[:, :3, :3], box_magnitudes(lo_c[g], hi_c[g])) \
                + am[:, :3, 3]
            self.flat_boxes[:, sl] = np.vstack([(cw - hw).T, (cw + hw).T, magw.T])
        # Other instances (big meshes, NaN/Inf vertices) are grouped by mesh, in scene order,
        # and go through their mesh's object-space cluster BVH.
        groups: dict[int, list[int]] = {}
        for i in np.flatnonzero(self.nonempty & ~flat).tolist():
            groups.setdefault(id(meshes[i]), []).append(i)
        self.groups = [(meshes[v[0]], np.array(v, np.int64)) for v in groups.values()]


def _prepare(scene: Scene, max_triangles: int, max_vertices: int) -> _SceneCull:
    def mesh_data(mesh: Mesh) -> _MeshCull:
        return scene.mesh_memo(mesh, ("cull", max_triangles, max_vertices),
                               lambda: _MeshCull(clusters_of(mesh, max_triangles,
                                                             max_vertices)))

    return scene.memo(("cull", max_triangles, max_vertices),
                      lambda: _SceneCull(scene, [mesh_data(i.mesh) for i in scene.instances]))


#: Clusters per leaf of a mesh's cluster BVH.
CLUSTER_LEAF_SIZE = 32
#: Instances of meshes with at most this many clusters take the flat path: their
#: (instance, cluster) boxes are precomputed in world space and tested all at once.
FLAT_CLUSTERS = 64
#: ... unless the scene has more such pairs than this (84 bytes each, kept with the scene).
FLAT_MAX_PAIRS = 1 << 21
#: Meshes with at most this many (bounded) clusters are tested densely, every cluster
#: against every intersecting instance's planes (three matrix products), not through
#: their BVH: for small meshes with many instances that is several times faster.
DENSE_CLUSTERS = 64
#: ... and so are meshes whose (instances × clusters) grid is at most this large.
DENSE_PAIRS = 16384
_DENSE_CHUNK = 1 << 18  # (instance, cluster) pairs per dense batch


def _cluster_frustum(bvh: BVH, planes: np.ndarray, scales: np.ndarray, masks: np.ndarray,
                     inside_margin: float, outside_margin: float):
    """(query, item, state) of the non-OUTSIDE (instance, cluster) pairs, sorted."""
    if bvh.n_items > DENSE_CLUSTERS and planes.shape[0] * bvh.n_items > DENSE_PAIRS:
        q, item, st, _ = bvh.cull_batch(planes, scales, masks, inside_margin=inside_margin,
                                        outside_margin=outside_margin)
        return q, item, st
    out_q, out_i, out_s = [], [], []
    step = max(1, _DENSE_CHUNK // max(bvh.n_items, 1))
    for q0 in range(0, planes.shape[0], step):
        sl = slice(q0, q0 + step)
        st, _ = dense_row_states(planes[sl], scales[sl], masks[sl], bvh.dense_rows,
                                 inside_margin=inside_margin, outside_margin=outside_margin)
        q, item = np.nonzero(st != OUTSIDE)
        out_q.append(q + q0)
        out_i.append(item)
        out_s.append(st[q, item])
    return np.concatenate(out_q), np.concatenate(out_i), np.concatenate(out_s)


def _flat_frustum(prep: _SceneCull, inst_state: np.ndarray, inst_mask: np.ndarray,
                  planes: np.ndarray | None, scales: np.ndarray | None,
                  inside_margin: float, outside_margin: float):
    """Frustum test of the flat-path pairs: (inst, cluster, inside, triangles, global
    cluster) of those not culled, in (instance, cluster) order."""
    ids = prep.flat_ids
    st = inst_state[ids]
    keep_inst = st != OUTSIDE
    if planes is None:  # frustum off: every pair, none marked inside
        pos = _ranges(prep.flat_start[keep_inst], prep.flat_count[keep_inst])
        ins = np.zeros(pos.size, bool)
    else:
        test = st == INTERSECTING
        pos_in = _ranges(prep.flat_start[st == INSIDE], prep.flat_count[st == INSIDE])
        pos_t = _ranges(prep.flat_start[test], prep.flat_count[test])
        if pos_t.size:
            box = np.take(prep.flat_boxes, pos_t, axis=1)
            mask = np.repeat(inst_mask[ids[test]], prep.flat_count[test])
            cst, _ = _decide(*_box_extremes(planes, scales, box[0:3], box[3:6], box[6:9]),
                             mask, inside_margin, outside_margin)
            alive = cst != OUTSIDE
            pos_t, cst = pos_t[alive], cst[alive]
        else:
            cst = np.zeros(0, np.uint8)
        pos = np.concatenate([pos_in, pos_t])
        ins = np.concatenate([np.ones(pos_in.size, bool), cst == INSIDE])
        if pos_in.size and pos_t.size:  # merge the two sorted runs
            order = _sort_keys(pos, prep.flat_inst.size)
            pos, ins = pos[order], ins[order]
    g = prep.flat_g[pos]
    return (prep.flat_inst[pos].astype(np.int64), prep.flat_cl[pos].astype(np.int64), ins,
            prep.g_tri[g], g)


def _cone_cull(mc: _MeshCull, inst: np.ndarray, cl: np.ndarray, visible: np.ndarray,
               eye_obj: np.ndarray, side: np.ndarray, sin_m: np.ndarray,
               ortho: bool) -> np.ndarray:
    """Cone test of the pairs (inst, cl) of one mesh's instances; bool (P,).

    Evaluated densely over (visible instance, every cluster) when the pairs cover at least
    a third of that grid (contiguous arithmetic, no gathers), else per pair."""
    n_c = mc.cm.n_clusters
    if 3 * cl.size >= visible.size * n_c and visible.size * n_c <= (1 << 22):
        e = eye_obj[visible].T[:, :, None]  # (3, Q, 1)
        dense = cone_kernel(mc.cones[:, None, :], e, side[visible][:, None],
                            sin_m[visible][:, None], ortho)  # (Q, C)
        row = np.searchsorted(visible, inst)
        return dense[row, cl]
    table = np.take(mc.cones, cl, axis=1)
    return cone_kernel(table, eye_obj[inst].T, side[inst], sin_m[inst], ortho)


def build_draw_list(scene: Scene, view_proj: npt.ArrayLike, *, frustum: bool = True,
                    cones: bool = True, cull: str = "back", max_triangles: int = 128,
                    max_vertices: int = 128, inside_margin: float = DEFAULT_MARGIN,
                    outside_margin: float = DEFAULT_MARGIN,
                    cone_margin: float = DEFAULT_CONE_MARGIN,
                    keep_cone_culled: bool = False) -> DrawList:
    """The (instance, cluster) pairs of `scene` to draw for one view.

    Args:
        scene: the scene; its clusters (`clusters_of`) and BVHs are built on first use and
            cached (per mesh, and per scene version).
        view_proj: (4, 4) world → clip matrix (OpenGL conventions, see `frustum_planes`).
        frustum: cull instances and clusters outside the view frustum (top-level BVH over
            instance world boxes, then each intersecting instance's clusters against the
            planes it still crosses; see the module docstring).
        cones: cull clusters that face away, with their normal cones (only when `cull` is
            "back" or "front", and never for a mirroring projection). The test is
            conservative: a culled cluster's non-degenerate triangles are all seen from
            their culled side, at least `cone_margin` radians from edge-on (measured in
            world space: the object-space margin is widened by the condition number of
            the instance's transform). Instances with a mirroring transform (negative
            determinant) are tested for the opposite side, as their winding flips.
        cull: the renderer's face culling mode: "back", "front" or "none".
        max_triangles, max_vertices: cluster limits (see `clusterize`).
        inside_margin, outside_margin: relative frustum margins (module docstring).
        cone_margin: radians, >= 0.
        keep_cone_culled: also return the cone-culled pairs (``DrawList.cone_culled``).

    Returns:
        A `DrawList`.

    Raises:
        ValueError: bad matrix, cull mode or margins.
    """
    t_start = time.perf_counter()
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a clraster.scene.Scene, got {type(scene).__name__}; "
                         f"wrap a mesh with Scene.from_mesh(mesh)")
    vp = _check_vp(view_proj)
    if cull not in CULL_MODES:
        raise ValueError(f"cull must be one of {sorted(CULL_MODES)}, got {cull!r}")
    for name, v in (("inside_margin", inside_margin), ("outside_margin", outside_margin),
                    ("cone_margin", cone_margin)):
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    if cone_margin >= math.pi / 2:
        raise ValueError(f"cone_margin must be < pi/2 radians, got {cone_margin!r}")

    prep = _prepare(scene, max_triangles, max_vertices)
    t_prep = time.perf_counter()
    timings = {"prepare": (t_prep - t_start) * 1e3}

    # Top level: instances.
    inst_state = np.full(prep.n, OUTSIDE, np.uint8)
    inst_mask = np.zeros(prep.n, np.uint8)
    raw, rmag = _raw_planes(vp)
    planes, scales = _normalize(raw, rmag)
    if frustum:
        items, st, mk = prep.inst_bvh.cull(planes, scales, inside_margin=inside_margin,
                                           outside_margin=outside_margin, return_mask=True)
        ids = prep.inst_ids[items]
        inst_state[ids] = st
        inst_mask[ids] = mk
        inst_state[prep.unbounded_ids] = INTERSECTING
        inst_mask[prep.unbounded_ids] = ALL_PLANES
    else:
        inst_state[prep.nonempty] = INTERSECTING  # mask 0: no plane tests below
    t_inst = time.perf_counter()
    timings["instances"] = (t_inst - t_prep) * 1e3

    # Cone set-up: eye in each instance's object space, side and margin per instance.
    use_cones = cones and cull != "none"
    eye_obj = side = sin_m = np.zeros(0)
    ortho = False
    if use_cones:
        try:
            eye, flips = _eye_and_flip(vp)
        except ValueError:
            use_cones = False
        else:
            use_cones = not flips
    if use_cones:
        # Object-space eye (I, 3): a point (perspective: M is affine, so w stays 1) or a unit
        # direction (orthographic). Side: mirroring transforms swap front and back.
        ortho = eye[3] == 0.0
        eye_obj = (prep.minv @ eye)[:, :3]
        if ortho:
            eye_obj /= np.linalg.norm(eye_obj, axis=1)[:, None]
        side = np.where(prep.det_neg ^ (cull == "front"), -1.0, 1.0)
        # An angle margin m in world space needs sin(m)·cond(M) in object space: for unit
        # n, u, sin of the world angle = dot(n, u) / (|M^-T n|·|M u|) >= sin_obj / cond.
        sin_m = np.minimum(1.0, math.sin(cone_margin) * prep.cond)
        use_cones = bool((sin_m < 1.0).any())

    out_inst, out_cl, out_in = [], [], []
    tri_frustum = 0
    clusters_after_frustum = 0
    n_cone_cl = 0
    n_cone_tri = 0
    cone_pairs: list[tuple[np.ndarray, np.ndarray]] = []  # with keep_cone_culled
    t_clusters = 0.0
    t_cones = 0.0
    t0 = time.perf_counter()
    if prep.flat_ids.size:
        inst, cl, ins, tri, g = _flat_frustum(prep, inst_state, inst_mask, planes if frustum
                                              else None, scales if frustum else None,
                                              inside_margin, outside_margin)
        clusters_after_frustum += cl.size
        tri_frustum += int(tri.sum())
        t1 = time.perf_counter()
        t_clusters += t1 - t0
        if use_cones and cl.size:
            sel = np.flatnonzero(prep.g_can_cone[g])
            if sel.size:
                ip = inst[sel]
                table = np.take(prep.g_cones, g[sel], axis=1)
                back_sel = cone_kernel(table, np.take(eye_obj, ip, axis=0).T, side[ip],
                                       sin_m[ip], ortho)
                if back_sel.any():
                    back = np.zeros(cl.size, bool)
                    back[sel[back_sel]] = True
                    n_cone_cl += int(back_sel.sum())
                    n_cone_tri += int(tri[back].sum())
                    if keep_cone_culled:
                        cone_pairs.append((inst[back], cl[back]))
                    keep = ~back
                    inst, cl, ins = inst[keep], cl[keep], ins[keep]
            t_cones += time.perf_counter() - t1
        out_inst.append(inst)
        out_cl.append(cl)
        out_in.append(ins)
    in_order = True  # the flat path emits pairs in (instance, cluster) order; groups do not

    for mc, members in prep.groups:
        t0 = time.perf_counter()
        st = inst_state[members]
        vis = st != OUTSIDE
        if not vis.any():
            continue
        c_count = mc.cm.n_clusters
        inside_i = members[st == INSIDE]
        inter_i = members[st == INTERSECTING]
        pi_list, pc_list, pin_list = [], [], []
        if inside_i.size:  # every cluster of an INSIDE instance is INSIDE: no tests
            pi_list.append(np.repeat(inside_i, c_count))
            pc_list.append(np.tile(np.arange(c_count, dtype=np.int64), inside_i.size))
            pin_list.append(np.ones(inside_i.size * c_count, bool))
        if inter_i.size:
            qmask = inst_mask[inter_i]
            tested = inter_i[qmask != 0]
            untested = inter_i[qmask == 0]  # frustum off (or nothing left to test)
            if untested.size:
                pi_list.append(np.repeat(untested, c_count))
                pc_list.append(np.tile(np.arange(c_count, dtype=np.int64), untested.size))
                pin_list.append(np.zeros(untested.size * c_count, bool))
            if tested.size:
                m = prep.m[tested]
                oraw = np.einsum("kj,qjl->qkl", raw, m)
                omag = np.einsum("kj,qjl->qkl", rmag, prep.abs_m[tested])
                oplanes, oscales = _normalize(oraw, omag)
                q, item, cst = _cluster_frustum(mc.bvh, oplanes, oscales, inst_mask[tested],
                                                inside_margin, outside_margin)
                pi_list.append(tested[q])
                pc_list.append(mc.bvh_ids[item].astype(np.int64))
                pin_list.append(cst == INSIDE)
                if mc.unbounded.size:  # clusters with NaN/Inf vertices: never culled
                    pi_list.append(np.repeat(tested, mc.unbounded.size))
                    pc_list.append(np.tile(mc.unbounded.astype(np.int64), tested.size))
                    pin_list.append(np.zeros(tested.size * mc.unbounded.size, bool))
        in_order = False
        inst = np.concatenate(pi_list)
        cl = np.concatenate(pc_list)
        ins = np.concatenate(pin_list)
        tri = mc.tri_count[cl]
        clusters_after_frustum += cl.size
        tri_frustum += int(tri.sum())
        t1 = time.perf_counter()
        t_clusters += t1 - t0
        if use_cones and mc.can_cone and cl.size:
            back = _cone_cull(mc, inst, cl, members[vis], eye_obj, side, sin_m, ortho)
            if back.any():
                keep = ~back
                n_cone_cl += int(back.sum())
                n_cone_tri += int(tri[back].sum())
                if keep_cone_culled:
                    cone_pairs.append((inst[back], cl[back]))
                inst, cl, ins = inst[keep], cl[keep], ins[keep]
            t_cones += time.perf_counter() - t1
        out_inst.append(inst)
        out_cl.append(cl)
        out_in.append(ins)

    t_order = time.perf_counter()
    if len(out_inst) == 1 and in_order:  # only flat-path pairs: already in draw order
        inst, cl, ins = out_inst[0], out_cl[0], out_in[0]
    elif out_inst:
        inst = np.concatenate(out_inst)
        cl = np.concatenate(out_cl)
        ins = np.concatenate(out_in)
        order = _sort_keys(prep.cluster_base[inst] + cl, prep.clusters_total)
        inst, cl, ins = inst[order], cl[order], ins[order]
    else:
        inst = cl = np.zeros(0, np.int64)
        ins = np.zeros(0, bool)
    t_end = time.perf_counter()
    timings.update(clusters=t_clusters * 1e3, cones=t_cones * 1e3,
                   order=(t_end - t_order) * 1e3, total=(t_end - t_start) * 1e3)

    n_empty = int((~prep.nonempty).sum())
    counts = {
        "instances_total": prep.n,
        "instances_frustum_culled": int(((inst_state == OUTSIDE) & prep.nonempty).sum()),
        "instances_empty": n_empty,
        "clusters_total": prep.clusters_total,
        "clusters_frustum_culled": prep.clusters_total - clusters_after_frustum,
        "clusters_cone_culled": n_cone_cl,
        "clusters_drawn": int(cl.size),
        "triangles_total": prep.tri_total,
        "triangles_frustum_culled": prep.tri_total - tri_frustum,
        "triangles_cone_culled": n_cone_tri,
        "triangles_drawn": tri_frustum - n_cone_tri,
    }
    cone_culled = None
    if keep_cone_culled:
        cone_culled = np.zeros((0, 2), np.int32) if not cone_pairs else np.stack(
            [np.concatenate([a for a, _ in cone_pairs]),
             np.concatenate([b for _, b in cone_pairs])], axis=1).astype(np.int32)
    return DrawList(instance=inst.astype(np.int32), cluster=cl.astype(np.int32),
                    inside=ins.astype(bool), counts=counts, timings_ms=timings,
                    cone_culled=cone_culled)

