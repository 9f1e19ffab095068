/* The vertex stage and triangle setup: object -> clip space, outcodes and the viewport
 * transform of each draw's vertices; trivial reject, clipping, back-face / zero-area cull,
 * fixed-point snap of its triangles.
 *
 * setup_triangles (a work-item per draw: its vertices VERTEX_LANES at a time, draw_vertices,
 * into private memory, then its triangles SETUP_LANES at a time) writes, for
 * every unclipped survivor, one Piece at the triangle's slot in the frame's triangle
 * stream, and a status per triangle; setup_count_clipped, for the triangles that need the
 * clipper, the number of pieces they make. The host scans those counts; setup_clipped then
 * re-runs the clipper for just those triangles and writes their pieces in order. Clipping
 * is rare, so recomputing it beats storing up to 14 pieces per triangle for everyone. (On a
 * GPU a work-item per draw would leave most of a warp idle; this is written for CPUs.)
 *
 * Clipping is Sutherland–Hodgman in homogeneous clip space against near, far and — only when
 * a vertex leaves the guard band — the x/y guard-band planes (config.guard_band_factors).
 * Intersections are always interpolated from the inside vertex towards the outside one, so
 * two triangles sharing an edge compute bit-identical new vertices: no cracks.
 */
#include "common.h"

/* POLY_MAX (clraster/base/layout.py, 24) > MAX_CLIP_VERTICES (3 + 6 + USER_PLANES_MAX = 17):
 * float rounding can make a clipped polygon a hair non-convex. */

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

/* The clipper works in double: interpolating float32 positions between far-apart vertices
 * (|w| ~ 1e5 around a near plane at 1e-3, or x ~ ±1e15 around a guard band of 2**19 px)
 * cancels away more than the plane's own scale, and whole triangles vanished. Its inputs
 * are clip positions recomputed in double from the object-space vertices and the float64
 * matrix (CLIP_IN, per corner of a clipped triangle): the vertex stage's float32 clip
 * positions are rounded by ~4e-3 at |w| ~ 1e5, more than a near distance of 1e-3, and the
 * near-plane crossing landed at w <= 0. A polygon vertex that is one of the triangle's own
 * (orig >= 0) is emitted as the vertex stage's float32 position, so an edge shared with an
 * unclipped neighbour stays bit-identical; each new vertex is rounded to float once, at the
 * end. */
typedef struct { double4 p; double r, b0, b1, b2; int orig; } ClipVert;

/* A vertex in double from object space (CLIP_IN): clip position p, and r, the depth
 * numerator its value planes use instead of p.z: p.z itself for ordinary depth; for
 * reversed-Z the draw's depth row (FrameDraws.zrows: w row − z row, formed in float64 on
 * the host) times the position, so r = w − z keeps its relative
 * precision far away, where it is a small difference of two large values. */
typedef struct { double4 p; double r; } ClipIn;

__constant uint PLANE_BIT[6] = {OC_Z_NEG, OC_Z_POS, OC_GB_X_NEG, OC_GB_X_POS, OC_GB_Y_NEG,
                                OC_GB_Y_POS};

/* Signed distance to clip plane p, >= 0 inside; the same expressions as the outcodes
 * (vertex_outcode). */
inline double plane_dist(int p, double4 v, double kx, double ky)
{
    switch (p) {
    case 0: return v.z + v.w;
    case 1: return v.w - v.z;
    case 2: return v.x + kx * v.w;
    case 3: return kx * v.w - v.x;
    case 4: return v.y + ky * v.w;
    default: return ky * v.w - v.y;
    }
}

/* Put a vertex cut by plane p exactly on it: the interpolated coordinate along the plane's
 * normal carries the cancellation error of |vi - vo| (~1e14 for vertices at ±1e30), while
 * the plane's own expression in w is exact to rounding. */
inline double4 onto_plane(int p, double4 v, double kx, double ky)
{
    switch (p) {
    case 0: v.z = -v.w; break;
    case 1: v.z = v.w; break;
    case 2: v.x = -kx * v.w; break;
    case 3: v.x = kx * v.w; break;
    case 4: v.y = -ky * v.w; break;
    default: v.y = ky * v.w; break;
    }
    return v;
}

/* The double clip position and depth numerator (ClipIn) of pool vertex pv of instance inst,
 * into `out`: the instance's float64 matrix (FrameDraws.mvps64: VP · model before it is
 * rounded to float32 for coverage, so the value planes do not inherit that rounding, ~1e-7
 * relative, which put barycentrics of 1-px triangles off by up to 2.6e-5) times the pool
 * position, and for reversed-Z frames (the kernel argument `reversed`) the depth row
 * (FrameDraws.zrows, w row − z row formed in float64) times it; else r = p.z. The same sums
 * as the twin's object_clip (reference/setup.py). Made here for the corners of the
 * triangles that become pieces or meet the clipper — a few per draw on a dense mesh — not
 * for every vertex by the vertex stage, whose stores of 40 bytes a vertex nothing else read
 * (kernels pos, mvps64, zrows and reversed in scope). A macro, not a function returning
 * the struct: inlining that (an sret pointer, noalias) emitted an intrinsic Oclgrind
 * cannot run. */
#define CLIP_IN(out, pv, inst) do {                                                         \
    double x_ = (double)pos[3 * (pv)], y_ = (double)pos[3 * (pv) + 1];                       \
    double z_ = (double)pos[3 * (pv) + 2];                                                  \
    __global const double *m_ = mvps64 + 16 * (inst);                                      \
    (out).p = (double4)(MAT_ROW(m_, 0, x_, y_, z_), MAT_ROW(m_, 1, x_, y_, z_),           \
                        MAT_ROW(m_, 2, x_, y_, z_), MAT_ROW(m_, 3, x_, y_, z_));          \
    (out).r = reversed ? MAT_ROW(zrows + 4 * (inst), 0, x_, y_, z_) : (out).p.z;           \
} while (0)

/* The clip position with z replaced by the depth numerator: what value_planes reads. */
inline double4 value_vertex(double4 p, double r)
{
    p.z = r;
    return p;
}

/* The cull mode for one draw: a mirroring instance (DRAW_MIRRORED) keeps its faces' outward
 * side (glTF 2.0; trimesh's apply_transform), so its screen winding is reversed and back
 * and front swap. */
inline int draw_cull(int cull, int flags)
{
    if (!(flags & DRAW_MIRRORED)) return cull;
    return cull == CULL_BACK ? CULL_FRONT : (cull == CULL_FRONT ? CULL_BACK : cull);
}

/* Facing from the homogeneous determinant det[x y w] of the clip-space vertices: > 0 is
 * counter-clockwise in NDC (front by default), < 0 clockwise. It is the sign of the NDC
 * area for w > 0 and stays meaningful for triangles that cross w = 0, so back-face culling
 * happens before clipping (Olano & Greer 1997). Deciding facing on the unsnapped positions
 * (not on the 1/256-snapped area, which can flip for sub-pixel triangles) is what lets the
 * cluster normal-cone test be conservative: it culls only clusters whose every triangle
 * faces away by a margin far above float32 rounding. setup_triangles takes det == 0
 * (edge-on) as ST_DEGENERATE, then the draw's cull mode (draw_cull) as ST_BACKFACE.
 *
 * det is computed in double from the float32 clip positions: a product of two floats is
 * exact in double and a triple product of finite floats can neither overflow nor underflow
 * there (3.4e38^3, 1.4e-45^3), so the sign is right at any scene scale. In float32 the
 * triple product underflowed for a mesh scaled by 1e-15 (5,711 of 5,856 faces "degenerate")
 * and overflowed to NaN for a projection times 1e13. Rescaling each vertex by a power of
 * two in float32 instead was slower than the doubles (its bit operations defeat PoCL's
 * vectorizer). */
#define FACING_DET(ax, ay, aw, bx, by, bw, cx, cy, cw) \
    (((ax) * ((by) * (cw) - (bw) * (cy)) - (ay) * ((bx) * (cw) - (bw) * (cx)))           \
     + (aw) * ((bx) * (cy) - (by) * (cx)))

/* Value planes of a piece (depth, screen-space weights, perspective ratios) from its
 * UNSNAPPED vertices a, b, c (clip space, double, in the piece's vertex order), while
 * coverage keeps the snapped 24.8 vertices X, Y. Interpolating values from the snapped
 * positions moved them by up to 1/512 px: window-depth errors of 1.7e-6..7.3e-6 on real
 * meshes (7e-5 with the near plane cutting them) against a float64 ray caster, where Mesa
 * llvmpipe is at ~2e-7. Everything here is double, each stored value is rounded to float
 * once, and every plane is written relative to the reference pixel centre (px0 + 0.5,
 * py0 + 0.5), so the raster evaluates it at small exact integer offsets and its float
 * error stays ~1 ulp of the value (not of the window coordinate). The unsnapped doubled area
 * is used only while it stays within a factor 2 of the snapped one (as = area2 / 256^2,
 * exact): a sub-pixel sliver whose snap changed its shape that much (or flipped it) falls
 * back to the snapped positions, so weights at its covered pixel centres stay bounded.
 * clraster/pipeline/reference/setup.py `value_planes` does the same double operations in order. */
ALWAYS_INLINE void value_planes(double4 a, double4 b, double4 c, int X0, int Y0, int X1, int Y1,
                         int X2, int Y2, long area2, double hw, double hh, int px0, int py0,
                         double zs, double zo, Piece *pc)
{
    double iw0 = 1.0 / a.w, iw1 = 1.0 / b.w, iw2 = 1.0 / c.w;
    double x0 = (a.x * iw0 + 1.0) * hw, y0 = (1.0 - a.y * iw0) * hh;
    double x1 = (b.x * iw1 + 1.0) * hw, y1 = (1.0 - b.y * iw1) * hh;
    double x2 = (c.x * iw2 + 1.0) * hw, y2 = (1.0 - c.y * iw2) * hh;
    /* depth key from the depth numerator r in .z (ClipIn): zs = 0.5, zo = 0.5 (r = z) give
     * window depth (z/w + 1)/2; zs = -0.5, zo = 0 (r = w - z) give minus the reversed-Z
     * depth, -(1 - z/w)/2, so the raster's LESS test still means nearer, and far away,
     * where (z/w + 1)/2 rounds to 1 in float, the key keeps float's relative precision
     * (clraster.params.FrameParams.reversed_z) */
    double z0 = (a.z * iw0) * zs + zo, z1 = (b.z * iw1) * zs + zo;
    double z2 = (c.z * iw2) * zs + zo;
    double as = (double)area2 * (1.0 / 65536.0);
    double ar = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0);
    if (!(ar >= 0.5 * as && ar <= 2.0 * as)) {
        x0 = (double)X0 * (1.0 / 256.0); y0 = (double)Y0 * (1.0 / 256.0);
        x1 = (double)X1 * (1.0 / 256.0); y1 = (double)Y1 * (1.0 / 256.0);
        x2 = (double)X2 * (1.0 / 256.0); y2 = (double)Y2 * (1.0 / 256.0);
        ar = as;
    }
    double inv = 1.0 / ar;
    double rx = (double)px0 + 0.5, ry = (double)py0 + 0.5;
    /* l1 = E(v2 -> v0) / area, l2 = E(v0 -> v1) / area (edge_fn's orientation) */
    double l1 = ((x0 - x2) * (ry - y2) - (y0 - y2) * (rx - x2)) * inv;
    double l1x = -(y0 - y2) * inv, l1y = (x0 - x2) * inv;
    double l2 = ((x1 - x0) * (ry - y0) - (y1 - y0) * (rx - x0)) * inv;
    double l2x = -(y1 - y0) * inv, l2y = (x1 - x0) * inv;
    double dz10 = z1 - z0, dz20 = z2 - z0;
    pc->z0 = (float)((z0 + l1 * dz10) + l2 * dz20);
    pc->dzdx = (float)(l1x * dz10 + l2x * dz20);
    pc->dzdy = (float)(l1y * dz10 + l2y * dz20);
    pc->l1 = (float)l1; pc->l1x = (float)l1x; pc->l1y = (float)l1y;
    pc->l2 = (float)l2; pc->l2x = (float)l2x; pc->l2y = (float)l2y;
    pc->r1 = (float)(a.w / b.w);
    pc->r2 = (float)(a.w / c.w);
    /* nearest vertex depth: the raster raises fragment depth to it (layout.py PIECE_DTYPE) */
    pc->zlo = (float)mind(mind(z0, z1), z2);
    pc->pad = 0;
}

/* The centres of the 4 x 4 pixels from the one E is set up at that lie inside its three
 * edges, as bits k + 4j (column k, row j). small: the piece's vertices span fewer than
 * SMALL_COVER_SPAN sub-pixels each way, so every edge value there is under 2^24 (edge
 * deltas under 2^11, offsets under 2^12 with the lanes past a narrower box): the same
 * exact integers in int lanes, one centre per lane, a centre inside iff the OR of its
 * three values is >= 0; else 64-bit, one at a time. Not inlined: in setup_triangles' loop
 * it cost more than its own work (registers). */
__attribute__((noinline)) uint box_cover(const PieceEdges *E, int small)
{
    if (small) {
        const int16 lk = (int16)(0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2, 3);
        const int16 lj = (int16)(0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3);
        int16 o = (int16)(0);
        for (int i = 0; i < 3; ++i)
            o |= (int16)((int)E->e[i]) + lk * (int16)((int)E->sx[i])
                 + lj * (int16)((int)E->sy[i]);
        int16 b = (o >= (int16)(0)) & (int16)(1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024,
                                              2048, 4096, 8192, 16384, 32768);
        int8 b8 = b.lo | b.hi;
        int4 b4 = b8.lo | b8.hi;
        int2 b2 = b4.lo | b4.hi;
        return (uint)(b2.x | b2.y);
    }
    uint c = 0;
    for (int j = 0; j < COVER_SPAN; ++j)
        for (int k = 0; k < COVER_SPAN; ++k)
            c |= (uint)edges_inside(E, k, j) << (COVER_SPAN * j + k);
    return c;
}

/* piece_cover tests the centres of a box in int lanes when the piece's vertices span fewer
 * sub-pixels than this in x and in y (its edge values there then stay far below 2^31) */
#define SMALL_COVER_SPAN (8 << SUBPIXEL_BITS)

/* make_piece's coverage part: the doubled area (ST_DEGENERATE at 0), vertices 1 and 2
 * swapped where it is negative (*swapped, *area2 then positive), the pixel box
 * (ST_NO_SAMPLE without a centre) and the cover test of a box of at most COVER_SPAN x
 * COVER_SPAN centres (`known`: the bits the lanes found for a 2 x 2 box); on ST_RASTER
 * the piece's x, y, bb_min, bb_max and cover are set, and value_planes is what is left. */
ALWAYS_INLINE int piece_cover(int2 v0, int2 v1, int2 v2, int width, int height, int known,
                              Piece *pc, int *swapped, long *area2_out)
{
    long area2 = edge_fn(v0.x, v0.y, v1.x, v1.y, v2.x, v2.y);
    if (area2 == 0) return ST_DEGENERATE;
    /* y points down in window space: counter-clockwise in NDC is area2 < 0. Rasterize
     * every piece with positive area; facing was decided before (FACING_DET). */
    *swapped = area2 < 0;
    if (area2 < 0) {
        int2 t = v1; v1 = v2; v2 = t;
        area2 = -area2;
    }
    *area2_out = area2;
    int xmin = imin(imin(v0.x, v1.x), v2.x), xmax = imax(imax(v0.x, v1.x), v2.x);
    int ymin = imin(imin(v0.y, v1.y), v2.y), ymax = imax(imax(v0.y, v1.y), v2.y);
    /* pixel x is inside iff its centre 256x + 128 lies in [xmin, xmax] */
    int px0 = imax((xmin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, 0);
    int px1 = imin((xmax - SUB_HALF) >> SUBPIXEL_BITS, width - 1);
    int py0 = imax((ymin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, 0);
    int py1 = imin((ymax - SUB_HALF) >> SUBPIXEL_BITS, height - 1);
    if (px0 > px1 || py0 > py1) return ST_NO_SAMPLE;
    int cover = known ? known | COVER_KNOWN : 0;   /* Piece.cover */
    if (!known && px1 - px0 < COVER_SPAN && py1 - py0 < COVER_SPAN) {
        /* A box of at most COVER_SPAN x COVER_SPAN pixel centres (most pieces of a dense
         * mesh): test them here, with the raster's edges (common.h piece_edges), and drop
         * the piece if it covers none: on a dense mesh most small boxes cover nothing,
         * and were set up, binned and rasterized for no fragment. */
        PieceEdges E;
        piece_edges(v0.x, v0.y, v1.x, v1.y, v2.x, v2.y, px0, py0, &E);
        /* the box's centres as bits k + 4j, those outside it masked off */
        uint box = cover_mask(0, px1 - px0, 0, py1 - py0);
        cover = (int)(box_cover(&E, xmax - xmin < SMALL_COVER_SPAN
                                        && ymax - ymin < SMALL_COVER_SPAN) & box);
        if (!cover) return ST_NO_SAMPLE;
        /* the raster reads these bits instead of evaluating the edges (layout.py
         * COVER_KNOWN): its per-pixel edge tests were mispredicted branches, and their
         * set-up 64-bit products, on every such entry */
        cover |= COVER_KNOWN;
    }
    pc->x[0] = v0.x; pc->x[1] = v1.x; pc->x[2] = v2.x;
    pc->y[0] = v0.y; pc->y[1] = v1.y; pc->y[2] = v2.y;
    pc->bb_min = px0 | (py0 << 16);
    pc->bb_max = px1 | (py1 << 16);
    pc->cover = cover;
    return ST_RASTER;
}

/* Set up one triangle from its three snapped window positions (coverage: win_xy) and the
 * same three vertices in clip space, double (values: value_planes). Returns ST_RASTER when
 * it survives, otherwise the reason it was dropped; *swapped says whether vertices 1 and 2
 * were exchanged to make the doubled area positive. (setup_triangles does the same in two
 * steps: piece_cover per piece, then value_planes8 for SETUP_LANES pieces at a time.) */
ALWAYS_INLINE int make_piece(int2 v0, int2 v1, int2 v2, double4 c0, double4 c1, double4 c2,
                      int width, int height, double zs, double zo, int known, Piece *pc,
                      int *swapped)
{
    long area2;
    int st = piece_cover(v0, v1, v2, width, height, known, pc, swapped, &area2);
    if (st != ST_RASTER) return st;
    if (*swapped) {
        double4 tc = c1; c1 = c2; c2 = tc;
    }
    value_planes(c0, c1, c2, pc->x[0], pc->y[0], pc->x[1], pc->y[1], pc->x[2], pc->y[2],
                 area2, 0.5 * (double)width, 0.5 * (double)height, bb_x(pc->bb_min),
                 bb_y(pc->bb_min), zs, zo, pc);
    return ST_RASTER;
}

/* Clip triangle (c0, c1, c2) against the planes in `planes`, fan the polygon and snap each
 * piece. Returns the number of surviving pieces; with write != 0 also stores them (and their
 * parent barycentrics, 9 floats per piece) at index base, base+1, ... */
/* Distance of a polygon vertex to user plane k: the parent's vertex distances ud[3k..3k+2]
 * weighted by the vertex's parent barycentrics. Distances are affine in position and the
 * barycentrics are the clip-space interpolation weights, so this is the distance at the
 * clipped vertex (OpenGL interpolates gl_ClipDistance the same way); at the triangle's own
 * vertices (barycentrics 1, 0, 0...) it is exactly the vertex stage's user_dist. */
inline double user_plane_dist(const double *ud, int k, ClipVert v)
{
    return (v.b0 * ud[3 * k] + v.b1 * ud[3 * k + 1]) + v.b2 * ud[3 * k + 2];
}

/* Clip triangle (c0, c1, c2) against the planes in `planes` (frustum/guard-band bits, in
 * PLANE_BIT order) and then the user planes in `umask` (bit k: plane k, vertex distances
 * ud[3k..3k+2]), fan the polygon and snap each piece. */
inline int clip_and_emit(float4 c0, float4 c1, float4 c2, ClipIn d0, ClipIn d1, ClipIn d2,
                         uint planes, uint umask, const double *ud, float kx, float ky,
                         int width, int height, double zs, double zo, int id, int write,
                         __global Piece *out, __global float *out_bary, int base)
{
    ClipVert poly[POLY_MAX], tmp[POLY_MAX];
    double kxd = (double)kx, kyd = (double)ky;
    float4 corig[3] = {c0, c1, c2};   /* the vertex stage's positions (see ClipVert) */
    poly[0].p = d0.p; poly[0].r = d0.r; poly[0].orig = 0;
    poly[1].p = d1.p; poly[1].r = d1.r; poly[1].orig = 1;
    poly[2].p = d2.p; poly[2].r = d2.r; poly[2].orig = 2;
    poly[0].b0 = 1.0; poly[0].b1 = 0.0; poly[0].b2 = 0.0;
    poly[1].b0 = 0.0; poly[1].b1 = 1.0; poly[1].b2 = 0.0;
    poly[2].b0 = 0.0; poly[2].b1 = 0.0; poly[2].b2 = 1.0;
    int n = 3;
    for (int p = 0; p < 6 + USER_PLANES_MAX && n >= 3; ++p) {
        bool user = p >= 6;
        if (user ? !(umask & (1u << (p - 6))) : !(planes & PLANE_BIT[p])) continue;
        for (int i = 0; i < n; ++i) tmp[i] = poly[i];
        int m = 0;
        for (int i = 0; i < n && m < POLY_MAX; ++i) {
            ClipVert a = tmp[i], b = tmp[i + 1 == n ? 0 : i + 1];
            double da = user ? user_plane_dist(ud, p - 6, a) : plane_dist(p, a.p, kxd, kyd);
            double db = user ? user_plane_dist(ud, p - 6, b) : plane_dist(p, b.p, kxd, kyd);
            bool ain = da >= 0.0, bin = db >= 0.0;
            if (ain) poly[m++] = a;
            if (ain != bin && m < POLY_MAX) {
                ClipVert vi = ain ? a : b, vo = ain ? b : a;
                double di = ain ? da : db, dout = ain ? db : da;
                double t = di / (di - dout);
                ClipVert r;
                r.p = vi.p + t * (vo.p - vi.p);
                if (!user) r.p = onto_plane(p, r.p, kxd, kyd);
                r.r = vi.r + t * (vo.r - vi.r);
                r.b0 = vi.b0 + t * (vo.b0 - vi.b0);
                r.b1 = vi.b1 + t * (vo.b1 - vi.b1);
                r.b2 = vi.b2 + t * (vo.b2 - vi.b2);
                r.orig = -1;
                poly[m++] = r;
            }
        }
        n = m;
    }
    int count = 0;
    float hw = 0.5f * (float)width, hh = 0.5f * (float)height;
    for (int k = 1; k + 1 < n; ++k) {
        Piece pc;
        int sw = 0;
        ClipVert q0 = poly[0], q1 = poly[k], q2 = poly[k + 1];
        float4 f0 = q0.orig >= 0 ? corig[q0.orig] : convert_float4(q0.p);
        float4 f1 = q1.orig >= 0 ? corig[q1.orig] : convert_float4(q1.p);
        float4 f2 = q2.orig >= 0 ? corig[q2.orig] : convert_float4(q2.p);
        /* a piece with a vertex at w <= 0 can only come from a projection matrix that
         * does not put w > 0 on the near plane; it has no window position: dropped */
        if (!(f0.w > 0.0f && f1.w > 0.0f && f2.w > 0.0f))
            continue;
        if (make_piece(win_xy(viewport_vertex(f0, hw, hh)),
                       win_xy(viewport_vertex(f1, hw, hh)),
                       win_xy(viewport_vertex(f2, hw, hh)), value_vertex(poly[0].p, poly[0].r),
                       value_vertex(poly[k].p, poly[k].r),
                       value_vertex(poly[k + 1].p, poly[k + 1].r), width, height, zs, zo, 0,
                       &pc, &sw)
            != ST_RASTER)
            continue;
        if (write) {
            pc.id = id;
            pc.flags = PF_CLIPPED | (sw ? PF_SWAPPED : 0) | ((base + count) << PF_INDEX_SHIFT);
            out[base + count] = pc;
            /* parent barycentrics of the piece's vertices, in the piece's (swapped) order */
            ClipVert v1 = sw ? poly[k + 1] : poly[k], v2 = sw ? poly[k] : poly[k + 1];
            __global float *b = out_bary + 9 * (base + count);
            b[0] = (float)poly[0].b0; b[1] = (float)poly[0].b1; b[2] = (float)poly[0].b2;
            b[3] = (float)v1.b0; b[4] = (float)v1.b1; b[5] = (float)v1.b2;
            b[6] = (float)v2.b0; b[7] = (float)v2.b1; b[8] = (float)v2.b2;
        }
        ++count;
    }
    return count;
}

/* ---- The vertex stage: a draw's vertices, made by the setup work-item of the draw -------
 *
 * Object space -> clip space (the instance's row-major float32 matrix, mvps[16 * instance]:
 * clip = M · [x y z 1]ᵀ, MAT_ROW), the outcodes, the snapped window x, y of the vertices that
 * can be drawn unclipped, and the user clip plane codes. setup_triangles makes them for
 * the CLUSTER_MAX vertices of its draw at most, into private memory (DrawVerts), before it
 * sets up the draw's triangles from them; the clipper's kernels make them for the three
 * corners of their triangle (vertex_of). The same operations in the same order either
 * way, so the same bits. (A kernel of its own wrote them to a vertex stream in global
 * memory that setup then gathered from: on the dragon at 1080p ~1 ms of device time for
 * 27 bytes a vertex written and read back; bench/README.md.)
 * Outcode bit k is set iff the signed distance to plane k is negative; the distances are the
 * same expressions the clipper uses (plane_dist), so the two never disagree. A draw inside
 * the frustum by a margin (DRAW_INSIDE) skips the plane tests: all their bits would be 0.
 * User clip planes (n_user of them): ucode bit k is set iff the vertex's distance to plane
 * k, in double from its object-space position and the instance's object-space plane
 * (uplanes[(instance·n_user + k)·4 ..]), is negative: user_dist, the expression the
 * clipper evaluates for the same vertex. */

/* One vertex of a draw with flags `flags`: its outcode from clip position c, and its
 * window position (24.8, viewport_vertex's rounding; (0, 0) where it cannot be drawn
 * unclipped). */
ALWAYS_INLINE uint vertex_outcode(float4 c, int flags, float kx, float ky)
{
    if (!(finite_f(c.x) && finite_f(c.y) && finite_f(c.z) && finite_f(c.w)))
        return OC_INVALID;
    if (flags & DRAW_INSIDE) return 0;
    uint o = frustum_outcode(c);
    o |= (c.x + kx * c.w < 0.0f) ? OC_GB_X_NEG : 0;
    o |= (kx * c.w - c.x < 0.0f) ? OC_GB_X_POS : 0;
    o |= (c.y + ky * c.w < 0.0f) ? OC_GB_Y_NEG : 0;
    o |= (ky * c.w - c.y < 0.0f) ? OC_GB_Y_POS : 0;
    o |= (c.w > 0.0f) ? 0 : OC_W_NONPOS;
    return o;
}

/* The user clip plane bits of object-space vertex (px, py, pz) of instance plane rows q
 * (n_user planes; none for a vertex with OC_INVALID, as the clipper never sees one). */
ALWAYS_INLINE uint vertex_ucode(__global const double *q, int n_user, uint o, float px,
                                float py, float pz)
{
    uint uc = 0;
    if (o & OC_INVALID) return 0;
    for (int k = 0; k < n_user; ++k)
        uc |= user_dist(q + 4 * k, px, py, pz) < 0.0 ? 1u << k : 0u;
    return uc;
}

/* The clip position, outcode and user plane bits of pool vertex pv of a draw of instance
 * `inst` with flags `flags` (the clipper's corners). */
ALWAYS_INLINE float4 vertex_of(__global const float *pos, __global const float *mvps,
                               __global const double *uplanes, int n_user, int pv, int inst,
                               int flags, float kx, float ky, uint *oc, uint *uc)
{
    float px = pos[3 * pv], py = pos[3 * pv + 1], pz = pos[3 * pv + 2];
    float4 c = clip_transform(mvps + 16 * inst, px, py, pz);
    *oc = vertex_outcode(c, flags, kx, ky);
    *uc = n_user > 0 ? vertex_ucode(uplanes + 4 * n_user * inst, n_user, *oc, px, py, pz) : 0u;
    return c;
}

/* A draw's vertices by local index (its cluster's, CLUSTER_MAX at most), as setup reads
 * them: clip x, y, w (z is only tested), window x, y (24.8; 0 where the vertex cannot be
 * drawn unclipped), outcode and user plane bits (0 without user planes); and in double,
 * for the value planes (value_planes8), the window x, y and depth key and clip w of the
 * double clip position (CLIP_IN: the float64 matrix times the pool position) — value_planes'
 * per-vertex steps, made once per vertex instead of once per piece corner (meaningless
 * where w <= 0: such a vertex is never a piece's). */
typedef struct {
    double vx[CLUSTER_MAX], vy[CLUSTER_MAX], vz[CLUSTER_MAX], vw[CLUSTER_MAX];
    float x[CLUSTER_MAX], y[CLUSTER_MAX], w[CLUSTER_MAX];
    int wx[CLUSTER_MAX], wy[CLUSTER_MAX], oc[CLUSTER_MAX], uc[CLUSTER_MAX];
} __attribute__((aligned(64))) DrawVerts;

/* The nv vertices of a draw (instance matrix m, flags, pool positions from `first`: a
 * cluster's positions lie side by side in the pool) into V; returns the OR of their
 * outcodes. VERTEX_LANES (8) vertices at a time in float8 lanes where the compiler has
 * the builtins (CLRASTER_VERTEX_LANES, common.h): a full set's 24 floats as three vector
 * loads with x, y and z picked out by shuffles (eight rounds of scalar loads stored to
 * private lanes and loaded back as vectors stalled on store-to-load forwarding: the
 * transform cost setup ~0.5 ms more on the dragon at 1080p, against ~0.03 ms this way),
 * outcodes as vector compares selected into int8 bits, window positions by
 * __builtin_elementwise_roundeven (rint in the default rounding mode). Otherwise, and under
 * CLRASTER_PORTABLE (Oclgrind computed vector compares ORed into int8 masks wrongly, and
 * has no roundeven), vertex by vertex. */
#ifdef CLRASTER_VERTEX_LANES
#if VERTEX_LANES != 8
#error "draw_vertices is written for 8 lanes (float8, int8): VERTEX_LANES must be 8"
#endif
#define LANE_BIT8(test, bit) ((test) ? (int8)(bit) : (int8)0)
#endif
ALWAYS_INLINE uint draw_vertices(__global const float *pos, int first, int nv,
                                 __global const float *m, int flags, float kx, float ky,
                                 float hw, float hh, __global const double *q, int n_user,
                                 __global const double *m64, __global const double *zr,
                                 int reversed, double hwd, double hhd, double zs, double zo,
                                 DrawVerts *V)
{
    uint any = 0;
#ifdef CLRASTER_VERTEX_LANES
    int8 any8 = (int8)0;
    for (int lv0 = 0; lv0 < nv; lv0 += 8) {
        int n = imin(8, nv - lv0);
        __global const float *p0 = pos + 3 * (first + lv0);
        float8 x, y, z;
        if (n == 8) {
            float8 a = LOAD_F8(p0), b = LOAD_F8(p0 + 8), c = LOAD_F8(p0 + 16);
            x = __builtin_shufflevector(__builtin_shufflevector(a, b, 0, 3, 6, 9, 12, 15, 0, 0),
                                        c, 0, 1, 2, 3, 4, 5, 10, 13);
            y = __builtin_shufflevector(__builtin_shufflevector(a, b, 1, 4, 7, 10, 13, 0, 0, 0),
                                        c, 0, 1, 2, 3, 4, 8, 11, 14);
            z = __builtin_shufflevector(__builtin_shufflevector(a, b, 2, 5, 8, 11, 14, 0, 0, 0),
                                        c, 0, 1, 2, 3, 4, 9, 12, 15);
        } else {
            /* the draw's last, partial set (its spare lanes repeat vertex lv0, and nothing
             * reads them: a triangle's local indices are < nv); a vector load here could
             * read past the pool's end */
            float px[8] __attribute__((aligned(32))), py[8] __attribute__((aligned(32)));
            float pz[8] __attribute__((aligned(32)));
            for (int l = 0; l < 8; ++l) {
                int k = l < n ? l : 0;
                px[l] = p0[3 * k]; py[l] = p0[3 * k + 1]; pz[l] = p0[3 * k + 2];
            }
            x = *(float8 *)px; y = *(float8 *)py; z = *(float8 *)pz;
        }
        /* clip_transform, per lane */
        float8 cx = MAT_ROW(m, 0, x, y, z), cy = MAT_ROW(m, 1, x, y, z);
        float8 cz = MAT_ROW(m, 2, x, y, z), cw = MAT_ROW(m, 3, x, y, z);
        /* viewport_vertex's arithmetic (a lane with w = 0 gets inf here, never kept) */
        float8 iw = 1.0f / cw;
        float8 xs = WIN_X_SUB(cx, iw, hw), ys = WIN_Y_SUB(cy, iw, hh);
        /* vertex_outcode, per lane */
        const int8 exp_mask = (int8)0x7f800000;
        int8 finite = ((as_int8(cx) & exp_mask) != exp_mask)
                      & ((as_int8(cy) & exp_mask) != exp_mask)
                      & ((as_int8(cz) & exp_mask) != exp_mask)
                      & ((as_int8(cw) & exp_mask) != exp_mask);
        int8 o = (int8)0;
        if (!(flags & DRAW_INSIDE)) {
            o |= FRUSTUM_OUTCODE(cx, cy, cz, cw, 0.0f, LANE_BIT8);
            o |= (cx + kx * cw < 0.0f) ? (int8)OC_GB_X_NEG : (int8)0;
            o |= (kx * cw - cx < 0.0f) ? (int8)OC_GB_X_POS : (int8)0;
            o |= (cy + ky * cw < 0.0f) ? (int8)OC_GB_Y_NEG : (int8)0;
            o |= (ky * cw - cy < 0.0f) ? (int8)OC_GB_Y_POS : (int8)0;
            o |= (cw > 0.0f) ? (int8)0 : (int8)OC_W_NONPOS;
        }
        o = finite ? o : (int8)OC_INVALID;
        int8 drawn = (o & (int8)(OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP)) == 0;
        /* 0 chosen before the conversion: a non-finite or out-of-range lane converted to
         * int would be undefined (LLVM's poison), even where the choice then drops it */
        int8 wx = convert_int8(__builtin_elementwise_roundeven(drawn ? xs : (float8)0.0f));
        int8 wy = convert_int8(__builtin_elementwise_roundeven(drawn ? ys : (float8)0.0f));
        *(float8 *)&V->x[lv0] = cx; *(float8 *)&V->y[lv0] = cy; *(float8 *)&V->w[lv0] = cw;
        *(int8 *)&V->wx[lv0] = wx; *(int8 *)&V->wy[lv0] = wy; *(int8 *)&V->oc[lv0] = o;
        any8 |= o;
        /* CLIP_IN and value_planes' window position and depth key, per lane */
        double8 dx = TO_DOUBLE8(x), dy = TO_DOUBLE8(y), dz = TO_DOUBLE8(z);
        double8 vw = MAT_ROW(m64, 3, dx, dy, dz);
        double8 vr = reversed ? MAT_ROW(zr, 0, dx, dy, dz) : MAT_ROW(m64, 2, dx, dy, dz);
        double8 iwd = 1.0 / vw;
        *(double8 *)&V->vx[lv0] = (MAT_ROW(m64, 0, dx, dy, dz) * iwd + 1.0) * hwd;
        *(double8 *)&V->vy[lv0] = (1.0 - MAT_ROW(m64, 1, dx, dy, dz) * iwd) * hhd;
        *(double8 *)&V->vz[lv0] = (vr * iwd) * zs + zo;
        *(double8 *)&V->vw[lv0] = vw;
    }
    any = (uint)(((any8.s0 | any8.s1) | (any8.s2 | any8.s3))
                 | ((any8.s4 | any8.s5) | (any8.s6 | any8.s7)));
    if (n_user > 0)
        for (int v = 0; v < nv; ++v) {
            __global const float *p = pos + 3 * (first + v);
            V->uc[v] = (int)vertex_ucode(q, n_user, (uint)V->oc[v], p[0], p[1], p[2]);
        }
#else
    for (int v = 0; v < nv; ++v) {
        __global const float *p = pos + 3 * (first + v);
        float4 c = clip_transform(m, p[0], p[1], p[2]);
        uint o = vertex_outcode(c, flags, kx, ky);
        int wx = 0, wy = 0;
        if (!(o & (OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP))) {
            float iw = 1.0f / c.w;
            wx = (int)RINTF(WIN_X_SUB(c.x, iw, hw));
            wy = (int)RINTF(WIN_Y_SUB(c.y, iw, hh));
        }
        V->x[v] = c.x; V->y[v] = c.y; V->w[v] = c.w;
        V->wx[v] = wx; V->wy[v] = wy; V->oc[v] = (int)o;
        double dx = (double)p[0], dy = (double)p[1], dz = (double)p[2];
        double vw = MAT_ROW(m64, 3, dx, dy, dz);
        double vr = reversed ? MAT_ROW(zr, 0, dx, dy, dz) : MAT_ROW(m64, 2, dx, dy, dz);
        double iwd = 1.0 / vw;
        V->vx[v] = (MAT_ROW(m64, 0, dx, dy, dz) * iwd + 1.0) * hwd;
        V->vy[v] = (1.0 - MAT_ROW(m64, 1, dx, dy, dz) * iwd) * hhd;
        V->vz[v] = (vr * iwd) * zs + zo;
        V->vw[v] = vw;
        V->uc[v] = n_user > 0 ? (int)vertex_ucode(q, n_user, o, p[0], p[1], p[2]) : 0;
        any |= o;
    }
#endif
    return any;
}

/* The triangle this work-item of the clipper's kernels works on: entry get_global_id of
 * setup_triangles' list of the n_clip clipped triangles, (draw, local triangle). Gives its
 * draw, its slot in the frame's triangle stream, its three vertices in the geometry pool
 * and its id. Returns 0 for idle work-items (past the list's end). */
inline int clipped_triangle(__global const int2 *clip_list, int n_clip,
                            __global const Draw *draws, __global const int4 *clusters,
                            __global const uchar4 *local_tris,
                            __global const int *face_ids, int *g, int *d, int *slot,
                            int *i0, int *i1, int *i2, int *id)
{
    *g = (int)get_global_id(0);
    if (*g >= n_clip) return 0;
    int2 e = clip_list[*g];
    Draw dr = draws[e.x];
    int4 ci = clusters[dr.cluster];
    uchar4 tv = local_tris[ci.x + e.y];
    *d = e.x;
    *slot = dr.tri_base + e.y;
    *i0 = ci.z + tv.x;
    *i1 = ci.z + tv.y;
    *i2 = ci.z + tv.z;
    *id = dr.face_base + face_ids[ci.x + e.y];
    return 1;
}

#define DRAW_ARGS                                                                          \
    __global const Draw *restrict draws, const uint n_draws,                               \
    __global const int4 *restrict clusters, __global const uchar4 *restrict local_tris,    \
    __global const int *restrict face_ids, __global const float *restrict pos,             \
    __global const double *restrict mvps64,                                                \
    __global const double *restrict zrows, __global const double *restrict uplanes,       \
    const int n_user, const uint uclip, __global const float *restrict mvps

/* The distances of triangle (i0, i1, i2) (pool vertices) of draw dr to the user planes in
 * umask, into ud[3k + j] (vertex j, plane k): user_dist, as vertex_ucode. */
inline void user_dists(__global const float *pos, __global const double *uplanes,
                       int n_user, uint umask, Draw dr, int i0, int i1, int i2, double *ud)
{
    int v[3] = {i0, i1, i2};
    __global const double *q = uplanes + 4 * n_user * dr.instance;
    for (int k = 0; k < n_user; ++k) {
        if (!(umask & (1u << k))) continue;
        for (int j = 0; j < 3; ++j)
            ud[3 * k + j] = user_dist(q + 4 * k, pos[3 * v[j]], pos[3 * v[j] + 1],
                                      pos[3 * v[j] + 2]);
    }
}

/* The frame's depth convention (kernel argument `reversed`): value_planes' scale and
 * offset of the depth key (see ClipIn and value_planes). */
#define DEPTH_MODE(reversed) \
    double zs = (reversed) ? -0.5 : 0.5, zo = (reversed) ? 0.0 : 0.5

/* ---- setup_triangles: a draw per work-item, its triangles SETUP_LANES at a time ---------
 *
 * On a dense mesh few triangles become pieces (the dragon at 640 x 480: 47K of 694K, the
 * rest back faces or boxes without a sample), and one work-item per triangle spent most of
 * its time on branches that went either way at random. Here a work-item takes a whole draw
 * and decides the fates of SETUP_LANES consecutive triangles at a time (batch_fates) in
 * vector lanes, branch-free, in the scalar path's order (outcodes, facing, clipping, w,
 * then make_piece's area, box and 2 x 2 test for triangles under SMALL_EXTENT sub-pixels
 * wide and high, where every product fits in 32 bits); only the triangles still open after
 * that (a sample found, or a larger box) go on, SETUP_LAG batches later: make_piece's
 * coverage one after the other (raster_piece: piece_cover, which tests the centres of the
 * boxes of up to 4 x 4 the lanes left to it), then their value planes
 * SETUP_LANES pieces at a time in double lanes (value_planes8). Same statuses, records and
 * tile words as the scalar make_piece: a lane test is the scalar test on the same integers
 * and doubles (FP_CONTRACT is off). */

/* A lane's box is tested in lanes when the triangle spans fewer than this many sub-pixels
 * in x and in y: its edge products stay under 2^21 (int), and its box holds at most 4 x 4
 * pixel centres. */
#define SMALL_EXTENT (4 * SUB_ONE)
#if SETUP_LANES != 8
#error "batch_fates is written for 8 lanes (int8, double8): SETUP_LANES must be 8"
#endif
/* raster_piece runs for a batch's open lanes this many batches after their fates, so that
 * their records' lines have arrived (2 to 8 measured alike; 1 or 0 waited) */
#define SETUP_LAG 4

/* Lanes of index vector ix through the scalar expression E(i). */
#define GATHER8(T, E, ix) ((T)(E((ix).s0), E((ix).s1), E((ix).s2), E((ix).s3),            \
                               E((ix).s4), E((ix).s5), E((ix).s6), E((ix).s7)))
/* a where lane mask m (-1/0) is set, else b; min and max of int8 variables. Bit operations,
 * not ?: (Oclgrind computes ?: on int vector masks wrongly). */
#define SEL8(m, a, b) (((a) & (m)) | ((b) & ~(m)))
#define MIN8(a, b) SEL8((a) < (b), (a), (b))
#define MAX8(a, b) SEL8((a) > (b), (a), (b))

/* Edge (a -> b) of the lanes' pieces at their pixel centre (cx, cy), as set_edge (common.h)
 * in int lanes: e (minus the top-left bias), sx and sy (one pixel right / down). Inputs are
 * masked to the lanes mk whose values stay small (the others get e = -1, sx = sy = 0,
 * never read). */
#define EDGE8(ax, ay, bx, by, mk, e, sx, sy) do {                                          \
    int8 dx_ = ((bx) - (ax)) & (mk), dy_ = ((by) - (ay)) & (mk);                           \
    int8 rx_ = (cx - (ax)) & (mk), ry_ = (cy - (ay)) & (mk);                               \
    int8 tl_ = (dy_ < 0) | ((dy_ == 0) & (dx_ > 0));   /* -1: top or left, bias 0 */        \
    e = (dx_ * ry_ - dy_ * rx_) - (1 + tl_);                                               \
    sx = -dy_ * SUB_ONE;                                                                   \
    sy = dx_ * SUB_ONE;                                                                    \
} while (0)
#define INSIDE8(k, j) ((e0 + (k) * sx0 + (j) * sy0 >= 0) & (e1 + (k) * sx1 + (j) * sy1 >= 0) \
                       & (e2 + (k) * sx2 + (j) * sy2 >= 0))

/* Pieces of one draw whose coverage is set up (piece_cover) and whose value planes wait
 * to be made SETUP_LANES at a time in double lanes (value_planes8): per lane its record
 * slot, its corners' pool vertices and snapped window positions in the piece's order (1
 * and 2 swapped where the area was negative), its doubled area over 65536 (exact: the
 * area of a piece in the guard band is far below 2^53), its box's first pixel, and the
 * record's id, flags and cover words. value_planes8 does value_planes' double operations
 * in the same order on each lane, so each record's bytes are those of make_piece. */
typedef struct {
    double as[SETUP_LANES];   /* first: read as one double8, 64-byte aligned */
    int slot[SETUP_LANES], pa[SETUP_LANES], pb[SETUP_LANES], pc[SETUP_LANES];
    int x0[SETUP_LANES], y0[SETUP_LANES], x1[SETUP_LANES], y1[SETUP_LANES];
    int x2[SETUP_LANES], y2[SETUP_LANES], px0[SETUP_LANES], py0[SETUP_LANES];
    int id[SETUP_LANES], flags[SETUP_LANES], cover[SETUP_LANES];
    int n;   /* pieces waiting */
} __attribute__((aligned(64))) ValueQueue;

/* Per lane: a where the lane mask m (long8 -1/0) is set, else b (double8); min as mind */
#define SELD8(m, a, b) as_double8((as_long8(a) & (m)) | (as_long8(b) & ~(m)))
#define MIND8(a, b) SELD8((a) <= (b), (a), (b))
#define LOAD_Q8(a) (*(int8 *)(a))

/* The 8 x 8 int matrix of vectors a[0..7] transposed into t[0..7] (t[k].sj = a[j].sk): by
 * shuffles (unpack the pairs, then their 64-bit halves, then the 128-bit halves: 24 where
 * lane-by-lane rows took ~130 moves); fallback: lane by lane. */
#ifdef CLRASTER_NO_SHUFFLEVECTOR
#define TRANSPOSE8_I(a, t)                                                                 \
    for (int k_ = 0; k_ < 8; ++k_) {                                                       \
        int e_[8];                                                                         \
        for (int j_ = 0; j_ < 8; ++j_) e_[j_] = ((int *)&(a)[j_])[k_];                     \
        (t)[k_] = (int8)(e_[0], e_[1], e_[2], e_[3], e_[4], e_[5], e_[6], e_[7]);          \
    }
#else
#define TRANSPOSE8_I(a, t) {                                                               \
    int8 u0_ = __builtin_shufflevector((a)[0], (a)[1], 0, 8, 1, 9, 4, 12, 5, 13);          \
    int8 u1_ = __builtin_shufflevector((a)[0], (a)[1], 2, 10, 3, 11, 6, 14, 7, 15);        \
    int8 u2_ = __builtin_shufflevector((a)[2], (a)[3], 0, 8, 1, 9, 4, 12, 5, 13);          \
    int8 u3_ = __builtin_shufflevector((a)[2], (a)[3], 2, 10, 3, 11, 6, 14, 7, 15);        \
    int8 u4_ = __builtin_shufflevector((a)[4], (a)[5], 0, 8, 1, 9, 4, 12, 5, 13);          \
    int8 u5_ = __builtin_shufflevector((a)[4], (a)[5], 2, 10, 3, 11, 6, 14, 7, 15);        \
    int8 u6_ = __builtin_shufflevector((a)[6], (a)[7], 0, 8, 1, 9, 4, 12, 5, 13);          \
    int8 u7_ = __builtin_shufflevector((a)[6], (a)[7], 2, 10, 3, 11, 6, 14, 7, 15);        \
    int8 v0_ = __builtin_shufflevector(u0_, u2_, 0, 1, 8, 9, 4, 5, 12, 13);                \
    int8 v1_ = __builtin_shufflevector(u0_, u2_, 2, 3, 10, 11, 6, 7, 14, 15);              \
    int8 v2_ = __builtin_shufflevector(u1_, u3_, 0, 1, 8, 9, 4, 5, 12, 13);                \
    int8 v3_ = __builtin_shufflevector(u1_, u3_, 2, 3, 10, 11, 6, 7, 14, 15);              \
    int8 v4_ = __builtin_shufflevector(u4_, u6_, 0, 1, 8, 9, 4, 5, 12, 13);                \
    int8 v5_ = __builtin_shufflevector(u4_, u6_, 2, 3, 10, 11, 6, 7, 14, 15);              \
    int8 v6_ = __builtin_shufflevector(u5_, u7_, 0, 1, 8, 9, 4, 5, 12, 13);                \
    int8 v7_ = __builtin_shufflevector(u5_, u7_, 2, 3, 10, 11, 6, 7, 14, 15);              \
    (t)[0] = __builtin_shufflevector(v0_, v4_, 0, 1, 2, 3, 8, 9, 10, 11);                  \
    (t)[1] = __builtin_shufflevector(v1_, v5_, 0, 1, 2, 3, 8, 9, 10, 11);                  \
    (t)[2] = __builtin_shufflevector(v2_, v6_, 0, 1, 2, 3, 8, 9, 10, 11);                  \
    (t)[3] = __builtin_shufflevector(v3_, v7_, 0, 1, 2, 3, 8, 9, 10, 11);                  \
    (t)[4] = __builtin_shufflevector(v0_, v4_, 4, 5, 6, 7, 12, 13, 14, 15);                \
    (t)[5] = __builtin_shufflevector(v1_, v5_, 4, 5, 6, 7, 12, 13, 14, 15);                \
    (t)[6] = __builtin_shufflevector(v2_, v6_, 4, 5, 6, 7, 12, 13, 14, 15);                \
    (t)[7] = __builtin_shufflevector(v3_, v7_, 4, 5, 6, 7, 12, 13, 14, 15);                \
}
#endif

/* The value planes of the q->n (1..SETUP_LANES) queued pieces of the draw whose vertices
 * are V, in lanes, and the rest of their records (id, flags, values, cover, pad: the
 * record's last 64 bytes); the queue is emptied. */
ALWAYS_INLINE void value_planes8(ValueQueue *q, const DrawVerts *V, __global Piece *pieces)
{
    int n = q->n;
    for (int k = n; k < SETUP_LANES; ++k) {   /* idle lanes: lane 0's piece (never stored) */
        q->pa[k] = q->pa[0]; q->pb[k] = q->pb[0]; q->pc[k] = q->pc[0];
        q->x0[k] = q->x0[0]; q->y0[k] = q->y0[0]; q->x1[k] = q->x1[0];
        q->y1[k] = q->y1[0]; q->x2[k] = q->x2[0]; q->y2[k] = q->y2[0];
        q->px0[k] = q->px0[0]; q->py0[k] = q->py0[0]; q->as[k] = q->as[0];
    }
    /* value_planes, lane by lane, from its per-vertex steps made by draw_vertices */
#define V_X(i) V->vx[i]
#define V_Y(i) V->vy[i]
#define V_Z(i) V->vz[i]
#define V_W(i) V->vw[i]
    int8 ia = LOAD_Q8(q->pa), ib = LOAD_Q8(q->pb), ic = LOAD_Q8(q->pc);
    double8 x0 = GATHER8(double8, V_X, ia), y0 = GATHER8(double8, V_Y, ia);
    double8 x1 = GATHER8(double8, V_X, ib), y1 = GATHER8(double8, V_Y, ib);
    double8 x2 = GATHER8(double8, V_X, ic), y2 = GATHER8(double8, V_Y, ic);
    double8 z0 = GATHER8(double8, V_Z, ia), z1 = GATHER8(double8, V_Z, ib);
    double8 z2 = GATHER8(double8, V_Z, ic);
    double8 aw = GATHER8(double8, V_W, ia), bw = GATHER8(double8, V_W, ib);
    double8 cw = GATHER8(double8, V_W, ic);
    double8 as = *(double8 *)q->as;
    double8 area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0);
    long8 keep = (area >= 0.5 * as) & (area <= 2.0 * as);   /* else the snapped corners */
    const double s = 1.0 / 256.0;
    x0 = SELD8(keep, x0, TO_DOUBLE8(LOAD_Q8(q->x0)) * s);
    y0 = SELD8(keep, y0, TO_DOUBLE8(LOAD_Q8(q->y0)) * s);
    x1 = SELD8(keep, x1, TO_DOUBLE8(LOAD_Q8(q->x1)) * s);
    y1 = SELD8(keep, y1, TO_DOUBLE8(LOAD_Q8(q->y1)) * s);
    x2 = SELD8(keep, x2, TO_DOUBLE8(LOAD_Q8(q->x2)) * s);
    y2 = SELD8(keep, y2, TO_DOUBLE8(LOAD_Q8(q->y2)) * s);
    area = SELD8(keep, area, as);
    double8 inv = 1.0 / area;
    double8 rx = TO_DOUBLE8(LOAD_Q8(q->px0)) + 0.5;
    double8 ry = TO_DOUBLE8(LOAD_Q8(q->py0)) + 0.5;
    double8 l1 = ((x0 - x2) * (ry - y2) - (y0 - y2) * (rx - x2)) * inv;
    double8 l1x = -(y0 - y2) * inv, l1y = (x0 - x2) * inv;
    double8 l2 = ((x1 - x0) * (ry - y0) - (y1 - y0) * (rx - x0)) * inv;
    double8 l2x = -(y1 - y0) * inv, l2y = (x1 - x0) * inv;
    double8 dz10 = z1 - z0, dz20 = z2 - z0;
    /* the record's words 10..21 (z0 .. zlo), lane by lane */
    int8 w[16];   /* words 8..23 of the records (id .. pad), a vector per word */
    w[0] = LOAD_Q8(q->id);
    w[1] = LOAD_Q8(q->flags);
    w[2] = as_int8(TO_FLOAT8((z0 + l1 * dz10) + l2 * dz20));
    w[3] = as_int8(TO_FLOAT8(l1x * dz10 + l2x * dz20));
    w[4] = as_int8(TO_FLOAT8(l1y * dz10 + l2y * dz20));
    w[5] = as_int8(TO_FLOAT8(l1));
    w[6] = as_int8(TO_FLOAT8(l1x));
    w[7] = as_int8(TO_FLOAT8(l1y));
    w[8] = as_int8(TO_FLOAT8(l2));
    w[9] = as_int8(TO_FLOAT8(l2x));
    w[10] = as_int8(TO_FLOAT8(l2y));
    w[11] = as_int8(TO_FLOAT8(aw / bw));
    w[12] = as_int8(TO_FLOAT8(aw / cw));
    w[13] = as_int8(TO_FLOAT8(MIND8(MIND8(z0, z1), z2)));
    w[14] = LOAD_Q8(q->cover);
    w[15] = (int8)0;   /* pad */
    /* the records' last 64 bytes, a row per lane (as int words: the bits, whatever they
     * are): two 8 x 8 transposes, then two stores per piece */
    int8 r[16];
    TRANSPOSE8_I(w, r)
    TRANSPOSE8_I(w + 8, r + 8)
    for (int k = 0; k < n; ++k) {
        __global int8 *d8 = (__global int8 *)&pieces[q->slot[k]];
        d8[1] = r[k];
        d8[2] = r[8 + k];
    }
    q->n = 0;
}

/* The piece of unclipped triangle t (local vertices i0, i1, i2 of the draw's vertices V,
 * id) that passed the outcode, facing,
 * clipping and w tests: piece_cover (with the cover bits `known` the lanes found), its
 * status and tile word, and, for a piece, its record's first 32 bytes (x, y, box) now and
 * the rest through the queue q (value_planes8 once SETUP_LANES are waiting; the caller
 * empties it at the draw's end). */
ALWAYS_INLINE void raster_piece(int t, int i0, int i1, int i2, int id, int known, const DrawVerts *V, int width, int height,
                                int tiles_x, __global Piece *pieces, __global uchar *status,
                                __global int *tile1, ValueQueue *q)
{
    Piece pc;
    int sw = 0, one = TILE1_NONE;
    long area2;
    int st = piece_cover((int2)(V->wx[i0], V->wy[i0]), (int2)(V->wx[i1], V->wy[i1]),
                         (int2)(V->wx[i2], V->wy[i2]), width, height, known, &pc, &sw,
                         &area2);
    if (st == ST_RASTER) {
        /* the record's first 32 bytes; binning reads the records right after this stage
         * and, with a large enough last-level cache, finds them there (ordinary stores) */
        *(__global int8 *)&pieces[t] = (int8)(pc.x[0], pc.x[1], pc.x[2], pc.y[0], pc.y[1],
                                              pc.y[2], pc.bb_min, pc.bb_max);
        int k = q->n++;
        q->slot[k] = t;
        q->pa[k] = i0;
        q->pb[k] = sw ? i2 : i1;
        q->pc[k] = sw ? i1 : i2;
        q->x0[k] = pc.x[0]; q->y0[k] = pc.y[0];
        q->x1[k] = pc.x[1]; q->y1[k] = pc.y[1];
        q->x2[k] = pc.x[2]; q->y2[k] = pc.y[2];
        q->px0[k] = bb_x(pc.bb_min); q->py0[k] = bb_y(pc.bb_min);
        q->as[k] = (double)area2 * (1.0 / 65536.0);
        q->id[k] = id;
        q->flags[k] = sw ? PF_SWAPPED : 0;
        q->cover[k] = pc.cover;
        /* the one tile of a piece whose pixel box lies in one tile (most pieces of a dense
         * mesh), or the tiles of one over at most 2 x 2: binning counts them from this word
         * alone (common.h TILE1_*), without the record of every piece over several tiles:
         * a cache miss each when the slots' buffer is bigger than the cache. */
        int bx0 = bb_x(pc.bb_min), by0 = bb_y(pc.bb_min);
        int bx1 = bb_x(pc.bb_max), by1 = bb_y(pc.bb_max);
        int tx0 = bx0 >> TILE_LOG2, ty0 = by0 >> TILE_LOG2;
        int tx1 = bx1 >> TILE_LOG2, ty1 = by1 >> TILE_LOG2;
        if (tx0 == tx1 && ty0 == ty1) {
            one = ty0 * tiles_x + tx0;
        } else if (tx1 - tx0 <= 1 && ty1 - ty0 <= 1) {
            uint mask = few_tile_mask(pc.x, pc.y, bx0, by0, bx1, by1, tx0, ty0, tx1, ty1);
            one = TILE1_FEW - (int)(((uint)(ty0 * tiles_x + tx0) << 4) | mask);
        } else {
            one = TILE1_WALK;
        }
    }
    status[t] = (uchar)st;
    tile1[t] = one;
}

/* The fates of local triangles lt0 .. lt0 + n - 1 (n <= SETUP_LANES) of draw dr (its
 * cluster's triangles tv, its vertices V; codes = 0: every outcode of the draw is 0) in
 * lanes: the decided ones' status and tile word stored; returns the lanes still open (bit
 * j: triangle lt0 + j, for raster_piece), their records' lines asked for. */
ALWAYS_INLINE uint batch_fates(int lt0, int n, Draw dr, __global const uchar4 *tv,
                               const DrawVerts *V, int n_user, uint uclip, int width,
                               int height, int cull,
                               __global const Piece *pieces, __global uchar *status,
                               __global int *tile1, __global int *n_clipped,
                               __global int *clip_count, __global int2 *clip_list,
                               uint d, uchar *known, int codes)
{
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 open = lane < (int8)n;               /* lanes whose fate is not decided yet */
    /* idle lanes (past the draw's last triangle) repeat its last triangle: every gather
     * stays in the buffers; nothing of theirs is stored */
    int8 lt = lt0 + SEL8(open, lane, (int8)(n - 1));
#define TV_X(i) (int)tv[i].x
#define TV_Y(i) (int)tv[i].y
#define TV_Z(i) (int)tv[i].z
    int8 i0 = GATHER8(int8, TV_X, lt);
    int8 i1 = GATHER8(int8, TV_Y, lt);
    int8 i2 = GATHER8(int8, TV_Z, lt);
#define OUTC(i) V->oc[i]
    int8 o_or = (int8)0, o_and = (int8)0;   /* (all 0 where the draw's outcodes are) */
    if (codes) {
        int8 o0 = GATHER8(int8, OUTC, i0), o1 = GATHER8(int8, OUTC, i1);
        int8 o2 = GATHER8(int8, OUTC, i2);
        o_or = o0 | o1 | o2;
        o_and = o0 & o1 & o2;
    }
    /* user clip planes: all three vertices outside one → rejected; any outside one of the
     * clipping planes (uclip bits; the others, a polygon window's, only reject) → clipped */
    int8 u_or = (int8)0, u_and = (int8)0;
    if (n_user > 0) {
#define UC(i) V->uc[i]
        int8 u0 = GATHER8(int8, UC, i0), u1 = GATHER8(int8, UC, i1);
        int8 u2 = GATHER8(int8, UC, i2);
        u_or = u0 | u1 | u2;
        u_and = u0 & u1 & u2;
    }
    int8 st = (int8)ST_RASTER;
/* lanes m (among the open ones) take status `code` and close */
#define DECIDE(m, code) do {                                                               \
    int8 m_ = (m) & open;                                                                  \
    st = SEL8(m_, (int8)(code), st);                                                       \
    open &= ~m_;                                                                           \
} while (0)
    DECIDE((o_or & OC_INVALID) != 0, ST_INVALID);
    DECIDE(((o_and & OC_FRUSTUM) != 0) | (u_and != 0), ST_TRIVIAL_REJECT);
    /* facing (FACING_DET) from the float32 clip positions in double lanes */
#define CX(i) V->x[i]
#define CY(i) V->y[i]
#define CW(i) V->w[i]
#define CLIP_D8(E, ix) TO_DOUBLE8(GATHER8(float8, E, ix))
    double8 ax = CLIP_D8(CX, i0), ay = CLIP_D8(CY, i0), aw = CLIP_D8(CW, i0);
    double8 bx = CLIP_D8(CX, i1), by = CLIP_D8(CY, i1), bw = CLIP_D8(CW, i1);
    double8 cx_ = CLIP_D8(CX, i2), cy_ = CLIP_D8(CY, i2), cw_ = CLIP_D8(CW, i2);
    double8 det = FACING_DET(ax, ay, aw, bx, by, bw, cx_, cy_, cw_);
    DECIDE(MASK_INT8(det == 0.0), ST_DEGENERATE);
    int dcull = draw_cull(cull, dr.flags);
    if (dcull == CULL_BACK) DECIDE(MASK_INT8(det < 0.0), ST_BACKFACE);
    if (dcull == CULL_FRONT) DECIDE(MASK_INT8(det > 0.0), ST_BACKFACE);
    int8 clipped = (((o_or & OC_NEEDS_CLIP) != 0) | ((u_or & (int)uclip) != 0)) & open;
    DECIDE(clipped, ST_CLIPPED);
    /* the host skips the clipper's count and scan when no triangle needs it; its pieces
     * are counted by setup_count_clipped (the clipper's polygon arrays inlined here made
     * every work-item pay for them), which runs over the clipped triangles listed here
     * (draw d, local triangle) alone: few of a frame's triangles are clipped, and over
     * every triangle of the frame the clipper's kernels spent most of their time on the
     * others. The list's order varies from run to run; each triangle's pieces go to its
     * place in the stream (clip_offset, a scan over the slots), so the output does not. */
    if (any8(clipped)) {
        /* no pieces until setup_count_clipped counts them: a pass the host enqueued
         * binning for without that count (every draw DRAW_INSIDE or DRAW_NO_CLIP, which
         * the host's margins make this branch never see) bins none of this triangle, and
         * the host raises on the count, rather than binning from unwritten counts */
        int c_[8] __attribute__((aligned(32)));
        *(int8 *)c_ = clipped;
        for (int j = 0; j < n; ++j)
            if (c_[j]) {
                clip_count[dr.tri_base + lt0 + j] = 0;
                clip_list[atomic_inc(n_clipped)] = (int2)((int)d, lt0 + j);
            }
    }
    DECIDE((o_or & OC_W_NONPOS) != 0, ST_DEGENERATE);   /* a vertex at w = 0 */
    /* a mesh's back faces come in runs (a cluster's triangles are neighbours): a batch
     * with no lane left open skips the rest */
    int8 kc = (int8)0;   /* cover bits found here (piece_cover adds COVER_KNOWN), else 0 */
    if (any8(open)) {
        /* make_piece's first steps for small triangles: area, box, the 2 x 2 test */
#define WX(i) V->wx[i]
#define WY(i) V->wy[i]
        int8 x0 = GATHER8(int8, WX, i0) & open, y0 = GATHER8(int8, WY, i0) & open;
        int8 x1 = GATHER8(int8, WX, i1) & open, y1 = GATHER8(int8, WY, i1) & open;
        int8 x2 = GATHER8(int8, WX, i2) & open, y2 = GATHER8(int8, WY, i2) & open;
        int8 xmin = MIN8(x0, x1), xmax = MAX8(x0, x1);
        int8 ymin = MIN8(y0, y1), ymax = MAX8(y0, y1);
        xmin = MIN8(xmin, x2); xmax = MAX8(xmax, x2);
        ymin = MIN8(ymin, y2); ymax = MAX8(ymax, y2);
        int8 small = open & (xmax - xmin < SMALL_EXTENT) & (ymax - ymin < SMALL_EXTENT);
        int8 area2 = ((x1 - x0) & small) * ((y2 - y0) & small)
                     - ((y1 - y0) & small) * ((x2 - x0) & small);   /* edge_fn(v0, v1, v2) */
        DECIDE(small & (area2 == 0), ST_DEGENERATE);
        small &= open;
        int8 px0 = MAX8((xmin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, (int8)0);
        int8 px1 = MIN8((xmax - SUB_HALF) >> SUBPIXEL_BITS, (int8)(width - 1));
        int8 py0 = MAX8((ymin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, (int8)0);
        int8 py1 = MIN8((ymax - SUB_HALF) >> SUBPIXEL_BITS, (int8)(height - 1));
        int8 boxed = (px0 <= px1) & (py0 <= py1);
        DECIDE(small & ~boxed, ST_NO_SAMPLE);
        int8 two_x = px1 > px0, two_y = py1 > py0;
        int8 m22 = small & open & (px1 - px0 <= 1) & (py1 - py0 <= 1);
        /* positive area: vertices 1 and 2 swapped where area2 < 0 (make_piece) */
        int8 swap = area2 < 0;
        int8 X1 = SEL8(swap, x2, x1), Y1 = SEL8(swap, y2, y1);
        int8 X2 = SEL8(swap, x1, x2), Y2 = SEL8(swap, y1, y2);
        int8 cx = (px0 << SUBPIXEL_BITS) + SUB_HALF, cy = (py0 << SUBPIXEL_BITS) + SUB_HALF;
        int8 e0, e1, e2, sx0, sx1, sx2, sy0, sy1, sy2;
        EDGE8(X1, Y1, X2, Y2, m22, e0, sx0, sy0);
        EDGE8(X2, Y2, x0, y0, m22, e1, sx1, sy1);
        EDGE8(x0, y0, X1, Y1, m22, e2, sx2, sy2);
        /* Piece.cover's bits: centre (k, j) at bit k + COVER_SPAN·j (piece_cover); the
         * larger small boxes are tested by piece_cover, one piece at a time */
        int8 cover = (INSIDE8(0, 0) & 1) | (two_x & INSIDE8(1, 0) & 2)
                     | (two_y & INSIDE8(0, 1) & (1 << COVER_SPAN))
                     | (two_x & two_y & INSIDE8(1, 1) & (2 << COVER_SPAN));
        DECIDE(m22 & (cover == 0), ST_NO_SAMPLE);
        kc = cover & m22 & open;
    }
    *(uchar8 *)(known + lt0) = CONVERT_VEC(kc, uchar8);
    /* the decided lanes' status and tile word; the open ones are written by raster_piece.
     * clip_count is not written here: setup_count_clipped writes it for ST_CLIPPED slots,
     * and nothing reads it for others (the scan and setup_clipped look at status first;
     * binning reads it for clipped slots only), which saves a 4-byte store per triangle. */
    int8 one = SEL8(st == ST_CLIPPED, (int8)TILE1_WALK, (int8)TILE1_NONE);
    int t0 = dr.tri_base + lt0;
    if (n == SETUP_LANES) {
        STORE_UC8(CONVERT_VEC(st, uchar8), status + t0);
        STORE_I8(one, tile1 + t0);
    } else {
#define STORE_LANE(k)                                                                      \
    if ((k) < n) {                                                                         \
        status[t0 + (k)] = (uchar)st.s##k;                                                 \
        tile1[t0 + (k)] = one.s##k;                                                        \
    }
        STORE_LANE(0) STORE_LANE(1) STORE_LANE(2) STORE_LANE(3)
        STORE_LANE(4) STORE_LANE(5) STORE_LANE(6)
    }
    /* the open lanes' record lines, asked for now: most slots of the records' buffer are
     * never written in a frame of a dense mesh, and a store to a line not in the cache
     * waited for it (raster_piece runs SETUP_LAG batches later) */
    int8 bits = open & (int8)(1, 2, 4, 8, 16, 32, 64, 128);
    uint left = (uint)(((bits.s0 | bits.s1) | (bits.s2 | bits.s3))
                       | ((bits.s4 | bits.s5) | (bits.s6 | bits.s7)));
    for (uint m = left; m; m &= m - 1) {
        __global const char *rec = (__global const char *)&pieces[t0 + CTZ(m)];
        PREFETCH(rec); PREFETCH(rec + 64);
    }
    return left;
}

__kernel void setup_triangles(DRAW_ARGS, const int width, const int height, const int cull,
                              const float kx, const float ky, const int reversed,
                              __global Piece *restrict pieces,
                              __global uchar *restrict status,
                              const int tiles_x, __global int *restrict tile1,
                              __global int *restrict n_clipped,
                              __global int *restrict clip_count,
                              __global int2 *restrict clip_list)
{
    DEPTH_MODE(reversed);
    /* one work-item per draw (work-groups of one): its triangles in batches of SETUP_LANES */
    uint d = get_group_id(0);
    if (d >= n_draws) return;
    Draw dr = draws[d];
    int4 ci = clusters[dr.cluster];
    __global const uchar4 *tv = local_tris + ci.x;
    int nt = imin(ci.y, CLUSTER_MAX);   /* (the host refuses larger clusters) */
    int nb = (nt + SETUP_LANES - 1) / SETUP_LANES;
    /* the draw's vertices, and whether any has an outcode bit: most draws of a framed mesh
     * have none (inside the frustum by a margin: only OC_INVALID is tested there), and
     * their batches then skip the outcodes' gathers */
    DrawVerts V;
    uint any_code = draw_vertices(pos, ci.z, imin(ci.w, CLUSTER_MAX), mvps + 16 * dr.instance,
                                  dr.flags, kx, ky, 0.5f * (float)width,
                                  0.5f * (float)height, uplanes + 4 * n_user * dr.instance,
                                  n_user, mvps64 + 16 * dr.instance, zrows + 4 * dr.instance,
                                  reversed, 0.5 * (double)width, 0.5 * (double)height, zs,
                                  zo, &V);
    int codes = any_code != 0;
    uint open[CLUSTER_MAX / SETUP_LANES];   /* batch h's open lanes (batch_fates) */
    uchar known[CLUSTER_MAX] __attribute__((aligned(8)));   /* their cover bits, or 0 */
    ValueQueue q;   /* pieces waiting for their value planes */
    q.n = 0;
    /* batch h's fates, then the pieces of batch h - SETUP_LAG: their records' lines were
     * asked for SETUP_LAG batches earlier */
    for (int h = 0; h < nb + SETUP_LAG; ++h) {
        if (h < nb) {
            int lt0 = SETUP_LANES * h;
            open[h] = batch_fates(lt0, imin(nt - lt0, SETUP_LANES), dr, tv, &V, n_user,
                                  uclip, width, height, cull, pieces,
                                  status, tile1, n_clipped, clip_count, clip_list, d,
                                  known, codes);
        }
        if (h < SETUP_LAG) continue;
        int lt0 = SETUP_LANES * (h - SETUP_LAG);
        for (uint left = open[h - SETUP_LAG]; left; left &= left - 1) {
            int l = lt0 + CTZ(left);
            uchar4 v = tv[l];
            raster_piece(dr.tri_base + l, v.x, v.y, v.z, dr.face_base + face_ids[ci.x + l],
                         known[l], &V, width, height, tiles_x, pieces, status, tile1, &q);
            if (q.n == SETUP_LANES) value_planes8(&q, &V, pieces);
        }
    }
    if (q.n > 0) value_planes8(&q, &V, pieces);
}

/* The clipper on triangle (i0, i1, i2) (pool vertices) of draw `dix` (setup_count_clipped,
 * setup_clipped and setup_clip_scratch, whose arguments carry these names): its corners
 * (vertex_of: the clip positions, outcodes and user plane bits setup_triangles made), its
 * frustum/guard-band planes and clipping user planes from those codes, the user-plane
 * distances, then clip_and_emit
 * with (write, out, out_bary, base), its piece count into `count`. A macro because the
 * buffers are kernel arguments of each of those kernels. */
#define CLIP_TRIANGLE(dix, count, write, out, out_bary, base) do {                        \
    Draw dr_ = draws[dix];                                                                \
    uint oc0_, oc1_, oc2_, uc0_, uc1_, uc2_;                                              \
    float4 c0_ = vertex_of(pos, mvps, uplanes, n_user, i0, dr_.instance, dr_.flags, kx, ky, \
                           &oc0_, &uc0_);                                                 \
    float4 c1_ = vertex_of(pos, mvps, uplanes, n_user, i1, dr_.instance, dr_.flags, kx, ky, \
                           &oc1_, &uc1_);                                                 \
    float4 c2_ = vertex_of(pos, mvps, uplanes, n_user, i2, dr_.instance, dr_.flags, kx, ky, \
                           &oc2_, &uc2_);                                                 \
    uint o_or_ = oc0_ | oc1_ | oc2_;                                                      \
    uint u_or_ = (uc0_ | uc1_ | uc2_) & uclip;                                            \
    double ud_[3 * USER_PLANES_MAX];                                                      \
    user_dists(pos, uplanes, n_user, u_or_, dr_, i0, i1, i2, ud_);                        \
    ClipIn d0_, d1_, d2_;                                                                 \
    CLIP_IN(d0_, i0, dr_.instance);                                                       \
    CLIP_IN(d1_, i1, dr_.instance);                                                       \
    CLIP_IN(d2_, i2, dr_.instance);                                                       \
    count = clip_and_emit(c0_, c1_, c2_, d0_, d1_, d2_,                                   \
                  o_or_ & OC_NEEDS_CLIP, u_or_, ud_, kx, ky, width, height, zs, zo, id,   \
                  (write), (out), (out_bary), (base));                                    \
} while (0)

/* Clipped pieces per ST_CLIPPED triangle (the clipper run without writing), into
 * clip_count; other triangles' entries are left unwritten (read through status). One
 * work-item per entry of the list of clipped triangles (n_clip of them). */
__kernel void setup_count_clipped(DRAW_ARGS,
                                  const int width, const int height, const float kx,
                                  const float ky, const int reversed,
                                  __global const int2 *restrict clip_list, const int n_clip,
                                  __global int *restrict clip_count)
{
    DEPTH_MODE(reversed);
    int g, d, t, i0, i1, i2, id;
    if (!clipped_triangle(clip_list, n_clip, draws, clusters, local_tris, face_ids, &g, &d,
                          &t, &i0, &i1, &i2, &id))
        return;
    CLIP_TRIANGLE(d, clip_count[t], 0, 0, 0, 0);
}

__kernel void setup_clipped(DRAW_ARGS,
                            const int width, const int height, const float kx, const float ky,
                            const int reversed, __global const int2 *restrict clip_list,
                            const int n_clip, __global const int *restrict clip_count,
                            __global const int *restrict clip_offset,
                            __global Piece *restrict clip_pieces,
                            __global float *restrict clip_bary)
{
    DEPTH_MODE(reversed);
    int g, d, t, i0, i1, i2, id;
    if (!clipped_triangle(clip_list, n_clip, draws, clusters, local_tris, face_ids, &g, &d,
                          &t, &i0, &i1, &i2, &id))
        return;
    if (clip_count[t] == 0) return;
    int written;   /* clip_count[t], counted before */
    CLIP_TRIANGLE(d, written, 1, clip_pieces, clip_bary, clip_offset[t]);
}

/* The clipper once (the host's choice when the bound below fits its scratch budget): one
 * work-item per entry g of the clipped triangles' list, its pieces and their parent
 * barycentrics written to rows g·bound .. g·bound + count − 1 of the scratch buffers (bound:
 * the most pieces a triangle can give, 1 + the planes that clip: each adds a polygon vertex
 * at most), its count to clip_count[t]; setup_clip_place then moves them to their places
 * in the stream (the scan's clip_offset). The same pieces as setup_count_clipped then
 * setup_clipped make, which run the clipper twice. */
__kernel void setup_clip_scratch(DRAW_ARGS,
                                 const int width, const int height, const float kx,
                                 const float ky, const int reversed,
                                 __global const int2 *restrict clip_list, const int n_clip,
                                 const int bound, __global int *restrict clip_count,
                                 __global Piece *restrict scratch,
                                 __global float *restrict scratch_bary)
{
    DEPTH_MODE(reversed);
    int g, d, t, i0, i1, i2, id;
    if (!clipped_triangle(clip_list, n_clip, draws, clusters, local_tris, face_ids, &g, &d,
                          &t, &i0, &i1, &i2, &id))
        return;
    int count;
    CLIP_TRIANGLE(d, count, 1, scratch, scratch_bary, g * bound);
    clip_count[t] = count;
}

/* setup_clip_scratch's pieces of list entry g to clip_pieces[clip_offset[t] ..] and their
 * parent barycentrics to clip_bary, each record's clip index (flags >> PF_INDEX_SHIFT,
 * where its barycentrics are) made its place in the stream. */
__kernel void setup_clip_place(__global const int2 *restrict clip_list, const int n_clip,
                               const int bound, __global const Draw *restrict draws,
                               __global const int *restrict clip_count,
                               __global const int *restrict clip_offset,
                               __global const Piece *restrict scratch,
                               __global const float *restrict scratch_bary,
                               __global Piece *restrict clip_pieces,
                               __global float *restrict clip_bary)
{
    int g = (int)get_global_id(0);
    if (g >= n_clip) return;
    int2 e = clip_list[g];
    int t = draws[e.x].tri_base + e.y;
    int c = clip_count[t], o = clip_offset[t];
    for (int k = 0; k < c; ++k) {
        Piece pc = scratch[g * bound + k];
        pc.flags = (pc.flags & ((1 << PF_INDEX_SHIFT) - 1)) | ((o + k) << PF_INDEX_SHIFT);
        clip_pieces[o + k] = pc;
        for (int j = 0; j < 9; ++j)
            clip_bary[9 * (o + k) + j] = scratch_bary[9 * (g * bound + k) + j];
    }
}

/* Exclusive scan of clip_count into clip_offset (and the total), in two launches over
 * `chunks` contiguous ranges: scan_partials sums each range; scan_offsets adds the sums of
 * the ranges before it and writes the prefix. One work-item per range, no barriers or local
 * memory (pyopencl's GenericScanKernel has a benign but real data race that Oclgrind
 * reports, and is slower on PoCL for these sizes). */
/* Pieces of triangle i for the scan: its clip_count where it is ST_CLIPPED (the only slots
 * where clip_count is written), else 0. */
#define CLIPPED_COUNT(i) (status[i] == ST_CLIPPED ? cnt[i] : 0)

__kernel void scan_partials(__global const uchar *restrict status,
                            __global const int *restrict cnt, const uint m, const uint chunks,
                            __global int *restrict partial)
{
    uint c = get_global_id(0);
    if (c >= chunks) return;
    uint s0 = (uint)(((ulong)c * m) / chunks), s1 = (uint)(((ulong)(c + 1) * m) / chunks);
    int s = 0;
    for (uint i = s0; i < s1; ++i) s += CLIPPED_COUNT(i);
    partial[c] = s;
}

__kernel void scan_offsets(__global const uchar *restrict status,
                           __global const int *restrict cnt, const uint m, const uint chunks,
                           __global const int *restrict partial, __global int *restrict off,
                           __global int *restrict total)
{
    uint c = get_global_id(0);
    if (c >= chunks) return;
    int s = 0;
    for (uint k = 0; k < c; ++k) s += partial[k];
    uint s0 = (uint)(((ulong)c * m) / chunks), s1 = (uint)(((ulong)(c + 1) * m) / chunks);
    for (uint i = s0; i < s1; ++i) { off[i] = s; s += CLIPPED_COUNT(i); }
    if (c + 1 == chunks) total[0] = s;
}
