"""NumPy twin of kernels/bin.cl: per-tile lists of setup records in submission order."""

from __future__ import annotations

import numpy as np

from ...base.config import RasterConfig
from ...base.layout import ST_CLIPPED, ST_RASTER, SUBPIXEL_BITS, SUBPIXEL_ONE
from ..params import BinBudgetExceeded


def unified_order(status: np.ndarray, clip_count: np.ndarray, clip_offset: np.ndarray
                  ) -> np.ndarray:
    """Piece indices (unified space: t for slot t, M + j for clipped piece j) in submission
    order: by triangle, and by fan position within a clipped triangle."""
    m = status.size
    raster = np.nonzero(status == ST_RASTER)[0]
    clipped = np.nonzero((status == ST_CLIPPED) & (clip_count > 0))[0]
    cnt = clip_count[clipped]
    owner = np.repeat(clipped, cnt)
    sub = np.arange(owner.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    cpiece = m + clip_offset[owner] + sub
    tri = np.concatenate([raster, owner])
    sub_all = np.concatenate([np.zeros(raster.size, np.int64), sub])
    piece = np.concatenate([raster, cpiece]).astype(np.int64)
    order = np.lexsort((sub_all, tri))
    return piece[order]


def _edge_reaches(ax, ay, bx, by, x0, y0, x1, y1) -> np.ndarray:
    """edge_reaches in kernels/common.h, vectorized (int64)."""
    dx, dy = bx - ax, by - ay
    px = (np.where(dy < 0, x1, x0).astype(np.int64) << SUBPIXEL_BITS) + SUBPIXEL_ONE // 2
    py = (np.where(dx > 0, y1, y0).astype(np.int64) << SUBPIXEL_BITS) + SUBPIXEL_ONE // 2
    e = dx * (py - ay) - dy * (px - ax)
    bias = np.where((dy < 0) | ((dy == 0) & (dx > 0)), 0, 1)
    return e >= bias


def rect_outside(X: np.ndarray, Y: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    """rect_outside in kernels/common.h: X, Y int (K, 3) fixed-point vertices, pixel
    rectangles [x0, x1] × [y0, y1] (K,)."""
    X, Y = X.astype(np.int64), Y.astype(np.int64)
    out = np.zeros(X.shape[0], bool)
    for a, b in ((1, 2), (2, 0), (0, 1)):
        out |= ~_edge_reaches(X[:, a], Y[:, a], X[:, b], Y[:, b], x0, y0, x1, y1)
    return out


def bin_pieces(pieces: np.ndarray, order: np.ndarray, width: int, height: int,
               config: RasterConfig, max_entries: int | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Bin pieces into tiles.

    Args:
        pieces: PIECE_DTYPE (M + P,) unified piece array (slots, then clipped pieces).
        order: int64 (K,) indices of the live pieces in submission order (`unified_order`).
        max_entries: as bin.cl's host side: more (piece, tile) pairs than this raise
            `clraster.pipeline.params.BinBudgetExceeded` before the records are gathered
            (None: no limit).

    Returns:
        tile_start int32 (T + 1,) and entries PIECE_DTYPE (E,) (copies of the records),
        tile-major, submission order within each tile — what kernels/bin.cl produces.
    """
    owner, tile = piece_tiles(pieces, order, width, height, config)
    if max_entries is not None and owner.size > max_entries:
        raise BinBudgetExceeded(owner.size, max_entries)
    tiles_x, tiles_y = config.tiles(width, height)
    srt = np.argsort(tile, kind="stable")
    entries = pieces[order[owner[srt]]]
    counts = np.bincount(tile, minlength=tiles_x * tiles_y)
    if counts.sum() > np.iinfo(np.int32).max:
        raise ValueError("binning would need more than 2**31 entries; use larger tiles")
    tile_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    return tile_start, entries


def piece_tiles(pieces: np.ndarray, order: np.ndarray, width: int, height: int,
                config: RasterConfig) -> tuple[np.ndarray, np.ndarray]:
    """The (piece, tile) pairs of `bin_pieces`, the count step of kernels/bin.cl: int64
    (E,) positions in ``order`` and int64 (E,) tiles, piece by piece in submission order
    and each piece's tiles row by row."""
    bb_min, bb_max = pieces["bb_min"][order], pieces["bb_max"][order]
    tiles_x, tiles_y = config.tiles(width, height)
    s = config.tile_log2
    tx0, ty0 = (bb_min & 0xFFFF) >> s, (bb_min >> 16) >> s
    tx1, ty1 = (bb_max & 0xFFFF) >> s, (bb_max >> 16) >> s
    nx, ny = (tx1 - tx0 + 1).astype(np.int64), (ty1 - ty0 + 1).astype(np.int64)
    cnt = nx * ny
    owner = np.repeat(np.arange(order.size), cnt)
    local = np.arange(owner.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    # per piece, tiles are visited row by row (ty outer, tx inner) as in the kernel
    tile = (ty0[owner] + local // nx[owner]) * tiles_x + tx0[owner] + local % nx[owner]
    # keep only tiles whose (tile ∩ box) pixel centres the edges can reach (rect_outside in
    # kernels/common.h); single-tile pieces are kept as they are, as in the kernel
    single = (nx * ny == 1)[owner]
    tx = tile % tiles_x
    ty = tile // tiles_x
    x0 = np.maximum(bb_min[owner] & 0xFFFF, tx << s)
    y0 = np.maximum(bb_min[owner] >> 16, ty << s)
    x1 = np.minimum(bb_max[owner] & 0xFFFF, ((tx + 1) << s) - 1)
    y1 = np.minimum(bb_max[owner] >> 16, ((ty + 1) << s) - 1)
    keep = single | ~rect_outside(pieces["x"][order][owner], pieces["y"][order][owner],
                                  x0, y0, x1, y1)
    return owner[keep], tile[keep]
