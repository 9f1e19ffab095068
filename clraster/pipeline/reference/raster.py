"""NumPy twin of kernels/raster.cl: per-tile z-buffer raster over the bin lists.

Every (entry, pixel) candidate of a tile is generated at once (in batches), coverage and
depth use the kernel's exact integer edge functions and float32 operations, and the
sequential depth test — LESS, equal depth won by the lower triangle id — is reproduced with a
segmented running minimum of (depth, id) keys over fragments sorted by (pixel, list position).
"""

from __future__ import annotations

import numpy as np

from ...base.config import RasterConfig
from ...base.layout import PF_CLIPPED, PF_INDEX_SHIFT, PF_SWAPPED, SUBPIXEL_BITS, SUBPIXEL_ONE

F32 = np.float32
_BATCH = 1 << 22  # candidate pixels per batch (memory bound, not a semantic limit)


def _edge(ax, ay, bx, by, px, py):
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


def _bias(ax, ay, bx, by):
    dx, dy = bx - ax, by - ay
    return np.where((dy < 0) | ((dy == 0) & (dx > 0)), 0, 1)


def _ordered(z: np.ndarray) -> np.ndarray:
    """float32 → int64 whose order is the float order (−0.0 treated as +0.0)."""
    b = np.where(z == 0, F32(0), z).view(np.int32).astype(np.int64)
    return np.where(b < 0, -(b & 0x7FFFFFFF), b)


def _key(z: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """int64 keys ordered as the depth test orders (depth, id): depth first, then id.
    ids are −1 for the clear value, which only loses to a strictly nearer depth."""
    return ((_ordered(z) + (1 << 31)) << 31) | (ids.astype(np.int64) + 1)


def edges_at(pc: np.ndarray, px: np.ndarray, py: np.ndarray):
    """Edge functions E0, E1, E2 (int64) of pieces ``pc`` at fixed-point points."""
    X = pc["x"].astype(np.int64)
    Y = pc["y"].astype(np.int64)
    e0 = _edge(X[:, 1], Y[:, 1], X[:, 2], Y[:, 2], px, py)
    e1 = _edge(X[:, 2], Y[:, 2], X[:, 0], Y[:, 0], px, py)
    e2 = _edge(X[:, 0], Y[:, 0], X[:, 1], Y[:, 1], px, py)
    return e0, e1, e2


def covered_fragments(tile_start: np.ndarray, entries: np.ndarray, width: int, height: int,
                      config: RasterConfig):
    """Every covered pixel centre of the binned entries, batch by batch in entry order.

    Each (entry, pixel) candidate of the entry's box ∩ its tile is tested with the kernels'
    exact edge functions and top-left rule; depth is the kernels' float32 expression.

    Yields:
        (entry index int64 (F,), pixel index y·W + x int64 (F,), depth float32 (F,),
        records PIECE_DTYPE (F,)) for the covered fragments of a batch of entries.
    """
    s = config.tile_log2
    tiles_x, _ = config.tiles(width, height)
    tile_of = np.repeat(np.arange(tile_start.size - 1), np.diff(tile_start))
    tx0 = (tile_of % tiles_x) << s
    ty0 = (tile_of // tiles_x) << s
    x0 = np.maximum(entries["bb_min"] & 0xFFFF, tx0)
    y0 = np.maximum(entries["bb_min"] >> 16, ty0)
    x1 = np.minimum(np.minimum(entries["bb_max"] & 0xFFFF, tx0 + (1 << s) - 1), width - 1)
    y1 = np.minimum(np.minimum(entries["bb_max"] >> 16, ty0 + (1 << s) - 1), height - 1)
    nx = np.maximum(x1 - x0 + 1, 0).astype(np.int64)
    ny = np.maximum(y1 - y0 + 1, 0).astype(np.int64)
    cnt = np.where((nx > 0) & (ny > 0), nx * ny, 0)
    csum = np.cumsum(cnt)
    start = 0
    while start < entries.size:
        # entries [start, stop) hold at most _BATCH candidates (at least one entry)
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + _BATCH, side="right")), start + 1)
        c = cnt[start:stop]
        owner = np.repeat(np.arange(start, stop), c)
        local = np.arange(owner.size) - np.repeat(np.cumsum(c) - c, c)
        px_i = x0[owner] + local % nx[owner]
        py_i = y0[owner] + local // nx[owner]
        pc = entries[owner]
        fx = (px_i.astype(np.int64) << SUBPIXEL_BITS) + SUBPIXEL_ONE // 2
        fy = (py_i.astype(np.int64) << SUBPIXEL_BITS) + SUBPIXEL_ONE // 2
        e0, e1, e2 = edges_at(pc, fx, fy)
        X, Y = pc["x"].astype(np.int64), pc["y"].astype(np.int64)
        cov = ((e0 >= _bias(X[:, 1], Y[:, 1], X[:, 2], Y[:, 2]))
               & (e1 >= _bias(X[:, 2], Y[:, 2], X[:, 0], Y[:, 0]))
               & (e2 >= _bias(X[:, 0], Y[:, 0], X[:, 1], Y[:, 1])))
        owner, pc = owner[cov], pc[cov]
        pix = py_i[cov].astype(np.int64) * width + px_i[cov]
        # depth plane relative to the piece's reference pixel (setup.cl value_planes)
        fx = (px_i[cov] - (pc["bb_min"] & 0xFFFF)).astype(F32)
        fy = (py_i[cov] - (pc["bb_min"] >> 16)).astype(F32)
        z = (pc["z0"] + pc["dzdy"] * fy) + pc["dzdx"] * fx
        # never nearer than the nearest vertex, as the kernels (layout.py PIECE_DTYPE)
        z = np.maximum(z, pc["zlo"])
        yield owner, pix, z, pc
        start = stop


def raster(clip_bary: np.ndarray, tile_start: np.ndarray, entries: np.ndarray, width: int,
           height: int, config: RasterConfig,
           into: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
           window: np.ndarray | None = None):
    """Rasterize binned pieces.

    Args:
        clip_bary: float32 (P, 3, 3) parent barycentrics of clipped pieces.
        tile_start: int32 (T + 1,). entries: PIECE_DTYPE (E,) records, tile-major.
        into: (depth, ids, bary) of an earlier pass over the same image to continue from,
            as raster_tiles with ``load``: their depth and ids take part in the depth test
            as if drawn in this pass, and pixels nobody beats keep their values (two-phase
            occlusion culling). Not modified. None: start from the clear values.
        window: uint8/bool (H, W) polygon window mask (`clraster.window`) or None: as
            raster_tiles with use_window, tiles the window lets no pixel of are not
            rasterized at all, and in the others fragments at shut pixels are tested
            (counted) but never pass.

    Returns:
        depth float32 (H, W), ids int32 (H, W), bary float32 (H, W, 3),
        fragments tested, fragments passed.
    """
    npx = width * height
    win = np.full(npx, -1, np.int64)
    if into is None:
        zbuf = np.ones(npx, F32)
        wid = np.full(npx, -1, np.int64)  # winning id (−1: clear value)
    else:
        zbuf = np.array(into[0], F32).reshape(npx)
        wid = into[1].reshape(npx).astype(np.int64)
    tested = passed = 0
    hiz = config.tile_hiz and entries.size > 0
    if hiz:   # what the tile Hi-Z decisions need (hiz_skipped)
        covered = np.zeros(entries.size, np.int64)   # fragments tested per entry, no Hi-Z
        zbuf0 = zbuf.copy()
    events: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []   # depth-test passes
    open_px = shut = None
    if window is not None:
        shut = ~np.asarray(window, bool).reshape(npx)
        t = config.tile_size
        ty, tx = -(-height // t), -(-width // t)
        pad = np.zeros((ty * t, tx * t), bool)
        pad[:height, :width] = ~shut.reshape(height, width)
        tile_open = pad.reshape(ty, t, tx, t).any(axis=(1, 3))
        open_px = np.repeat(np.repeat(tile_open, t, 0), t, 1)[:height, :width].reshape(npx)

    for owner, pix, z, pc in covered_fragments(tile_start, entries, width, height, config):
        if open_px is not None:
            keep = open_px[pix]             # tiles the window shuts are not rasterized
            owner, pix, z, pc = owner[keep], pix[keep], z[keep], pc[keep]
        tested += z.size
        if hiz and z.size:
            lo = int(owner.min())
            bc = np.bincount(owner - lo)
            covered[lo:lo + bc.size] += bc
        if shut is not None:                # tested, but never passing (-inf depth)
            keep = ~shut[pix]
            owner, pix, z, pc = owner[keep], pix[keep], z[keep], pc[keep]
        # sequential LESS in list order == segmented running min over (pixel, entry index)
        srt = np.lexsort((owner, pix))
        pix, z, owner = pix[srt], z[srt], owner[srt]
        ids = pc["id"][srt]
        # Ranks of the keys (fragments and the z-buffer before this batch) keep the order
        # and fit 24 bits, so a per-segment offset lets one minimum.accumulate restart at
        # every pixel (offsets decrease along the sorted pixels).
        keys = np.concatenate([_key(z, ids), _key(zbuf[pix], wid[pix])])
        rank = np.unique(keys, return_inverse=True)[1].reshape(-1).astype(np.int64)
        rk, rbuf = rank[:pix.size], rank[pix.size:]
        first = np.ones(pix.size, bool)
        first[1:] = pix[1:] != pix[:-1]
        seg_off = (npx - pix) << 24
        incl = np.minimum.accumulate(rk + seg_off) - seg_off
        prev = np.empty_like(incl)
        prev[1:] = incl[:-1]
        prev[first] = np.iinfo(np.int64).max
        prev = np.minimum(prev, rbuf)
        ok = rk < prev
        passed += int(ok.sum())
        pix_ok, z_ok, own_ok, id_ok = pix[ok], z[ok], owner[ok], ids[ok]
        if hiz:
            events.append((pix_ok, own_ok, z_ok))
        last = np.ones(pix_ok.size, bool)
        last[:-1] = pix_ok[1:] != pix_ok[:-1]
        zbuf[pix_ok[last]] = z_ok[last]
        win[pix_ok[last]] = own_ok[last]
        wid[pix_ok[last]] = id_ok[last]

    if hiz:
        if shut is not None:
            zbuf0[shut] = -np.inf      # as raster.cl: shut pixels never count as farthest
        skip = hiz_skipped(tile_start, entries, width, height, config, zbuf0, events)
        tested -= int(covered[skip].sum())

    if into is None:
        ids = np.full(npx, -1, np.int32)
        bary = np.zeros((npx, 3), F32)
    else:   # the earlier pass's winners stay where nothing of this pass beat them
        ids = into[1].reshape(npx).astype(np.int32)
        bary = np.array(into[2], F32).reshape(npx, 3)
    hit = np.nonzero(win >= 0)[0]
    if hit.size:
        pc = entries[win[hit]]
        # screen-space weights from the unsnapped value planes (setup.cl value_planes)
        fx = ((hit % width) - (pc["bb_min"] & 0xFFFF)).astype(F32)
        fy = ((hit // width) - (pc["bb_min"] >> 16)).astype(F32)
        l1 = (pc["l1"] + pc["l1x"] * fx) + pc["l1y"] * fy
        l2 = (pc["l2"] + pc["l2x"] * fx) + pc["l2y"] * fy
        l0 = (F32(1) - l1) - l2
        q1, q2 = l1 * pc["r1"], l2 * pc["r2"]
        ssum = (l0 + q1) + q2
        inv = F32(1) / ssum   # raster.cl: one division, three products
        c = np.stack([l0 * inv, q1 * inv, q2 * inv], axis=1)
        clipped = (pc["flags"] & PF_CLIPPED) != 0
        swapped = ((pc["flags"] & PF_SWAPPED) != 0) & ~clipped
        c[swapped] = c[swapped][:, [0, 2, 1]]
        if clipped.any():
            # (K, 3 piece vertices, 3 parent weights)
            pb = clip_bary[pc["flags"][clipped] >> PF_INDEX_SHIFT]
            cc = c[clipped]
            c[clipped] = ((cc[:, 0:1] * pb[:, 0] + cc[:, 1:2] * pb[:, 1])
                          + cc[:, 2:3] * pb[:, 2])
        bary[hit] = c
        ids[hit] = pc["id"]
    return (zbuf.reshape(height, width), ids.reshape(height, width),
            bary.reshape(height, width, 3), tested, passed)


def hiz_skipped(tile_start: np.ndarray, entries: np.ndarray, width: int, height: int,
                config: RasterConfig, zbuf0: np.ndarray,
                events: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """The entries raster.cl's tile Hi-Z skips: those whose nearest depth (``zlo``) is
    farther than the farthest depth of their tile just before them.

    A skipped entry passes nowhere, so the depth history of the run without skipping is
    the kernel's: each pixel holds its start value until its first depth-test pass, then
    each pass's depth until the next. A value held until entry b (it is there when b is
    tested) is a *segment* ending at b. Depths only decrease, so the farthest depth of a
    tile before entry k is the largest value of its segments that end at k or later (any
    such segment's pixel holds at least that value before k): a suffix maximum over each
    tile's entries, taken for all tiles at once with a per-tile offset.

    Args:
        tile_start: int32 (T + 1,); entries: PIECE_DTYPE (E,), tile-major.
        zbuf0: float32 (H·W,) depths before the pass (the clear value, an earlier pass's
            depth, −inf at pixels a window shuts).
        events: per batch, the passes (pixel int64, entry int64, depth float32), sorted by
            pixel then entry within the batch; batches in entry order.

    Returns:
        bool (E,): True for the entries the kernel skips.
    """
    s = config.tile_log2
    tiles_x, _ = config.tiles(width, height)
    n_tiles = tile_start.size - 1
    if events:
        pix = np.concatenate([e[0] for e in events])
        own = np.concatenate([e[1] for e in events])
        val = np.concatenate([e[2] for e in events])
        o = np.lexsort((own, pix))
        pix, own, val = pix[o], own[o], val[o]
    else:
        pix = own = np.zeros(0, np.int64)
        val = np.zeros(0, F32)
    npx = zbuf0.size
    big = np.iinfo(np.int64).max
    # the entry each value is last held for: the next pass at its pixel, or the end
    same = np.zeros(pix.size, bool)
    same[:-1] = pix[1:] == pix[:-1]
    ev_end = np.where(same, np.append(own[1:], 0), big)
    first = np.full(npx, big, np.int64)
    starts = np.ones(pix.size, bool)
    starts[1:] = ~same[:-1]
    first[pix[starts]] = own[starts]
    seg_pix = np.concatenate([np.arange(npx, dtype=np.int64), pix])
    seg_val = np.concatenate([zbuf0.astype(F32), val])
    seg_end = np.concatenate([first, ev_end])
    x, y = seg_pix % width, seg_pix // width
    tile = (y >> s) * tiles_x + (x >> s)
    last = tile_start[tile + 1].astype(np.int64) - 1   # the tile's last entry
    has = last >= tile_start[tile]
    seg_end = np.minimum(seg_end[has], last[has])
    # ordered depth keys, offset so that a lower tile's keys exceed every higher tile's
    # (the suffix maximum restarts at each tile's last entry)
    off = (np.int64(n_tiles) - tile[has]) << 33
    acc = np.full(entries.size, np.iinfo(np.int64).min, np.int64)
    np.maximum.at(acc, seg_end, _ordered(seg_val[has]) + off)
    acc = np.maximum.accumulate(acc[::-1])[::-1]
    entry_tile = np.repeat(np.arange(n_tiles, dtype=np.int64), np.diff(tile_start))
    farthest = acc - ((np.int64(n_tiles) - entry_tile) << 33)
    return _ordered(entries["zlo"]) > farthest
