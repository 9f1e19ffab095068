/* Binning: setup records -> per-tile lists, in submission order, exact sizes.
 *
 * The triangle slots are cut into `chunks` contiguous ranges (one work-item each).
 *   bin_count:   each chunk lists its slots that have something to bin (live), counts
 *                their pieces per tile into its own row counts[chunk][tile], and its
 *                triangles per setup status into hist[chunk][status] (the frame's stats:
 *                the host no longer reads and counts a status byte per triangle).
 *   bin_offsets: per tile, turns the column counts[.][tile] into exclusive offsets within the
 *                tile and writes the tile's total.
 *   bin_scan_tiles: one work-item scans the tile totals into tile_start[0..tiles] and sums
 *                the status counts into summary[]; the host reads the summary (total
 *                entries, overflow, status counts) and sizes the entry buffer to fit.
 *   bin_scatter: each chunk walks its listed slots again and copies each setup record to
 *                entries[tile_start[tile] + counts[chunk][tile]++].
 * Copying whole 96-byte records (not indices) makes the raster read its tile's list
 * sequentially: with indices it chased one random cache line per entry, and on the dragon at
 * 1080p that pointer chase was most of the raster time.
 * A piece goes to the tiles of its pixel box that its edges can reach (rect_outside):
 * a thin diagonal triangle's box crosses many tiles it never touches.
 * Chunks are ordered and each writes its pieces in order, so every tile list is in
 * submission order with no atomics: deterministic, and nothing can overflow.
 *
 * Setup says per slot (tile1[t]) whether it has nothing to bin, one piece whose pixel box
 * lies in one tile (that tile: most pieces of a dense mesh), one piece over at most 2 x 2
 * tiles (which of them its edges reach), or pieces to walk: both passes handle the first
 * three from that word alone, bin_count without a branch on the first two (random from
 * slot to slot on a dense mesh) and without reading the 96-byte records; walked pieces over
 * at most 2 x 2 tiles (clipped ones) test each tile (products) instead of finding runs
 * (divisions); the 2 x 2 masks from setup: see setup.cl.
 *
 * Piece index space: 0..m-1 are the unclipped slots (Piece at pieces[t]); m + j is clipped
 * piece j (clip_pieces[j]). A clipped triangle's pieces stay at its position in the stream.
 */
#include "common.h"

/* tile1[t] (setup.cl; the encoding: common.h TILE1_*): >= 0 the one tile of an ST_RASTER
 * piece whose box lies in one tile, TILE1_NONE nothing to bin, TILE1_WALK a piece or pieces
 * to walk (FOR_SLOT_ENTRY), <= TILE1_FEW a piece over at most 2 x 2 tiles with the mask of
 * those its edges reach (FOR_FEW_TILES) */

/* Each tile of a TILE1_FEW word c, in the order FOR_SLOT_ENTRY visits them (rows, then
 * columns). BODY sees `tile`. */
#define FOR_FEW_TILES(c, BODY)                                                            \
    {                                                                                     \
        uint code_ = (uint)(TILE1_FEW - (c));                                              \
        int t0_ = (int)(code_ >> 4);                                                      \
        for (int j_ = 0; j_ < 4; ++j_) {                                                  \
            if (!(code_ & (1u << j_))) continue;                                          \
            int tile = t0_ + (j_ & 1) + (j_ >> 1) * tiles_x;                              \
            BODY                                                                          \
        }                                                                                 \
    }

inline void tile_rect(int bb_min, int bb_max, int *tx0, int *ty0, int *tx1, int *ty1)
{
    *tx0 = bb_x(bb_min) >> TILE_LOG2;
    *ty0 = bb_y(bb_min) >> TILE_LOG2;
    *tx1 = bb_x(bb_max) >> TILE_LOG2;
    *ty1 = bb_y(bb_max) >> TILE_LOG2;
}

/* The tile columns [*lo, *hi] of row ty that all three edges reach — exactly the columns
 * where rect_outside(tile ∩ box) is false. Along a row, edge_reaches tests the corner its
 * gradient points to: the tile's right end (clamped to the box) when the edge function
 * grows with x (dy < 0), its left end when it shrinks (dy > 0), and either when dy = 0.
 * So each edge's test holds on a suffix / prefix / all or none of the columns, and the
 * bound is one exact division: the first (last) pixel column where the edge function at
 * the row's test y reaches the bias, then the tile holding it. O(1) per edge and row; it
 * replaced a binary search over the columns (same columns). */
ALWAYS_INLINE void row_span(__global const Piece *pc, int ty, int *lo, int *hi)
{
    int bx0 = bb_x(pc->bb_min), bx1 = bb_x(pc->bb_max);
    int y0 = imax(bb_y(pc->bb_min), ty << TILE_LOG2);
    int y1 = imin(bb_y(pc->bb_max), ((ty + 1) << TILE_LOG2) - 1);
    for (int e = 0; e < 3 && *lo <= *hi; ++e) {
        int a = e == 0 ? 1 : (e == 1 ? 2 : 0), b = e == 0 ? 2 : (e == 1 ? 0 : 1);
        int ax = pc->x[a], ay = pc->y[a], bx = pc->x[b], by = pc->y[b];
        long dx = (long)bx - ax, dy = (long)by - ay;
        long py = ((long)(dx > 0 ? y1 : y0) << SUBPIXEL_BITS) + SUB_HALF;
        /* E at pixel column x: K - dy·256·x */
        long k = dx * (py - ay) - dy * ((long)SUB_HALF - ax) - edge_bias(ax, ay, bx, by);
        if (dy == 0) {
            if (k < 0) *hi = *lo - 1;
        } else if (dy < 0) {   /* E >= bias from pixel column xs on */
            long xs = -floor_div(k, -dy * SUB_ONE);
            if (xs > bx1) *hi = *lo - 1;
            else *lo = (int)max((long)*lo, xs >> TILE_LOG2);
        } else {               /* E >= bias up to pixel column xs */
            long xs = floor_div(k, dy * SUB_ONE);
            if (xs < bx0) *hi = *lo - 1;
            else *hi = (int)min((long)*hi, xs >> TILE_LOG2);
        }
    }
}

/* Whether the piece's edges miss every pixel centre of tile (tx, ty) ∩ its pixel box:
 * rect_outside, the test row_span answers a row at a time (common.h tile_box_outside, the
 * test setup's 2 x 2 tile masks make too). */
inline bool tile_missed(__global const Piece *pc, int tx, int ty)
{
    return tile_box_outside(pc->x[0], pc->y[0], pc->x[1], pc->y[1], pc->x[2], pc->y[2],
                            bb_x(pc->bb_min), bb_y(pc->bb_min), bb_x(pc->bb_max),
                            bb_y(pc->bb_max), tx, ty);
}

/* Copy a 96-byte record with non-temporal stores (three aligned 32-byte halves of lines:
 * records start at multiples of 96 bytes in a page-aligned buffer). */
inline void put_piece(__global Piece *dst, __global const Piece *src)
{
    __global const float8 *s8 = (__global const float8 *)src;
    __global float8 *d8 = (__global float8 *)dst;
    NT_STORE(s8[0], d8);
    NT_STORE(s8[1], d8 + 1);
    NT_STORE(s8[2], d8 + 2);
}

/* Visit every (piece, tile) pair of triangle slot t (status st) in order. BODY sees `pc`
 * (the piece) and `tile`. */
#define FOR_SLOT_ENTRY(t, st, BODY)                                                       \
    {                                                                                     \
        int first = (int)(t), count = 1;                                                  \
        if ((st) == ST_CLIPPED) { first = (int)m + clip_offset[t]; count = clip_count[t]; } \
        for (int piece = first; piece < first + count; ++piece) {                         \
            __global const Piece *pc = piece < (int)m ? &pieces[piece]                    \
                                                      : &clip_pieces[piece - (int)m];      \
            int tx0, ty0, tx1, ty1;                                                       \
            tile_rect(pc->bb_min, pc->bb_max, &tx0, &ty0, &tx1, &ty1);                    \
            bool single = tx0 == tx1 && ty0 == ty1;                                       \
            /* a box over at most 2 x 2 tiles tests each tile (rect_outside: products, no \
             * division); bigger ones find each row's run of tiles (row_span) */          \
            bool few = tx1 - tx0 <= 1 && ty1 - ty0 <= 1;                                  \
            for (int ty = ty0; ty <= ty1; ++ty) {                                         \
                int lo = tx0, hi = tx1;                                                   \
                if (!single && !few) row_span(pc, ty, &lo, &hi);                         \
                for (int tx = lo; tx <= hi; ++tx) {                                       \
                    if (few && !single && tile_missed(pc, tx, ty)) continue;              \
                    int tile = ty * tiles_x + tx;                                         \
                    BODY                                                                  \
                }                                                                         \
            }                                                                             \
        }                                                                                 \
    }

/* The chunk's triangle slots [s0, s1). */
#define CHUNK_SLOTS                                                                       \
    uint s0 = (uint)(((ulong)chunk * m) / chunks);                                        \
    uint s1 = (uint)(((ulong)(chunk + 1) * m) / chunks);

__kernel void bin_count(__global const uchar *restrict status,
                        __global const int *restrict clip_count,
                        __global const int *restrict clip_offset,
                        __global const Piece *restrict pieces,
                        __global const Piece *restrict clip_pieces, const uint m,
                        const uint chunks, const int tiles_x, const int n_tiles,
                        __global int *restrict counts, __global const int *restrict tile1,
                        __global int *restrict hist, __global int *restrict live,
                        __global int *restrict n_live)
{
    uint chunk = get_global_id(0);
    if (chunk >= chunks) return;
    __global int *row = counts + (size_t)chunk * n_tiles;
    for (int i = 0; i < n_tiles; ++i) row[i] = 0;
    /* four histograms taken in turn: with one, runs of equal statuses made a chain of
     * dependent increments of one counter */
    int h[4][8] = {{0}};
    CHUNK_SLOTS
    uint u = s0;
    for (; u + 4 <= s1; u += 4) {
        h[0][status[u] & 7] += 1;
        h[1][status[u + 1] & 7] += 1;
        h[2][status[u + 2] & 7] += 1;
        h[3][status[u + 3] & 7] += 1;
    }
    for (; u < s1; ++u) h[0][status[u] & 7] += 1;
    for (int k = 0; k < 8; ++k) hist[8 * chunk + k] = (h[0][k] + h[1][k]) + (h[2][k] + h[3][k]);
    /* The chunk's slots with something to bin (tile1 not TILE1_NONE), listed in order at
     * live[s0..] without a branch per slot: whether a slot has a piece is random from one
     * triangle to the next on a dense mesh (on the dragon at 1080p 70% have none), so a
     * branch on it was mispredicted about every other slot, and counting every slot
     * branch-free (row[0] += 0 for an empty one) chained each slot's increment to the
     * last through memory. bin_scatter walks the same list. */
    uint n = 0;
    for (uint t = s0; t < s1; ++t) {
        live[s0 + n] = (int)t;   /* n <= t - s0: inside the chunk's range */
        n += tile1[t] != TILE1_NONE;
    }
    n_live[chunk] = (int)n;
    for (uint k = s0; k < s0 + n; ++k) {
        uint t = (uint)live[k];
        int c = tile1[t];
        if (c >= 0) {
            row[c] += 1;
        } else if (c <= TILE1_FEW) {
            FOR_FEW_TILES(c, row[tile] += 1;)
        } else {
            uchar st = status[t];
            FOR_SLOT_ENTRY(t, st, row[tile] += 1;)
        }
    }
}

__kernel void bin_offsets(const uint chunks, const int n_tiles, __global int *restrict counts,
                          __global int *restrict tile_count)
{
    int tile = get_global_id(0);
    if (tile >= n_tiles) return;
    int s = 0;
    for (uint c = 0; c < chunks; ++c) {
        size_t i = (size_t)c * n_tiles + tile;
        int v = counts[i];
        counts[i] = s;
        s += v;
    }
    tile_count[tile] = s;
}

/* tile_start has n_tiles + 1 entries; tile_start[n_tiles] is the total. summary[0]: the
 * total (clamped), summary[1]: set if the total does not fit an int (the host refuses the
 * frame with an error), summary[2 + k]: triangles with setup status k (hist summed over
 * the chunks). */
__kernel void bin_scan_tiles(const int n_tiles, __global const int *restrict tile_count,
                             __global int *restrict tile_start, const uint chunks,
                             __global const int *restrict hist, __global int *restrict summary)
{
    if (get_global_id(0) != 0) return;
    long s = 0;
    for (int i = 0; i < n_tiles; ++i) {
        tile_start[i] = (int)min(s, (long)INT_MAX);
        s += tile_count[i];
    }
    tile_start[n_tiles] = (int)min(s, (long)INT_MAX);
    summary[0] = (int)min(s, (long)INT_MAX);
    summary[1] = s > (long)INT_MAX;
    for (int k = 0; k < 8; ++k) {
        int n = 0;
        for (uint c = 0; c < chunks; ++c) n += hist[8 * c + k];
        summary[2 + k] = n;
    }
}

__kernel void bin_scatter(__global const uchar *restrict status,
                          __global const int *restrict clip_count,
                          __global const int *restrict clip_offset,
                          __global const Piece *restrict pieces,
                          __global const Piece *restrict clip_pieces, const uint m,
                          const uint chunks, const int tiles_x, const int n_tiles,
                          __global int *restrict counts, __global const int *restrict tile1,
                          __global const int *restrict tile_start,
                          __global Piece *restrict entries,
                          __global const int *restrict summary, const int cap,
                          __global const int *restrict live,
                          __global const int *restrict n_live)
{
    uint chunk = get_global_id(0);
    /* entries holds cap records: a list that does not fit (summary from bin_scan_tiles)
     * writes nothing; the host reads the total afterwards and scatters again into a
     * larger buffer (clraster/pipeline/stages/bin.py BinStage.run, defer) */
    if (chunk >= chunks || BIN_LIST_OVER(summary, cap)) return;
    __global int *row = counts + (size_t)chunk * n_tiles;
    CHUNK_SLOTS
    (void)s1;
    uint n = (uint)n_live[chunk];
    for (uint k = s0; k < s0 + n; ++k) {   /* the slots bin_count listed */
        uint t = (uint)live[k];
        int c = tile1[t];
        if (c >= 0) {
            put_piece(&entries[tile_start[c] + row[c]++], &pieces[t]);
        } else if (c <= TILE1_FEW) {
            FOR_FEW_TILES(c, put_piece(&entries[tile_start[tile] + row[tile]++], &pieces[t]);)
        } else {
            uchar st = status[t];
            FOR_SLOT_ENTRY(t, st, put_piece(&entries[tile_start[tile] + row[tile]++], pc);)
        }
    }
}
