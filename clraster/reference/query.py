"""NumPy twin of kernels/query.cl: exact occlusion queries ("samples passed") for boxes.

The boxes become a triangle mesh (`box_geometry`, which the OpenCL side draws too) that goes
through the twin's vertex, setup (cull "none") and binning stages; then every (entry, pixel)
candidate of every tile is generated in batches with the raster's exact integer coverage and
float32 depth, and a box counts a pixel once if any of its fragments there has depth LESS
than the depth buffer's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import (
    CLUSTER_MAX,
    DRAW_DTYPE,
    RasterConfig,
    guard_band_factors,
)
from ..drawlist import FrameDraws
from . import bin as bin_
from . import setup as setup_
from . import vertex as vertex_
from .raster import covered_fragments

F32 = np.float32
#: Triangles per box: box b is faces 12b .. 12b+11 (triangle id // 12 is the box).
BOX_TRIS = 12
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
    return pool, FrameDraws(draws, int(v.shape[0]), n_boxes * BOX_TRIS, mvp)


def count_samples(tile_start: np.ndarray, entries: np.ndarray, depth: np.ndarray,
                  n_boxes: int, config: RasterConfig) -> np.ndarray:
    """Twin of query_tiles: int64 (n_boxes,) pixels at which some entry of box b (entry id
    // 12) covers the pixel centre with depth < depth[pixel]."""
    height, width = depth.shape
    npx = width * height
    tile_of = np.repeat(np.arange(tile_start.size - 1), np.diff(tile_start))
    box_of = entries["id"].astype(np.int64) // BOX_TRIS
    # the kernel's ordering check: box numbers never decrease along a tile list
    if entries.size > 1:
        same_tile = tile_of[1:] == tile_of[:-1]
        if np.any(same_tile & (box_of[1:] < box_of[:-1])):
            raise RuntimeError("query: box entries are not in box order within a tile")
    dflat = depth.reshape(-1)
    keys = []
    for owner, pix, z, _pc in covered_fragments(tile_start, entries, width, height, config):
        ok = z < dflat[pix]
        keys.append(np.unique(box_of[owner[ok]] * npx + pix[ok]))
    if not keys:
        return np.zeros(n_boxes, np.int64)
    uniq = np.unique(np.concatenate(keys))
    return np.bincount(uniq // npx, minlength=n_boxes).astype(np.int64)


def samples_passed(depth: np.ndarray, mins: np.ndarray, maxs: np.ndarray,
                   view_proj: np.ndarray, config: RasterConfig | None = None) -> np.ndarray:
    """Exact occlusion query, NumPy twin of `clraster.occlusion.query`'s samples.

    Args:
        depth: float32 (H, W) depth buffer (window depth, 1.0 = clear), only read.
        mins, maxs: (K, 3) world-space box corners. view_proj: float32 (4, 4) row-major
            world → clip matrix (clip = VP · [p, 1]).
        config: tile size for binning; it never changes the counts.

    Returns:
        int64 (K,): per box, the pixels whose centre some (near-clipped) triangle of the
        box covers with window depth strictly less than ``depth`` there.
    """
    depth = np.asarray(depth)
    if depth.dtype != np.float32 or depth.ndim != 2 or depth.size == 0:
        raise ValueError(f"depth must be a non-empty float32 (H, W) array, got {depth.dtype} "
                         f"{depth.shape}")
    config = config or RasterConfig()
    height, width = depth.shape
    n_boxes = int(np.asarray(mins).shape[0])
    if n_boxes == 0:
        return np.zeros(0, np.int64)
    pool, fd = box_geometry(mins, maxs, view_proj)
    kx, ky = guard_band_factors(width, height)
    clip, oc, win = vertex_.transform_draws(pool, fd, kx, ky, width, height)
    tri_verts, ids = setup_.draw_triangles(pool, fd)
    st = setup_.setup(clip, oc, win, tri_verts, ids, width, height, "none", kx, ky)
    order = bin_.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = bin_.bin_pieces(allp, order, width, height, config)
    return count_samples(tile_start, entries, depth, n_boxes, config)
