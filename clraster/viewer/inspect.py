"""The third-person pane: the scene seen from outside, every cluster coloured by its fate in
the first-person frame shown beside it, and the first-person view frustum drawn as lines —
Yoon's figure 6.1 (the seeds' walkthrough figure), live.

The outside camera does not move while the user walks, so its triangle ids are rendered
once per (size, cut) and kept (`ThirdPerson._base`): each frame then only looks up, per
covered pixel, the fate of its cluster in the new first-person `clraster.ClusterFates`
(a gather over the pane's pixels) and draws the frustum's 12 edges (two line renders:
depth-tested in `FRUSTUM_COLOR`, hidden parts in `FRUSTUM_HIDDEN_COLOR`).

In a plant (`clraster.scenes.plant`) the pane shows the storey the eye is on, everything
more than `CUT` metres over its floor cut away by a horizontal clip plane (as
``clraster demo``'s inspector); elsewhere the whole target. The page's cut-away slider
lowers that plane further (and cuts the first-person view the same way).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..culling.fates import ClusterFates, Fate
from ..world.camera import Camera
from .pictures import BACKGROUND, FATE_COLORS, pack
from .scene import ViewerScene

__all__ = ["CUT", "FRUSTUM_COLOR", "FRUSTUM_HIDDEN_COLOR", "ThirdPerson", "storey_floor"]

#: Height (metres) over the eye's storey floor above which a plant is cut away in the pane.
CUT = 2.6
FRUSTUM_COLOR = (255, 240, 60)
FRUSTUM_HIDDEN_COLOR = (165, 150, 70)
#: Shading of the fate colours: ``colour · (SHADE_BASE + (1 − SHADE_BASE) · |n · l|)``.
SHADE_BASE = 0.45
_LIGHT = np.array([0.35, 0.85, 0.45]) / np.linalg.norm([0.35, 0.85, 0.45])
#: Depth bias (window depth) of the frustum lines against the pane's surfaces.
_LINE_BIAS = 1e-4


def storey_floor(vs: ViewerScene, eye_y: float) -> float | None:
    """World y of the floor of the plant storey holding height `eye_y` (None: not a plant)."""
    if not vs.plant:
        return None
    from ..world.generators.dimensions import SLAB, STOREY

    storeys = max(1, round((vs.hi[1] - vs.lo[1] - SLAB) / STOREY))
    k = min(max(math.floor((eye_y - vs.lo[1] - SLAB) / STOREY), 0), storeys - 1)
    return float(vs.lo[1] + SLAB + k * STOREY)


@dataclass
class _Base:
    """One outside render, kept: the camera, its (4, 4) view-projection, depth (H, W)
    float32, covered mask (H, W) bool, per covered pixel (row-major) its instance and
    mesh-local face, and ``shades``: uint32 (len(Fate), covered pixels), each covered
    pixel's packed colour under each fate (the fate colour times its Lambert factor), so a
    frame's picture is one gather."""

    camera: Camera
    view_proj: np.ndarray
    depth: np.ndarray
    covered: np.ndarray
    instance: np.ndarray
    face: np.ndarray
    shades: np.ndarray
    cluster_key: np.ndarray | None = None   # keys in the fates' numbering, made on first use


class ThirdPerson:
    """The pane for one `ViewerScene` at one size (``width × height``), drawn with
    `renderer` (a `clraster.Renderer` of that size, occlusion culling off: it is not walked)
    and `lines` (a `clraster.LineRenderer` of that size)."""

    def __init__(self, vs: ViewerScene, renderer: Any, lines: Any) -> None:
        self.vs = vs
        self.renderer = renderer
        self.lines = lines
        self.width, self.height = renderer.width, renderer.height
        self._bases: dict[tuple[float | None, float | None], _Base] = {}
        self._normals: dict[int, np.ndarray] = {}

    def planes(self, eye_y: float, cut_y: float | None) -> tuple[np.ndarray | None,
                                                                  float | None, float | None]:
        """(clip planes (K, 4) or None, storey floor or None, plane height or None) of the
        pane for an eye at height `eye_y` and the user's cut-away at `cut_y` (None: off)."""
        floor = storey_floor(self.vs, eye_y)
        top = None if floor is None else floor + CUT
        if cut_y is not None:
            top = cut_y if top is None else min(top, cut_y)
        planes = None if top is None else np.array([[0.0, -1.0, 0.0, top]])
        return planes, floor, top

    def _camera(self, floor: float | None, top: float | None) -> Camera:
        lo, hi = self.vs.lo.copy(), self.vs.hi.copy()
        if floor is not None:
            lo[1] = floor - 0.3
        if top is not None:
            hi[1] = max(min(hi[1], top), lo[1] + 1e-3 * self.vs.diagonal)
        return Camera.framing(lo, hi, direction=(-0.35, 1.0, 0.95), fov_y=40.0,
                              aspect=self.width / self.height)

    def _base(self, eye_y: float, cut_y: float | None) -> _Base:
        planes, floor, top = self.planes(eye_y, cut_y)
        key = (floor, top)
        base = self._bases.get(key)
        if base is not None:
            return base
        cam = self._camera(floor, top)
        frame = self.renderer.render(self.vs.scene, cam, clip_planes=planes,
                                     outputs=("depth", "ids"))
        scene = self.vs.scene
        ids = frame.triangle_id
        covered = ids >= 0
        inst, face = scene.split_ids(ids[covered])
        nw = np.empty((inst.size, 3))
        for i in np.unique(inst):
            sel = inst == i
            mesh = scene.instances[i].mesh
            n = self._normals.get(id(mesh))
            if n is None:
                n = self._normals[id(mesh)] = np.asarray(mesh.face_normals(), np.float64)
            m = np.linalg.inv(np.asarray(scene.instances[i].transform, np.float64)[:3, :3]).T
            nw[sel] = n[face[sel]] @ m.T
        length = np.linalg.norm(nw, axis=1)
        lam = np.abs(nw @ _LIGHT) / np.where(length > 0, length, 1.0)
        light = (SHADE_BASE + (1.0 - SHADE_BASE) * lam)[:, None]
        palette = np.array([FATE_COLORS[f] for f in Fate], np.float64)
        shades = np.stack([pack(np.clip(c * light, 0, 255).astype(np.uint8)) for c in palette])
        base = _Base(cam, cam.view_projection(self.width, self.height), frame.depth,
                     covered, inst, face, shades)
        if len(self._bases) > 8:   # a walk through many storeys: keep the memory bounded
            self._bases.clear()
        self._bases[key] = base
        return base

    def picture(self, fates: ClusterFates | None, fp_view_proj: np.ndarray, eye_y: float,
                cut_y: float | None) -> tuple[np.ndarray, dict[str, Any]]:
        """(packed (H, W) picture, info) of the pane for a first-person frame with these
        `fates` (None: every covered pixel drawn as DRAWN) and view-projection. Info: the
        outside camera's view-projection (row-major lists) and the clip plane height."""
        base = self._base(eye_y, cut_y)
        out = np.full((self.height, self.width), pack(np.array(BACKGROUND)), np.uint32)
        if fates is None:
            out[base.covered] = base.shades[Fate.DRAWN]
        else:
            if base.cluster_key is None:
                base.cluster_key = (fates.instance_key_base[base.instance]
                                    + fates.face_cluster(base.instance, base.face))
            fate = fates.fate[base.cluster_key]
            out[base.covered] = base.shades[fate, np.arange(fate.size)]
        # one line render, every fragment: a pixel's nearest fragment passes the depth test
        # (z <= depth + bias, float32, as the kernel's) iff any of its fragments does, so
        # this is the depth-tested render's mask without a second render
        lines = self.lines.render(_frustum(fp_view_proj), base.view_proj)
        hidden = lines.mask
        shown = hidden & (lines.depth <= base.depth + np.float32(_LINE_BIAS))
        out[hidden] = pack(np.array(FRUSTUM_HIDDEN_COLOR))
        out[shown] = pack(np.array(FRUSTUM_COLOR))
        _, _, top = self.planes(eye_y, cut_y)
        return out, {"view_proj": base.view_proj.tolist(), "cut": top}


def _frustum(view_proj: np.ndarray) -> np.ndarray:
    from ..pipeline.lines import frustum_segments

    return frustum_segments(view_proj)
