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

from .boxes import Occlusion
from .drawlist import FrameDraws, FramePlan, key_boxes
from .frustum import eye_from_view_proj
from .params import FrameTotals

__all__ = ["OCCLUSION_FIRST_CLUSTERS", "OcclusionHistory", "TwoPhaseResult", "eye_position",
           "two_phase", "view_direction"]

#: First frame of occlusion culling: at least this many of the nearest clusters (or 1/8 of
#: those that survive frustum culling, if more) are drawn before the first pyramid.
OCCLUSION_FIRST_CLUSTERS = 256


def eye_position(view_proj: np.ndarray) -> np.ndarray | None:
    """World eye point of a perspective view-projection, None for an orthographic one."""
    e = eye_from_view_proj(view_proj)
    return None if abs(e[3]) < 1e-300 else e[:3] / e[3]


def view_direction(view_proj: np.ndarray) -> np.ndarray:
    """World direction the view looks along (normal of the near plane), unit length."""
    n = view_proj[3, :3] + view_proj[2, :3]
    return n / np.linalg.norm(n)


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
        self._visible_key: tuple | None = None
        # world boxes of every key (float64 (K, 3) mins and maxs, bool (K,) bounded) + the
        # boxes in the Hi-Z test's layout, float32 (6, K), gathered per frame
        self._boxes: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._boxes_key: tuple | None = None

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

    def remember(self, scene, n_keys: int, visible_keys: np.ndarray) -> None:
        """Store ``visible_keys`` (int (V,) keys) as the visible set of ``scene``."""
        self._visible = np.zeros(n_keys, bool)
        self._visible[visible_keys] = True
        self._visible_key = (scene, getattr(scene, "version", 0))


@dataclass
class TwoPhaseResult:
    """What `two_phase` returns. out: the frame buffers ``draw`` made (opaque here).
    occluded_keys: int64 (O,) keys of the clusters the Hi-Z test removed (for
    `fates.ClusterFates`)."""

    out: Any
    occluded_keys: np.ndarray


def _box_rows(box_rows: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """The boxes of ``keys`` (int64 (K,), K > 0) in the Hi-Z test's layout, float32 (6,
    K'), K' the next multiple of 8 (the last key repeated; callers keep the first K
    verdicts): the device's test takes that as it is (PyramidStage.enqueue_test_rows, no
    copy into a padded array). Only the boxes a frame tests are gathered."""
    k = keys.size
    pad = -(-k // 8) * 8
    idx = keys if pad == k else np.concatenate([keys, np.full(pad - k, keys[-1])])
    return np.take(box_rows, idx, axis=1)


#: draw(draws, into) → frame buffers: run the stage chain over ``draws`` (a subset of the
#: frame's draws, maybe empty) into ``into`` (None: fresh cleared buffers).
DrawFn = Callable[[FrameDraws, Any], Any]
class HizFn(Protocol):
    """hiz(frame buffers, rows float32 (6, K), view_proj float32 (16,), same_depth) →
    (uint8 (K,) `Occlusion` codes, milliseconds or None): the pyramid of the frame's depth
    and the box test; same_depth=True: nothing was drawn since the last call of this
    frame, so the pyramid that call built may be tested again."""

    def __call__(self, out: Any, rows: np.ndarray, vp32: np.ndarray,
                 same_depth: bool = False) -> tuple[np.ndarray, float | None]: ...


def two_phase(plan: FramePlan, history: OcclusionHistory, draw: DrawFn, hiz: HizFn,
              totals: FrameTotals, counts: dict[str, int]) -> TwoPhaseResult:
    """Render ``plan`` with two-phase occlusion culling (see the module docstring).

    Adds "pyramid+test" (the phase-2 test's time as ``hiz`` reports it) and
    "occlusion (host)" to ``totals.timings_ms``, the occlusion rows
    (clusters_occlusion_culled, triangles_occlusion_culled, clusters_phase1,
    clusters_phase2) to ``counts``, and updates ``history`` for the next frame.
    """
    pool, scene, dl = plan.pool, plan.scene, plan.draw_list
    n_draws = len(dl)
    # the draws' keys, from the draw list's (instance, mesh-local cluster)
    keys = np.take(pool.instance_key_base, dl.instance) + dl.cluster
    wlo, whi, wbounded, box_rows = history.boxes(pool, scene)
    bounded = wbounded[keys]
    vp32 = plan.view_proj.astype(np.float32).reshape(-1)
    hist = history.last_visible(scene)
    first = hist[keys] if hist is not None else None
    if first is None or not first.any():
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
    out = draw(plan.draws_of(second), out)
    # visibility for the next frame: everything drawn whose box is not hidden in the
    # final depth buffer
    drawn = first | second
    vis = np.zeros(n_draws, bool)
    if drawn.any():
        # phase 2 drew nothing (a still camera): the depth buffer, so its pyramid, is the
        # one phase 2 was tested against
        tested = keys[drawn]
        v2, _ = hiz(out, _box_rows(box_rows, tested), vp32, same_depth=not second.any())
        vis[drawn] = (v2[:tested.size] == Occlusion.VISIBLE) | ~bounded[drawn]
    history.remember(scene, int(pool.instance_key_base[-1]), keys[vis])
    totals.timings_ms["occlusion (host)"] = (time.perf_counter() - t0) * 1e3 \
        - totals.timings_ms.get("pyramid+test", 0.0)
    counts["clusters_occlusion_culled"] = int(occluded.sum())
    counts["triangles_occlusion_culled"] = int(
        np.take(pool.clusters[:, 1], pool.pool_clusters(dl.instance[occluded],
                                                        dl.cluster[occluded])).sum(
            dtype=np.int64))
    counts["clusters_phase1"] = int(first.sum())
    counts["clusters_phase2"] = int(second.sum())
    return TwoPhaseResult(out, keys[occluded])
