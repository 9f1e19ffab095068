/* Per-pixel passes over a finished frame: screen-space ambient occlusion (three kernels) and
 * FXAA 3.11. The NumPy twins are in clraster/output/post.py (`ssao_inputs`,
 * `ssao_taps_pass`, `ssao_upsample`, `fxaa`), whose module docstring gives the methods; the
 * float expressions here are written in their order (FP contraction off, common.h), so the
 * kernels and the twins give the same bits.
 *
 * The kernels work on LANES = 8 pixels of a row per work-item in float8 lanes (one ymm
 * register on AVX2): PoCL did not vectorize the per-pixel versions across work-items (no
 * ymm in `perf annotate`, even without branches), and their scalar code spent much of its
 * time in calls to library routines (sqrt, fabs, fmax, min, floor, vload8, any). So the
 * code below avoids OpenCL builtins that PoCL does not inline: abs by a mask, max / min /
 * clamp by comparisons, floor by truncation, any by an OR of the lanes, sqrt through SQRTF
 * (common.h), unaligned vectors through common.h's LOAD_F8 and STORE8U below.
 * bench/README.md's log has the measurements. */
#include "common.h"

#define LANES 8
/* FXAA pixels per work-item (a multiple of LANES) */
#ifndef FXAA_SPAN
#define FXAA_SPAN 16
#endif

static inline float8 sqrt8(float8 v)
{
    return (float8)(SQRTF(v.s0), SQRTF(v.s1), SQRTF(v.s2), SQRTF(v.s3), SQRTF(v.s4),
                    SQRTF(v.s5), SQRTF(v.s6), SQRTF(v.s7));
}

/* 8 floats stored at any float's alignment (loads: common.h's LOAD_F8): the element-aligned
 * vector type, or OpenCL's vstore8 (a call in PoCL) where the compiler lacks it. */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE
#define STORE8U(v, p) vstore8((v), 0, (p))
#else
#define STORE8U(v, p) (*(__global float8u *)(p) = (v))
#endif
/* The first n of float8 v's lanes stored from p: all 8 at once where n >= 8, else
 * through a private copy (a row's last, short lane group). */
#define STORE8_ROW(v, p, n) do {                                                            \
    if ((n) >= 8) {                                                                         \
        STORE8U((v), (p));                                                                  \
    } else {                                                                                \
        float tmp_[8];                                                                      \
        vstore8((v), 0, tmp_);                                                              \
        for (int k_ = 0; k_ < (n); ++k_) (p)[k_] = tmp_[k_];                                \
    }                                                                                       \
} while (0)

/* max / min as the twin's np.maximum / np.minimum for non-NaN lanes (fmax is a call) */
static inline float8 max8(float8 a, float8 b) { return a >= b ? a : b; }
static inline float8 min8(float8 a, float8 b) { return a <= b ? a : b; }

static inline float8 abs8(float8 v) { return as_float8(as_int8(v) & 0x7fffffff); }

/* floor of lanes |v| < 2^31 as int: truncation, less one where that rounded up */
static inline int8 floor8(float8 v)
{
    int8 t = CONVERT_VEC(v, int8);
    return t + (v < CONVERT_VEC(t, float8));   /* a true comparison is -1 */
}

/* x lanes: pixel x0 + i's centre as an NDC x, ((x + ½) · sx − 1) in float32 */
static inline float8 ndc_x8(int x0, float sx)
{
    float8 x = (float8)((float)x0) + (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
    return (x + 0.5f) * sx - 1.0f;
}

/* -- SSAO ---------------------------------------------------------------------------------
 * Three passes, the first two at half resolution: low-res pixel (lx, ly) of the
 * (⌈H/2⌉, ⌈W/2⌉) grid stands for full-res pixel (2lx, 2ly).
 *
 * ssao_prepare, in float32, LANES low-res pixels of a row per work-item, each: NDC
 * (nx, ny, nz) of the full-res pixel centre (nx = (x + ½)·sx − 1, ny = 1 − (y + ½)·sy,
 * sx = 2/W, sy = 2/H; nz = 2d − 1, or 1 − 2d reversed), hom = M · (nx, ny, nz, 1) with M
 * (rows m0..m3) = vp⁻¹ moved to `ssao_origin` (row 3 is vp⁻¹'s: hom.w = 1 / clip w),
 * z = 1 / hom.w the linear depth, the point relative to the origin hom.xyz · z and the
 * projected radius in low-res pixels kr · hom.w (kr = radius · ‖vp[1, :3]‖ · H/4).
 * pos = (p, radius px), on the background (INFINITY ×3, 0): a tap there fails ssao's
 * |v|² < R² test with no test of its own; zlow = z (INFINITY on the background), read by
 * ssao_upsample. The normals are not copied here: ssao reads its centre pixels' own from
 * the frame (ssao_normals8), which halves this pass's writes and spares the upsample a
 * 16-byte stride. `ssao_inputs` is the twin (its positions; its normals' w is zlow). */

/* The unprojection of ssao_prepare, for its positions and for ssao's normal test: hom =
 * M · (nx, ny, nz, 1) row by row, summed left to right (the twin's order) */
#define SSAO_ROW(m, nx, ny, nz) ((((m).x * (nx) + (m).y * (ny)) + (m).z * (nz)) + (m).w)

/* NDC x of the full-res pixels 2·(lx0 + i) (the low-res pixels' own), and their column
 * indices clamped to the frame (lanes past the edge: not stored) */
#define SSAO_FULL_COLUMNS(lx0, width, px, pxc, nx, sx)                                      \
    int8 px = 2 * ((int8)(lx0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7));                           \
    int8 pxc = px < (width) ? px : (int8)((width) - 1);                                     \
    float8 nx = (CONVERT_VEC(px, float8) + 0.5f) * (sx) - 1.0f;

/* NDC z of window depths d, as the twin's ndc_grid */
static inline float8 ssao_ndc_z(float8 d, int reversed_z)
{
    return reversed_z ? 1.0f - 2.0f * d : 2.0f * d - 1.0f;
}

__kernel void ssao_prepare(__global const float *depth, __global float4 *pos,
                           __global float *zlow, const int width, const int height,
                           const int reversed_z, const float4 m0, const float4 m1,
                           const float4 m2, const float4 m3, const float sx, const float sy,
                           const float kr)
{
    /* LANES low-res pixels of a row per work-item: full-res pixels px = 2·(lx0 + i) */
    int lx0 = get_global_id(0) * LANES, ly = get_global_id(1);
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    if (lx0 >= w2 || ly >= h2) return;
    int py = 2 * ly;
    size_t row = (size_t)py * width, orow = (size_t)ly * w2;
    SSAO_FULL_COLUMNS(lx0, width, px, pxc, nx, sx)
    float8 d = (float8)(depth[row + pxc.s0], depth[row + pxc.s1], depth[row + pxc.s2],
                        depth[row + pxc.s3], depth[row + pxc.s4], depth[row + pxc.s5],
                        depth[row + pxc.s6], depth[row + pxc.s7]);
    int8 covered = reversed_z ? d > 0.0f : d < 1.0f;
    float ny = 1.0f - ((float)py + 0.5f) * sy;
    float8 nz = ssao_ndc_z(d, reversed_z);
    float8 hx = SSAO_ROW(m0, nx, ny, nz), hy = SSAO_ROW(m1, nx, ny, nz);
    float8 hz = SSAO_ROW(m2, nx, ny, nz), hw = SSAO_ROW(m3, nx, ny, nz);
    float8 z = 1.0f / hw;
    float8 inf = (float8)(INFINITY);
    float8 qx = covered ? hx * z : inf, qy = covered ? hy * z : inf;
    float8 qz = covered ? hz * z : inf, qw = covered ? kr * hw : (float8)(0.0f);
    z = covered ? z : inf;
    STORE8_ROW(z, zlow + orow + lx0, w2 - lx0);
#define STORE_LANE(k)                                                                        \
    if (lx0 + k < w2) pos[orow + lx0 + k] = (float4)(qx.s##k, qy.s##k, qz.s##k, qw.s##k);
    STORE_LANE(0) STORE_LANE(1) STORE_LANE(2) STORE_LANE(3)
    STORE_LANE(4) STORE_LANE(5) STORE_LANE(6) STORE_LANE(7)
#undef STORE_LANE
}

/* The unit normals of the full-res pixels 2·(lx0 + i) of row py (as ssao_prepare's
 * positions), turned against the view ray (lighting is two-sided): the ray's direction is
 * p − pn, pn the pixel's point on the near plane (g = M · (nx, ny, −1, 1), pn = g.xyz / g.w),
 * whose sign along n is that of n · (p · g.w − g.xyz) (g.w > 0): no division, and p is
 * the position ssao_prepare stored (cx, cy, cz). The twin's `ssao_inputs` normals (xyz). */
static inline void ssao_normals8(__global const float *normals, int lx0, int py, int width,
                                 float8 cx, float8 cy, float8 cz, float4 m0, float4 m1,
                                 float4 m2, float4 m3, float sx, float sy, float8 *n0,
                                 float8 *n1, float8 *n2)
{
    size_t row = (size_t)py * width;
    SSAO_FULL_COLUMNS(lx0, width, px, pxc, nx, sx)
    float8 a0, a1, a2;
#define LOAD_LANE(k)                                                                         \
    a0.s##k = normals[3 * (row + pxc.s##k)];                                                 \
    a1.s##k = normals[3 * (row + pxc.s##k) + 1];                                             \
    a2.s##k = normals[3 * (row + pxc.s##k) + 2];
    LOAD_LANE(0) LOAD_LANE(1) LOAD_LANE(2) LOAD_LANE(3)
    LOAD_LANE(4) LOAD_LANE(5) LOAD_LANE(6) LOAD_LANE(7)
#undef LOAD_LANE
    float ny = 1.0f - ((float)py + 0.5f) * sy;
    float8 mz = (float8)(-1.0f);
    float8 gx = SSAO_ROW(m0, nx, ny, mz), gy = SSAO_ROW(m1, nx, ny, mz);
    float8 gz = SSAO_ROW(m2, nx, ny, mz), gw = SSAO_ROW(m3, nx, ny, mz);
    float8 rx = cx * gw - gx, ry = cy * gw - gy, rz = cz * gw - gz;
    int8 flip = (a0 * rx + a1 * ry) + a2 * rz > 0.0f;
    *n0 = flip ? -a0 : a0;
    *n1 = flip ? -a1 : a1;
    *n2 = flip ? -a2 : a2;
}

/* Eight float4 (a0..a7) as four float8 lanes x, y, z, w: two rounds of shuffles (unpack
 * low/high of the pairs, then of their 64-bit halves) instead of 32 lane inserts. Fallback:
 * lane by lane. SSAO_TRANSPOSE3 leaves w out. */
#ifdef CLRASTER_NO_SHUFFLEVECTOR
#define SSAO_TRANSPOSE3(a0, a1, a2, a3, a4, a5, a6, a7, X, Y, Z)                             \
    X = (float8)(a0.x, a1.x, a2.x, a3.x, a4.x, a5.x, a6.x, a7.x);                            \
    Y = (float8)(a0.y, a1.y, a2.y, a3.y, a4.y, a5.y, a6.y, a7.y);                            \
    Z = (float8)(a0.z, a1.z, a2.z, a3.z, a4.z, a5.z, a6.z, a7.z);
#define SSAO_TRANSPOSE4(a0, a1, a2, a3, a4, a5, a6, a7, X, Y, Z, W)                          \
    SSAO_TRANSPOSE3(a0, a1, a2, a3, a4, a5, a6, a7, X, Y, Z)                                 \
    W = (float8)(a0.w, a1.w, a2.w, a3.w, a4.w, a5.w, a6.w, a7.w);
#else
#define SSAO_CAT(a, b) __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7)
#define SSAO_TRANSPOSE_T(a0, a1, a2, a3, a4, a5, a6, a7)                                     \
    float8 r0_ = SSAO_CAT(a0, a4), r1_ = SSAO_CAT(a1, a5);                                   \
    float8 r2_ = SSAO_CAT(a2, a6), r3_ = SSAO_CAT(a3, a7);                                   \
    SSAO_TRANSPOSE_R
#define SSAO_TRANSPOSE_R                                                                     \
    float8 t0_ = __builtin_shufflevector(r0_, r1_, 0, 8, 1, 9, 4, 12, 5, 13);                \
    float8 t1_ = __builtin_shufflevector(r0_, r1_, 2, 10, 3, 11, 6, 14, 7, 15);              \
    float8 t2_ = __builtin_shufflevector(r2_, r3_, 0, 8, 1, 9, 4, 12, 5, 13);                \
    float8 t3_ = __builtin_shufflevector(r2_, r3_, 2, 10, 3, 11, 6, 14, 7, 15);
#define SSAO_LO64(a, b) __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13)
#define SSAO_HI64(a, b) __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15)
#define SSAO_TRANSPOSE3(a0, a1, a2, a3, a4, a5, a6, a7, X, Y, Z)                             \
    {                                                                                        \
        SSAO_TRANSPOSE_T(a0, a1, a2, a3, a4, a5, a6, a7)                                     \
        X = SSAO_LO64(t0_, t2_);                                                             \
        Y = SSAO_HI64(t0_, t2_);                                                             \
        Z = SSAO_LO64(t1_, t3_);                                                             \
    }
#define SSAO_TRANSPOSE4(a0, a1, a2, a3, a4, a5, a6, a7, X, Y, Z, W)                          \
    {                                                                                        \
        SSAO_TRANSPOSE_T(a0, a1, a2, a3, a4, a5, a6, a7)                                     \
        X = SSAO_LO64(t0_, t2_);                                                             \
        Y = SSAO_HI64(t0_, t2_);                                                             \
        Z = SSAO_LO64(t1_, t3_);                                                             \
        W = SSAO_HI64(t1_, t3_);                                                             \
    }
/* pos[i0 .. i0 + 7], contiguous, as x, y, z lanes: four 8-float loads, whose halves
 * pair up as (a0, a4), (a1, a5), ... for the transpose */
#define SSAO_LOAD3(p, X, Y, Z)                                                               \
    {                                                                                        \
        __global const float *f_ = (__global const float *)(p);                             \
        float8 s0_ = LOAD_F8(f_), s1_ = LOAD_F8(f_ + 8);                                       \
        float8 s2_ = LOAD_F8(f_ + 16), s3_ = LOAD_F8(f_ + 24);                                 \
        float8 r0_ = __builtin_shufflevector(s0_, s2_, 0, 1, 2, 3, 8, 9, 10, 11);            \
        float8 r1_ = __builtin_shufflevector(s0_, s2_, 4, 5, 6, 7, 12, 13, 14, 15);          \
        float8 r2_ = __builtin_shufflevector(s1_, s3_, 0, 1, 2, 3, 8, 9, 10, 11);            \
        float8 r3_ = __builtin_shufflevector(s1_, s3_, 4, 5, 6, 7, 12, 13, 14, 15);          \
        SSAO_TRANSPOSE_R                                                                     \
        X = SSAO_LO64(t0_, t2_);                                                             \
        Y = SSAO_HI64(t0_, t2_);                                                             \
        Z = SSAO_LO64(t1_, t3_);                                                             \
    }
#endif
/* pos[i.s0..s7] as x, y, z (, w) lanes */
#define SSAO_GATHER3(pos, i, X, Y, Z)                                                        \
    SSAO_TRANSPOSE3(pos[i.s0], pos[i.s1], pos[i.s2], pos[i.s3], pos[i.s4], pos[i.s5],        \
                    pos[i.s6], pos[i.s7], X, Y, Z)
#define SSAO_GATHER4(pos, i, X, Y, Z, W)                                                     \
    SSAO_TRANSPOSE4(pos[i.s0], pos[i.s1], pos[i.s2], pos[i.s3], pos[i.s4], pos[i.s5],        \
                    pos[i.s6], pos[i.s7], X, Y, Z, W)

/* any lane of a mask set, by halving (OpenCL's any() is a call in PoCL; the preamble's
 * any8 ORs lane by lane, ~14 instructions where this is ~6) */
static inline bool any8_halves(int8 m)
{
    int4 a = m.lo | m.hi;
    int2 b = a.lo | a.hi;
    return (b.x | b.y) < 0;
}
/* every lane of a mask set */
static inline bool all8_halves(int8 m)
{
    int4 a = m.lo & m.hi;
    int2 b = a.lo & a.hi;
    return (b.x & b.y) < 0;
}

/* Rows ahead at which ssao asks for the positions (a tap reaches up to the projected
 * radius, ~15 low-res rows in bench/post_passes.py's frame) */
#define SSAO_AHEAD 24

/* ssao: the taps (float32) on the low-res grid, LANES low-res pixels of a row per
 * work-item (width, height: the full-res frame's; w2, h2 below the low-res grid's). taps:
 * (samples, 2) offsets as fractions of the radius; a low-res pixel's centre is
 * (lx + ¼, ly + ¼) (its full-res pixel's); a tap reads the low-res pixel whose square holds
 * it (a gather per lane); kscale = strength / samples, bias2 = bias² · (1 − 2^-10)
 * (float32, host). The centre normals come from the frame's float (H, W, 3) normals
 * (ssao_normals8; m0..m3, sx, sy as for ssao_prepare). */
__kernel void ssao(__global const float4 *pos, __global const float *normals,
                   __constant float2 *taps, __global float *out, const int width,
                   const int height, const int samples, const float r2, const float inv_r2,
                   const float bias, const float bias2, const float kscale, const float4 m0,
                   const float4 m1, const float4 m2, const float4 m3, const float sx,
                   const float sy)
{
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    int x0 = get_global_id(0) * LANES, py = get_global_id(1);
    if (x0 >= w2 || py >= h2) return;
    size_t row = (size_t)py * w2;
    int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 px = (int8)x0 + lane;
    /* lanes past the right edge repeat the last pixel and are not stored */
    int8 pxc = px < w2 ? px : (int8)(w2 - 1);
    float8 cx, cy, cz, cw;
    int8 ic = (int8)((int)row) + pxc;
    SSAO_GATHER4(pos, ic, cx, cy, cz, cw)
    int8 covered = cw > 0.0f;
    float8 ao = (float8)(1.0f);
    /* this work-item's columns SSAO_AHEAD rows down: the taps of the rows above reach
     * them first (from the L3 or memory, where ssao_prepare left them) */
    if (py + SSAO_AHEAD < h2) {
        __global const float4 *ahead = pos + (size_t)(py + SSAO_AHEAD) * w2 + x0;
        PREFETCH(ahead);
        PREFETCH(ahead + 4);
    }
    if (any8_halves(covered)) {
        float8 nx, ny, nz;
        ssao_normals8(normals, x0, 2 * py, width, cx, cy, cz, m0, m1, m2, m3, sx, sy, &nx, &ny,
                      &nz);
        float8 fx = CONVERT_VEC(px, float8) + 0.25f;
        float fy = (float)py + 0.25f;
        float fw = (float)w2, fh = (float)h2;
        float8 occ = (float8)(0.0f);
        int8 self = (int8)((int)row) + px;   /* own index (row < 2^31: a frame's pixel count) */
        for (int k = 0; k < samples; ++k) {
            float2 o = taps[k];
            /* the tap's pixel is on the grid iff 0 <= u < size (floor(u) >= 0 iff u >= 0;
             * floor(u) < size iff u < size, an integer); there floor is truncation, and
             * lanes off the grid read their own pixel */
            float8 ux = fx + cw * o.x, uy = fy + cw * o.y;
            int8 ok = covered & (ux >= 0.0f) & (ux < fw) & (uy >= 0.0f) & (uy < fh);
            int8 q = CONVERT_VEC(uy, int8) * w2 + CONVERT_VEC(ux, int8);
            ok &= q != self;
            q = ok ? q : self;
            float8 qx4, qy4, qz4;
#ifndef CLRASTER_NO_SHUFFLEVECTOR
            /* the 8 lanes' taps mostly land on 8 pixels in a row (the radius varies
             * slowly): then 4 loads instead of 8 gathered ones */
            if (all8_halves(q == (int8)(q.s0) + lane)) {
                SSAO_LOAD3(pos + q.s0, qx4, qy4, qz4)
            } else
#endif
            {
                SSAO_GATHER3(pos, q, qx4, qy4, qz4)
            }
            float8 vx = qx4 - cx, vy = qy4 - cy, vz = qz4 - cz;
            float8 vv = (vx * vx + vy * vy) + vz * vz;
            ok &= vv < r2;
            float8 vd = (vx * nx + vy * ny) + vz * nz;
            /* The term is +0 (and occ + 0 is occ) unless vd / |v| > bias; most taps are
             * far from it (a plane's neighbours: vd ≈ 0), so the sqrt and division are
             * skipped where all 8 lanes pass vd <= 0 or vd² < bias2 · vv (bias2 = bias²
             * less 2^-10 of it: a margin far above the rounding of either side, so a
             * skipped lane's vd / sqrt(vv) rounds below bias), vv >= 2^-60 keeping both
             * products clear of underflow. */
            int8 live = ok & (vd > 0.0f) & ((vd * vd >= bias2 * vv) | (vv < 0x1p-60f));
            if (any8_halves(live)) {
                float8 vn = vd / sqrt8(ok ? vv : (float8)(1.0f));
                float8 c = vn - bias;
                float8 term = (1.0f - vv * inv_r2) * (c > 0.0f ? c : (float8)(0.0f));
                occ = occ + (ok ? term : (float8)(0.0f));
            }
        }
        float8 a = 1.0f - kscale * occ;
        a = a > 0.0f ? a : (float8)(0.0f);
        a = a < 1.0f ? a : (float8)(1.0f);
        ao = covered ? a : ao;
    }
    STORE8_ROW(ao, out + row + x0, w2 - x0);
}

/* ssao_upsample: full resolution, LANES pixels of a row per work-item, from the low-res
 * factor and the low-res linear depths (zlow); `ssao_upsample` in clraster/output/post.py
 * says the rule. ivp: row 3 of vp⁻¹ (float32); tol = SSAO_UPSAMPLE_DEPTH. Pixel x0 + i
 * (x0 a multiple of 8) blends low-res columns x0/2 + (i >> 1) + b, b ∈ {0, 1}: lanes
 * (0 0 1 1 2 2 3 3) and (1 1 2 2 3 3 4 4) of the five columns from x0/2 (an even pixel's
 * b = 1 sample has weight 0, but takes part in the nearest-depth fallback, as in the
 * twin). Where all the samples are 1, so is every pixel (below): no depth read, no blend. */
__kernel void ssao_upsample(__global const float *depth, __global const float *zlow,
                            __global const float *ao_low, __global float *out,
                            const float4 ivp, const int width, const int height,
                            const float sx, const float sy, const int reversed_z,
                            const float tol)
{
    int x0 = get_global_id(0) * LANES, y = get_global_id(1);
    if (x0 >= width || y >= height) return;
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    size_t row = (size_t)y * width;
    int c0 = x0 >> 1;
    int q1 = imin(c0 + 1, w2 - 1), q2 = imin(c0 + 2, w2 - 1);
    int q3 = imin(c0 + 3, w2 - 1), q4 = imin(c0 + 4, w2 - 1);
    /* the samples: low-res rows r0 (a = 0) and r1 (a = 1), columns b = 0, 1 as lanes */
    size_t r0 = (size_t)(y >> 1) * w2, r1 = (size_t)imin((y >> 1) + 1, h2 - 1) * w2;
#define SAMPLE_LANES(buf, r, v0, v1)                                                         \
    float8 v0, v1;                                                                           \
    {                                                                                        \
        float e0 = buf[r + c0], e1 = buf[r + q1], e2 = buf[r + q2];                          \
        float e3 = buf[r + q3], e4 = buf[r + q4];                                            \
        v0 = (float8)(e0, e0, e1, e1, e2, e2, e3, e3);                                       \
        v1 = (float8)(e1, e1, e2, e2, e3, e3, e4, e4);                                       \
    }
    SAMPLE_LANES(ao_low, r0, ao00, ao01)
    SAMPLE_LANES(ao_low, r1, ao10, ao11)
    /* All the samples open (1: much of a frame): each pixel is 1 whatever its depth, which
     * is not read — a covered pixel's num sums the same weights as its den (w · 1 = w), so
     * num / den = 1, or it takes its nearest sample, 1; the background is 1. */
    bool open = all8_halves((ao00 == 1.0f) & (ao01 == 1.0f) & (ao10 == 1.0f) & (ao11 == 1.0f));
    float8 d = (float8)(1.0f);   /* unread where open: the blend below is skipped */
    if (open) {
    } else if (x0 + LANES <= width) {
        d = LOAD_F8(depth + row + x0);
    } else {
        float tmp[LANES];
        for (int k = 0; k < LANES; ++k) tmp[k] = depth[row + imin(x0 + k, width - 1)];
        d = vload8(0, tmp);
    }
    int8 covered = reversed_z ? d > 0.0f : d < 1.0f;
    float8 res = (float8)(1.0f);
    if (!open && any8_halves(covered)) {
        SAMPLE_LANES(zlow, r0, z00, z01)
        SAMPLE_LANES(zlow, r1, z10, z11)
        float8 nx = ndc_x8(x0, sx);
        float ny = 1.0f - ((float)y + 0.5f) * sy;
        float8 nz = reversed_z ? 1.0f - 2.0f * d : 2.0f * d - 1.0f;
        float8 z = 1.0f / (((ivp.x * nx + ivp.y * ny) + ivp.z * nz) + ivp.w);
        float8 tx = (float8)(0.0f, 0.5f, 0.0f, 0.5f, 0.0f, 0.5f, 0.0f, 0.5f);
        float ty = (float)(y & 1) * 0.5f;
        float8 zt = z * tol;
        float8 num = (float8)(0.0f), den = (float8)(0.0f), best = (float8)(INFINITY);
        float8 best_ao = (float8)(1.0f);
        for (int a = 0; a < 2; ++a) {
            float wy = a ? ty : 1.0f - ty;
            for (int b = 0; b < 2; ++b) {
                float8 zq = a ? (b ? z11 : z10) : (b ? z01 : z00);
                float8 aq = a ? (b ? ao11 : ao10) : (b ? ao01 : ao00);
                float8 wx = b ? tx : 1.0f - tx;
                float8 wgt = wy * wx;
                float8 dz = abs8(zq - z);
                int8 ok = dz <= zt;
                num = num + (ok ? wgt * aq : (float8)(0.0f));
                den = den + (ok ? wgt : (float8)(0.0f));
                int8 nearer = dz < best;
                best = nearer ? dz : best;
                best_ao = nearer ? aq : best_ao;
            }
        }
        float8 v = den > 0.0f ? num / den : best_ao;
        res = covered ? v : res;
    }
#undef SAMPLE_LANES
    STORE8_ROW(res, out + row + x0, width - x0);
}

/* -- FXAA 3.11, quality preset 12 -----------------------------------------------------------
 * rgb: uchar (H, W, 3), the 8-bit display image; lum: float (H, W) luma
 * (0.299 R + 0.587 G) + 0.114 B of the 0..255 channel values. Reads clamp to the edge;
 * bilinear reads as the twin's `_bilinear`. Both kernels run LANES pixels per lane group in
 * float8 lanes. */

/* luma: one work-item per LANES pixels (n = H·W), the 24 interleaved bytes deinterleaved */
__kernel void luma(__global const uchar *rgb, __global float *lum, const int n)
{
    int i0 = get_global_id(0) * LANES;
    if (i0 >= n) return;
    if (i0 + LANES <= n) {
        __global const uchar *p = rgb + 3 * (size_t)i0;
        uchar8 v0 = LOAD_UC8(p), v1 = LOAD_UC8(p + 8), v2 = LOAD_UC8(p + 16);
        float8 r = CONVERT_VEC(((uchar8)(v0.s0, v0.s3, v0.s6, v1.s1, v1.s4, v1.s7, v2.s2,
                                         v2.s5)), float8);
        float8 g = CONVERT_VEC(((uchar8)(v0.s1, v0.s4, v0.s7, v1.s2, v1.s5, v2.s0, v2.s3,
                                         v2.s6)), float8);
        float8 b = CONVERT_VEC(((uchar8)(v0.s2, v0.s5, v1.s0, v1.s3, v1.s6, v2.s1, v2.s4,
                                         v2.s7)), float8);
        STORE8U((r * 0.299f + g * 0.587f) + b * 0.114f, lum + i0);
        return;
    }
    for (int i = i0; i < n; ++i)
        lum[i] = ((float)rgb[3 * i] * 0.299f + (float)rgb[3 * i + 1] * 0.587f) +
                 (float)rgb[3 * i + 2] * 0.114f;
}

__constant float FXAA_P[5] = {1.0f, 1.5f, 2.0f, 4.0f, 12.0f};

/* lum row `row` (a row offset) at columns x + i, clamped to [0, w) */
static inline float8 lum_row8(__global const float *lum, size_t row, int x, int w)
{
    if (x >= 0 && x + LANES <= w) return LOAD_F8(lum + row + x);
    float8 v;
    v.s0 = lum[row + imin(imax(x, 0), w - 1)];
    v.s1 = lum[row + imin(imax(x + 1, 0), w - 1)];
    v.s2 = lum[row + imin(imax(x + 2, 0), w - 1)];
    v.s3 = lum[row + imin(imax(x + 3, 0), w - 1)];
    v.s4 = lum[row + imin(imax(x + 4, 0), w - 1)];
    v.s5 = lum[row + imin(imax(x + 5, 0), w - 1)];
    v.s6 = lum[row + imin(imax(x + 6, 0), w - 1)];
    v.s7 = lum[row + imin(imax(x + 7, 0), w - 1)];
    return v;
}

/* floor as a float, lanes |v| < 2^31 (truncation, less one where that rounded up) */
static inline float8 floorf8(float8 v) { return CONVERT_VEC(floor8(v), float8); }

static inline int8 clampi8(int8 v, int hi)
{
    v = v > 0 ? v : (int8)(0);
    return v < hi ? v : (int8)(hi);
}

#define GATHER8(buf, idx)                                                                    \
    ((float8)((float)(buf)[(idx).s0], (float)(buf)[(idx).s1], (float)(buf)[(idx).s2],        \
              (float)(buf)[(idx).s3], (float)(buf)[(idx).s4], (float)(buf)[(idx).s5],        \
              (float)(buf)[(idx).s6], (float)(buf)[(idx).s7]))

/* bilinear luma at pixel coordinates (x, y) per lane (the twin's `_bilinear`) */
ALWAYS_INLINE static float8 lum_bilinear8(__global const float *lum, float8 x, float8 y, int w,
                                          int h)
{
    float8 fx = x - 0.5f, fy = y - 0.5f;
    float8 x0 = floorf8(fx), y0 = floorf8(fy);
    float8 tx = fx - x0, ty = fy - y0;
    int8 c0 = CONVERT_VEC(x0, int8), r0 = CONVERT_VEC(y0, int8);
    int8 ca = clampi8(c0, w - 1), cb = clampi8(c0 + 1, w - 1);
    int8 ra = clampi8(r0, h - 1) * w, rb = clampi8(r0 + 1, h - 1) * w;
    float8 a = GATHER8(lum, ra + ca), b = GATHER8(lum, ra + cb);
    float8 c = GATHER8(lum, rb + ca), d = GATHER8(lum, rb + cb);
    float8 top = a + (b - a) * tx;
    float8 bot = c + (d - c) * tx;
    return top + (bot - top) * ty;
}

/* FXAA of up to LANES edge pixels (px, py) given their luma neighbourhood (lanes that are
 * not `edge` are neither computed to the end nor stored): the twin's order of operations,
 * lane by lane, the search in lanes held by masks, each edge lane's final colour read and
 * stored one by one. */
ALWAYS_INLINE static void fxaa_lanes(__global const uchar *rgb, __global const float *lum,
                                     __global uchar *out, const int8 px, const int8 py,
                                     const int8 edge, float8 lM, float8 lN, float8 lS,
                                     float8 lW, float8 lE, float8 lNW, float8 lNE,
                                     float8 lSW, float8 lSE, const float8 range,
                                     const int w, const int h)
{
    /* lanes that are no edge: any finite range (their results are dropped) */
    float8 rcp_range = 1.0f / (edge ? range : (float8)(1.0f));
    float8 ns = lN + lS, we = lW + lE;
    float8 subpix_nswe = ns + we;
    float8 eh1 = -2.0f * lM + ns, ev1 = -2.0f * lM + we;
    float8 nese = lNE + lSE, nwne = lNW + lNE;
    float8 eh2 = -2.0f * lE + nese, ev2 = -2.0f * lN + nwne;
    float8 nwsw = lNW + lSW, swse = lSW + lSE;
    float8 eh4 = abs8(eh1) * 2.0f + abs8(eh2), ev4 = abs8(ev1) * 2.0f + abs8(ev2);
    float8 eh3 = -2.0f * lW + nwsw, ev3 = -2.0f * lS + swse;
    float8 eh = abs8(eh3) + eh4, ev = abs8(ev3) + ev4;
    float8 subpix_nwswnese = nwsw + nese;
    int8 horz = eh >= ev;
    float8 subpix_a = subpix_nswe * 2.0f + subpix_nwswnese;
    lN = horz ? lN : lW;
    lS = horz ? lS : lE;
    float8 subpix_b = subpix_a * (1.0f / 12.0f) - lM;
    float8 gn = lN - lM, gs = lS - lM;
    float8 lNN = lN + lM, lSS = lS + lM;
    int8 pair_n = abs8(gn) >= abs8(gs);
    float8 gradient = max8(abs8(gn), abs8(gs));
    float8 sign = pair_n ? (float8)(-1.0f) : (float8)(1.0f);
    float8 subpix_c = abs8(subpix_b) * rcp_range;
    subpix_c = subpix_c > 0.0f ? subpix_c : (float8)(0.0f);
    subpix_c = subpix_c < 1.0f ? subpix_c : (float8)(1.0f);
    float8 pmx = CONVERT_VEC(px, float8) + 0.5f;
    float8 pmy = CONVERT_VEC(py, float8) + 0.5f;
    float8 pbx = horz ? pmx : pmx + sign * 0.5f;
    float8 pby = horz ? pmy + sign * 0.5f : pmy;
    float8 offx = horz ? (float8)(1.0f) : (float8)(0.0f);
    float8 offy = horz ? (float8)(0.0f) : (float8)(1.0f);
    float8 pnx = pbx - offx * FXAA_P[0], pny = pby - offy * FXAA_P[0];
    float8 ppx = pbx + offx * FXAA_P[0], ppy = pby + offy * FXAA_P[0];
    float8 subpix_d = -2.0f * subpix_c + 3.0f;
    float8 end_n = lum_bilinear8(lum, pnx, pny, w, h);
    float8 subpix_e = subpix_c * subpix_c;
    float8 end_p = lum_bilinear8(lum, ppx, ppy, w, h);
    lNN = pair_n ? lNN : lSS;
    float8 grad_scaled = gradient * (1.0f / 4.0f);
    float8 lMM = lM - lNN * 0.5f;
    float8 subpix_f = subpix_d * subpix_e;
    int8 mlt_zero = lMM < 0.0f;
    end_n = end_n - lNN * 0.5f;
    end_p = end_p - lNN * 0.5f;
    /* a lane that is no edge counts as done, so it never holds the loop */
    int8 done_n = (abs8(end_n) >= grad_scaled) | ~edge;
    int8 done_p = (abs8(end_p) >= grad_scaled) | ~edge;
    for (int k = 1; k < 5; ++k) {
        float st = k == 1 ? 1.5f : k == 2 ? 2.0f : k == 3 ? 4.0f : 12.0f;   /* FXAA_P[k] */
        pnx = done_n ? pnx : pnx - offx * st;
        pny = done_n ? pny : pny - offy * st;
        ppx = done_p ? ppx : ppx + offx * st;
        ppy = done_p ? ppy : ppy + offy * st;
        if (k == 4 || !any8(~(done_n & done_p))) break;
        if (any8(~done_n)) {
            float8 e = lum_bilinear8(lum, pnx, pny, w, h) - lNN * 0.5f;
            end_n = done_n ? end_n : e;
        }
        if (any8(~done_p)) {
            float8 e = lum_bilinear8(lum, ppx, ppy, w, h) - lNN * 0.5f;
            end_p = done_p ? end_p : e;
        }
        done_n = (abs8(end_n) >= grad_scaled) | ~edge;
        done_p = (abs8(end_p) >= grad_scaled) | ~edge;
    }
    float8 dst_n = horz ? pmx - pnx : pmy - pny;
    float8 dst_p = horz ? ppx - pmx : ppy - pmy;
    int8 good_n = (end_n < 0.0f) ^ mlt_zero, good_p = (end_p < 0.0f) ^ mlt_zero;
    float8 span_rcp = 1.0f / (dst_p + dst_n);
    int8 dir_n = dst_n < dst_p;
    float8 dst = min8(dst_n, dst_p);
    /* masks combined by bit operations: Oclgrind 21.10 gets `!` and `?:` on int8 masks
     * wrong (1 for true, not −1), PoCL does not */
    int8 good = (dir_n & good_n) | (~dir_n & good_p);
    float8 subpix_g = subpix_f * subpix_f;
    float8 pixel_offset = dst * (-span_rcp) + 0.5f;
    float8 subpix_h = subpix_g * 0.75f;
    float8 offset = max8(good ? pixel_offset : (float8)(0.0f), subpix_h);
    float8 fx8 = horz ? pmx : pmx + offset * sign;
    float8 fy8 = horz ? pmy + offset * sign : pmy;
    /* each edge lane's colour: bilinear reads of the 0..255 values, rounded to the nearest
     * byte (a blend of bytes stays in 0..255) */
    float bxs[LANES], bys[LANES];
    int es[LANES], xs[LANES], ys[LANES];
    float8 bx8 = fx8 - 0.5f, by8 = fy8 - 0.5f;
#define LANE(k)                                                                              \
    bxs[k] = bx8.s##k; bys[k] = by8.s##k; es[k] = edge.s##k; xs[k] = px.s##k; ys[k] = py.s##k;
    LANE(0) LANE(1) LANE(2) LANE(3) LANE(4) LANE(5) LANE(6) LANE(7)
#undef LANE
    for (int k = 0; k < LANES; ++k) {
        if (!es[k]) continue;
        float bx = bxs[k], by = bys[k];
        int ix = (int)bx, iy = (int)by;
        ix -= bx < (float)ix;
        iy -= by < (float)iy;
        float tx = bx - (float)ix, ty = by - (float)iy;
        int c0 = imin(imax(ix, 0), w - 1), c1 = imin(imax(ix + 1, 0), w - 1);
        size_t r0 = (size_t)imin(imax(iy, 0), h - 1) * w;
        size_t r1 = (size_t)imin(imax(iy + 1, 0), h - 1) * w;
        size_t o = 3 * ((size_t)ys[k] * w + xs[k]);
        for (int ch = 0; ch < 3; ++ch) {
            float a = (float)rgb[3 * (r0 + c0) + ch], b = (float)rgb[3 * (r0 + c1) + ch];
            float c = (float)rgb[3 * (r1 + c0) + ch], d = (float)rgb[3 * (r1 + c1) + ch];
            float top = a + (b - a) * tx;
            float bot = c + (d - c) * tx;
            out[o + ch] = (uchar)RINTF(top + (bot - top) * ty);
        }
    }
}

/* fxaa_mark: one work-item per FXAA_SPAN pixels of a row (a multiple of LANES). Copies the
 * span to `out` and appends the index (y·w + x) of each of its edge pixels to `list`
 * (count[0] counts them; their order does not matter: each is computed on its own by
 * fxaa_edges, which overwrites its bytes). */
__kernel void fxaa_mark(__global const uchar *rgb, __global const float *lum,
                        __global uchar *out, __global int *list,
                        volatile __global int *count, const int w, const int h)
{
    int x0 = get_global_id(0) * FXAA_SPAN, y = get_global_id(1);
    if (y >= h || x0 >= w) return;
    size_t r = (size_t)y * w;
    size_t rn = (size_t)imax(y - 1, 0) * w, rs = (size_t)imin(y + 1, h - 1) * w;
    int x1 = imin(x0 + FXAA_SPAN, w);
    size_t o = 3 * (r + x0);
    int nb = 3 * (x1 - x0);
    if (nb == 3 * FXAA_SPAN) {
        for (int k = 0; k < 3 * FXAA_SPAN; k += 8) STORE_UC8(LOAD_UC8(rgb + o + k), out + o + k);
    } else {
        for (int k = 0; k < nb; ++k) out[o + k] = rgb[o + k];
    }
    for (int x = x0; x < x1; x += LANES) {
        float8 lM = lum_row8(lum, r, x, w);
        float8 lN = lum_row8(lum, rn, x, w), lS = lum_row8(lum, rs, x, w);
        float8 lW = lum_row8(lum, r, x - 1, w), lE = lum_row8(lum, r, x + 1, w);
        float8 rmax = max8(max8(lN, lW), max8(lE, max8(lS, lM)));
        float8 rmin = min8(min8(lN, lW), min8(lE, min8(lS, lM)));
        /* the minimum threshold in 0..255 luma units: float32 0.0833 · 255, as the twin */
        int8 edge = ~(rmax - rmin < max8((float8)(0.0833f * 255.0f), rmax * 0.166f));
        edge &= ((int8)(x) + (int8)(0, 1, 2, 3, 4, 5, 6, 7)) < w;
        if (!any8(edge)) continue;
        /* a true comparison is -1: the negated sum counts the lanes */
        int8 c = edge;
        int m = -(((c.s0 + c.s1) + (c.s2 + c.s3)) + ((c.s4 + c.s5) + (c.s6 + c.s7)));
        int at = atomic_add(count, m);
        int base = (int)r + x;
#define PUT(k) if (edge.s##k) list[at++] = base + k;
        PUT(0) PUT(1) PUT(2) PUT(3) PUT(4) PUT(5) PUT(6) PUT(7)
#undef PUT
    }
}

/* luma of pixel (x, y) with the coordinates clamped to the image, per lane */
static inline float8 lum_at8(__global const float *lum, int8 x, int8 y, int w, int h)
{
    int8 i = clampi8(y, h - 1) * w + clampi8(x, w - 1);
    return GATHER8(lum, i);
}

/* fxaa_edges: LANES of fxaa_mark's listed pixels per work-item (n of them in all; the
 * last work-item's spare lanes repeat its last pixel and are not stored) */
__kernel void fxaa_edges(__global const uchar *rgb, __global const float *lum,
                         __global uchar *out, __global const int *list,
                         __global const int *count, const int w, const int h)
{
    int i0 = get_global_id(0) * LANES, n = count[0];
    if (i0 >= n) return;
    int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 edge = ((int8)(i0) + lane) < n;
    int last = n - 1;
    int8 p = (int8)(list[imin(i0, last)], list[imin(i0 + 1, last)], list[imin(i0 + 2, last)],
                    list[imin(i0 + 3, last)], list[imin(i0 + 4, last)],
                    list[imin(i0 + 5, last)], list[imin(i0 + 6, last)],
                    list[imin(i0 + 7, last)]);
    int8 py = p / w, px = p - py * w;
    /* the final colour reads (rows y − 1 .. y + 1 about each pixel) come after the search:
     * ask for them now (the image went through the cache in fxaa_mark) */
#define ASK(k)                                                                               \
    PREFETCH(rgb + 3 * (size_t)p.s##k);                                                      \
    PREFETCH(rgb + 3 * (size_t)imax(p.s##k - w, 0));                                         \
    PREFETCH(rgb + 3 * (size_t)imin(p.s##k + w, last_px));
    int last_px = w * h - 1;
    ASK(0) ASK(1) ASK(2) ASK(3) ASK(4) ASK(5) ASK(6) ASK(7)
#undef ASK
    float8 lM = GATHER8(lum, p);
    float8 lN = lum_at8(lum, px, py - 1, w, h), lS = lum_at8(lum, px, py + 1, w, h);
    float8 lW = lum_at8(lum, px - 1, py, w, h), lE = lum_at8(lum, px + 1, py, w, h);
    float8 lNW = lum_at8(lum, px - 1, py - 1, w, h), lNE = lum_at8(lum, px + 1, py - 1, w, h);
    float8 lSW = lum_at8(lum, px - 1, py + 1, w, h), lSE = lum_at8(lum, px + 1, py + 1, w, h);
    float8 rmax = max8(max8(lN, lW), max8(lE, max8(lS, lM)));
    float8 rmin = min8(min8(lN, lW), min8(lE, min8(lS, lM)));
    fxaa_lanes(rgb, lum, out, px, py, edge, lM, lN, lS, lW, lE, lNW, lNE, lSW, lSE,
               rmax - rmin, w, h);
}
