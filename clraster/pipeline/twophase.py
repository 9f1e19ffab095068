"""Two-phase occlusion culling: the schedule, shared by the OpenCL renderer and the NumPy twin.

One frame (after frustum/cone culling has made the frame's draw list, `drawlist.FramePlan`;
each phase's draw records are laid out when it is drawn, `FramePlan.draws_of`):

1. **Phase 1** draws the clusters that were visible in the previous frame of the same
   target (`OcclusionHistory`); on a first frame — or after a camera cut, when none of last
   frame's visible clusters is among this frame's draws — the nearest clusters, front to
   back, up to a budget (`OCCLUSION_FIRST_CLUSTERS`). Clusters without a finite bounding
   box are always drawn here (they cannot be tested).
2. The **depth pyramid** of that partial frame is built and every other cluster's world box
   is **Hi-Z tested** against it.
3. **Phase 2** draws the clusters the test could not prove hidden, into the same frame
   buffers (their depth and ids take part in the depth test, so the image is the one
   drawing everything would give: occlusion culling is conservative).
4. **Next frame's visibility**: of everything drawn, the clusters whose box is not hidden
   in a pyramid of the final depth buffer.

**Hierarchical** (``group_clusters`` > 0, `RasterConfig.occlusion_groups`, from the second
frame on): each instance's clusters are cut into groups of neighbours (`KeyGroups`: runs of
its mesh's cluster BVH leaf order; an instance of a small mesh is one group). Phase 1 culls
(frustum, cones: `cull.ViewCull.pairs`) and draws only last frame's visible clusters; the
groups holding the other clusters of the instances in view are Hi-Z tested against phase
1's pyramid first, and only the clusters of the groups not proved hidden are Hi-Z tested
one by one, and those not hidden culled (frustum, cones) and drawn (phase 1's clusters are
tested with the groups: when phase 2 draws nothing, the depth is final and those verdicts
are step 4's). The clusters of a hidden group, and a hidden cluster, are counted
occlusion-culled without their frustum and cone tests (those the test finds wholly outside
a frustum plane, frustum-culled); the image is the same. 10M plant, first person: 6.1K of
the 106K clusters are tested one by one, and none of them culled or drawn in a still
view.

The schedule (`two_phase`) is NumPy over the frame plan; the pipeline itself is handed in as
two functions — ``draw`` (run the stage chain over a subset of the draws into the frame
buffers) and ``hiz`` (build the pyramid of a frame's depth and test boxes against it) — so
the OpenCL renderer (`clraster.renderer`) and the NumPy twin (the reference package) run
the very same schedule with their own stages and produce the same frame and counts.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np

from ..base.config import OCCLUSION_FIRST_CLUSTERS  # the first frame's budget (a tunable)
from ..culling.bvh import OUTSIDE, concat_ranges
from ..culling.cull import DrawList
from ..culling.frustum import eye_from_view_proj
from .boxes import Occlusion
from .drawlist import FramePlan, key_boxes
from .params import FrameTotals

__all__ = ["OCCLUSION_FIRST_CLUSTERS", "KeyGroups", "OcclusionHistory", "TwoPhaseResult",
           "eye_position", "two_phase", "view_direction"]



def eye_position(view_proj: np.ndarray) -> np.ndarray | None:
    """World eye point of a perspective view-projection, None for an orthographic one."""
    e = eye_from_view_proj(view_proj)
    return None if abs(e[3]) < 1e-300 else e[:3] / e[3]


def view_direction(view_proj: np.ndarray) -> np.ndarray:
    """World direction the view looks along (normal of the near plane), unit length."""
    n = view_proj[3, :3] + view_proj[2, :3]
    return n / np.linalg.norm(n)


@dataclass
class KeyGroups:
    """Every key of a scene (one per (instance, cluster), `drawlist.key_boxes`' numbering)
    with its group for hierarchical occlusion culling. K keys, G groups.

    An instance with at most ``size`` clusters is one group; a bigger one's clusters go in
    runs of ``size`` along its mesh's cluster BVH leaf order (neighbours in space; the
    clusters with NaN/Inf vertices, outside the BVH, in a group of their own).
    """

    #: int64 (K,) each: the key's instance, its cluster in that instance's mesh, its
    #: triangles
    inst: np.ndarray
    cluster: np.ndarray
    tris: np.ndarray
    #: int64 (K,): the key's group
    group: np.ndarray
    #: float32 (6, G): the groups' world boxes (min xyz, max xyz: the union of their keys'
    #: boxes; non-finite when one of them is), the Hi-Z test's layout
    rows: np.ndarray
    #: int64 (K,): the keys by group (group j's are order[start[j]:start[j] + size[j]]);
    #: int64 (G,) each: start, size (keys), triangles and instance of every group
    order: np.ndarray
    start: np.ndarray
    size: np.ndarray
    group_tris: np.ndarray
    group_inst: np.ndarray
    #: int64: the keys without a finite box
    unbounded: np.ndarray

    @property
    def n_groups(self) -> int:
        return int(self.rows.shape[1])

    def keys_of(self, groups: np.ndarray) -> np.ndarray:
        """int64: the keys of ``groups`` (int64), group by group."""
        return self.order[concat_ranges(self.start[groups], self.size[groups])]

    @classmethod
    def build(cls, pool, prep, wlo: np.ndarray, whi: np.ndarray, wbounded: np.ndarray,
              size: int) -> KeyGroups:
        """Groups of at most ``size`` clusters; ``prep``: the scene's culling data
        (`cull._prepare`: each instance's mesh with its cluster BVH), wlo, whi, wbounded:
        the keys' world boxes (float64 (K, 3)) and whether they are finite."""
        base = np.asarray(pool.instance_key_base, np.int64)
        n_keys = np.diff(base)
        inst = np.repeat(np.arange(n_keys.size, dtype=np.int64), n_keys)
        cluster = np.arange(inst.size, dtype=np.int64) - np.repeat(base[:-1], n_keys)
        local = np.zeros(inst.size, np.int64)   # group within the instance
        per_inst = (n_keys > 0).astype(np.int64)   # groups per instance
        runs: dict[int, tuple[np.ndarray, int]] = {}   # per mesh: (group of each cluster, G)
        for i in np.flatnonzero(n_keys > size).tolist():
            mc = prep.meshes[i]
            run = runs.get(id(mc))
            if run is None:
                lg = np.empty(int(n_keys[i]), np.int64)
                leaf = mc.bvh_ids[mc.bvh.order]
                lg[leaf] = np.arange(leaf.size) // size
                m = -(-leaf.size // size)
                if mc.unbounded.size:
                    lg[mc.unbounded] = m
                    m += 1
                run = runs[id(mc)] = (lg, m)
            local[base[i]:base[i + 1]] = run[0]
            per_inst[i] = run[1]
        group = np.repeat(np.cumsum(per_inst) - per_inst, n_keys) + local
        tris = np.take(pool.clusters[:, 1], pool.pool_clusters(inst, cluster)).astype(np.int64)
        order = np.argsort(group, kind="stable")
        if not order.size:   # no keys, no groups
            e = np.zeros(0, np.int64)
            return cls(inst, cluster, tris, group, np.zeros((6, 0), np.float32), order, e, e,
                       e, e, e)
        sg = group[order]
        starts = np.flatnonzero(np.r_[True, sg[1:] != sg[:-1]])
        glo = np.minimum.reduceat(wlo[order], starts)
        ghi = np.maximum.reduceat(whi[order], starts)
        rows = np.ascontiguousarray(np.vstack([glo.T, ghi.T]).astype(np.float32))
        return cls(inst, cluster, tris, group, rows, order, starts,
                   np.diff(np.append(starts, sg.size)),
                   np.add.reduceat(tris[order], starts), inst[order[starts]],
                   np.flatnonzero(~wbounded))


class OcclusionHistory:
    """What two-phase occlusion culling keeps from frame to frame (one per renderer).

    visible: bool (K,) per key (drawlist.GeometryPool.instance_key_base: one key per
    (instance, cluster) of the scene) — visible at the end of the last frame — and the
    (scene, version) it belongs to. The world boxes of every key (`drawlist.key_boxes`) are
    cached per (scene, version) too: they depend only on the scene.

    The scene object itself is kept and compared with ``is`` (not its id(), which a new
    scene can reuse once the old one is freed), together with its version. A history used
    with another scene (or a changed one) starts over as on a first frame.
    """

    def __init__(self) -> None:
        self._visible: np.ndarray | None = None
        self._visible_keys = np.zeros(0, np.int64)
        self._visible_key: tuple | None = None
        # world boxes of every key (float64 (K, 3) mins and maxs, bool (K,) bounded) + the
        # boxes in the Hi-Z test's layout, float32 (6, K), gathered per frame
        self._boxes: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._boxes_key: tuple | None = None
        self._groups: KeyGroups | None = None
        self._groups_key: tuple | None = None

    def groups(self, pool, scene, prep, size: int) -> KeyGroups:
        """`KeyGroups` of every key of ``scene`` for groups of ``size`` clusters (cached
        with the scene and version, as the boxes)."""
        version = getattr(scene, "version", 0)
        key = self._groups_key
        if key is None or not (key[0] is scene and key[1] == version and key[2] == size
                               and key[3] is prep):
            wlo, whi, wbounded, _ = self.boxes(pool, scene)
            self._groups = KeyGroups.build(pool, prep, wlo, whi, wbounded, size)
            self._groups_key = (scene, version, size, prep)
        return cast(KeyGroups, self._groups)

    def boxes(self, pool, scene) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(wlo, whi, bounded, rows) of every key of ``scene`` (see the class docstring)."""
        version = getattr(scene, "version", 0)
        if self._boxes_key is None or not (self._boxes_key[0] is scene
                                           and self._boxes_key[1] == version):
            wlo, whi, wbounded = key_boxes(pool, scene)
            self._boxes = (wlo, whi, wbounded,
                           np.ascontiguousarray(np.vstack([wlo.T, whi.T]).astype(np.float32)))
            self._boxes_key = (scene, version)
        return cast("tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]", self._boxes)

    def last_visible(self, scene) -> np.ndarray | None:
        """bool (K,) keys visible at the end of the last frame of ``scene``, or None."""
        key = self._visible_key
        if key is not None and key[0] is scene and key[1] == getattr(scene, "version", 0):
            return self._visible
        return None

    def last_visible_keys(self, scene) -> np.ndarray:
        """int64 (V,) sorted: the keys `last_visible` sets (empty without a history)."""
        key = self._visible_key
        if key is not None and key[0] is scene and key[1] == getattr(scene, "version", 0):
            return self._visible_keys
        return np.zeros(0, np.int64)

    def remember(self, scene, n_keys: int, visible_keys: np.ndarray) -> None:
        """Store ``visible_keys`` (int (V,) keys) as the visible set of ``scene``."""
        self._visible = np.zeros(n_keys, bool)
        self._visible[visible_keys] = True
        self._visible_keys = np.flatnonzero(self._visible)
        self._visible_key = (scene, getattr(scene, "version", 0))


class TwoPhaseResult:
    """What `two_phase` returns. out: the frame buffers ``draw`` made (opaque here).
    occluded_keys: int64 (O,) keys of the clusters the Hi-Z test removed (for
    `fates.ClusterFates`; listed when asked for: the hierarchical schedule counts a hidden
    group's keys without listing them)."""

    def __init__(self, out: Any, occluded: np.ndarray | Callable[[], np.ndarray]) -> None:
        self.out = out
        self._occluded = occluded

    @property
    def occluded_keys(self) -> np.ndarray:
        if callable(self._occluded):
            self._occluded = self._occluded()
        return self._occluded


def _box_rows(box_rows: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """The boxes of ``keys`` (int64 (K,), K > 0) in the Hi-Z test's layout, float32 (6,
    K'), K' the next multiple of 8 (the last key repeated; callers keep the first K
    verdicts): the device's test takes that as it is (PyramidStage.enqueue_test_rows, no
    copy into a padded array). Only the boxes a frame tests are gathered."""
    k = keys.size
    pad = -(-k // 8) * 8
    idx = keys if pad == k else np.concatenate([keys, np.full(pad - k, keys[-1])])
    return np.take(box_rows, idx, axis=1)


#: draw(draws, into[, after]) → frame buffers: run the stage chain over ``draws`` (a subset
#: of the frame's draws, maybe empty) into ``into`` (None: fresh cleared buffers);
#: ``after``: a follow the backend's passes call right after each raster launch (the
#: ``hiz`` step's `follow`, where it has one).
DrawFn = Callable[..., Any]
class HizFn(Protocol):
    """hiz(frame buffers, rows float32 (6, K), view_proj float32 (16,), same_depth) →
    (uint8 (K,) `Occlusion` codes, milliseconds or None): the pyramid of the frame's depth
    and the box test; same_depth=True: nothing was drawn since the last call of this
    frame, so the pyramid that call built may be tested again."""

    def __call__(self, out: Any, rows: np.ndarray, vp32: np.ndarray,
                 same_depth: bool = False) -> tuple[np.ndarray, float | None]: ...


def two_phase(plan: FramePlan, history: OcclusionHistory, draw: DrawFn, hiz: HizFn,
              totals: FrameTotals, counts: dict[str, int],
              group_clusters: int = 0) -> TwoPhaseResult:
    """Render ``plan`` with two-phase occlusion culling (see the module docstring);
    ``group_clusters`` > 0: hierarchically, with groups of that many clusters, when
    there is a history to start from.

    Culls the plan's clusters (its draw list is set to the frame's: the clusters that
    survived the frustum and cone tests, drawn or occlusion-culled one by one), adds the
    time to "cull (host)", adds "pyramid+test" (the Hi-Z tests' time as ``hiz`` reports
    it) and "occlusion (host)" to ``totals.timings_ms``, the culling counts
    (`cull.COUNT_NAMES`: clusters_drawn is what the frustum and cone tests let through,
    = phase 1 + phase 2 + occlusion-culled) and the occlusion rows
    (clusters_occlusion_culled, triangles_occlusion_culled, clusters_phase1,
    clusters_phase2) to ``counts``, and updates ``history`` for the next frame.
    """
    if group_clusters > 0:
        res = _two_phase_groups(plan, history, draw, hiz, totals, counts, group_clusters)
        if res is not None:
            return res
    t_cull = time.perf_counter()
    dl = plan.draw_list
    _add_ms(totals, "cull (host)", (time.perf_counter() - t_cull) * 1e3)
    counts.update(dl.counts)
    pool, scene = plan.pool, plan.scene
    n_draws = len(dl)
    # the draws' keys, from the draw list's (instance, mesh-local cluster)
    keys = np.take(pool.instance_key_base, dl.instance) + dl.cluster
    wlo, whi, wbounded, box_rows = history.boxes(pool, scene)
    bounded = wbounded[keys]
    vp32 = plan.view_proj.astype(np.float32).reshape(-1)
    if n_draws == 0:
        # nothing in view: the cleared frame; the history stays for the frames after
        counts.update(clusters_occlusion_culled=0, triangles_occlusion_culled=0,
                      clusters_phase1=0, clusters_phase2=0)
        return TwoPhaseResult(draw(plan.draws_of(np.zeros(0, bool)), None),
                              np.zeros(0, np.int64))
    hist = history.last_visible(scene)
    first = hist[keys] if hist is not None else None
    # (clusters without a box are in every visible set: they do not tell a camera cut)
    if first is None or not (first & bounded).any():
        # first frame, or a camera cut (none of last frame's visible clusters is in
        # view): the nearest clusters, front to back, up to a budget
        vp_inv_eye = eye_position(plan.view_proj)
        centre = 0.5 * (wlo[keys] + whi[keys])
        dist = np.linalg.norm(centre - vp_inv_eye, axis=1) if vp_inv_eye is not None \
            else centre @ view_direction(plan.view_proj)
        budget = max(OCCLUSION_FIRST_CLUSTERS, n_draws // 8)
        first = np.zeros(n_draws, bool)
        first[np.argsort(dist, kind="stable")[:budget]] = True
    first |= ~bounded
    out = draw(plan.draws_of(first), None)
    rest = ~first
    t0 = time.perf_counter()
    verdict = np.zeros(n_draws, np.uint8)
    if rest.any():
        tested = keys[rest]
        codes, ms = hiz(out, _box_rows(box_rows, tested), vp32)
        verdict[rest] = codes[:tested.size]
        if ms is not None:
            totals.timings_ms["pyramid+test"] = ms
    second = rest & (verdict == Occlusion.VISIBLE)
    occluded = rest & ~second
    t_draw = time.perf_counter()
    out = draw(plan.draws_of(second), out)
    draw_ms = (time.perf_counter() - t_draw) * 1e3
    # visibility for the next frame: everything drawn whose box is not hidden in the
    # final depth buffer
    drawn = first | second
    vis = np.zeros(n_draws, bool)
    if drawn.any():
        # phase 2 drew nothing (a still camera): the depth buffer, so its pyramid, is the
        # one phase 2 was tested against
        tested = keys[drawn]
        v2, ms2 = hiz(out, _box_rows(box_rows, tested), vp32, same_depth=not second.any())
        vis[drawn] = (v2[:tested.size] == Occlusion.VISIBLE) | ~bounded[drawn]
        if ms2 is not None:
            _add_ms(totals, "pyramid+test", ms2)
    history.remember(scene, int(pool.instance_key_base[-1]), keys[vis])
    # the schedule's own host time: all of this but phase 2's draw and the tests
    totals.timings_ms["occlusion (host)"] = (time.perf_counter() - t0) * 1e3 - draw_ms \
        - totals.timings_ms.get("pyramid+test", 0.0)
    counts["clusters_occlusion_culled"] = int(occluded.sum())
    counts["triangles_occlusion_culled"] = int(
        np.take(pool.clusters[:, 1], pool.pool_clusters(dl.instance[occluded],
                                                        dl.cluster[occluded])).sum(
            dtype=np.int64))
    counts["clusters_phase1"] = int(first.sum())
    counts["clusters_phase2"] = int(second.sum())
    return TwoPhaseResult(out, keys[occluded])


def _add_ms(totals: FrameTotals, name: str, ms: float) -> None:
    totals.timings_ms[name] = totals.timings_ms.get(name, 0.0) + ms


def _merge(a: DrawList, b: DrawList, base: np.ndarray, counts: dict[str, int]) -> DrawList:
    """The pairs of ``a`` and ``b`` (disjoint, each in draw order) in draw order, their
    cone-culled pairs together, ``counts``."""
    inst = np.concatenate([a.instance, b.instance])
    cl = np.concatenate([a.cluster, b.cluster])
    order = np.argsort(base[inst] + cl, kind="stable")
    cone = None
    if a.cone_culled is not None and b.cone_culled is not None:
        cone = np.concatenate([a.cone_culled, b.cone_culled])
    return DrawList(inst[order], cl[order], np.concatenate([a.inside, b.inside])[order],
                    counts=counts, cone_culled=cone)


def _two_phase_groups(plan: FramePlan, history: OcclusionHistory, draw: DrawFn, hiz: HizFn,
                      totals: FrameTotals, counts: dict[str, int],
                      size: int) -> TwoPhaseResult | None:
    """`two_phase` with groups of ``size`` clusters (the module docstring); None, having
    drawn nothing, on a first frame or a camera cut (none of last frame's visible
    clusters survives this frame's culling): the flat schedule then starts over."""
    pool, scene, vc = plan.pool, plan.scene, plan.culler
    hist = history.last_visible(scene)
    if hist is None:
        return None
    t0 = time.perf_counter()
    base = np.asarray(pool.instance_key_base, np.int64)
    n_keys = int(base[-1])
    _, _, wbounded, box_rows = history.boxes(pool, scene)
    grp = history.groups(pool, scene, vc.prep, size)
    inst_alive = vc.inst_state != OUTSIDE   # instances not culled whole by the frustum
    # phase 1: last frame's visible clusters, and those that cannot be tested (no box), of
    # the instances in view
    k1 = np.union1d(history.last_visible_keys(scene), grp.unbounded)
    k1 = k1[inst_alive[grp.inst[k1]]]
    dl1 = vc.pairs(grp.inst[k1], grp.cluster[k1])
    keys1 = base[dl1.instance] + dl1.cluster
    t_cull = dl1.timings_ms["total"]
    if not (hist[keys1] & wbounded[keys1]).any():
        # a camera cut (clusters without a box are in every visible set: they do not
        # count): start over as on a first frame
        _add_ms(totals, "cull (host)", t_cull)
        return None
    vp32 = plan.view_proj.astype(np.float32).reshape(-1)
    # the groups of the instances in view against phase 1's pyramid (their phase-1 keys
    # aside: decided above), and in the same launch phase 1's keys: if phase 2 draws
    # nothing, the depth stays as it is and their verdicts are the next frame's
    # visibility (the test below, one launch and wait fewer). Where the backend can
    # (``hiz.follow``), the pyramid and this test are enqueued behind phase 1's raster,
    # their boxes gathered while it runs: one wait for the three.
    tested_g = np.flatnonzero(inst_alive[grp.group_inst])
    n_rows_g = -(-tested_g.size // 8) * 8   # (`_box_rows` pads to a multiple of 8)
    rows_made: list[np.ndarray] = []

    def rows1() -> np.ndarray:
        if not rows_made:
            rows_g = _box_rows(grp.rows, tested_g)
            rows_made.append(rows_g if not keys1.size else np.concatenate(
                [rows_g, _box_rows(box_rows, keys1)], axis=1))
        return rows_made[0]

    follow = getattr(hiz, "follow", None)
    after = follow(rows1, vp32) if follow is not None and tested_g.size else None
    t_draw = time.perf_counter()
    out = draw(plan.draws_for(dl1), None, after)
    draw_ms = (time.perf_counter() - t_draw) * 1e3
    hiz_ms = 0.0
    g_code = np.full(grp.n_groups, Occlusion.VISIBLE, np.uint8)
    codes1 = None
    if tested_g.size:
        res = after.result() if after is not None else None
        if res is not None:
            codes, ms = res
            draw_ms -= ms   # (the draw's wait covered them: they are counted as tests)
        else:
            codes, ms = hiz(out, rows1(), vp32)
        g_code[tested_g] = codes[:tested_g.size]
        if keys1.size:
            codes1 = codes[n_rows_g:n_rows_g + keys1.size]
        hiz_ms += ms or 0.0
    # wholly outside a frustum plane: frustum-culled, when frustum culling is on (else,
    # as in the flat schedule, occlusion-culled)
    outside = (g_code == Occlusion.VIEW_CULLED) & vc.view.frustum
    hidden = (g_code == Occlusion.OCCLUDED) | ((g_code == Occlusion.VIEW_CULLED) & ~outside)
    in_phase1 = np.zeros(n_keys, bool)
    in_phase1[k1] = True
    k2 = grp.keys_of(tested_g[g_code[tested_g] == Occlusion.VISIBLE])
    k2 = np.sort(k2[~in_phase1[k2]])
    # the clusters of the groups in view, one by one: Hi-Z tested, and those not hidden
    # culled (frustum, cones) and drawn. A cluster the test hides counts occlusion-culled
    # untested, one wholly outside a frustum plane frustum-culled, as the groups' are (in
    # a still view the test hides all of them: culling them first was host time with the
    # device idle)
    n_view2 = tri_view2 = tri_occ2 = 0
    occ2 = k2[:0]   # the clusters the test hid
    if k2.size:
        codes, ms = hiz(out, _box_rows(box_rows, k2), vp32, same_depth=bool(tested_g.size))
        codes = codes[:k2.size]
        hiz_ms += ms or 0.0
        view2 = (codes == Occlusion.VIEW_CULLED) & vc.view.frustum & wbounded[k2]
        shown = (codes == Occlusion.VISIBLE) | ~wbounded[k2]   # (no box: never hidden)
        occ2 = k2[~shown & ~view2]
        n_view2, tri_view2 = int(view2.sum()), int(np.take(grp.tris, k2[view2]).sum())
        tri_occ2 = int(np.take(grp.tris, occ2).sum())
        k2 = k2[shown]
    dl2 = vc.pairs(grp.inst[k2], grp.cluster[k2])
    t_cull += dl2.timings_ms["total"]
    keys2 = base[dl2.instance] + dl2.cluster   # (every cluster that survived is drawn)
    t_draw = time.perf_counter()
    out = draw(plan.draws_for(dl2), out)
    draw_ms += (time.perf_counter() - t_draw) * 1e3
    # visibility for the next frame, as the flat schedule
    drawn = np.concatenate([keys1, keys2])
    if drawn.size:
        if codes1 is not None and not keys2.size:   # (drawn is keys1)
            codes = codes1
        else:
            codes, ms = hiz(out, _box_rows(box_rows, drawn), vp32,
                            same_depth=not keys2.size)
            hiz_ms += ms or 0.0
        vis = (codes[:drawn.size] == Occlusion.VISIBLE) | ~wbounded[drawn]
        visible = drawn[vis]
    else:
        visible = drawn
    history.remember(scene, n_keys, visible)
    # occlusion-culled: the hidden groups' keys (but their phase-1 ones) untested, and the
    # clusters the one-by-one test hid; frustum-culled: those of the groups wholly outside
    def group_totals(flag: np.ndarray) -> tuple[int, int]:
        gs = np.flatnonzero(flag)
        k1_in = k1[flag[grp.group[k1]]]
        return (int(grp.size[gs].sum()) - int(k1_in.size),
                int(grp.group_tris[gs].sum()) - int(grp.tris[k1_in].sum()))

    hid_g = np.flatnonzero(hidden)
    n_hidden, tri_hidden = group_totals(hidden)
    n_outside, tri_outside = group_totals(outside)

    def occluded_keys() -> np.ndarray:
        keys = grp.keys_of(hid_g)
        return np.concatenate([keys[~in_phase1[keys]], occ2])

    # the frame's counts: instances from the instance test, clusters and triangles from
    # the instances culled whole, the groups outside or hidden and the two pair lists
    c1, c2 = dl1.counts, dl2.counts
    out_cl, out_tri = vc.outside_totals()
    prep = vc.prep
    frame_counts = {
        "instances_total": prep.n,
        "instances_frustum_culled": int(((vc.inst_state == OUTSIDE) & prep.nonempty).sum()),
        "instances_empty": prep.n_empty,
        "clusters_total": prep.clusters_total,
        "clusters_frustum_culled": out_cl + n_outside + n_view2
        + c1["clusters_frustum_culled"] + c2["clusters_frustum_culled"],
        "clusters_cone_culled": c1["clusters_cone_culled"] + c2["clusters_cone_culled"],
        "clusters_drawn": len(dl1) + len(dl2) + n_hidden + int(occ2.size),
        "triangles_total": prep.tri_total,
        "triangles_frustum_culled": out_tri + tri_outside + tri_view2
        + c1["triangles_frustum_culled"] + c2["triangles_frustum_culled"],
        "triangles_cone_culled": c1["triangles_cone_culled"] + c2["triangles_cone_culled"],
        "triangles_drawn": c1["triangles_drawn"] + c2["triangles_drawn"] + tri_hidden
        + tri_occ2,
    }
    counts.update(frame_counts)
    counts["clusters_occlusion_culled"] = n_hidden + int(occ2.size)
    counts["triangles_occlusion_culled"] = tri_hidden + tri_occ2
    counts["clusters_phase1"] = len(dl1)
    counts["clusters_phase2"] = int(keys2.size)
    plan.draw_list = _merge(dl1, dl2, base, frame_counts)
    _add_ms(totals, "cull (host)", t_cull)
    if hiz_ms:
        totals.timings_ms["pyramid+test"] = hiz_ms
    # the schedule's own host time: all of this but the culling, the draws and the tests
    totals.timings_ms["occlusion (host)"] = ((time.perf_counter() - t0) * 1e3 - t_cull
                                             - draw_ms - hiz_ms)
    return TwoPhaseResult(out, occluded_keys)
