"""Boxes, as both the OpenCL side and the NumPy twin see them: the Hi-Z box test's
three-state answer (`Occlusion`) and the triangle geometry an exact occlusion query draws
(`box_geometry`).

This is a lower layer: `clraster.occlusion` and `clraster.pipeline.stages` (OpenCL) and
the NumPy twin (the reference package) all import it, and it imports neither, so the two sides never
import each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..base.layout import (
    BOX_TRIS,
    CLUSTER_MAX,
    DRAW_DTYPE,
    OCC_OCCLUDED,
    OCC_VIEW_CULLED,
    OCC_VISIBLE,
)
from .draws import FrameDraws, depth_rows

__all__ = ["BOX_FACES", "CLUSTER_BOXES", "BoxGeometry", "Occlusion", "box_corners",
           "box_geometry", "box_mesh"]

F32 = np.float32


class Occlusion(IntEnum):
    """Result of the Hi-Z test of one bounding volume (as Intel MOC's CullingResult)."""

    #: Possibly visible: the box crosses the near plane, has non-finite corners, or some
    #: pixel it may cover has depth-buffer content at or behind its nearest point.
    VISIBLE = OCC_VISIBLE
    #: Provably hidden: no pixel centre it can cover has a depth-buffer value at or beyond
    #: its nearest depth (or it covers no pixel centre at all).
    OCCLUDED = OCC_OCCLUDED
    #: All 8 corners outside one plane of the view frustum (by more than float32 error).
    VIEW_CULLED = OCC_VIEW_CULLED


#: Boxes per cluster (draw): 120 triangles and 80 vertices, within CLUSTER_MAX = 128.
CLUSTER_BOXES = CLUSTER_MAX // BOX_TRIS
#: The 12 triangles of a box over its corners, counter-clockwise seen from outside. Corner k
#: is (k & 1 ? max.x : min.x, k & 2 ? max.y : min.y, k & 4 ? max.z : min.z).
BOX_FACES = np.array([[0, 2, 1], [1, 2, 3],     # −z
                      [4, 5, 6], [5, 7, 6],     # +z
                      [0, 4, 2], [2, 4, 6],     # −x
                      [1, 3, 5], [3, 7, 5],     # +x
                      [0, 1, 4], [1, 5, 4],     # −y
                      [2, 6, 3], [3, 6, 7]],    # +y
                     np.int64)


def box_corners(mins: np.ndarray, maxs: np.ndarray) -> np.ndarray:
    """float32 (K, 8, 3) corners of boxes (K, 3), corner k as in `BOX_FACES`."""
    lo = np.asarray(mins, F32)
    hi = np.asarray(maxs, F32)
    k = np.arange(8)
    sel = np.stack([(k & 1) != 0, (k & 2) != 0, (k & 4) != 0], axis=1)  # (8, 3)
    return np.where(sel[None], hi[:, None, :], lo[:, None, :])


def box_mesh(mins: np.ndarray, maxs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices float32 (8K, 3) and faces int32 (12K, 3) of K boxes, box after box."""
    v = box_corners(mins, maxs).reshape(-1, 3)
    k = v.shape[0] // 8
    f = (np.arange(k, dtype=np.int64)[:, None, None] * 8 + BOX_FACES[None]).reshape(-1, 3)
    return np.ascontiguousarray(v), f.astype(np.int32)


@dataclass(frozen=True)
class BoxGeometry:
    """The box mesh laid out as the vertex and setup stages read a `drawlist.GeometryPool`
    (only the fields they read; the pool's culling data does not apply to boxes).

    positions: float32 (8K, 3) corners, box after box. vert_ids: int32 (8K,) identity.
    local_tris: uint8 (12K, 4) cluster-local corner indices (4th byte padding).
    face_ids: int32 (12K,) identity. clusters: int32 (C, 4) (tri_offset, n_tris,
    vert_offset, n_verts) of each cluster of `CLUSTER_BOXES` boxes.
    """

    positions: np.ndarray
    vert_ids: np.ndarray
    local_tris: np.ndarray
    face_ids: np.ndarray
    clusters: np.ndarray


def box_geometry(mins: np.ndarray, maxs: np.ndarray, view_proj: np.ndarray
                 ) -> tuple[BoxGeometry, FrameDraws]:
    """The boxes as the vertex and setup stages read them: one mesh, one instance whose
    matrix is ``view_proj`` (float32 (4, 4) row-major), clusters of `CLUSTER_BOXES` boxes
    drawn in box order, so every tile list holds each box's entries contiguously and box
    numbers never decrease along it. Triangle id = face index = 12·box + local face."""
    v, _ = box_mesh(mins, maxs)
    n_boxes = v.shape[0] // 8
    n_cl = -(-n_boxes // CLUSTER_BOXES)
    b = np.arange(n_boxes, dtype=np.int64)
    local = ((b % CLUSTER_BOXES) * 8)[:, None, None] + BOX_FACES[None]   # (K, 12, 3)
    lt = np.zeros((n_boxes * BOX_TRIS, 4), np.uint8)
    lt[:, :3] = local.reshape(-1, 3)
    c = np.arange(n_cl, dtype=np.int64)
    nb = np.minimum(CLUSTER_BOXES, n_boxes - c * CLUSTER_BOXES)
    clusters = np.stack([c * CLUSTER_BOXES * BOX_TRIS, nb * BOX_TRIS, c * CLUSTER_BOXES * 8,
                         nb * 8], axis=1).astype(np.int32)
    pool = BoxGeometry(positions=v, vert_ids=np.arange(v.shape[0], dtype=np.int32),
                       local_tris=lt, face_ids=np.arange(n_boxes * BOX_TRIS, dtype=np.int32),
                       clusters=np.ascontiguousarray(clusters))
    draws = np.zeros(n_cl, DRAW_DTYPE)
    draws["cluster"] = c
    draws["vert_base"] = clusters[:, 2]
    draws["tri_base"] = clusters[:, 0]
    mvp = np.ascontiguousarray(np.asarray(view_proj, F32).reshape(1, 16))
    # the query's values come from the float32 matrix it was given (as before float64
    # matrices reached setup): its depth test compares with a frame drawn from it
    mvp64 = mvp.astype(np.float64)
    return pool, FrameDraws(draws, int(v.shape[0]), n_boxes * BOX_TRIS, mvp, mvp64,
                            depth_rows(mvp64))
