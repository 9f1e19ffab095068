/* Tile raster: one work-item per segment of a row of screen tiles (raster_tiles); each tile
 * walks its bin list in submission order.
 *
 * Per entry: intersect the piece's pixel box with the tile and find the covered pixel
 * centres exactly (top-left rule via edge_bias): from the coverage bits setup found for a
 * box of at most 4 x 4 centres (Piece.cover) when few of them lie in the tile, else from
 * three exact 64-bit edge functions, a row's run or its blocks of eight columns at a time;
 * interpolate window depth linearly in screen space from the piece's depth plane (set up
 * from the unsnapped vertices) and depth-test LESS against the tile's private z-buffer
 * (equal depth: the lower triangle id wins, i.e. first drawn in id order). Only the
 * winning entry per pixel is kept; depth, id and perspective-correct barycentrics
 * (relative to the parent triangle's vertices) are resolved once at the end. With hiz, an entry whose nearest depth is behind the tile's
 * farthest depth is skipped untested (tile Hi-Z, see raster_tile). A tile whose list is one
 * wide piece, drawn into cleared outputs, goes row by row without the private buffers
 * (sole_piece_tile: the interior of a large triangle).
 *
 * Depth arithmetic is spelled out operation by operation; clraster/pipeline/reference/raster.py
 * does the same float32 operations, so both z-buffers and hence the triangle ids agree exactly.
 */
#include "common.h"

#if TILE_SIZE < 8
#error "the raster works in blocks of eight columns of a tile row: TILE_LOG2 >= 3"
#endif
/* Tunables of the edge-function path, -D options from clraster/base/config.py (speed only:
 * any value gives the same fragments). WIDE_RUN: a piece spanning at least WIDE_RUN columns
 * of a tile (x1 - x0 >= WIDE_RUN) finds each row's run by division (edge_columns); a
 * narrower one tests its edges in lanes. TRIM_ROWS: a piece over at least TRIM_ROWS rows of
 * a tile first narrows its rows. */
#if !defined(WIDE_RUN) || !defined(TRIM_ROWS)
#error "WIDE_RUN and TRIM_ROWS come from clraster.base.config (RasterConfig.build_options)"
#endif
#define LANE8 ((int8)(0, 1, 2, 3, 4, 5, 6, 7))

/* Counting the true lanes (-1) of int8 masks: LANE_COUNTER(c) declares counter c,
 * COUNT_LANES(c, mask) adds a mask's, LANE_TOTAL(c) is the int total. On PoCL an int8 of
 * per-lane counts, summed once per piece (cheaper than a count through memory per block).
 * Oclgrind (CLRASTER_PORTABLE) evaluates the vector form wrong — every true lane counted
 * 255 (its zero-extension of an i1 vector, by all appearances) — so there the mask goes
 * through memory. */
#ifdef CLRASTER_PORTABLE
#define LANE_COUNTER(c) int c = 0
#define COUNT_LANES(c, mask)                                                              \
    do {                                                                                  \
        int m_[8] __attribute__((aligned(32)));                                           \
        *(int8 *)m_ = (mask);                                                             \
        for (int j_ = 0; j_ < 8; ++j_) c += m_[j_] != 0;                                  \
    } while (0)
#define LANE_TOTAL(c) (c)
#else
#define LANE_COUNTER(c) int8 c = (int8)(0)
#define COUNT_LANES(c, mask) (c -= (mask))
#define LANE_TOTAL(c) lane_sum(c)
#endif

inline int lane_sum(int8 v)
{
    int4 v4 = v.lo + v.hi;
    int2 v2 = v4.lo + v4.hi;
    return v2.x + v2.y;
}

/* Narrow [*lo, *hi] (tile-local columns) to the columns lx where the edge value (less its
 * bias: PieceEdges) r + lx·s is >= 0. The value is linear in lx: if both ends of the run are
 * inside (outside), all of it is; otherwise the edge crosses the run (so s != 0) and the
 * bound is one exact integer division, which lies inside the run. */
inline void edge_columns(long r, long s, int *lo, int *hi)
{
    bool in_lo = r + (long)*lo * s >= 0, in_hi = r + (long)*hi * s >= 0;
    if (in_lo && in_hi) return;
    if (!in_lo && !in_hi) { *hi = *lo - 1; return; }
    if (s > 0)   /* inside from lx = ceil(-r / s) on */
        *lo = (int)-floor_div(r, s);
    else         /* inside up to lx = floor(r / -s) */
        *hi = (int)floor_div(r, -s);
}

/* an entry with setup's cover bits takes the one-centre-at-a-time path (cover_fragments)
 * when at most this many of its centres lie in the tile (raster_tile) */
#define COVER_FRAGMENTS 4

/* The set bits of a 16-bit mask m. Oclgrind's interpreter has no llvm.ctpop, which Clang
 * makes of popcount() and of loops that count bits, so there (CLRASTER_PORTABLE) the
 * nibbles are looked up instead. */
ALWAYS_INLINE uint bits16(uint m)
{
#ifdef CLRASTER_PORTABLE
    const uchar n4[16] = {0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4};
    return (uint)n4[m & 15] + n4[(m >> 4) & 15] + n4[(m >> 8) & 15] + n4[(m >> 12) & 15];
#else
    return popcount(m);
#endif
}

/* Perspective-correct barycentrics of pixel (x, y) of piece pc, relative to its parent
 * triangle's vertices: screen-space weights from the unsnapped value planes (setup.cl),
 * weighted by the perspective ratios, one division (the reciprocal of their sum, not three
 * chained divisions, whose latency was the resolve's cost; the twin multiplies by the same
 * reciprocal), then through the clipped piece's parent barycentrics or its vertex swap. */
ALWAYS_INLINE void resolve1(__global const Piece *pc, int x, int y,
                            __global const float *clip_bary, float *B0, float *B1, float *B2)
{
    float fx = (float)(x - bb_x(pc->bb_min)), fy = (float)(y - bb_y(pc->bb_min));
    float l1 = (pc->l1 + pc->l1x * fx) + pc->l1y * fy;
    float l2 = (pc->l2 + pc->l2x * fx) + pc->l2y * fy;
    float l0 = (1.0f - l1) - l2;
    float q1 = l1 * pc->r1, q2 = l2 * pc->r2;
    float s = (l0 + q1) + q2;
    float inv = 1.0f / s;
    float c0 = l0 * inv, c1 = q1 * inv, c2 = q2 * inv;
    if (pc->flags & PF_CLIPPED) {
        __global const float *pb = clip_bary + 9 * (pc->flags >> PF_INDEX_SHIFT);
        *B0 = (c0 * pb[0] + c1 * pb[3]) + c2 * pb[6];
        *B1 = (c0 * pb[1] + c1 * pb[4]) + c2 * pb[7];
        *B2 = (c0 * pb[2] + c1 * pb[5]) + c2 * pb[8];
    } else if (pc->flags & PF_SWAPPED) {
        *B0 = c0; *B1 = c2; *B2 = c1;
    } else {
        *B0 = c0; *B1 = c1; *B2 = c2;
    }
}

/* resolve1 for the eight pixels (x .. x + 7, y) of one piece, in float8 lanes with the same
 * operations in the same order; out: their 24 interleaved barycentrics. */
ALWAYS_INLINE void resolve8(__global const Piece *pc, int x, int y,
                            __global const float *clip_bary, float *out)
{
    int8 xs = (int8)(x - bb_x(pc->bb_min)) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    float8 fx = CONVERT_VEC(xs, float8);
    float fy = (float)(y - bb_y(pc->bb_min));
    float8 l1 = ((float8)(pc->l1) + (float8)(pc->l1x) * fx) + (float8)(pc->l1y * fy);
    float8 l2 = ((float8)(pc->l2) + (float8)(pc->l2x) * fx) + (float8)(pc->l2y * fy);
    float8 l0 = ((float8)(1.0f) - l1) - l2;
    float8 q1 = l1 * (float8)(pc->r1), q2 = l2 * (float8)(pc->r2);
    float8 s = (l0 + q1) + q2;
    float8 inv = (float8)(1.0f) / s;
    float8 c0 = l0 * inv, c1 = q1 * inv, c2 = q2 * inv;
    float8 B0, B1, B2;
    if (pc->flags & PF_CLIPPED) {
        __global const float *pb = clip_bary + 9 * (pc->flags >> PF_INDEX_SHIFT);
        B0 = (c0 * pb[0] + c1 * pb[3]) + c2 * pb[6];
        B1 = (c0 * pb[1] + c1 * pb[4]) + c2 * pb[7];
        B2 = (c0 * pb[2] + c1 * pb[5]) + c2 * pb[8];
    } else if (pc->flags & PF_SWAPPED) {
        B0 = c0; B1 = c2; B2 = c1;
    } else {
        B0 = c0; B1 = c1; B2 = c2;
    }
    float b0[8] __attribute__((aligned(32))), b1[8] __attribute__((aligned(32)));
    float b2[8] __attribute__((aligned(32)));
    *(float8 *)b0 = B0; *(float8 *)b1 = B1; *(float8 *)b2 = B2;
    for (int k = 0; k < 8; ++k) {
        out[3 * k] = b0[k]; out[3 * k + 1] = b1[k]; out[3 * k + 2] = b2[k];
    }
}

/* resolve1 for the eight pixels (x .. x + 7, y) whose winners are w[0..7] (entry indices,
 * -1: none, barycentrics 0), none of them clipped, in float8 lanes: each lane's record
 * fields gathered (a background lane reads another lane's record and is zeroed), then
 * resolve1's operations in its order, so the same bits. Pixels of a dense mesh have
 * different winners in most blocks of eight, which resolve8 cannot take: one at a time,
 * the division's latency was the resolve's cost. */
ALWAYS_INLINE void resolve8_mixed(__global const Piece *entries, const int *w, int x, int y,
                                  float *out)
{
    int any = w[0];
    for (int k = 1; k < 8; ++k) any = any >= 0 ? any : w[k];
    if (any < 0) {   /* background only: no record to read */
        for (int k = 0; k < 24; ++k) out[k] = 0.0f;
        return;
    }
    __global const Piece *p[8];
    for (int k = 0; k < 8; ++k) p[k] = &entries[w[k] >= 0 ? w[k] : any];
#define G8(f) ((float8)(p[0]->f, p[1]->f, p[2]->f, p[3]->f, p[4]->f, p[5]->f, p[6]->f, p[7]->f))
#define G8I(f) ((int8)(p[0]->f, p[1]->f, p[2]->f, p[3]->f, p[4]->f, p[5]->f, p[6]->f, p[7]->f))
    int8 bbmin = G8I(bb_min), fl = G8I(flags);
    int8 live = *(const int8 *)w >= (int8)(0);
    float8 fx = CONVERT_VEC((int8)(x) + LANE8 - (bbmin & (int8)(0xFFFF)), float8);
    float8 fy = CONVERT_VEC((int8)(y) - (bbmin >> 16), float8);
    float8 l1 = (G8(l1) + G8(l1x) * fx) + G8(l1y) * fy;
    float8 l2 = (G8(l2) + G8(l2x) * fx) + G8(l2y) * fy;
    float8 l0 = ((float8)(1.0f) - l1) - l2;
    float8 q1 = l1 * G8(r1), q2 = l2 * G8(r2);
#undef G8
#undef G8I
    float8 s = (l0 + q1) + q2;
    float8 inv = (float8)(1.0f) / s;
    float8 c0 = l0 * inv, c1 = q1 * inv, c2 = q2 * inv;
    int8 sw = (fl & (int8)(PF_SWAPPED)) != (int8)(0);
    float8 zero = (float8)(0.0f);
    float8 B0 = live ? c0 : zero;
    float8 B1 = live ? (sw ? c2 : c1) : zero;
    float8 B2 = live ? (sw ? c1 : c2) : zero;
    float b0[8] __attribute__((aligned(32))), b1[8] __attribute__((aligned(32)));
    float b2[8] __attribute__((aligned(32)));
    *(float8 *)b0 = B0; *(float8 *)b1 = B1; *(float8 *)b2 = B2;
    for (int k = 0; k < 8; ++k) {
        out[3 * k] = b0[k]; out[3 * k + 1] = b1[k]; out[3 * k + 2] = b2[k];
    }
}

/* What a tile's depth ties are decided from: its entries, its origin (tx0, ty0), and, in
 * a later pass (load), the earlier pass's ids in the frame. */
typedef struct {
    __global const Piece *entries;
    __global const int *id_out;
    int load, tx0, ty0, width;
} TieCtx;

/* For a fragment whose depth ties tile pixel i's (its winning entry win, -1: none): the
 * triangle id it must be below to win there, that of the winning entry, else, in a later
 * pass, the earlier pass's id there; INT_MIN for the background (the clear value, or a
 * window's shut pixel), which no tie beats. Ties are rare (coplanar overlaps, depths that
 * round alike), so the tile keeps no per-pixel id buffer for them: the id was a load and a
 * store in every depth-test block. */
inline int tie_id(const TieCtx *T, int win, int i)
{
    if (win >= 0) return T->entries[win].id;
    if (!T->load) return INT_MIN;
    int id0 = T->id_out[(size_t)(T->ty0 + (i >> TILE_LOG2)) * T->width + T->tx0
                        + (i & (TILE_SIZE - 1))];
    return id0 < 0 ? INT_MIN : id0;
}

/* The depth test of one block of eight columns of a tile row, pixels (row + b .. + 7) of
 * the tile's private buffers, lanes lx = b + 0..7 where `in` is set: fragment depth
 * common.h depth_at per lane, maxf(zrow + dzdx·(lx − rx0), zlo) (rx0: the plane's reference
 * column in the tile; the same operations, so the same bits), LESS with the lower id
 * winning ties (tie_id) and nothing beating the clear value; winners store their depth and
 * entry k. Returns the lanes that passed. */
ALWAYS_INLINE int8 depth_block8(float *zbuf, int *win, int i, int8 lx, int8 in,
                                float zrow, float dzdx, int rx0, float zlo, int id, int k,
                                const TieCtx *T)
{
    float8 zf = (float8)(zrow) + (float8)(dzdx) * CONVERT_VEC(lx - (int8)(rx0), float8);
    float8 z = zf >= (float8)(zlo) ? zf : (float8)(zlo);   /* maxf */
    float8 zb = *(float8 *)&zbuf[i];
    int8 wk = *(int8 *)&win[i];
    int8 pass = in & (z < zb);
    int8 tie = in & (z == zb);
    int4 t4 = tie.lo | tie.hi;
    int2 t2 = t4.lo | t4.hi;
    if (t2.x | t2.y) {
        int tm[8] __attribute__((aligned(32))), wv[8] __attribute__((aligned(32)));
        int pm[8] __attribute__((aligned(32)));
        *(int8 *)tm = tie; *(int8 *)wv = wk; *(int8 *)pm = pass;
        for (int j = 0; j < 8; ++j)
            if (tm[j] && id < tie_id(T, wv[j], i + j))
                pm[j] = -1;
        pass = *(int8 *)pm;
    }
    *(float8 *)&zbuf[i] = pass ? z : zb;
    *(int8 *)&win[i] = pass ? (int8)(k) : wk;
    return pass;
}

/* edges_inside (common.h) for the eight centres of columns b + 0..7 of the row E is set up
 * at, as an int8 mask; sv[i] = lane·sx[i], the lane products made once per entry (64-bit
 * vector multiplies are slow). */
ALWAYS_INLINE int8 edges_inside8(const PieceEdges *E, const long8 *sv, int b)
{
    long8 in = ((long8)(E->e[0] + (long)b * E->sx[0]) + sv[0] >= (long8)(0))
               & ((long8)(E->e[1] + (long)b * E->sx[1]) + sv[1] >= (long8)(0))
               & ((long8)(E->e[2] + (long)b * E->sx[2]) + sv[2] >= (long8)(0));
    return MASK_INT8(in);
}

/* Write one resolved tile row (rd depth, ri ids, rb interleaved barycentrics, columns
 * tx0 .. tx0 + nx - 1 of row y) into the outputs: a whole aligned tile row with
 * non-temporal stores (they skip reading each output line into the cache before
 * overwriting it: half the memory traffic), other rows pixel by pixel. ``keep``: the
 * winners of the row (a later pass, load: the earlier pass's pixels that nothing beat, win
 * < 0, stay as they are); NULL: every pixel is written. */
ALWAYS_INLINE void store_row(const float *rd, const int *ri, const float *rb, const int *keep,
                             int y, int tx0, int nx, const int width,
                             __global float *depth_out, __global int *id_out,
                             __global float *bary_out, const int want_bary)
{
    size_t orow = (size_t)y * width + tx0;
#if TILE_SIZE >= 8
    if (!keep && nx == TILE_SIZE && (orow & 7) == 0) {
        /* 32-byte aligned: the frame arrays are page-aligned (RasterOutput.allocate) */
        __global float8 *d8 = (__global float8 *)(depth_out + orow);
        __global int8 *i8 = (__global int8 *)(id_out + orow);
        for (int j = 0; j < TILE_SIZE / 8; ++j) {
            NT_STORE(((const float8 *)rd)[j], d8 + j);
            NT_STORE(((const int8 *)ri)[j], i8 + j);
        }
        if (want_bary) {
            __global float8 *b8 = (__global float8 *)(bary_out + 3 * orow);
            for (int j = 0; j < 3 * TILE_SIZE / 8; ++j)
                NT_STORE(((const float8 *)rb)[j], b8 + j);
        }
        return;
    }
#endif
    for (int lx = 0; lx < nx; ++lx) {
        if (keep && keep[lx] < 0) continue;   /* the earlier pass's winner stays */
        size_t o = orow + lx;
        depth_out[o] = rd[lx];
        id_out[o] = ri[lx];
        if (want_bary) {
            bary_out[3 * o] = rb[3 * lx];
            bary_out[3 * o + 1] = rb[3 * lx + 1];
            bary_out[3 * o + 2] = rb[3 * lx + 2];
        }
    }
}

/* A tile whose list is one wide piece (at least WIDE_RUN columns of the tile, not a cover
 * piece), drawn into cleared outputs with no window and no overdraw count: every covered
 * centre is tested against the clear depth alone (z < 1: nothing beats or ties the clear
 * value), so the depth, id and barycentrics of each row follow from its run of covered
 * columns without the tile's private buffers — no clearing them, no depth-test stores,
 * no resolve pass re-reading them. The same runs (edge_columns), depths (depth_at's
 * operations in lanes, as depth_block8), barycentrics (resolve8 lanes, the bits of
 * resolve1), counts and tile Hi-Z decision as raster_tile's general path, which the
 * differential tests compare against the twin. (A large triangle's interior: most tiles
 * of a quad, a wall or a floor seen from close by.) Returns false, having done nothing,
 * for a piece this does not take. */
ALWAYS_INLINE bool sole_piece_tile(int tx0, int ty0, int e0,
                                   __global const float *clip_bary,
                                   __global const Piece *entries, const int width,
                                   const int height, __global float *depth_out,
                                   __global int *id_out, __global float *bary_out,
                                   long *tile_tested, long *tile_passed, const int want_bary,
                                   const int hiz)
{
    int tx1 = imin(tx0 + TILE_SIZE, width) - 1, ty1 = imin(ty0 + TILE_SIZE, height) - 1;
    __global const Piece *pc = &entries[e0];
    int x0 = imax(bb_x(pc->bb_min), tx0), x1 = imin(bb_x(pc->bb_max), tx1);
    int y0 = imax(bb_y(pc->bb_min), ty0), y1 = imin(bb_y(pc->bb_max), ty1);
    if (pc->cover || x1 - x0 < WIDE_RUN) return false;
    /* the general path's tile Hi-Z skips the piece untested when its nearest depth is
     * behind the clear value, the tile's farthest depth */
    if (y0 > y1 || (hiz && pc->zlo > 1.0f)) y1 = y0 - 1;   /* no covered row */
    PieceEdges E;
    piece_edges(pc->x[0], pc->y[0], pc->x[1], pc->y[1], pc->x[2], pc->y[2], tx0, y0, &E);
    DepthPlane P;
    depth_plane(pc, &P);
    int rx0 = P.x0 - tx0, id = pc->id;
    int lx0 = x0 - tx0, lx1 = x1 - tx0;
    if (y1 - y0 >= TRIM_ROWS) {   /* the general path's row trim, the same rows */
        int k0 = 0, k1 = y1 - y0;
        for (int i = 0; i < 3; ++i)
            edge_columns(E.e[i] + (long)(E.sx[i] > 0 ? lx1 : lx0) * E.sx[i], E.sy[i], &k0,
                         &k1);
        if (k0 > k1) {
            y1 = y0 - 1;
        } else {
            edges_down(&E, k0);
            y1 = y0 + k1;
            y0 += k0;
        }
    }
    long tested = 0;
    LANE_COUNTER(npass);
    int nx = tx1 - tx0 + 1;
    for (int y = ty0; y <= ty1; ++y) {
        /* the row's outputs, written out whole by store_row: whole lines of each stream
         * (blocks stored as they are made would be half lines of three streams at once) */
        float rd[TILE_SIZE] __attribute__((aligned(32)));
        float rb[3 * TILE_SIZE] __attribute__((aligned(32)));
        int ri[TILE_SIZE] __attribute__((aligned(32)));
        int c0 = 0, c1 = -1;   /* the row's covered columns */
        float zrow = 0.0f;
        if (y >= y0 && y <= y1) {
            c0 = lx0; c1 = lx1;
            for (int i = 0; i < 3; ++i) edge_columns(E.e[i], E.sx[i], &c0, &c1);
            zrow = depth_row(&P, y);
            edges_down(&E, 1);
            tested += c1 >= c0 ? c1 - c0 + 1 : 0;
        }
        for (int b = 0; b < nx; b += 8) {
            int8 lx = (int8)(b) + LANE8;
            int8 in = (lx >= (int8)(c0)) & (lx <= (int8)(c1));
            float8 zf = (float8)(zrow) + (float8)(P.dzdx) * CONVERT_VEC(lx - (int8)(rx0), float8);
            float8 z = zf >= (float8)(P.zlo) ? zf : (float8)(P.zlo);   /* maxf */
            int8 pass = in & (z < (float8)(1.0f));
            COUNT_LANES(npass, pass);
            float8 d = pass ? z : (float8)(1.0f);
            int8 i8 = pass ? (int8)(id) : (int8)(-1);
            int n = imin(8, nx - b);   /* the image's last tile column may be partial */
            if (n == 8) {
                *(float8 *)&rd[b] = d;
                *(int8 *)&ri[b] = i8;
            } else {
                float dd[8] __attribute__((aligned(32)));
                int ii[8] __attribute__((aligned(32)));
                *(float8 *)dd = d; *(int8 *)ii = i8;
                for (int j = 0; j < n; ++j) { rd[b + j] = dd[j]; ri[b + j] = ii[j]; }
            }
            if (!want_bary) continue;
            int4 p4 = pass.lo & pass.hi, q4 = pass.lo | pass.hi;
            int2 p2 = p4.lo & p4.hi, q2 = q4.lo | q4.hi;
            if ((p2.x & p2.y) && n == 8) {   /* all eight passed */
                resolve8(pc, tx0 + b, y, clip_bary, &rb[3 * b]);
            } else if (!(q2.x | q2.y)) {   /* none */
                for (int j = 0; j < 3 * n; ++j) rb[3 * b + j] = 0.0f;
            } else {
                float b24[24] __attribute__((aligned(32)));
                int pm[8] __attribute__((aligned(32)));
                *(int8 *)pm = pass;
                resolve8(pc, tx0 + b, y, clip_bary, b24);
                for (int j = 0; j < n; ++j) {
                    rb[3 * (b + j)] = pm[j] ? b24[3 * j] : 0.0f;
                    rb[3 * (b + j) + 1] = pm[j] ? b24[3 * j + 1] : 0.0f;
                    rb[3 * (b + j) + 2] = pm[j] ? b24[3 * j + 2] : 0.0f;
                }
            }
        }
        store_row(rd, ri, rb, 0, y, tx0, nx, width, depth_out, id_out, bary_out, want_bary);
    }
    *tile_tested += tested;
    *tile_passed += LANE_TOTAL(npass);
    return true;
}

/* The depth tests of entry k (record pc) at its covered centres `covered` (setup's cover
 * bits, bit k + 4j for column k and row j of its box, masked to the tile T), one at a time: depth_at's operations, LESS with the lower id winning ties,
 * winners' depth and entry into zbuf and win; odc (or 0): fragments counted per pixel.
 * Returns the fragments that passed. Not inlined: inlined into raster_tile, even in part,
 * it made the other paths slower (the blocks' loops, the sole-piece tiles; registers:
 * bench/README.md's performance log). */
__attribute__((noinline)) int cover_fragments(__global const Piece *pc, uint covered, int k,
                                               float *zbuf, int *win, const TieCtx *T,
                                               int *odc)
{
    DepthPlane P;
    depth_plane(pc, &P);
    int bx = P.x0, by = P.y0, id = pc->id, passed = 0;
    for (uint m = covered; m; m &= m - 1) {
        int b = CTZ(m);   /* lowest set bit */
        int x = bx + (b & 3), y = by + (b >> 2);
        float z = depth_at(&P, depth_row(&P, y), x);
        int i = ((y - T->ty0) << TILE_LOG2) + (x - T->tx0);
        float zb = zbuf[i];
        if (odc) ++odc[i];
        if (z < zb || (z == zb && id < tie_id(T, win[i], i))) {
            zbuf[i] = z; win[i] = k;
            ++passed;
        }
    }
    return passed;
}

/* One non-empty tile: walk its list, then resolve its pixels into the outputs. */
inline void raster_tile(int tile, int tx0, int ty0, int e0, int e1,
                        __global const float *clip_bary, __global const Piece *entries,
                        const int width, const int height,
                        __global float *depth_out, __global int *id_out,
                        __global float *bary_out, long *tile_tested, long *tile_passed,
                        const int load, const int want_overdraw, __global int *overdraw,
                        const int want_bary, __global const uchar *wmask,
                        const int use_window, const int hiz)
{
    if (e1 - e0 == 1 && !load && !use_window && !want_overdraw
        && sole_piece_tile(tx0, ty0, e0, clip_bary, entries, width, height, depth_out,
                           id_out, bary_out, tile_tested, tile_passed, want_bary, hiz))
        return;
    int tx1 = imin(tx0 + TILE_SIZE, width) - 1, ty1 = imin(ty0 + TILE_SIZE, height) - 1;
    float zbuf[TILE_PIXELS] __attribute__((aligned(32)));
    int win[TILE_PIXELS] __attribute__((aligned(32)));   /* winning entry, -1 = none */
    int odc[TILE_PIXELS] __attribute__((aligned(32)));   /* fragments tested per pixel
                                                            * (after the tile Hi-Z) */
    for (int i = 0; i < TILE_PIXELS; ++i) {
        zbuf[i] = 1.0f; win[i] = -1; odc[i] = 0;
    }
    if (load) {
        /* continue from an earlier pass over the same image (two-phase occlusion culling):
         * its depth and ids take part in the test exactly as if drawn in this pass */
        for (int y = ty0; y <= ty1; ++y)
            for (int x = tx0; x <= tx1; ++x) {
                int i = ((y - ty0) << TILE_LOG2) + (x - tx0);
                size_t o = (size_t)y * width + x;
                zbuf[i] = depth_out[o];   /* (its ids: tie_id) */
                if (want_overdraw) odc[i] = overdraw[o];
            }
    }
    if (use_window) {
        /* pixels the window shuts: no fragment passes a -inf depth (and none ties) */
        for (int y = ty0; y <= ty1; ++y)
            for (int x = tx0; x <= tx1; ++x)
                if (!wmask[(size_t)y * width + x])
                    zbuf[((y - ty0) << TILE_LOG2) + (x - tx0)] = -INFINITY;
    }
    long tested = 0, passed = 0;
    /* Tile Hi-Z (hiz != 0): a piece whose nearest depth (zlo) is farther than the tile's
     * farthest depth cannot pass anywhere in it (fragment depths are clamped to >= zlo,
     * and ties need equal depths), so it is skipped untested, like cudaraster's per-tile
     * zmax. tzmax is that farthest depth, attained at pixel zarg. Depths only decrease,
     * so once tzmax is known, zbuf[zarg] <= farthest <= tzmax: a piece not behind
     * zbuf[zarg] is not skipped with no more work, and only one behind it finds the
     * farthest depth again (when zbuf[zarg] has fallen below tzmax). Every decision is thus
     * the exact "zlo > farthest depth now", whatever the order of work, and the twin takes
     * the same decisions from the depth history (clraster/pipeline/reference/raster.py
     * hiz_skipped).
     * Pixels outside the image hold -inf so they never count as the farthest. */
    for (int y = ty1 - ty0 + 1; y < TILE_SIZE; ++y)
        for (int x = 0; x < TILE_SIZE; ++x) zbuf[(y << TILE_LOG2) + x] = -INFINITY;
    for (int y = 0; y <= ty1 - ty0; ++y)
        for (int x = tx1 - tx0 + 1; x < TILE_SIZE; ++x) zbuf[(y << TILE_LOG2) + x] = -INFINITY;
    /* without a load or a window every pixel in the image starts at the clear value 1 */
    bool known = !load && !use_window;
    TieCtx T = {entries, id_out, load, tx0, ty0, width};
    float tzmax = 1.0f;
    int zarg = 0;   /* pixel (0, 0) of the tile is always inside the image */

    for (int k = e0; k < e1; ++k) {
        __global const Piece *pc = &entries[k];
        /* the record eight entries on (1.5 lines of 64 bytes): the first loads of each
         * record, written non-temporally by bin_scatter, were cache misses */
        PREFETCH(pc + 8);
        PREFETCH((__global const char *)(pc + 8) + 64);
        int x0 = imax(bb_x(pc->bb_min), tx0), x1 = imin(bb_x(pc->bb_max), tx1);
        int y0 = imax(bb_y(pc->bb_min), ty0), y1 = imin(bb_y(pc->bb_max), ty1);
        if (x0 > x1 || y0 > y1) continue;
        if (hiz) {
            float zlo = pc->zlo, za = zbuf[zarg];
            if (zlo > za) {
                if (!known || za != tzmax) {
                    /* the farthest depth, in float8 lanes (LLVM does not vectorize the
                     * scalar loop) */
                    float8 m8 = ((float8 *)zbuf)[0];
                    for (int j = 1; j < TILE_PIXELS / 8; ++j) {
                        float8 v = ((float8 *)zbuf)[j];
                        m8 = v > m8 ? v : m8;
                    }
                    float4 m4 = m8.lo > m8.hi ? m8.lo : m8.hi;
                    float2 m2 = m4.lo > m4.hi ? m4.lo : m4.hi;
                    tzmax = m2.x > m2.y ? m2.x : m2.y;
                    zarg = 0;
                    while (zbuf[zarg] != tzmax) ++zarg;
                    known = true;
                }
                if (zlo > tzmax) continue;
            }
        }
        int cover = pc->cover;
        if (cover) {
            /* a box of at most 4 x 4 pixel centres whose coverage setup found (layout.py
             * COVER_KNOWN, COVER_SPAN; most entries of a dense mesh). Its covered centres
             * inside this tile (columns x0 - bx .. x1 - bx and rows y0 - by .. y1 - by of
             * the box, all within 0 .. 3; bit k + 4j is column k of row j); when at most
             * COVER_FRAGMENTS of them: the same fragments and depths as the edge-function
             * blocks below, one at a time (cover_fragments), without the blocks' edge
             * set-up and lane masks (more of them go through the blocks, in lanes) */
            int bx = bb_x(pc->bb_min), by = bb_y(pc->bb_min);
            uint covered = (uint)cover & cover_mask(x0 - bx, x1 - bx, y0 - by, y1 - by);
            uint nc = bits16(covered);
            if (nc <= COVER_FRAGMENTS) {
                tested += nc;
                if (nc)
                    passed += cover_fragments(pc, covered, k, zbuf, win, &T,
                                              want_overdraw ? odc : 0);
                continue;
            }
        }
        /* the edges at the tile's first column of row y0 */
        PieceEdges E;
        piece_edges(pc->x[0], pc->y[0], pc->x[1], pc->y[1], pc->x[2], pc->y[2], tx0, y0, &E);
        DepthPlane P;
        depth_plane(pc, &P);
        int rx0 = P.x0 - tx0;   /* the plane's reference column in the tile */
        int id = pc->id;
        int lx0 = x0 - tx0, lx1 = x1 - tx0;
        /* Rows as aligned blocks of eight columns of the tile row, in int8/float8 lanes: a
         * lane mask of the covered columns, the depth test as selects and whole stores
         * (the same operations per lane as one pixel at a time, so the same bits). A
         * piece at least WIDE_RUN columns wide first finds the exact run of columns of
         * each row inside all three edges (edge_columns: a triangle meets a row in one
         * run) and masks by the run; a narrower one evaluates its three edges in 64-bit
         * lanes. Both are the same exact set. Masked blocks rather than scalar loops:
         * those had a scalar remainder per run and mispredicted per-pixel edge branches.
         * In every path the test is LESS; on equal depth the lower triangle id wins, which
         * is "first drawn wins" for triangles submitted in id order, whatever order
         * culling or clustering actually submits them in. Nothing beats the clear value
         * (tie_id INT_MIN). */
        bool wide = x1 - x0 >= WIDE_RUN;
        long8 lane8 = CONVERT_VEC(LANE8, long8);
        long8 sv[3] = {lane8 * (long8)(E.sx[0]), lane8 * (long8)(E.sx[1]),
                       lane8 * (long8)(E.sx[2])};   /* lane·sx per edge (narrow rows) */
        LANE_COUNTER(npass);   /* passed fragments of the masked blocks */
        LANE_COUNTER(ntest);   /* tested fragments of the narrow rows */
        /* Only the rows in which each edge can be met by some column of [lx0, lx1]: an
         * edge's best value over the columns is linear in the row, so edge_columns on it
         * narrows the rows (one division at most per edge and entry). The rows cut cover
         * nothing. A thin triangle crossing a tile's box (most of the plant's list) covers
         * nothing in most of the box's rows. */
        if (y1 - y0 >= TRIM_ROWS) {
            int k0 = 0, k1 = y1 - y0;
            for (int i = 0; i < 3; ++i)
                edge_columns(E.e[i] + (long)(E.sx[i] > 0 ? lx1 : lx0) * E.sx[i], E.sy[i], &k0,
                             &k1);
            if (k0 > k1) continue;
            edges_down(&E, k0);
            y1 = y0 + k1;
            y0 += k0;
        }
        for (int y = y0; y <= y1; ++y) {
            int row = (y - ty0) << TILE_LOG2;
            float zrow = depth_row(&P, y);
            int c0 = lx0, c1 = lx1;
            if (wide) {
                for (int i = 0; i < 3; ++i) edge_columns(E.e[i], E.sx[i], &c0, &c1);
                /* the run is all covered */
                for (int b = c0 & ~7; b <= c1; b += 8) {
                    int8 lx = (int8)(b) + LANE8;
                    int8 in = (lx >= (int8)(c0)) & (lx <= (int8)(c1));
                    int8 pass = depth_block8(zbuf, win, row + b, lx, in, zrow, P.dzdx,
                                             rx0, P.zlo, id, k, &T);
                    COUNT_LANES(npass, pass);
                }
                if (want_overdraw)
                    for (int lx = c0; lx <= c1; ++lx) ++odc[row + lx];
                tested += c1 >= c0 ? c1 - c0 + 1 : 0;
                edges_down(&E, 1);
                continue;
            }
            for (int b = c0 & ~7; b <= c1; b += 8) {
                int8 lx = (int8)(b) + LANE8;
                int8 in = edges_inside8(&E, sv, b) & (lx >= (int8)(c0)) & (lx <= (int8)(c1));
                int8 pass = depth_block8(zbuf, win, row + b, lx, in, zrow, P.dzdx, rx0,
                                         P.zlo, id, k, &T);
                COUNT_LANES(npass, pass);
                COUNT_LANES(ntest, in);
                if (want_overdraw) {
                    int m_[8] __attribute__((aligned(32)));
                    *(int8 *)m_ = in;
                    for (int j = 0; j < 8; ++j) odc[row + b + j] += m_[j] != 0;
                }
            }
            edges_down(&E, 1);
        }
        passed += LANE_TOTAL(npass);
        tested += LANE_TOTAL(ntest);
    }

    /* resolve: id and perspective-correct barycentrics of the winner, per pixel, a row at
     * a time into private arrays, then written out (store_row). A later pass (load)
     * leaves the earlier pass's pixels that nothing beat as they are. */
    int nx = tx1 - tx0 + 1;
    for (int y = ty0; y <= ty1; ++y) {
        /* aligned for the float8 copies below (OpenCL's vload8 is a library call on PoCL) */
        float rd[TILE_SIZE] __attribute__((aligned(32)));
        float rb[3 * TILE_SIZE] __attribute__((aligned(32)));
        int ri[TILE_SIZE] __attribute__((aligned(32)));
        size_t orow = (size_t)y * width + tx0;
        int lrow = (y - ty0) << TILE_LOG2;
        if (want_overdraw)
            for (int lx = 0; lx < nx; ++lx) overdraw[orow + lx] = odc[lrow + lx];
        /* eight columns at a time (tile rows are multiples of 8 wide) */
        for (int lx0 = 0; lx0 < nx; lx0 += 8) {
            int e = win[lrow + lx0];
            if (e < 0 && lx0 + 8 <= nx && !use_window) {
                /* no winner in the eight (a silhouette tile's background): its depth as it
                 * stands, id -1, barycentrics 0, in lanes (sign bits: all eight are -1) */
                int8 w8 = *(int8 *)&win[lrow + lx0];
                int4 a4 = w8.lo & w8.hi;
                int2 a2 = a4.lo & a4.hi;
                if ((a2.x & a2.y) < 0) {
                    *(float8 *)&rd[lx0] = *(float8 *)&zbuf[lrow + lx0];
                    *(int8 *)&ri[lx0] = (int8)(-1);
                    if (want_bary)
                        for (int j = 0; j < 3; ++j) *(float8 *)&rb[3 * lx0 + 8 * j] = (float8)(0.0f);
                    continue;
                }
            }
            if (e >= 0 && lx0 + 8 <= nx) {
                /* one winner over all eight pixels (a piece wider than a few pixels: most
                 * pixels of the plant's first-person frame and of a framed spot): its
                 * record read once and the eight resolved in float8 lanes, the scalar
                 * loop's operations in the same order (FP_CONTRACT is off), so the same
                 * bits. The scalar loop's division's latency was the resolve's cost. */
                int8 d8 = *(int8 *)&win[lrow + lx0] ^ (int8)(e);
                int4 d4 = d8.lo | d8.hi;
                int2 d2 = d4.lo | d4.hi;
                if ((d2.x | d2.y) == 0) {
                    __global const Piece *pc = &entries[e];
                    *(float8 *)&rd[lx0] = *(float8 *)&zbuf[lrow + lx0];
                    *(int8 *)&ri[lx0] = (int8)(pc->id);
                    if (want_bary)
                        resolve8(pc, tx0 + lx0, y, clip_bary, &rb[3 * lx0]);
                    continue;
                }
            }
            if (want_bary && lx0 + 8 <= nx) {
                /* mixed winners, none clipped (a clipped one needs its parent
                 * barycentrics): depth and ids here, barycentrics in lanes */
                bool clipped = false;
                for (int j = 0; j < 8; ++j) {
                    int i = lrow + lx0 + j, ej = win[i];
                    size_t o = orow + lx0 + j;
                    rd[lx0 + j] = ej < 0 && use_window && !wmask[o] ? 1.0f : zbuf[i];
                    ri[lx0 + j] = ej >= 0 ? entries[ej].id : -1;
                    clipped |= ej >= 0 && (entries[ej].flags & PF_CLIPPED);
                }
                if (!clipped) {
                    resolve8_mixed(entries, &win[lrow + lx0], tx0 + lx0, y, &rb[3 * lx0]);
                    continue;
                }
            }
            int lxe = imin(lx0 + 8, nx);
            for (int lx = lx0; lx < lxe; ++lx) {
                int i = lrow + lx;
                size_t o = orow + lx;
                e = win[i];
                rd[lx] = e < 0 && use_window && !wmask[o] ? 1.0f : zbuf[i];
                ri[lx] = e >= 0 ? entries[e].id : -1;
                if (!want_bary) continue;
                float B0 = 0.0f, B1 = 0.0f, B2 = 0.0f;
                if (e >= 0)
                    resolve1(&entries[e], tx0 + lx, y, clip_bary, &B0, &B1, &B2);
                rb[3 * lx] = B0; rb[3 * lx + 1] = B1; rb[3 * lx + 2] = B2;
            }
        }
        store_row(rd, ri, rb, load ? &win[lrow] : 0, y, tx0, nx, width, depth_out, id_out,
                  bary_out, want_bary);
    }
    *tile_tested += tested;
    *tile_passed += passed;
}

/* One work-item per segment of a row of tiles (work-item g is segment g % segs of row
 * g / segs; segs = global size / rows of tiles), walking its tiles left to right;
 * seg_stats[2·g] and [2·g + 1]: fragments tested and passed in it. Whole rows were too
 * coarse: with the work of a frame in a few rows (big occluders of the 10M plant), one core
 * idled. A run of empty tiles (most of a typical frame) is cleared as one span per pixel
 * row: clearing tile by tile, in 16-pixel pieces of 48 rows of three arrays, took several
 * times as long as the same bytes written in long runs. A later pass (load) leaves the
 * earlier pass's pixels of its empty tiles as they are. want_bary = 0: barycentrics are
 * neither computed nor written (bary_out is not touched). */
__kernel void raster_tiles(__global const float *clip_bary,
                           __global const int *tile_start, __global const Piece *entries,
                           const int width, const int height, const int tiles_x,
                           __global float *depth_out, __global int *id_out,
                           __global float *bary_out, __global long *seg_stats,
                           const int load, const int want_overdraw,
                           __global int *overdraw, const int want_bary,
                           __global const uchar *wmask, const int use_window,
                           __global const int *bin_summary, const int bin_cap,
                           const int hiz)
{
    /* a bin list that did not fit its buffer was not scattered (bin.cl bin_scatter): draw
     * nothing, the outputs stay untouched, the host runs the pass again */
    if (BIN_LIST_OVER(bin_summary, bin_cap)) return;
    int tiles_y = (height + TILE_SIZE - 1) >> TILE_LOG2;
    /* segments per row: the host's choice (clraster/pipeline/stages/raster.py segments, whole
     * tiles of about SEG_PIXELS pixels each) */
    int segs = (int)get_global_size(0) / tiles_y, seg_tiles = (tiles_x + segs - 1) / segs;
    int g = get_global_id(0);
    int ty = g / segs, seg = g - ty * segs;
    if (ty >= tiles_y) return;
    int y0 = ty << TILE_LOG2, y1 = imin(y0 + TILE_SIZE, height) - 1;
    int txa = imin(seg * seg_tiles, tiles_x), txb = imin(txa + seg_tiles, tiles_x);
    int run = -1;   /* first tile column of the current run of empty tiles, -1: none */
    long tested = 0, passed = 0;   /* fragments of this segment */
    for (int tx = txa; tx <= txb; ++tx) {
        int tile = ty * tiles_x + tx;
        int e0 = 0, e1 = 0;
        if (tx < txb) {
            e0 = tile_start[tile];
            e1 = tile_start[tile + 1];
            if (use_window && e0 != e1) {
                /* a polygon window (clraster.window): a tile it lets no pixel of is
                 * drawn as empty */
                int open = 0, ya = ty << TILE_LOG2, xa = tx << TILE_LOG2;
                int yb = imin(ya + TILE_SIZE, height), xb = imin(xa + TILE_SIZE, width);
                for (int y = ya; y < yb; ++y)
                    for (int x = xa; x < xb; ++x) open |= wmask[(size_t)y * width + x];
                if (!open) e1 = e0;
            }
            if (e0 == e1) {
                if (run < 0) run = tx;
                continue;
            }
        }
        if (run >= 0 && !load) {
            /* clear values, in plain loops that vectorize */
            int xa = run << TILE_LOG2, xb = imin(tx << TILE_LOG2, width);
            for (int y = y0; y <= y1; ++y) {
                size_t o = (size_t)y * width;
                int xs = xa;
                if (((o + xa) & 7) == 0) {   /* 32-byte aligned (buffers are page-aligned) */
                    int n8 = (xb - xa) >> 3;
                    __global float8 *d8 = (__global float8 *)(depth_out + o + xa);
                    __global int8 *i8 = (__global int8 *)(id_out + o + xa);
                    for (int j = 0; j < n8; ++j) {
                        NT_STORE((float8)(1.0f), d8 + j);
                        NT_STORE((int8)(-1), i8 + j);
                    }
                    if (want_bary) {
                        __global float8 *b8 = (__global float8 *)(bary_out + 3 * (o + xa));
                        for (int j = 0; j < 3 * n8; ++j)
                            NT_STORE((float8)(0.0f), b8 + j);
                    }
                    xs = xa + (n8 << 3);
                }
                for (int x = xs; x < xb; ++x) { depth_out[o + x] = 1.0f; id_out[o + x] = -1; }
                if (want_bary)
                    for (int x = 3 * xs; x < 3 * xb; ++x) bary_out[3 * o + x] = 0.0f;
                if (want_overdraw)
                    for (int x = xa; x < xb; ++x) overdraw[o + x] = 0;
            }
        }
        run = -1;
        if (tx < txb)
            raster_tile(tile, tx << TILE_LOG2, y0, e0, e1, clip_bary, entries, width, height,
                        depth_out, id_out, bary_out, &tested, &passed, load,
                        want_overdraw, overdraw, want_bary, wmask, use_window, hiz);
    }
    seg_stats[2 * g] = tested;
    seg_stats[2 * g + 1] = passed;
}

/* The cleared frame (RasterStage.clear: a frame, or a first pass, with nothing to draw):
 * depth 1.0, id -1 and, with want_overdraw, overdraw 0 — raster_tiles' clear values — for
 * the n pixels, each work-item a contiguous share of whole blocks of eight (the last one
 * the remainder), in non-temporal float8/int8 stores: a few long streams per core, which
 * the memory takes faster than a tile row's short rows. The barycentrics are fresh zero
 * pages the host made (raster.py zeros_array). */
__kernel void clear_frame(__global float *restrict depth_out, __global int *restrict id_out,
                          __global int *restrict overdraw, const int want_overdraw,
                          const int n)
{
    int blocks = (n + 7) >> 3, items = (int)get_global_size(0);
    int per = (blocks + items - 1) / items;
    int a = (int)get_global_id(0) * per, b = imin(blocks, a + per);   /* blocks [a, b) */
    if (a >= b) return;
    int full = b == blocks ? n >> 3 : b;   /* whole blocks: the last may be partial */
    /* buffers are page-aligned and a block is 32 bytes: aligned vector stores */
    __global float8 *d8 = (__global float8 *)depth_out;
    __global int8 *i8 = (__global int8 *)id_out;
    __global int8 *o8 = (__global int8 *)overdraw;
    for (int j = a; j < full; ++j) {
        NT_STORE((float8)(1.0f), d8 + j);
        NT_STORE((int8)(-1), i8 + j);
    }
    if (want_overdraw)
        for (int j = a; j < full; ++j) NT_STORE((int8)(0), o8 + j);
    for (int x = 8 * imax(full, a); x < imin(n, 8 * b); ++x) {
        depth_out[x] = 1.0f;
        id_out[x] = -1;
        if (want_overdraw) overdraw[x] = 0;
    }
}
