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
 * (common.h), unaligned vectors through LOAD8U / STORE8U. bench/README.md's log has the measurements. */
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

/* Vectors at any float's alignment: Clang's ext_vector_type typedef of element alignment
 * (one vmovups), or OpenCL's vload8 / vstore8 (calls in PoCL) where the compiler lacks it
 * (common.h's probe: the same values). */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE
#define LOAD8U(p) vload8(0, (p))
#define STORE8U(v, p) vstore8((v), 0, (p))
#else
typedef float float8u __attribute__((ext_vector_type(8), aligned(4)));
#define LOAD8U(p) (*(__global const float8u *)(p))
#define STORE8U(v, p) (*(__global float8u *)(p) = (v))
#endif

/* any lane of a comparison mask set (OpenCL's any() is a call in PoCL) */
static inline bool any8(int8 m)
{
    return (((m.s0 | m.s1) | (m.s2 | m.s3)) | ((m.s4 | m.s5) | (m.s6 | m.s7))) < 0;
}

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
 * z = 1 / hom.w the linear depth, the point relative to the origin hom.xyz · z, the
 * projected radius in low-res pixels kr · hom.w (kr = radius · ‖vp[1, :3]‖ · H/4), and the
 * normal turned against the view ray: the ray's direction is p − pn, pn the pixel's point
 * on the near plane (homn = M · (nx, ny, −1, 1)), whose sign along n is that of
 * n · (hom.xyz · homn.w − homn.xyz · hom.w) (both w > 0). pos = (p, radius px) (0 on the
 * background); nrm = (n, z) (w = INFINITY on the background), read by ssao and
 * ssao_upsample. `ssao_inputs` is the twin. */
__kernel void ssao_prepare(__global const float *depth, __global const float *normals,
                           __global float4 *pos, __global float4 *nrm, const int width,
                           const int height, const int reversed_z, const float4 m0,
                           const float4 m1, const float4 m2, const float4 m3, const float sx,
                           const float sy, const float kr)
{
    /* LANES low-res pixels of a row per work-item: full-res pixels px = 2·(lx0 + i) */
    int lx0 = get_global_id(0) * LANES, ly = get_global_id(1);
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    if (lx0 >= w2 || ly >= h2) return;
    int py = 2 * ly;
    size_t row = (size_t)py * width, orow = (size_t)ly * w2;
    int8 px = 2 * ((int8)(lx0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7));
    int8 pxc = px < width ? px : (int8)(width - 1);   /* lanes past the edge: not stored */
    float8 d, n0, n1, n2;
#define LOAD_LANE(k)                                                                         \
    d.s##k = depth[row + pxc.s##k];                                                          \
    n0.s##k = normals[3 * (row + pxc.s##k)];                                                 \
    n1.s##k = normals[3 * (row + pxc.s##k) + 1];                                             \
    n2.s##k = normals[3 * (row + pxc.s##k) + 2];
    LOAD_LANE(0) LOAD_LANE(1) LOAD_LANE(2) LOAD_LANE(3)
    LOAD_LANE(4) LOAD_LANE(5) LOAD_LANE(6) LOAD_LANE(7)
#undef LOAD_LANE
    int8 covered = reversed_z ? d > 0.0f : d < 1.0f;
    float8 nx = (CONVERT_VEC(px, float8) + 0.5f) * sx - 1.0f;
    float ny = 1.0f - ((float)py + 0.5f) * sy;
    float8 nz = reversed_z ? 1.0f - 2.0f * d : 2.0f * d - 1.0f;
    float8 hx = ((m0.x * nx + m0.y * ny) + m0.z * nz) + m0.w;
    float8 hy = ((m1.x * nx + m1.y * ny) + m1.z * nz) + m1.w;
    float8 hz = ((m2.x * nx + m2.y * ny) + m2.z * nz) + m2.w;
    float8 hw = ((m3.x * nx + m3.y * ny) + m3.z * nz) + m3.w;
    float8 gx = ((m0.x * nx + m0.y * ny) - m0.z) + m0.w;
    float8 gy = ((m1.x * nx + m1.y * ny) - m1.z) + m1.w;
    float8 gz = ((m2.x * nx + m2.y * ny) - m2.z) + m2.w;
    float8 gw = ((m3.x * nx + m3.y * ny) - m3.z) + m3.w;
    float8 z = 1.0f / hw;
    float8 rx = hx * gw - gx * hw, ry = hy * gw - gy * hw, rz = hz * gw - gz * hw;
    int8 flip = (n0 * rx + n1 * ry) + n2 * rz > 0.0f;
    n0 = flip ? -n0 : n0;
    n1 = flip ? -n1 : n1;
    n2 = flip ? -n2 : n2;
    float8 zero = (float8)(0.0f);
    float8 qx = covered ? hx * z : zero, qy = covered ? hy * z : zero;
    float8 qz = covered ? hz * z : zero, qw = covered ? kr * hw : zero;
    n0 = covered ? n0 : zero;
    n1 = covered ? n1 : zero;
    n2 = covered ? n2 : zero;
    z = covered ? z : (float8)(INFINITY);
#define STORE_LANE(k)                                                                        \
    if (lx0 + k < w2) {                                                                      \
        pos[orow + lx0 + k] = (float4)(qx.s##k, qy.s##k, qz.s##k, qw.s##k);                  \
        nrm[orow + lx0 + k] = (float4)(n0.s##k, n1.s##k, n2.s##k, z.s##k);                   \
    }
    STORE_LANE(0) STORE_LANE(1) STORE_LANE(2) STORE_LANE(3)
    STORE_LANE(4) STORE_LANE(5) STORE_LANE(6) STORE_LANE(7)
#undef STORE_LANE
}

/* ssao: the taps (float32) on the low-res grid (w, h here are its size), LANES low-res pixels
 * of a row per work-item. taps: (samples, 2) offsets as fractions of the radius; a low-res
 * pixel's centre is (lx + ¼, ly + ¼) (its full-res pixel's); a tap reads the low-res pixel
 * whose square holds it (a gather per lane); kscale = strength / samples (float32, host). */
__kernel void ssao(__global const float4 *pos, __global const float4 *nrm,
                   __constant float2 *taps, __global float *out, const int width,
                   const int height, const int samples, const float r2, const float inv_r2,
                   const float bias, const float kscale)
{
    int x0 = get_global_id(0) * LANES, py = get_global_id(1);
    if (x0 >= width || py >= height) return;
    size_t row = (size_t)py * width;
    int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 px = (int8)x0 + lane;
    /* lanes past the right edge repeat the last pixel and are not stored */
    int8 pxc = px < width ? px : (int8)(width - 1);
    float8 cx, cy, cz, cw, nx, ny, nz;
    float4 t;
#define LOAD_LANE(k)                                                                         \
    t = pos[row + pxc.s##k];                                                                 \
    cx.s##k = t.x; cy.s##k = t.y; cz.s##k = t.z; cw.s##k = t.w;                            \
    t = nrm[row + pxc.s##k];                                                                 \
    nx.s##k = t.x; ny.s##k = t.y; nz.s##k = t.z;
    LOAD_LANE(0) LOAD_LANE(1) LOAD_LANE(2) LOAD_LANE(3)
    LOAD_LANE(4) LOAD_LANE(5) LOAD_LANE(6) LOAD_LANE(7)
#undef LOAD_LANE
    int8 covered = cw > 0.0f;
    float8 ao = (float8)(1.0f);
    if (any8(covered)) {
        float8 fx = CONVERT_VEC(px, float8) + 0.25f;
        float fy = (float)py + 0.25f;
        float fw = (float)width, fh = (float)height;
        float8 occ = (float8)(0.0f);
        int8 self = (int8)((int)row) + px;   /* own index (row < 2^31: a frame's pixel count) */
        for (int k = 0; k < samples; ++k) {
            float2 o = taps[k];
            /* clamped to [-1, size] first: the same pixel or none, and no int overflow */
            float8 ux = fx + cw * o.x, uy = fy + cw * o.y;
            ux = ux > -1.0f ? ux : (float8)(-1.0f);
            ux = ux < fw ? ux : (float8)(fw);
            uy = uy > -1.0f ? uy : (float8)(-1.0f);
            uy = uy < fh ? uy : (float8)(fh);
            int8 qx = floor8(ux), qy = floor8(uy);
            int8 q = qy * width + qx;
            int8 ok = covered & (qx >= 0) & (qx < width) & (qy >= 0) & (qy < height) &
                      (q != self);
            q = ok ? q : self;
            float8 qx4, qy4, qz4, qw4;
#define GATHER(k)                                                                            \
            t = pos[q.s##k];                                                                 \
            qx4.s##k = t.x; qy4.s##k = t.y; qz4.s##k = t.z; qw4.s##k = t.w;
            GATHER(0) GATHER(1) GATHER(2) GATHER(3) GATHER(4) GATHER(5) GATHER(6) GATHER(7)
#undef GATHER
            ok &= qw4 > 0.0f;
            float8 vx = qx4 - cx, vy = qy4 - cy, vz = qz4 - cz;
            float8 vv = (vx * vx + vy * vy) + vz * vz;
            ok &= vv < r2;
            float8 vn = ((vx * nx + vy * ny) + vz * nz) / sqrt8(ok ? vv : (float8)(1.0f));
            float8 c = vn - bias;
            float8 term = (1.0f - vv * inv_r2) * (c > 0.0f ? c : (float8)(0.0f));
            occ = occ + (ok ? term : (float8)(0.0f));
        }
        float8 a = 1.0f - kscale * occ;
        a = a > 0.0f ? a : (float8)(0.0f);
        a = a < 1.0f ? a : (float8)(1.0f);
        ao = covered ? a : ao;
    }
    if (x0 + LANES <= width) {
        STORE8U(ao, out + row + x0);
    } else {
        float tmp[LANES];
        vstore8(ao, 0, tmp);
        for (int k = 0; x0 + k < width; ++k) out[row + x0 + k] = tmp[k];
    }
}

/* ssao_upsample: full resolution, LANES pixels of a row per work-item, from the low-res
 * factor and the low-res linear depths (nrm.w); `ssao_upsample` in clraster/output/post.py
 * says the rule. ivp: row 3 of vp⁻¹ (float32); tol = SSAO_UPSAMPLE_DEPTH. Pixel x0 + i
 * (x0 a multiple of 8) blends low-res columns x0/2 + (i >> 1) + b, b ∈ {0, 1}: lanes
 * (0 0 1 1 2 2 3 3) and (1 1 2 2 3 3 4 4) of the five columns from x0/2 (an even pixel's
 * b = 1 sample has weight 0, but takes part in the nearest-depth fallback, as in the
 * twin). */
__kernel void ssao_upsample(__global const float *depth, __global const float4 *nrm,
                            __global const float *ao_low, __global float *out,
                            const float4 ivp, const int width, const int height,
                            const float sx, const float sy, const int reversed_z,
                            const float tol)
{
    int x0 = get_global_id(0) * LANES, y = get_global_id(1);
    if (x0 >= width || y >= height) return;
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    size_t row = (size_t)y * width;
    float8 d;
    if (x0 + LANES <= width) {
        d = LOAD8U(depth + row + x0);
    } else {
        float tmp[LANES];
        for (int k = 0; k < LANES; ++k) tmp[k] = depth[row + imin(x0 + k, width - 1)];
        d = vload8(0, tmp);
    }
    int8 covered = reversed_z ? d > 0.0f : d < 1.0f;
    float8 res = (float8)(1.0f);
    if (any8(covered)) {
        float8 nx = ndc_x8(x0, sx);
        float ny = 1.0f - ((float)y + 0.5f) * sy;
        float8 nz = reversed_z ? 1.0f - 2.0f * d : 2.0f * d - 1.0f;
        float8 z = 1.0f / (((ivp.x * nx + ivp.y * ny) + ivp.z * nz) + ivp.w);
        float8 tx = (float8)(0.0f, 0.5f, 0.0f, 0.5f, 0.0f, 0.5f, 0.0f, 0.5f);
        float ty = (float)(y & 1) * 0.5f;
        float8 zt = z * tol;
        float8 num = (float8)(0.0f), den = (float8)(0.0f), best = (float8)(INFINITY);
        float8 best_ao = (float8)(1.0f);
        int c0 = x0 >> 1;
        int q1 = imin(c0 + 1, w2 - 1), q2 = imin(c0 + 2, w2 - 1);
        int q3 = imin(c0 + 3, w2 - 1), q4 = imin(c0 + 4, w2 - 1);
        for (int a = 0; a < 2; ++a) {
            size_t r = (size_t)imin((y >> 1) + a, h2 - 1) * w2;
            float z0 = nrm[r + c0].w, z1 = nrm[r + q1].w, z2 = nrm[r + q2].w;
            float z3 = nrm[r + q3].w, z4 = nrm[r + q4].w;
            float a0 = ao_low[r + c0], a1 = ao_low[r + q1], a2 = ao_low[r + q2];
            float a3 = ao_low[r + q3], a4 = ao_low[r + q4];
            float wy = a ? ty : 1.0f - ty;
            for (int b = 0; b < 2; ++b) {
                float8 zq = b ? (float8)(z1, z1, z2, z2, z3, z3, z4, z4)
                              : (float8)(z0, z0, z1, z1, z2, z2, z3, z3);
                float8 aq = b ? (float8)(a1, a1, a2, a2, a3, a3, a4, a4)
                              : (float8)(a0, a0, a1, a1, a2, a2, a3, a3);
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
    if (x0 + LANES <= width) {
        STORE8U(res, out + row + x0);
    } else {
        float tmp[LANES];
        vstore8(res, 0, tmp);
        for (int k = 0; x0 + k < width; ++k) out[row + x0 + k] = tmp[k];
    }
}

/* -- FXAA 3.11, quality preset 12 -----------------------------------------------------------
 * rgb: float (H, W, 3); lum: float (H, W) luma (0.299 R + 0.587 G + 0.114 B). Reads clamp to
 * the edge; bilinear reads as the twin's `_bilinear`. Both kernels run LANES pixels per
 * lane group in float8 lanes. */

/* luma: one work-item per LANES pixels (n = H·W), the 24 interleaved floats deinterleaved */
__kernel void luma(__global const float *rgb, __global float *lum, const int n)
{
    int i0 = get_global_id(0) * LANES;
    if (i0 >= n) return;
    if (i0 + LANES <= n) {
        __global const float *p = rgb + 3 * (size_t)i0;
        float8 v0 = LOAD8U(p), v1 = LOAD8U(p + 8), v2 = LOAD8U(p + 16);
        float8 r = (float8)(v0.s0, v0.s3, v0.s6, v1.s1, v1.s4, v1.s7, v2.s2, v2.s5);
        float8 g = (float8)(v0.s1, v0.s4, v0.s7, v1.s2, v1.s5, v2.s0, v2.s3, v2.s6);
        float8 b = (float8)(v0.s2, v0.s5, v1.s0, v1.s3, v1.s6, v2.s1, v2.s4, v2.s7);
        STORE8U((r * 0.299f + g * 0.587f) + b * 0.114f, lum + i0);
        return;
    }
    for (int i = i0; i < n; ++i)
        lum[i] = (rgb[3 * i] * 0.299f + rgb[3 * i + 1] * 0.587f) + rgb[3 * i + 2] * 0.114f;
}

__constant float FXAA_P[5] = {1.0f, 1.5f, 2.0f, 4.0f, 12.0f};

/* lum row `row` (a row offset) at columns x0 + dx + i, clamped to [0, w) */
static inline float8 lum_row8(__global const float *lum, size_t row, int x, int w)
{
    if (x >= 0 && x + LANES <= w) return LOAD8U(lum + row + x);
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

#define GATHER8(buf, idx) ((float8)((buf)[(idx).s0], (buf)[(idx).s1], (buf)[(idx).s2],        \
                                    (buf)[(idx).s3], (buf)[(idx).s4], (buf)[(idx).s5],        \
                                    (buf)[(idx).s6], (buf)[(idx).s7]))

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

/* FXAA of pixels x0 .. x0 + 7 of row y (lanes past the right edge are computed on clamped
 * reads and not stored): the twin's order of operations, lane by lane. Most spans hold no
 * edge pixel and are copied; the others run the whole search in lanes, lanes that are no
 * edge (or whose search ended) held by masks, and read their final colour one by one. */
ALWAYS_INLINE static void fxaa_span(__global const float *rgb, __global const float *lum,
                             __global float *out, const int x0, const int y, const int w,
                             const int h)
{
    size_t r = (size_t)y * w;
    size_t rn = (size_t)imax(y - 1, 0) * w, rs = (size_t)imin(y + 1, h - 1) * w;
    bool full = x0 + LANES <= w;
    float8 lM = lum_row8(lum, r, x0, w);
    float8 lN = lum_row8(lum, rn, x0, w), lS = lum_row8(lum, rs, x0, w);
    float8 lW = lum_row8(lum, r, x0 - 1, w), lE = lum_row8(lum, r, x0 + 1, w);
    float8 rmax = max8(max8(lN, lW), max8(lE, max8(lS, lM)));
    float8 rmin = min8(min8(lN, lW), min8(lE, min8(lS, lM)));
    float8 range = rmax - rmin;
    int8 edge = !(range < max8((float8)(0.0833f), rmax * 0.166f));
    if (!full) edge &= ((int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7)) < w;
    size_t o = 3 * (r + x0);
    int n = 3 * (imin(x0 + LANES, w) - x0);   /* floats of the span in the image */
    if (!any8(edge)) {
        if (full) {
            STORE8U(LOAD8U(rgb + o), out + o);
            STORE8U(LOAD8U(rgb + o + 8), out + o + 8);
            STORE8U(LOAD8U(rgb + o + 16), out + o + 16);
        } else {
            for (int k = 0; k < n; ++k) out[o + k] = rgb[o + k];
        }
        return;
    }
    /* the final colour reads lie in rows y - 1 .. y + 1: row y + 1 is not in the cache yet
     * (its work-items come later) and y - 1 may have left it; ask for them before the
     * search */
    PREFETCH(rgb + 3 * (rn + x0));
    PREFETCH(rgb + 3 * (rn + x0) + 16);
    PREFETCH(rgb + 3 * (rs + x0));
    PREFETCH(rgb + 3 * (rs + x0) + 16);
    float8 lNW = lum_row8(lum, rn, x0 - 1, w), lSE = lum_row8(lum, rs, x0 + 1, w);
    float8 lNE = lum_row8(lum, rn, x0 + 1, w), lSW = lum_row8(lum, rs, x0 - 1, w);
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
    float8 pmx = CONVERT_VEC((int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7), float8) + 0.5f;
    float8 pmy = (float8)((float)y + 0.5f);
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
    int8 done_n = (abs8(end_n) >= grad_scaled) | !edge;
    int8 done_p = (abs8(end_p) >= grad_scaled) | !edge;
    for (int k = 1; k < 5; ++k) {
        float st = FXAA_P[k];
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
        done_n = (abs8(end_n) >= grad_scaled) | !edge;
        done_p = (abs8(end_p) >= grad_scaled) | !edge;
    }
    float8 dst_n = horz ? pmx - pnx : pmy - pny;
    float8 dst_p = horz ? ppx - pmx : ppy - pmy;
    int8 good_n = (end_n < 0.0f) != mlt_zero, good_p = (end_p < 0.0f) != mlt_zero;
    float8 span_rcp = 1.0f / (dst_p + dst_n);
    int8 dir_n = dst_n < dst_p;
    float8 dst = min8(dst_n, dst_p);
    int8 good = dir_n ? good_n : good_p;
    float8 subpix_g = subpix_f * subpix_f;
    float8 pixel_offset = dst * (-span_rcp) + 0.5f;
    float8 subpix_h = subpix_g * 0.75f;
    float8 offset = max8(good ? pixel_offset : (float8)(0.0f), subpix_h);
    float8 fx8 = horz ? pmx : pmx + offset * sign;
    float8 fy8 = horz ? pmy + offset * sign : pmy;
    /* the span's colours, the edge lanes' from bilinear reads, gathered here and stored
     * once (no reads of rgb between stores to out) */
    float col[3 * LANES], bxs[LANES], bys[LANES];
    int es[LANES];
    for (int k = 0; k < n; ++k) col[k] = rgb[o + k];
    vstore8(fx8 - 0.5f, 0, bxs);
    vstore8(fy8 - 0.5f, 0, bys);
    vstore8(as_float8(edge), 0, (float *)es);
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
        for (int ch = 0; ch < 3; ++ch) {
            float a = rgb[3 * (r0 + c0) + ch], b = rgb[3 * (r0 + c1) + ch];
            float c = rgb[3 * (r1 + c0) + ch], d = rgb[3 * (r1 + c1) + ch];
            float top = a + (b - a) * tx;
            float bot = c + (d - c) * tx;
            col[3 * k + ch] = top + (bot - top) * ty;
        }
    }
    for (int k = 0; k < n; ++k) out[o + k] = col[k];
}

/* fxaa: one work-item per FXAA_SPAN pixels of a row (a multiple of LANES), lane group by
 * lane group. */
__kernel void fxaa(__global const float *rgb, __global const float *lum,
                   __global float *out, const int w, const int h)
{
    int x0 = get_global_id(0) * FXAA_SPAN, y = get_global_id(1);
    if (y >= h) return;
    for (int x = x0; x < imin(x0 + FXAA_SPAN, w); x += LANES)
        fxaa_span(rgb, lum, out, x, y, w, h);
}
