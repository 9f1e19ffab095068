"""NumPy twin of kernels/query.cl: exact occlusion queries ("samples passed") for boxes.

The boxes become a triangle mesh (`clraster.pipeline.boxes.box_geometry`, which the OpenCL
side draws too) that goes through the twin's vertex, setup (cull "none") and binning stages;
then every (entry, pixel) candidate of every tile is generated in batches with the raster's
exact
integer coverage and float32 depth, and a box counts a pixel once if any of its fragments
there has depth LESS than the depth buffer's.
"""

from __future__ import annotations

import numpy as np

from ...base.config import RasterConfig, guard_band_factors
from ...base.layout import BOX_TRIS  # box b is faces 12b .. 12b+11 (triangle id // 12 is the box)

# the box geometry is shared with the OpenCL side (clraster.pipeline.boxes); re-exported here
from ..boxes import (  # noqa: F401
    BOX_FACES,
    CLUSTER_BOXES,
    BoxGeometry,
    box_corners,
    box_geometry,
    box_mesh,
)
from . import bin as bin_
from . import setup as setup_
from . import vertex as vertex_
from .raster import covered_fragments

F32 = np.float32


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
    st = setup_.setup(clip, oc, win, tri_verts, ids, width, height, "none", kx, ky,
                      setup_.object_clip(pool, fd))
    order = bin_.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = bin_.bin_pieces(allp, order, width, height, config)
    return count_samples(tile_start, entries, depth, n_boxes, config)
