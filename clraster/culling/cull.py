"""Object culling on the host: the draw list of (instance, cluster) pairs for one view.

Step 1 of the pipeline (docs/ARCHITECTURE.md): instances and clusters are classified against the six
frustum planes of the view-projection matrix (:mod:`clraster.culling.frustum`: planes, margins,
eye), and clusters that face away are removed with their normal cones. The result is a
:class:`DrawList` of (instance, cluster) pairs for the renderer.

Frustum culling has two levels. Top: the instances' world boxes (every box on its own up to
`DENSE_INSTANCES` instances, above that through a BVH over them: the same answers); an
instance OUTSIDE is dropped with all its clusters, one INSIDE makes all its clusters INSIDE
with no further test, one INTERSECTING passes on the planes it still crosses (its plane
mask).
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

A scene of one instance (a bare Mesh, the usual frame) takes the same tests without the
bookkeeping of many: its flat tables as they are (`_flat_one`), or its group's clusters in
the order its BVH keeps, not sorted again; the lists are the same.

Planes move to object space as rows times the object transform and boxes are never
transformed (see :mod:`clraster.culling.frustum`), so every path stays exact under any affine
transform; INSIDE and OUTSIDE use the float32 margins described there.

User clip planes (``clip_planes``: ``render(clip_planes=)`` and a polygon window's
reject-only planes) are appended to the six frustum planes as rows 6.. of every test
above (`_ViewPlanes`; plane masks are then up to 14 bits, :mod:`clraster.culling.bvh`): an instance
or cluster (or a BVH node) wholly on a plane's removed side is culled where the frustum's
outside ones are, and counted with them as frustum-culled; one wholly on its kept side
drops the plane's bit, so what lies below is not tested against it again. User planes are
tested in world space for instances and in each instance's object space (plane · model,
float64, as the vertex stage evaluates them: common.h user_dist) for clusters, with scale
rows ``|plane|`` and the small margin `CLIP_PLANE_MARGIN`. They never make a cluster
INSIDE: `DrawList.inside` speaks of the frustum planes only (the vertex stage tests user
planes for every draw).
"""

from __future__ import annotations

import functools
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

# the thresholds that choose a culling path (speed only): tunables, in clraster.base.config
from ..base.config import (
    CLUSTER_LEAF_SIZE,
    DENSE_CHUNK,
    DENSE_CLUSTERS,
    DENSE_INSTANCES,
    DENSE_PAIRS,
    FLAT_CLUSTERS,
    FLAT_MAX_PAIRS,
    THREAD_PAIRS,
)
from ..base.layout import CULL_MODES
from ..world.mesh import Mesh
from ..world.scene import Scene
from .bvh import (
    ALL_PLANES,
    BVH,
    DEFAULT_MARGIN,
    INSIDE,
    INTERSECTING,
    MAX_PLANES,
    OUTSIDE,
    argsort_distinct,
    box_extremes,
    box_extremes_table,
    box_magnitudes,
    classify_extremes,
    classify_one,
    concat_ranges,
    dense_row_states,
    plane_table,
)
from .clusters import ClusteredMesh, clusters_of, cone_kernel, cone_table
from .frustum import check_view_proj, eye_and_flip, normalize_planes, raw_planes

__all__ = ["CLIP_PLANE_MARGIN", "COUNT_NAMES", "DEFAULT_CONE_MARGIN", "DrawList", "ViewCull",
           "build_draw_list"]

#: Cone-culling margin in radians: a culled cluster's triangles are all seen at least this
#: far from edge-on (in world space).
DEFAULT_CONE_MARGIN = 1e-3
#: Relative margin of the user clip-plane tests (outside and inside): the kernels evaluate a
#: vertex's distance in double from its float32 position and the float64 object-space plane
#: (common.h user_dist), off by a few 1e-16 of the terms' magnitude; the box bounds here are
#: exact up to the same rounding, so 1e-9 of the magnitude keeps the test conservative many
#: times over. (The frustum planes need float32's DEFAULT_MARGIN: the vertex stage tests
#: them on float32 clip coordinates.)
CLIP_PLANE_MARGIN = 1e-9


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
            call; 0 when cached), "instances", "clusters", "cones", "order", "total". When
            the culling paths run on threads (`THREAD_PAIRS`), "clusters" and "cones" sum
            the paths' own times, so together they can exceed "total".
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


@dataclass(frozen=True)
class _PairTables:
    """Per global cluster (C) and instance (I) tables of `ViewCull.pairs`."""

    bounded: np.ndarray   #: bool (C,): finite box
    inst_tri: np.ndarray  #: int64 (I,): triangles of each instance (0 for empty ones)
    centre: np.ndarray    #: float64 (3, C): object-space box centre
    half: np.ndarray      #: float64 (3, C): its half extents
    mag: np.ndarray       #: float64 (3, C): its margin magnitudes (`box_magnitudes`)


class _SceneCull:
    """Per-scene culling data (rebuilt when the scene changes)."""

    def __init__(self, scene: Scene, meshes: list[_MeshCull]) -> None:
        n = scene.n_instances
        self.n = n
        self.meshes = meshes  # per instance
        self.nonempty = ~scene.empty
        self.n_empty = int((~self.nonempty).sum())
        # `_ViewPlanes` without user planes: (I, 0, 4) and (0, I), empty (nothing to share)
        self.no_user = (np.zeros((n, 0, 4)), np.zeros((0, n)))
        self.bounded = scene.bounded
        t = scene.transforms()
        self.m = t
        self.minv = np.linalg.inv(t) if n else np.zeros((0, 4, 4))
        self.abs_m = np.abs(t)
        lin = t[:, :3, :3]
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
        # One bounded instance (a bare Mesh, the common case): the tree is one leaf holding
        # it, and `BVH.cull`'s answer is its root test (the leaf's item test repeats it on
        # the same box with fewer planes), so `_classify_instances` makes just that test, on
        # a copy of the root box laid out as the traversal gathers it (coordinate-major
        # (9, 1): min, max, magnitudes; the same float64 values, so the same bits).
        root = self.inst_bvh
        self.inst_root = (np.ascontiguousarray(np.hstack([root.node_min[:1], root.node_max[:1],
                                                          root.node_mag[:1]]).T)
                          if ids.size == 1 else None)
        self._root_corners: tuple[np.ndarray, np.ndarray] | None = None
        #: `_cone_view`'s per-scene part, per (cull, cone_margin): (side, sin_m, cullable)
        self.cone_setup: dict[tuple[str, float], tuple[np.ndarray, np.ndarray, bool]] = {}
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
        pc = concat_ranges(self.flat_start, fc) - np.repeat(self.flat_start, fc)
        self.flat_inst = pi.astype(np.int32)
        self.flat_cl = pc.astype(np.int32)
        self.flat_g = (self.mesh_base[self.inst_umesh[pi]] + pc).astype(np.int32)
        self.flat_boxes = np.empty((9, pi.size))
        lo_c = np.concatenate([mc.cm.aabb_min for mc in umesh]).astype(np.float64) if umesh \
            else np.zeros((0, 3))
        hi_c = np.concatenate([mc.cm.aabb_max for mc in umesh]).astype(np.float64) if umesh \
            else np.zeros((0, 3))
        # object-space cluster boxes and their magnitudes (flat-path user clip planes)
        self.g_lo, self.g_hi = lo_c, hi_c
        self.g_mag = box_magnitudes(lo_c, hi_c)
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
        self._umesh = umesh
        self._pair_tables: _PairTables | None = None

    def root_corners(self) -> tuple[np.ndarray, np.ndarray]:
        """One bounded instance (`inst_root` set): its world box's eight corners as
        homogeneous rows float64 (8, 4), and its margin magnitudes [mag, 1] float64 (4,);
        made once per scene."""
        if self._root_corners is None:
            assert self.inst_root is not None
            lo, hi, mag = self.inst_root[0:3, 0], self.inst_root[3:6, 0], self.inst_root[6:9, 0]
            pick = (np.arange(8)[:, None] >> np.arange(3)) & 1   # corner k: bit j picks hi
            corners = np.where(pick == 1, hi, lo)
            self._root_corners = (np.hstack([corners, np.ones((8, 1))]),
                                  np.append(mag, 1.0))
        return self._root_corners

    def pair_tables(self) -> _PairTables:
        """`ViewCull.pairs`' tables, made on first use."""
        if self._pair_tables is None:
            bounded = (np.concatenate([mc.cm.bounded for mc in self._umesh]) if self._umesh
                       else np.zeros(0, bool))
            per_mesh = np.array([int(mc.tri_count.sum()) for mc in self._umesh], np.int64)
            inst_tri = np.where(self.nonempty, per_mesh[self.inst_umesh], 0) if self.n \
                else np.zeros(0, np.int64)
            # (clusters with NaN/Inf vertices are never tested: 0 for them)
            lo = np.where(bounded[:, None], self.g_lo, 0.0)
            hi = np.where(bounded[:, None], self.g_hi, 0.0)
            self._pair_tables = _PairTables(bounded, inst_tri,
                                            np.ascontiguousarray((0.5 * (lo + hi)).T),
                                            np.ascontiguousarray((0.5 * (hi - lo)).T),
                                            np.ascontiguousarray(self.g_mag.T))
        return self._pair_tables


def _prepare(scene: Scene, max_triangles: int, max_vertices: int) -> _SceneCull:
    def mesh_data(mesh: Mesh) -> _MeshCull:
        return scene.mesh_memo(mesh, ("cull", max_triangles, max_vertices),
                               lambda: _MeshCull(clusters_of(mesh, max_triangles,
                                                             max_vertices)))

    return scene.memo(("cull", max_triangles, max_vertices),
                      lambda: _SceneCull(scene, [mesh_data(i.mesh) for i in scene.instances]))


def _cluster_frustum(bvh: BVH, planes: np.ndarray, scales: np.ndarray, masks: np.ndarray,
                     inside_margin: float | np.ndarray, outside_margin: float | np.ndarray):
    """(query, item, mask) of the non-OUTSIDE (instance, cluster) pairs, sorted; planes,
    scales (Q, K, 4) object space, masks (Q,) K-bit; mask: the planes each pair may still
    cross (0 for INSIDE)."""
    if bvh.n_items > DENSE_CLUSTERS and planes.shape[0] * bvh.n_items > DENSE_PAIRS:
        q, item, _, mk = bvh.cull_batch(planes, scales, masks, inside_margin=inside_margin,
                                        outside_margin=outside_margin)
        return q, item, mk
    out_q, out_i, out_m = [], [], []
    step = max(1, DENSE_CHUNK // max(bvh.n_items, 1))
    for q0 in range(0, planes.shape[0], step):
        sl = slice(q0, q0 + step)
        st, mk = dense_row_states(planes[sl], scales[sl], masks[sl], bvh.dense_rows,
                                  inside_margin=inside_margin, outside_margin=outside_margin)
        q, item = np.nonzero(st != OUTSIDE)
        out_q.append(q + q0)
        out_i.append(item)
        out_m.append(mk[q, item])
    return np.concatenate(out_q), np.concatenate(out_i), np.concatenate(out_m)


def _pair_extremes(planes: np.ndarray, scales: np.ndarray, row: np.ndarray, g: np.ndarray,
                   prep: _SceneCull) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`box_extremes` of object-space cluster boxes against their own instance's planes:
    planes, scales float64 (Q, K, 4) per instance, row int64 (N,) each pair's instance
    row, g (N,) its global cluster. From the box's centre and half extents (min = n·c + d
    − |n|·e, max = n·c + d + |n|·e), each pair's values by the same elementwise operations
    whatever the other pairs (`ViewCull.pairs` decides every pair on its own). float64
    (K, N) each."""
    tables = prep.pair_tables()
    # coordinate-major (3, N) boxes and (4, K, N) plane rows: every operation below runs
    # on contiguous (K, N) rows (strided (N, K) views cost 4x, with classify_extremes)
    c, e = np.take(tables.centre, g, axis=1), np.take(tables.half, g, axis=1)
    mag = np.take(tables.mag, g, axis=1)
    p, s = np.ascontiguousarray(planes.transpose(2, 1, 0)), np.ascontiguousarray(
        scales.transpose(2, 1, 0))
    if (row[1:] >= row[:-1]).all():
        # pairs in instance order (the two-phase schedule's sorted keys): each instance's
        # rows repeated over its run, the same values as the gather below, without its
        # indexing
        n = np.bincount(row, minlength=p.shape[2])
        p, s = np.repeat(p, n, axis=2), np.repeat(s, n, axis=2)
    else:
        p, s = np.take(p, row, axis=2), np.take(s, row, axis=2)
    a = np.abs(p[:3])
    dist = ((p[0] * c[0] + p[1] * c[1]) + p[2] * c[2]) + p[3]
    reach = (a[0] * e[0] + a[1] * e[1]) + a[2] * e[2]
    mterm = ((s[0] * mag[0] + s[1] * mag[1]) + s[2] * mag[2]) + s[3]
    return dist - reach, dist + reach, mterm


def _flat_frustum(prep: _SceneCull, inst_state: np.ndarray, inst_mask: np.ndarray,
                  view: _ViewPlanes):
    """Plane test of the flat-path pairs: (inst, cluster, inside, triangles, global
    cluster) of those not culled, in (instance, cluster) order. The frustum rows test the
    pairs' world boxes (`_SceneCull.flat_boxes`) against the world planes; user rows test
    the object-space cluster boxes against the instance's object-space planes, as the
    cluster BVH does for the other meshes."""
    ids = prep.flat_ids
    st = inst_state[ids]
    if (st == OUTSIDE).all():   # nothing in view (~3 µs instead of ~19 µs here)
        e64 = np.zeros(0, np.int64)
        return e64, e64, np.zeros(0, bool), e64, np.zeros(0, prep.flat_g.dtype)
    mk = inst_mask[ids]
    # INSIDE instances, and INTERSECTING ones with nothing to test (frustum off, no user
    # plane left): every pair, inside iff the instance is
    test = (st == INTERSECTING) & (mk != 0)
    free = (st != OUTSIDE) & ~test
    pos_f = concat_ranges(prep.flat_start[free], prep.flat_count[free])
    ins_f = np.repeat(st[free] == INSIDE, prep.flat_count[free])
    pos_t = concat_ranges(prep.flat_start[test], prep.flat_count[test])
    if pos_t.size:
        mask = np.repeat(mk[test], prep.flat_count[test])
        alive = np.empty(pos_t.size, bool)
        ins_t = np.empty(pos_t.size, bool)
        for c0 in range(0, pos_t.size, DENSE_CHUNK):  # bounded temporaries
            sl = slice(c0, c0 + DENSE_CHUNK)
            p = pos_t[sl]
            box = np.take(prep.flat_boxes, p, axis=1)
            dmin, dmax, mterm = box_extremes(view.planes[:6], view.scales[:6], box[0:3],
                                             box[3:6], box[6:9])
            if view.n_user:  # user rows: object-space boxes, each instance's planes
                g = prep.flat_g[p]
                umin, umax, uterm = box_extremes_table(
                    np.take(view.user_table, prep.flat_inst[p], axis=1), prep.g_lo[g].T,
                    prep.g_hi[g].T, prep.g_mag[g].T)
                dmin = np.concatenate([dmin, umin])
                dmax = np.concatenate([dmax, umax])
                mterm = np.concatenate([mterm, uterm])
            cst, cmask = classify_extremes(dmin, dmax, mterm, mask[sl], view.inside_margin,
                                           view.outside_margin)
            alive[sl] = cst != OUTSIDE
            ins_t[sl] = view.inside(cmask)
        pos_t, ins_t = pos_t[alive], ins_t[alive]
    else:
        ins_t = np.zeros(0, bool)
    pos = np.concatenate([pos_f, pos_t])
    ins = np.concatenate([ins_f, ins_t])
    if pos_f.size and pos_t.size:  # merge the two sorted runs
        order = argsort_distinct(pos, prep.flat_inst.size)
        pos, ins = pos[order], ins[order]
    g = prep.flat_g[pos]
    return (prep.flat_inst[pos].astype(np.int64), prep.flat_cl[pos].astype(np.int64), ins,
            prep.g_tri[g], g)


#: Whether a flat path of one instance goes through `_flat_one` (tests turn it off to
#: compare it with the general path).
FLAT_ONE = True


def _flat_one(prep: _SceneCull, inst_state: np.ndarray, inst_mask: np.ndarray,
              view: _ViewPlanes, cone_view: _ConeView | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                         float]:
    """`_flat_frustum`, then `_flat_cone_cull`, for a flat path of one instance without
    user planes (a bare Mesh of up to FLAT_CLUSTERS clusters: most small meshes): its
    pairs are the columns of the flat tables, in order, so both tests take the tables as
    they are — no per-instance ranges, repeats, merges or gathers — on the same values as
    the general path (the same box and cone arithmetic: tests/test_cull.py compares the
    two). Returns (inst, cl, ins, triangles, back, frustum seconds) as `all`'s flat task
    splits them."""
    t0 = time.perf_counter()
    i = int(prep.flat_ids[0])
    state = inst_state[i]
    n = int(prep.flat_count[0])
    keep = None   # the pairs kept, or None: every one
    if state == OUTSIDE:
        keep = np.zeros(0, np.int64)
        ins = np.zeros(0, bool)
    elif state == INTERSECTING and inst_mask[i] != 0:
        fb = prep.flat_boxes
        dmin, dmax, mterm = box_extremes(view.planes, view.scales, fb[0:3], fb[3:6],
                                         fb[6:9])
        cst, cmask = classify_extremes(dmin, dmax, mterm,
                                       np.full(n, inst_mask[i], inst_mask.dtype),
                                       view.inside_margin, view.outside_margin)
        ins = view.inside(cmask)
        alive = cst != OUTSIDE
        if not alive.all():
            keep = np.flatnonzero(alive)
            ins = ins[keep]
    else:   # INSIDE, or nothing left to test: every pair
        ins = np.full(n, state == INSIDE)
    if keep is None:
        g, cl = prep.flat_g, prep.flat_cl
        inst = np.full(n, i, np.int64)
    else:
        g, cl = prep.flat_g[keep], prep.flat_cl[keep]
        inst = np.full(keep.size, i, np.int64)
    tri = prep.g_tri[g]
    t1 = time.perf_counter()
    back = None
    if cone_view is not None and g.size:
        can = prep.g_can_cone[g]
        # the instance's eye, side and margin broadcast over its pairs: the same values
        # `_flat_cone_cull` gathers per pair
        eye, side, sin_m = (cone_view.eye_obj[i][:, None], cone_view.side[i:i + 1],
                            cone_view.sin_m[i:i + 1])
        table = prep.g_cones if keep is None else np.take(prep.g_cones, g, axis=1)
        if can.all():
            back = cone_kernel(table, eye, side, sin_m, cone_view.ortho)
        else:
            back = np.zeros(g.size, bool)
            sel = np.flatnonzero(can)
            back[sel] = cone_kernel(table[:, sel], eye, side, sin_m, cone_view.ortho)
    return inst, cl.astype(np.int64), ins, tri, back, t1 - t0


@dataclass(frozen=True)
class _ConeView:
    """The normal-cone test's inputs for one view, per instance (I = scene.n_instances)."""

    #: float64 (I, 3): the eye in each instance's object space, a point (perspective: M is
    #: affine, so w stays 1) or a unit direction (orthographic).
    eye_obj: np.ndarray
    #: float64 (I,): +1 to cull back faces, −1 front faces. The same for every instance: a
    #: mirroring transform keeps its faces' outward side (the Scene rule, as glTF; setup
    #: swaps its cull sense, DRAW_MIRRORED), so the object-space cone test is unchanged.
    side: np.ndarray
    #: float64 (I,): sine of the object-space angle margin, <= 1 (1: never culled).
    sin_m: np.ndarray
    #: Orthographic projection (eye_obj holds directions).
    ortho: bool


def _cone_view(prep: _SceneCull, vp: np.ndarray, cones: bool, cull: str,
               cone_margin: float) -> _ConeView | None:
    """Cone set-up: eye in each instance's object space, side and margin per instance.
    None when no cluster can be cone-culled in this view (cones off, cull="none", a
    degenerate or mirroring projection, or margins too wide for every instance)."""
    if not cones or cull == "none":
        return None
    try:
        eye, flips = eye_and_flip(vp)
    except ValueError:
        return None
    if flips:
        return None
    # Object-space eye (I, 3): a point (perspective: M is affine, so w stays 1) or a unit
    # direction (orthographic). Side: the object-space normals are the outward ones for
    # every instance, mirrored or not (setup culls mirrored draws by their outward side).
    setup = prep.cone_setup.get((cull, cone_margin))
    if setup is None:   # depends on the scene and the margin only: made once per scene
        side = np.full(prep.n, -1.0 if cull == "front" else 1.0)
        # An angle margin m in world space needs sin(m)·cond(M) in object space: for unit
        # n, u, sin of the world angle = dot(n, u) / (|M^-T n|·|M u|) >= sin_obj / cond.
        sin_m = np.minimum(1.0, math.sin(cone_margin) * prep.cond)
        side.flags.writeable = sin_m.flags.writeable = False   # shared by every frame
        setup = prep.cone_setup[(cull, cone_margin)] = (side, sin_m, bool((sin_m < 1.0).any()))
    side, sin_m, cullable = setup
    if not cullable:
        return None
    ortho = bool(eye[3] == 0.0)
    # one (4I, 4) @ (4,) product: a stack of I (4, 4) @ (4,) ones took ~0.3 ms for the
    # 10M plant's 5,349 instances
    eye_obj = (prep.minv.reshape(-1, 4) @ eye).reshape(-1, 4)[:, :3]
    if ortho:
        eye_obj /= np.linalg.norm(eye_obj, axis=1)[:, None]
    return _ConeView(eye_obj, side, sin_m, ortho)


def _flat_cone_cull(prep: _SceneCull, inst: np.ndarray, g: np.ndarray,
                    view: _ConeView) -> np.ndarray:
    """Cone test of flat-path pairs (instance `inst`, global cluster `g`, int64 (P,));
    bool (P,), True = culled. Clusters whose cone admits every direction are not tested."""
    back = np.zeros(g.size, bool)
    sel = np.flatnonzero(prep.g_can_cone[g])
    if sel.size:
        ip = inst[sel]
        table = np.take(prep.g_cones, g[sel], axis=1)
        back[sel] = cone_kernel(table, np.take(view.eye_obj, ip, axis=0).T, view.side[ip],
                                view.sin_m[ip], view.ortho)
    return back


def _cone_cull(mc: _MeshCull, inst: np.ndarray, cl: np.ndarray, visible: np.ndarray,
               view: _ConeView) -> np.ndarray:
    """Cone test of the pairs (inst, cl) of one mesh's instances; bool (P,).

    Evaluated densely over (visible instance, every cluster) when the pairs cover at least
    a third of that grid (contiguous arithmetic, no gathers), else per pair."""
    eye_obj, side, sin_m, ortho = view.eye_obj, view.side, view.sin_m, view.ortho
    n_c = mc.cm.n_clusters
    if 3 * cl.size >= visible.size * n_c and visible.size * n_c <= (1 << 22):
        e = eye_obj[visible].T[:, :, None]  # (3, Q, 1)
        dense = cone_kernel(mc.cones[:, None, :], e, side[visible][:, None],
                            sin_m[visible][:, None], ortho)  # (Q, C)
        if visible.size == 1:   # one instance (a bare Mesh): its row
            return dense[0, cl]
        row = np.searchsorted(visible, inst)
        return dense[row, cl]
    table = np.take(mc.cones, cl, axis=1)
    return cone_kernel(table, eye_obj[inst].T, side[inst], sin_m[inst], ortho)


def _group_frustum(prep: _SceneCull, mc: _MeshCull, members: np.ndarray,
                   inst_state: np.ndarray, inst_mask: np.ndarray, view: _ViewPlanes):
    """Plane test of the clusters of one mesh's group instances (`members`, int64, some
    not OUTSIDE), against each instance's world planes (`view`) moved to object space:
    (inst int64, cluster int64, inside bool), (P,) each, the pairs not culled, grouped by
    how they were decided (not in draw order)."""
    st = inst_state[members]
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
            oplanes, oscales = view.object_space(prep, tested)
            q, item, cmask = _cluster_frustum(mc.bvh, oplanes, oscales, inst_mask[tested],
                                              view.inside_margin, view.outside_margin)
            pi_list.append(tested[q])
            pc_list.append(mc.bvh_ids[item].astype(np.int64))
            pin_list.append(view.inside(cmask))
            if mc.unbounded.size:  # clusters with NaN/Inf vertices: never culled
                pi_list.append(np.repeat(tested, mc.unbounded.size))
                pc_list.append(np.tile(mc.unbounded.astype(np.int64), tested.size))
                pin_list.append(np.zeros(tested.size * mc.unbounded.size, bool))
    return np.concatenate(pi_list), np.concatenate(pc_list), np.concatenate(pin_list)


def _check_draw_args(scene: Scene, view_proj: npt.ArrayLike, cull: str, inside_margin: float,
                     outside_margin: float, cone_margin: float) -> np.ndarray:
    """Validate `build_draw_list`'s arguments; the checked float64 (4, 4) view_proj."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene must be a clraster.scene.Scene, got {type(scene).__name__}; "
                         f"wrap a mesh with Scene.from_mesh(mesh)")
    vp = check_view_proj(view_proj)
    if cull not in CULL_MODES:
        raise ValueError(f"cull must be one of {sorted(CULL_MODES)}, got {cull!r}")
    for name, v in (("inside_margin", inside_margin), ("outside_margin", outside_margin),
                    ("cone_margin", cone_margin)):
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
    if cone_margin >= math.pi / 2:
        raise ValueError(f"cone_margin must be < pi/2 radians, got {cone_margin!r}")
    return vp


@dataclass(frozen=True)
class _ViewPlanes:
    """The K = 6 + U planes one view's object culling tests: rows 0..5 the frustum's (bits
    0..5 of the masks), rows 6.. the U user clip planes (bits 6..)."""

    #: float64 (K, 4) world space: the normalized frustum rows, then the user planes as
    #: given (scaling a plane changes no test: both sides of the margin scale with it).
    planes: np.ndarray
    #: float64 (K, 4) margin scales: `normalize_planes`' (float32 terms) for the frustum
    #: rows, ``|plane|`` (the terms of a float64 evaluation) for the user rows.
    scales: np.ndarray
    #: float64 (6, 4) each: the frustum rows and magnitude rows before normalizing
    #: (`raw_planes`), moved to object space as they are (``@ M``, ``@ |M|``).
    raw: np.ndarray
    rmag: np.ndarray
    #: float64 (I, U, 4): the user planes in each instance's object space (plane · model,
    #: as `drawlist.instance_matrices` gives the vertex stage), and their `bvh.plane_table`
    #: (11U, I) for per-pair gathers on the flat path.
    user_obj: np.ndarray
    user_table: np.ndarray
    #: Relative margins: floats without user planes (the frustum's, as always), else
    #: float64 (K,): the frustum's, then CLIP_PLANE_MARGIN for each user plane.
    inside_margin: float | np.ndarray
    outside_margin: float | np.ndarray
    #: The mask every instance starts from: bits 0..5 with the frustum test on, plus the
    #: user bits; 0 = nothing to test.
    start: int
    frustum: bool

    @property
    def n_user(self) -> int:
        return int(self.user_obj.shape[1])

    @classmethod
    def make(cls, prep: _SceneCull, raw: np.ndarray, rmag: np.ndarray, frustum: bool,
             clip_planes: npt.ArrayLike | None, inside_margin: float,
             outside_margin: float) -> _ViewPlanes:
        planes, scales = normalize_planes(raw, rmag)
        user = (np.zeros((0, 4)) if clip_planes is None
                else np.asarray(clip_planes, np.float64).reshape(-1, 4))
        n_u = user.shape[0]
        if n_u > MAX_PLANES - 6:
            raise ValueError(f"at most {MAX_PLANES - 6} clip planes, got {n_u}")
        start = (int(ALL_PLANES) if frustum else 0) | (((1 << n_u) - 1) << 6)
        if not n_u:
            return cls(planes, scales, raw, rmag, *prep.no_user, inside_margin,
                       outside_margin, start, frustum)
        # plane · model in float64, as drawlist.instance_matrices moves them for the vertex stage
        user_obj = np.einsum("kj,ijl->ikl", user, prep.m)
        mu_in = np.concatenate([np.full(6, inside_margin), np.full(n_u, CLIP_PLANE_MARGIN)])
        mu_out = np.concatenate([np.full(6, outside_margin),
                                 np.full(n_u, CLIP_PLANE_MARGIN)])
        return cls(np.concatenate([planes, user]), np.concatenate([scales, np.abs(user)]),
                   raw, rmag, user_obj, plane_table(user_obj, np.abs(user_obj)), mu_in,
                   mu_out, start, frustum)

    def object_space(self, prep: _SceneCull, inst: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
        """(planes, scales), float64 (Q, K, 4): the view's planes in the object space of
        the instances `inst` (int64 (Q,))."""
        oraw = np.einsum("kj,qjl->qkl", self.raw, prep.m[inst])
        omag = np.einsum("kj,qjl->qkl", self.rmag, prep.abs_m[inst])
        oplanes, oscales = normalize_planes(oraw, omag)
        if self.n_user:
            uo = self.user_obj[inst]
            oplanes = np.concatenate([oplanes, uo], axis=1)
            oscales = np.concatenate([oscales, np.abs(uo)], axis=1)
        return oplanes, oscales

    def inside(self, mask: np.ndarray) -> np.ndarray:
        """bool: pairs with these remaining masks are INSIDE the frustum (`DrawList.inside`:
        no frustum bit left, and the frustum test on; user bits do not matter)."""
        if not self.frustum:
            return np.zeros(mask.shape, bool)
        return (mask & int(ALL_PLANES)) == 0


def _classify_instances(prep: _SceneCull, view: _ViewPlanes
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Top level: (state uint8, plane mask uint16), (I,) each, per instance.

    Empty instances are OUTSIDE; unbounded ones (NaN/Inf vertices) INTERSECTING with every
    plane to test. INSIDE means inside every plane (frustum and user: all clusters drawn
    without further tests, marked inside). With frustum=False every non-empty instance not
    wholly outside a user plane is INTERSECTING, with the user bits it still crosses (mask 0
    without user planes: no plane tests below)."""
    inst_state = np.full(prep.n, OUTSIDE, np.uint8)
    inst_mask = np.zeros(prep.n, np.uint16)
    if view.start:
        # User planes test the world boxes here, with the instance BVH's magnitudes (|M| @
        # [object magnitudes, 1], which bound |plane · model| terms too): an instance culled
        # by a user plane is culled by each of its clusters' object-space tests below.
        if prep.inst_root is not None:
            # one bounded instance: the root test `BVH.cull` makes, without its traversal
            # machinery (same states and masks; a third of the time for a framed mesh)
            box = prep.inst_root
            st, mk = classify_one(
                *box_extremes(view.planes, view.scales, box[0:3], box[3:6], box[6:9]),
                view.start, view.inside_margin, view.outside_margin)
            if st != OUTSIDE:
                i = prep.inst_ids[0]
                inst_state[i] = st
                inst_mask[i] = mk
        elif prep.inst_ids.size <= DENSE_INSTANCES:
            # every instance box on its own (`BVH.cull` equals that by contract): three
            # matrix products instead of a traversal (the same states and masks; ~5× faster
            # for the 10M plant's 5,349 instances)
            k = view.planes.shape[0]
            start = np.full(1, view.start, np.uint8 if k <= 8 else np.uint16)
            st, mk = dense_row_states(view.planes[None], view.scales[None], start,
                                      prep.inst_bvh.dense_rows,
                                      inside_margin=view.inside_margin,
                                      outside_margin=view.outside_margin)
            keep = np.flatnonzero(st[0] != OUTSIDE)
            ids = prep.inst_ids[keep]
            inst_state[ids] = st[0, keep]
            inst_mask[ids] = mk[0, keep]
        else:
            items, st, mk = prep.inst_bvh.cull(view.planes, view.scales, mask=view.start,
                                               inside_margin=view.inside_margin,
                                               outside_margin=view.outside_margin,
                                               return_mask=True)
            ids = prep.inst_ids[items]
            inst_state[ids] = st
            inst_mask[ids] = mk
        inst_state[prep.unbounded_ids] = INTERSECTING
        inst_mask[prep.unbounded_ids] = view.start
        if not view.frustum:  # inside the user planes only: not INSIDE the frustum
            inst_state[inst_state == INSIDE] = INTERSECTING
    else:
        inst_state[prep.nonempty] = INTERSECTING  # mask 0: no plane tests below
    return inst_state, inst_mask


class _Pairs:
    """The pairs that survive, collected path by path (flat path first, then the groups),
    with the running counts and times the `DrawList` reports."""

    def __init__(self, keep_cone_culled: bool) -> None:
        self.keep_cone_culled = keep_cone_culled
        self.inst: list[np.ndarray] = []
        self.cl: list[np.ndarray] = []
        self.ins: list[np.ndarray] = []
        self.clusters_after_frustum = 0
        self.tri_frustum = 0  # triangles of the clusters that survive the frustum test
        self.n_cone_cl = 0
        self.n_cone_tri = 0
        self.cone_pairs: list[tuple[np.ndarray, np.ndarray]] = []  # with keep_cone_culled
        self.t_clusters = 0.0
        self.t_cones = 0.0
        # The flat path emits pairs in (instance, cluster) order; groups do not.
        self.in_order = True

    def frustum_done(self, cl: np.ndarray, tri: np.ndarray) -> None:
        """Count one path's frustum survivors (clusters `cl`, their triangle counts
        `tri`)."""
        self.clusters_after_frustum += cl.size
        self.tri_frustum += int(tri.sum())

    def drop_cone_culled(self, back: np.ndarray, inst: np.ndarray, cl: np.ndarray,
                         ins: np.ndarray, tri: np.ndarray):
        """(inst, cl, ins) without the pairs where `back` (bool (P,)) is set, counted."""
        if back.any():
            keep = ~back
            self.n_cone_cl += int(back.sum())
            self.n_cone_tri += int(tri[back].sum())
            if self.keep_cone_culled:
                self.cone_pairs.append((inst[back], cl[back]))
            inst, cl, ins = inst[keep], cl[keep], ins[keep]
        return inst, cl, ins

    def keep(self, inst: np.ndarray, cl: np.ndarray, ins: np.ndarray) -> None:
        self.inst.append(inst)
        self.cl.append(cl)
        self.ins.append(ins)

    def in_draw_order(self, prep: _SceneCull):
        """All kept pairs sorted by (instance, cluster): (inst int64, cl int64, ins bool)."""
        if len(self.inst) == 1 and self.in_order:  # only flat-path pairs: already in order
            return self.inst[0], self.cl[0], self.ins[0]
        if not self.inst:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
        inst = np.concatenate(self.inst)
        cl = np.concatenate(self.cl)
        ins = np.concatenate(self.ins)
        order = argsort_distinct(prep.cluster_base[inst] + cl, prep.clusters_total)
        return inst[order], cl[order], ins[order]

    def counts(self, prep: _SceneCull, inst_state: np.ndarray, n_drawn: int) -> dict[str, int]:
        """`DrawList.counts`."""
        return {
            "instances_total": prep.n,
            "instances_frustum_culled": int(((inst_state == OUTSIDE) & prep.nonempty).sum()),
            "instances_empty": prep.n_empty,
            "clusters_total": prep.clusters_total,
            "clusters_frustum_culled": prep.clusters_total - self.clusters_after_frustum,
            "clusters_cone_culled": self.n_cone_cl,
            "clusters_drawn": n_drawn,
            "triangles_total": prep.tri_total,
            "triangles_frustum_culled": prep.tri_total - self.tri_frustum,
            "triangles_cone_culled": self.n_cone_tri,
            "triangles_drawn": self.tri_frustum - self.n_cone_tri,
        }

    def cone_culled(self) -> np.ndarray | None:
        """`DrawList.cone_culled`: int32 (P, 2), or None without keep_cone_culled."""
        if not self.keep_cone_culled:
            return None
        if not self.cone_pairs:
            return np.zeros((0, 2), np.int32)
        return np.stack([np.concatenate([a for a, _ in self.cone_pairs]),
                         np.concatenate([b for _, b in self.cone_pairs])],
                        axis=1).astype(np.int32)


@dataclass
class _PathResult:
    """One culling path's output (the flat path, or one mesh's group): the frustum
    survivors (inst, cl int64, ins bool, tri their triangle counts), the cone verdict per
    survivor (bool, True = culled; None: no cone test) and the seconds each test took."""

    inst: np.ndarray
    cl: np.ndarray
    ins: np.ndarray
    tri: np.ndarray
    back: np.ndarray | None
    t_frustum: float
    t_cones: float
    #: the pairs come in draw order (instance, then cluster): the flat path's always, a
    #: group's when it holds one instance and its clusters came in order
    ordered: bool = True


#: CPUs this process may run on (read once: os.cpu_count() took ~15 µs a call, a tenth of
#: an empty frame's culling)
_NCPU = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
         else os.cpu_count() or 1)
_POOL: tuple[int, ThreadPoolExecutor] | None = None
_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """The culling helper threads (one fewer than the CPUs, 1..3), made on first use and
    again in a forked child (whose copy of the executor has no threads)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL[0] != os.getpid():
            n = max(1, min(3, _NCPU - 1))
            _POOL = (os.getpid(), ThreadPoolExecutor(n, thread_name_prefix="clraster-cull"))
        return _POOL[1]


def _run_tasks(tasks: list, work: list[int]) -> list[_PathResult]:
    """Results of the culling paths ``tasks`` ((function, args) each), in their order;
    ``work``: a bound on the (instance, cluster) pairs each looks at (its instances times
    their clusters).

    The paths are independent NumPy work (each reads the scene's tables and this view's
    planes and builds its own arrays), and NumPy releases the GIL in its loops and matrix
    products over arrays this size, so with more than `THREAD_PAIRS` pairs in all they
    run on this thread and `_pool`'s, biggest first, each thread taking the next path
    when done: object culling on one thread left the other core idle (10M plant, first
    person: the flat path and 8 meshes' groups). The results are combined in task order
    by the caller, so the draw list and its counts are the same either way."""
    if len(tasks) < 2 or _NCPU < 2 or sum(work) < THREAD_PAIRS:
        return [f(*a) for f, a in tasks]
    results: list = [None] * len(tasks)
    order = iter(sorted(range(len(tasks)), key=lambda k: -work[k]))
    lock = threading.Lock()

    def drain() -> None:
        while True:
            with lock:
                k = next(order, None)
            if k is None:
                return
            f, a = tasks[k]
            results[k] = f(*a)

    pool = _pool()
    helpers = [pool.submit(drain) for _ in range(min(len(tasks), _NCPU, 4) - 1)]
    drain()
    for h in helpers:
        # a helper still queued (this thread and the others took every path) is dropped
        # rather than waited for behind another caller's work; one that ran raises what
        # a path of it raised
        if not h.cancel():
            h.result()
    return results


def build_draw_list(scene: Scene, view_proj: npt.ArrayLike, *, frustum: bool = True,
                    cones: bool = True, cull: str = "back", max_triangles: int = 128,
                    max_vertices: int = 128, inside_margin: float = DEFAULT_MARGIN,
                    outside_margin: float = DEFAULT_MARGIN,
                    cone_margin: float = DEFAULT_CONE_MARGIN,
                    keep_cone_culled: bool = False,
                    clip_planes: np.ndarray | None = None) -> DrawList:
    """The (instance, cluster) pairs of `scene` to draw for one view.

    Args:
        scene: the scene; its clusters (`clusters_of`) and BVHs are built on first use and
            cached (per mesh, and per scene version).
        view_proj: (4, 4) world → clip matrix (OpenGL conventions, see
            `clraster.culling.frustum.frustum_planes`).
        frustum: cull instances and clusters outside the view frustum (instance world
            boxes first, then each intersecting instance's clusters against the planes it
            still crosses; see the module docstring).
        cones: cull clusters that face away, with their normal cones (only when `cull` is
            "back" or "front", and never for a mirroring projection). The test is
            conservative: a culled cluster's non-degenerate triangles are all seen from
            their culled side, at least `cone_margin` radians from edge-on (measured in
            world space: the object-space margin is widened by the condition number of
            the instance's transform). Instances with a mirroring transform (negative
            determinant) keep their faces' outward side (the Scene rule, as glTF): they are
            tested for the same side as the others.
        cull: the renderer's face culling mode: "back", "front" or "none".
        max_triangles, max_vertices: cluster limits (see `clusterize`).
        inside_margin, outside_margin: relative frustum margins (the module docstring of
            :mod:`clraster.culling.frustum`).
        cone_margin: radians, >= 0.
        keep_cone_culled: also return the cone-culled pairs (``DrawList.cone_culled``).
        clip_planes: float64 (K, 4) world-space user clip planes (`checks.check_clip_planes`;
            at most 8, with a window's reject-only planes) or None: instances and clusters
            whose box lies wholly outside one of them (by `CLIP_PLANE_MARGIN`; clusters in
            their instance's object space) are culled in the same traversals as the
            frustum's (their planes appended, see the module docstring), also with
            frustum=False, and counted with the frustum-culled ones. They never change
            `DrawList.inside`.

    Returns:
        A `DrawList`.

    Raises:
        ValueError: bad matrix, cull mode or margins.
    """
    return ViewCull(scene, view_proj, frustum=frustum, cones=cones, cull=cull,
                    max_triangles=max_triangles, max_vertices=max_vertices,
                    inside_margin=inside_margin, outside_margin=outside_margin,
                    cone_margin=cone_margin, keep_cone_culled=keep_cone_culled,
                    clip_planes=clip_planes).all()


def _clip_rows(kx: float, ky: float) -> np.ndarray:
    """`ViewCull.clip_free`'s planes as combinations (6, 4) of the view-projection's x, y,
    z, w rows: near w + z, far w − z, then x + kx·w, kx·w − x, y + ky·w, ky·w − y (the
    guard band, `clraster.base.config.guard_band_factors`)."""
    return np.array([[0, 0, 1, 1], [0, 0, -1, 1], [1, 0, 0, kx], [-1, 0, 0, kx],
                     [0, 1, 0, ky], [0, -1, 0, ky]], np.float64)


class ViewCull:
    """One view's object culling of a scene, in steps: the instances are classified when
    it is made; then `all` gives the draw list of every (instance, cluster) pair
    (`build_draw_list`), `pairs` that of given pairs only (hierarchical occlusion culling,
    `clraster.pipeline.twophase`, tests just the clusters of the groups it could not prove hidden).
    Arguments as `build_draw_list`."""

    def __init__(self, scene: Scene, view_proj: npt.ArrayLike, *, frustum: bool = True,
                 cones: bool = True, cull: str = "back", max_triangles: int = 128,
                 max_vertices: int = 128, inside_margin: float = DEFAULT_MARGIN,
                 outside_margin: float = DEFAULT_MARGIN,
                 cone_margin: float = DEFAULT_CONE_MARGIN, keep_cone_culled: bool = False,
                 clip_planes: np.ndarray | None = None) -> None:
        t_start = time.perf_counter()
        vp = _check_draw_args(scene, view_proj, cull, inside_margin, outside_margin,
                              cone_margin)
        self.prep = prep = _prepare(scene, max_triangles, max_vertices)
        t_prep = time.perf_counter()
        self.vp = vp
        self.margin = inside_margin
        self.keep_cone_culled = keep_cone_culled
        raw, rmag = raw_planes(vp)
        self.view = _ViewPlanes.make(prep, raw, rmag, frustum, clip_planes, inside_margin,
                                     outside_margin)
        #: uint8 (I,) `Visibility` per instance (empty ones OUTSIDE), uint16 (I,) the
        #: planes each still crosses (`_classify_instances`)
        self.inst_state, self.inst_mask = _classify_instances(prep, self.view)
        self._cone_args = (vp, cones, cull, cone_margin)
        t_inst = time.perf_counter()
        self.timings_ms = {"prepare": (t_prep - t_start) * 1e3,
                           "instances": (t_inst - t_prep) * 1e3}

    @functools.cached_property
    def cone_view(self) -> _ConeView | None:
        """`_cone_view` of this view, made when first asked for (a view with every
        instance outside never needs it)."""
        return _cone_view(self.prep, *self._cone_args)

    def outside_totals(self) -> tuple[int, int]:
        """(clusters, triangles) of the non-empty instances culled whole (OUTSIDE)."""
        prep = self.prep
        out = (self.inst_state == OUTSIDE) & prep.nonempty
        return int(prep.n_clusters[out].sum()), int(prep.pair_tables().inst_tri[out].sum())

    def pairs(self, inst: np.ndarray, cl: np.ndarray) -> DrawList:
        """The draw list of the pairs (``inst``, ``cl``) only: int64 (P,) each, distinct,
        in draw order (by instance, then cluster). Each pair is decided on its own: culled
        with its instance when that is OUTSIDE; else, while its instance still crosses
        planes, its object-space cluster box against them in the instance's object space
        (exact under any affine transform, as `_group_frustum`'s tests; `all`'s flat path
        tests looser world boxes, so the two can differ on pairs near a plane — both
        conservative); then the cone test. Counts: the cluster and triangle rows over these
        pairs (clusters_total = P), no instance rows; timings "clusters", "cones" and
        "total"."""
        t0 = time.perf_counter()
        prep, view = self.prep, self.view
        g_bounded, g_tri = prep.pair_tables().bounded, prep.g_tri
        st = self.inst_state[inst]
        mk = self.inst_mask[inst]
        g = prep.mesh_base[prep.inst_umesh[inst]] + cl
        alive = st != OUTSIDE
        ins = st == INSIDE
        # pairs of an INTERSECTING instance with planes left, and a finite box: tested
        # (clusters with NaN/Inf vertices are never culled, as on the other paths)
        test = np.flatnonzero((st == INTERSECTING) & (mk != 0) & g_bounded[g])
        if test.size:
            uniq, row = np.unique(inst[test], return_inverse=True)
            oplanes, oscales = view.object_space(prep, uniq)
            dmin, dmax, mterm = _pair_extremes(oplanes, oscales, row, g[test], prep)
            cst, cmask = classify_extremes(dmin, dmax, mterm, mk[test], view.inside_margin,
                                           view.outside_margin)
            alive[test] = cst != OUTSIDE
            ins[test] = view.inside(cmask)
        tri_total = int(g_tri[g].sum())
        keep = np.flatnonzero(alive)
        inst, cl, ins, g = inst[keep], cl[keep], ins[keep], g[keep]
        pairs = _Pairs(self.keep_cone_culled)
        pairs.frustum_done(cl, g_tri[g])
        t1 = time.perf_counter()
        if self.cone_view is not None and keep.size:
            inst, cl, ins = pairs.drop_cone_culled(
                _flat_cone_cull(prep, inst, g, self.cone_view), inst, cl, ins, g_tri[g])
        t2 = time.perf_counter()
        counts = {"clusters_total": int(alive.size),
                  "clusters_frustum_culled": int(alive.size) - pairs.clusters_after_frustum,
                  "clusters_cone_culled": pairs.n_cone_cl, "clusters_drawn": int(inst.size),
                  "triangles_total": tri_total,
                  "triangles_frustum_culled": tri_total - pairs.tri_frustum,
                  "triangles_cone_culled": pairs.n_cone_tri,
                  "triangles_drawn": pairs.tri_frustum - pairs.n_cone_tri}
        return DrawList(instance=inst.astype(np.int32), cluster=cl.astype(np.int32),
                        inside=ins.astype(bool), counts=counts,
                        timings_ms={"clusters": (t1 - t0) * 1e3, "cones": (t2 - t1) * 1e3,
                                    "total": (t2 - t0) * 1e3},
                        cone_culled=pairs.cone_culled())

    def clip_free(self, inst: np.ndarray, cl: np.ndarray, kx: float, ky: float) -> np.ndarray:
        """bool (P,): the pairs (``inst``, ``cl``: int (P,) each) none of whose triangles can
        need setup's clipper. Setup clips a triangle when a vertex lies behind the near or
        beyond the far plane or leaves the x/y guard band (the planes ±kx·w, ±ky·w of
        `clraster.base.config.guard_band_factors`; user clip planes aside): a pair is
        clip-free when its object-space cluster box is inside those six planes by the
        inside margin, in its instance's object space, as `pairs` tests the frustum. The
        plane values are linear, so the box's extremes bound every vertex; the margin
        covers the vertex stage's float32 evaluation (:mod:`clraster.culling.frustum`'s
        module docstring: the guard-band rows' magnitudes are ``|r0| + kx·|r3|``). Boxes
        with NaN/Inf are never clip-free."""
        inst, cl = np.asarray(inst, np.int64), np.asarray(cl, np.int64)
        if not inst.size:
            return np.zeros(0, bool)
        prep, vp = self.prep, self.vp
        # plane rows (6, 4) and their magnitude rows (plane values and margins scale alike:
        # no normalizing needed)
        rows = _clip_rows(kx, ky)
        raw, mag = rows @ vp, np.abs(rows) @ np.abs(vp)
        if prep.inst_ids.size == 1 and (inst == prep.inst_ids[0]).all():
            # one bounded instance (a bare Mesh): its world box first, the box and
            # magnitudes `_classify_instances` tests (`inst_root`), by its eight corners:
            # most close-ups have it wholly inside
            corners, cmag = prep.root_corners()
            if ((corners @ raw.T).min(axis=0) >= (mag @ cmag) * self.margin).all():
                return np.ones(inst.size, bool)
        g = prep.mesh_base[prep.inst_umesh[inst]] + cl
        uniq, row = np.unique(inst, return_inverse=True)
        dmin, _, mterm = _pair_extremes(np.matmul(raw, prep.m[uniq]),
                                        np.matmul(mag, prep.abs_m[uniq]), row.reshape(-1), g,
                                        prep)
        return (dmin >= mterm * self.margin).all(axis=0) & prep.pair_tables().bounded[g]

    def all(self) -> DrawList:
        """The draw list of every (instance, cluster) pair of the scene."""
        t_inst = time.perf_counter()
        prep, view = self.prep, self.view
        inst_state, inst_mask = self.inst_state, self.inst_mask
        timings = dict(self.timings_ms)
        pairs = _Pairs(self.keep_cone_culled)
        # nothing in view (every instance culled whole, or empty): no path to run (they
        # would find no pair), and the counts follow from the instances
        in_view = bool((inst_state != OUTSIDE).any())
        cone_view = self.cone_view if in_view else None

        def flat_task() -> _PathResult:   # small meshes: all their (instance, cluster) pairs
            if prep.flat_ids.size == 1 and not view.n_user and FLAT_ONE:
                t1 = time.perf_counter()
                inst, cl, ins, tri, back, t_frustum = _flat_one(prep, inst_state, inst_mask,
                                                                view, cone_view)
                return _PathResult(inst, cl, ins, tri, back, t_frustum,
                                   time.perf_counter() - t1 - t_frustum)
            t0 = time.perf_counter()
            inst, cl, ins, tri, g = _flat_frustum(prep, inst_state, inst_mask, view)
            t1 = time.perf_counter()
            back = (_flat_cone_cull(prep, inst, g, cone_view)
                    if cone_view is not None and cl.size else None)
            return _PathResult(inst, cl, ins, tri, back, t1 - t0, time.perf_counter() - t1)

        def group_task(mc: _MeshCull, members: np.ndarray, vis: np.ndarray) -> _PathResult:
            t0 = time.perf_counter()   # other meshes: one group of instances per mesh
            inst, cl, ins = _group_frustum(prep, mc, members, inst_state, inst_mask, view)
            tri = mc.tri_count[cl]
            t1 = time.perf_counter()
            back = (_cone_cull(mc, inst, cl, members[vis], cone_view)
                    if cone_view is not None and mc.can_cone and cl.size else None)
            # one instance whose clusters come in order (a bare Mesh: its BVH lists them
            # in their own order) needs no sort into draw order
            ordered = members.size == 1 and bool((cl[1:] > cl[:-1]).all())
            return _PathResult(inst, cl, ins, tri, back, t1 - t0, time.perf_counter() - t1,
                               ordered)

        tasks: list = []
        work: list[int] = []   # bounds on the pairs each task looks at (`_run_tasks`)
        if in_view and prep.flat_ids.size:
            tasks.append((flat_task, ()))
            work.append(int(prep.flat_count.sum()))   # (a bound: it is only compared)
        for mc, members in prep.groups if in_view else ():
            vis = inst_state[members] != OUTSIDE
            if vis.any():
                tasks.append((group_task, (mc, members, vis)))
                work.append(members.size * mc.cm.n_clusters)
        for k, res in enumerate(_run_tasks(tasks, work)):
            if k > 0 or not res.ordered:
                pairs.in_order = False   # groups emit pairs out of draw order
            pairs.t_clusters += res.t_frustum
            pairs.frustum_done(res.cl, res.tri)
            inst, cl, ins = res.inst, res.cl, res.ins
            if res.back is not None:
                inst, cl, ins = pairs.drop_cone_culled(res.back, inst, cl, ins, res.tri)
                pairs.t_cones += res.t_cones
            pairs.keep(inst, cl, ins)

        t_order = time.perf_counter()
        inst, cl, ins = pairs.in_draw_order(prep)
        counts = pairs.counts(prep, inst_state, int(cl.size))
        t_end = time.perf_counter()
        timings.update(clusters=pairs.t_clusters * 1e3, cones=pairs.t_cones * 1e3,
                       order=(t_end - t_order) * 1e3,
                       total=timings["prepare"] + timings["instances"]
                       + (t_end - t_inst) * 1e3)
        return DrawList(instance=inst.astype(np.int32), cluster=cl.astype(np.int32),
                        inside=ins.astype(bool), counts=counts,
                        timings_ms=timings, cone_culled=pairs.cone_culled())

