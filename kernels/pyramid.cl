/* Hierarchical depth pyramid (Hi-Z) and the conservative occlusion test of boxes against it.
 *
 * Level sizes and footprints. Level 0 is the W × H depth buffer; level k+1 is
 * ceil(w_k / 2) × ceil(h_k / 2), down to 1 × 1. Texel (i, j) of level k+1 holds the maximum
 * (farthest depth) of level-k texels (2i, 2j), (2i+1, 2j), (2i, 2j+1), (2i+1, 2j+1), each index
 * clamped to the last column / row of level k. With ceil sizes the grids nest exactly: texel
 * (i, j) of level L covers the level-0 pixels [i·2^L, min((i+1)·2^L, W) − 1] × (same in y),
 * so every pixel (x, y) lies under texel (x >> L, y >> L) of every level and that texel is
 * >= its depth. This is why odd sizes stay conservative: an odd last column is never
 * dropped (floor sizes would drop it unless its neighbours took 3×3 texels, niagara's fix in
 * depthreduce); it gets a texel of its own whose clamped second read repeats it. And since
 * (x >> L) <= (W − 1) >> L = w_L − 1, the test below can never read outside a level.
 * The maximum is exact, so the NumPy twin (clraster/pipeline/reference/pyramid.py) is
 * bit-identical.
 *
 * Level table (host-built, int4 per level): (offset of the level in the pyramid buffer in
 * floats, width, height, 0). All levels, level 0 included, live in one float buffer.
 */
#include "common.h"

/* Levels made per launch, PYR_LOG2 (clraster/base/layout.py, 6): each work-item reduces a
 * (1 << PYR_LOG2)² block of its source level through PYR_LOG2 levels in private memory (the
 * footprint of a level-(s+j) texel, j <= PYR_LOG2, lies inside one aligned block), so 1080p
 * takes 2 launches, 16384² 3. The private scratch is (block/2)² floats = 4 KiB. */
#define PYR_HALF (1 << (PYR_LOG2 - 1))

/* Vectors at any float's alignment (rows of odd widths): unaligned loads and stores, through
 * Clang's ext_vector_type typedefs of element alignment, or OpenCL's vload/vstore where the
 * compiler lacks them (common.h: the same values). */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE   /* vload8 pairs: the pip PoCL 3.0 lost this file's
                                       * kernels from programs it read back from its cache
                                       * when they called vload16 / vstore16 */
#define LOAD16U(p) ((float16)(vload8(0, (p)), vload8(1, (p))))
#define STORE16U(v, p) (vstore8((v).lo, 0, (p)), vstore8((v).hi, 1, (p)))
#define STORE8U(v, p) vstore8((v), 0, (p))
#else
#define LOAD16U(p) (*(__global const float16u *)(p))
#define STORE16U(v, p) (*(__global float16u *)(p) = (v))
#define STORE8U(v, p) (*(__global float8u *)(p) = (v))
#endif

/* Farthest of two depths, written as a comparison so the twin's np.where matches it bit for
 * bit for every input (fmax may return either zero for ±0). */
inline float farther(float a, float b) { return a > b ? a : b; }

inline float far4(float a, float b, float c, float d)
{
    return farther(farther(a, b), farther(c, d));
}

/* One work-item per block of the source level; makes levels src_level+1 .. src_level+n_make
 * of that block. src_level 0 reads the caller's depth buffer and also copies it into the
 * pyramid's level 0 (a pyramid must not change when the renderer reuses its depth buffer);
 * later launches read the pyramid itself. */
__kernel void pyramid_reduce(__global const float *depth, __global float *pyr,
                             __global const int4 *levels, const int src_level,
                             const int n_make, const int blocks_x, const int n_blocks)
{
    int g = get_global_id(0);
    if (g >= n_blocks) return;
    int4 S = levels[src_level];
    int ws = S.y, hs = S.z;
    int nb = 1 << n_make;              /* block side, in source texels */
    int bx = g % blocks_x, by = g / blocks_x;
    __global const float *src = src_level == 0 ? depth : pyr + S.x;
    /* current level of this block, row stride PYR_HALF */
    float t[PYR_HALF * PYR_HALF] __attribute__((aligned(32)));
    int side = nb >> 1;
    int4 D = levels[src_level + 1];
    int gx0 = bx * side, gy0 = by * side;
    int lw = imin(side, D.y - gx0), lh = imin(side, D.z - gy0);
    if (lw == side && (side & 7) == 0 && 2 * (gx0 + lw) <= ws) {
        /* A full block (its width a multiple of 8) whose columns need no clamp (every
         * block but, unless the width allows, the last column of blocks): the
         * first level in float8 lanes, sixteen source texels of a row at a time split into
         * even and odd columns, the same comparisons in the same order as far4 (so the
         * same bits), and level 0 copied from the same loads. The scalar loops below
         * (clamped indices, a separate copy) are for the other blocks. */
        for (int j = 0; j < lh; ++j) {
            int ya = 2 * (gy0 + j), yb = imin(ya + 1, hs - 1);
            size_t oa = (size_t)ya * ws + 2 * gx0, ob = (size_t)yb * ws + 2 * gx0;
            __global float *out = pyr + D.x + (size_t)(gy0 + j) * D.y + gx0;
            for (int c = 0; c < lw; c += 8) {
                float16 a = LOAD16U(src + oa + 2 * c);
                float16 b = LOAD16U(src + ob + 2 * c);
                if (src_level == 0) {
                    STORE16U(a, pyr + oa + 2 * c);
                    if (yb != ya) STORE16U(b, pyr + ob + 2 * c);
                }
                float8 h1 = a.even > a.odd ? a.even : a.odd;   /* farther(ra[xa], ra[xb]) */
                float8 h2 = b.even > b.odd ? b.even : b.odd;
                float8 v = h1 > h2 ? h1 : h2;
                *(float8 *)&t[j * PYR_HALF + c] = v;
                STORE8U(v, out + c);
            }
        }
    } else {
        if (src_level == 0) {
            int x0 = bx * nb, x1 = imin(x0 + nb, ws), y1 = imin(by * nb + nb, hs);
            for (int y = by * nb; y < y1; ++y)
                for (int x = x0; x < x1; ++x)
                    pyr[(size_t)y * ws + x] = src[(size_t)y * ws + x];
        }
        for (int j = 0; j < lh; ++j) {
            int ya = 2 * (gy0 + j), yb = imin(ya + 1, hs - 1);
            __global const float *ra = src + (size_t)ya * ws, *rb = src + (size_t)yb * ws;
            __global float *out = pyr + D.x + (size_t)(gy0 + j) * D.y + gx0;
            for (int i = 0; i < lw; ++i) {
                int xa = 2 * (gx0 + i), xb = imin(xa + 1, ws - 1);
                float v = far4(ra[xa], ra[xb], rb[xa], rb[xb]);
                t[j * PYR_HALF + i] = v;
                out[i] = v;
            }
        }
    }
    /* Further levels from the private copy, in place: texel (i, j) is written after its
     * reads, and every later texel reads indices >= 2j·PYR_HALF + 2i > j·PYR_HALF + i. The
     * clamp imin(2i+1, lw−1) is the global clamp imin(2g+1, w−1): the block's last valid
     * column is either the block edge (never exceeded) or the level's last column. */
    for (int k = 2; k <= n_make; ++k) {
        D = levels[src_level + k];
        side >>= 1;
        gx0 = bx * side;
        gy0 = by * side;
        int nw = imin(side, D.y - gx0), nh = imin(side, D.z - gy0);
        for (int j = 0; j < nh; ++j) {
            int ja = 2 * j, jb = imin(ja + 1, lh - 1);
            __global float *out = pyr + D.x + (size_t)(gy0 + j) * D.y + gx0;
            for (int i = 0; i < nw; ++i) {
                int ia = 2 * i, ib = imin(ia + 1, lw - 1);
                float v = far4(t[ja * PYR_HALF + ia], t[ja * PYR_HALF + ib],
                               t[jb * PYR_HALF + ia], t[jb * PYR_HALF + ib]);
                t[j * PYR_HALF + i] = v;
                out[i] = v;
            }
        }
        lw = nw;
        lh = nh;
    }
}

/* ---- Occlusion test --------------------------------------------------------------------
 *
 * Results OCC_VISIBLE, OCC_OCCLUDED, OCC_VIEW_CULLED (clraster.occlusion.Occlusion; values
 * from clraster/base/layout.py). */

/* Error model. What the renderer draws for a box is some content inside it (or, for the
 * exact query, the box's own triangles): vertices whose float32 clip positions are the exact
 * ones up to rounding. We bound that rounding, per box, by e_r = HIZ_EPS · A_r with
 * A_r = |m_r0|·a_x + |m_r1|·a_y + |m_r2|·a_z + |m_r3| per matrix row r, a_c = max(|min_c|,
 * |max_c|) (so A_r >= Σ|m_rc·p_c| at every point p of the box). A float32 dot product of 4
 * terms is off by <= 4u·A (u = 2^-24), the renderer's rounded float32(VP · model) adds about
 * u·A, our own corner evaluation another 4u·A: ~9u in all. HIZ_EPS = 64u leaves 7× headroom,
 * which also covers instance matrices whose terms are up to a few times the world ones (an
 * instance transform that cancels much larger model coordinates is not covered).
 * Since clip = VP · [p, 1] is affine, a content point's float clip position lies in the
 * convex hull of the corners' error boxes [c − e, c + e]; x/w, y/w and z/w are monotone in
 * each of x, y, z and w on w > 0, so their extremes over that hull are at error-box corners,
 * which is what the bounds below take. HIZ_EPS = 2^-18 = 64u.
 * (HIZ_EPS, HIZ_DEPTH_SLACK and HIZ_PIXEL_SLACK are defined in clraster/base/layout.py.)
 *
 * Window depth of a drawn fragment is never below its piece's least vertex depth: the raster
 * raises the interpolated plane to zlo (setup.cl value_planes),
 * because a pixel centre the snapped coverage takes in may lie up to 1/512 px outside the
 * unsnapped triangle, where the plane extrapolates by |grad z|/362 — unbounded for steep
 * triangles. A vertex's window depth is computed in double from its exact float32 inputs
 * and rounded once, so what remains is the vertex's own rounding (the box bounds above) and
 * the viewport transform's (<= 1u): 2^-18 (64u) subtracted from the box's nearest depth
 * covers it many times over: HIZ_DEPTH_SLACK = 2^-18.
 *
 * Window x/y of a vertex: rounded (~3 ulp of |x_win| <= 2^14 px on screen: < 0.01 px) and
 * then snapped to 1/256 px by rint (<= 1/512 px). 1/16 px covers both several times:
 * HIZ_PIXEL_SLACK = 0.0625. */

/* One work-item per 8 boxes, in float8 lanes (written as vectors because PoCL's implicit
 * vectorization across work-items gave up on this kernel: LLVM's SLP pass packed pairs of
 * scalars first, and a vector-typed value cannot be widened again). Lane l of work-item g is
 * box 8g + l; every lane does exactly the scalar float32 operations described here, so the
 * NumPy twin (clraster/pipeline/reference/pyramid.py test_boxes) matches it bit for bit.
 *
 * boxes: float32 (6, n_pad) rows min.x, min.y, min.z, max.x, max.y, max.z (world space),
 * n_pad a multiple of 8 (padding lanes are computed and ignored). vp: float32 (16,) row-major
 * view-projection, clip = VP · [p, 1]. result: uint8 (n_pad,).
 *   1. Any corner or error bound not finite → VISIBLE.
 *   2. All 8 corners outside one frustum plane by more than their error → VIEW_CULLED
 *      (the box is convex, so then all of it is outside).
 *   3. Any corner with w − e_w <= 0 (at or behind the eye) or in front of the near plane
 *      (z + w < 0), i.e. the box crosses the near plane → VISIBLE.
 *   4. Screen rectangle: bounds of x/w, y/w over the corners' error boxes → window
 *      coordinates widened by HIZ_PIXEL_SLACK → the pixels whose centres (x + 0.5, y + 0.5)
 *      it contains, clamped to the image. No pixel centre → OCCLUDED (nothing inside the box
 *      can produce a sample). Nearest depth: min over corners of the lower bound of z/w,
 *      → (zn + 1)/2 − HIZ_DEPTH_SLACK.
 *   5. Level L: the finest at which the pixel range spans <= 2 texels per axis; the
 *      maximum of those <= 4 texels bounds the depth under every pixel of the range.
 *      OCCLUDED iff nearest depth > that maximum, else VISIBLE.
 * Vector comparisons give -1 (true) / 0 per lane; select(a, b, c) is c ? b : a. Built-ins
 * get vector arguments only: Oclgrind mis-broadcasts min(int8, int) (garbage lanes). */
__kernel void hiz_test_boxes(__global const float *boxes, const int n_pad,
                             __constant float *vp, const int width, const int height,
                             __global const float *pyr, __constant int *levels,
                             const int n_levels, const float zoff,
                             __global uchar *result)
{
    int g = get_global_id(0);
    if (8 * g >= n_pad) return;
    float8 lo0 = vload8(g, boxes), lo1 = vload8(g, boxes + n_pad);
    float8 lo2 = vload8(g, boxes + 2 * n_pad), hi0 = vload8(g, boxes + 3 * n_pad);
    float8 hi1 = vload8(g, boxes + 4 * n_pad), hi2 = vload8(g, boxes + 5 * n_pad);
    float m[16], am[16];
    for (int i = 0; i < 16; ++i) { m[i] = vp[i]; am[i] = fabs(m[i]); }
    /* One error bound per box: A_r at the componentwise largest |p| bounds A_r at every
     * corner and every point inside (A is monotone in each |p_c|). */
    float8 ax = fmax(fabs(lo0), fabs(hi0)), ay = fmax(fabs(lo1), fabs(hi1));
    float8 az = fmax(fabs(lo2), fabs(hi2));
    float8 ex = HIZ_EPS * MAT_ROW(am, 0, ax, ay, az), ey = HIZ_EPS * MAT_ROW(am, 1, ax, ay, az);
    float8 ez = HIZ_EPS * MAT_ROW(am, 2, ax, ay, az), ew = HIZ_EPS * MAT_ROW(am, 3, ax, ay, az);
    float8 exw = ex + ew, eyw = ey + ew, ezw = ez + ew;
    int8 zero = (int8)0, one = (int8)1;
    float8 inf = (float8)INFINITY;
    /* flags are 0/1 ints set through select(): bit operations on comparison masks are
     * where simulators disagree (Oclgrind computed (a < b) & 1 as 255) */
    int8 bad = zero;
    bad = select(one, bad, fabs(ex) < inf);
    bad = select(one, bad, fabs(ey) < inf);
    bad = select(one, bad, fabs(ez) < inf);
    bad = select(one, bad, fabs(ew) < inf);
    bad = select(one, bad, fabs(exw) < inf);
    bad = select(one, bad, fabs(eyw) < inf);
    bad = select(one, bad, fabs(ezw) < inf);

    /* A non-finite corner makes the box VISIBLE, so what it does to the rest is moot. */
    int8 out_and = (int8)63, cross = zero;
    float8 xl = (float8)INFINITY, xh = (float8)(-INFINITY), yl = (float8)INFINITY;
    float8 yh = (float8)(-INFINITY), zl = (float8)INFINITY;
    for (int k = 0; k < 8; ++k) {
        float8 px = (k & 1) ? hi0 : lo0, py = (k & 2) ? hi1 : lo1, pz = (k & 4) ? hi2 : lo2;
        /* common.h MAT_ROW, as the vertex stage transforms vertices */
        float8 cx = MAT_ROW(m, 0, px, py, pz), cy = MAT_ROW(m, 1, px, py, pz);
        float8 cz = MAT_ROW(m, 2, px, py, pz), cw = MAT_ROW(m, 3, px, py, pz);
        bad = select(one, bad, fabs(cx) < inf);
        bad = select(one, bad, fabs(cy) < inf);
        bad = select(one, bad, fabs(cz) < inf);
        bad = select(one, bad, fabs(cw) < inf);
        int8 o = zero;   /* bit p: outside plane p by more than the error */
        o = select(o, o | 1, cx + cw < -exw);
        o = select(o, o | 2, cw - cx < -exw);
        o = select(o, o | 4, cy + cw < -eyw);
        o = select(o, o | 8, cw - cy < -eyw);
        o = select(o, o | 16, cz + cw < -ezw);
        o = select(o, o | 32, cw - cz < -ezw);
        out_and &= o;
        float8 wl = cw - ew, wh = cw + ew;
        cross = select(one, cross, wl > 0.0f);   /* also for NaN */
        cross = select(cross, one, cz + cw < 0.0f);
        float8 qx = cx - ex, rx = cx + ex, qy = cy - ey, ry = cy + ey, qz = cz - ez;
        float8 v;
        v = qx / select(wl, wh, qx >= 0.0f); xl = select(xl, v, v < xl);
        v = rx / select(wh, wl, rx >= 0.0f); xh = select(xh, v, v > xh);
        v = qy / select(wl, wh, qy >= 0.0f); yl = select(yl, v, v < yl);
        v = ry / select(wh, wl, ry >= 0.0f); yh = select(yh, v, v > yh);
        v = qz / select(wl, wh, qz >= 0.0f); zl = select(zl, v, v < zl);
    }

    /* Every lane computes a rectangle and reads 4 texels at indices clamped into the level;
     * the verdict is selected at the end. */
    float hw = 0.5f * (float)width, hh = 0.5f * (float)height;
    float fw = (float)width, fh = (float)height;
    float8 X0 = (xl + 1.0f) * hw - HIZ_PIXEL_SLACK, X1 = (xh + 1.0f) * hw + HIZ_PIXEL_SLACK;
    float8 Y0 = (1.0f - yh) * hh - HIZ_PIXEL_SLACK, Y1 = (1.0f - yl) * hh + HIZ_PIXEL_SLACK;
    /* pixel x is a candidate iff X0 <= x + 0.5 <= X1; clamping first keeps the int
     * conversion in range (the bounds may be ±inf) */
    int8 wm1 = (int8)(width - 1), hm1 = (int8)(height - 1);
    float8 lo_f = (float8)(-1.0f);
    int8 x0 = max(convert_int8(ceil(clamp(X0 - 0.5f, lo_f, (float8)fw))), zero);
    int8 x1 = min(convert_int8(floor(clamp(X1 - 0.5f, lo_f, (float8)fw))), wm1);
    int8 y0 = max(convert_int8(ceil(clamp(Y0 - 0.5f, lo_f, (float8)fh))), zero);
    int8 y1 = min(convert_int8(floor(clamp(Y1 - 0.5f, lo_f, (float8)fh))), hm1);
    int8 empty = select(zero, one, x0 > x1);
    empty = select(empty, one, y0 > y1);
    x0 = min(x0, wm1); x1 = max(x1, zero);
    y0 = min(y0, hm1); y1 = max(y1, zero);
    /* Finest level L with (x1 >> L) − (x0 >> L) <= 1 (and the same in y). For a span s, L
     * with 2^L >= s always works and L with 2^(L+1) <= s never does, so with
     * c = ceil(log2 s) the answer is c − 1 or c; the valid levels are upward closed, so the
     * larger of the x and y answers is right for both. */
    uint8 sx = as_uint8(max(x1 - x0, zero)), sy = as_uint8(max(y1 - y0, zero));
    int8 lx = select(32 - as_int8(clz(sx - 1u)), zero, sx <= 1u);
    int8 ly = select(32 - as_int8(clz(sy - 1u)), zero, sy <= 1u);
    lx = max(lx - 1, zero);
    ly = max(ly - 1, zero);
    lx = select(lx, lx + 1, (x1 >> lx) - (x0 >> lx) > one);
    ly = select(ly, ly + 1, (y1 >> ly) - (y0 >> ly) > one);
    int8 L = min(max(lx, ly), (int8)(n_levels - 1));
    int Ls[8], ax0[8], ax1[8], ay0[8], ay1[8];
    float zm[8];
    vstore8(L, 0, Ls);
    vstore8(x0 >> L, 0, ax0);
    vstore8(x1 >> L, 0, ax1);
    vstore8(y0 >> L, 0, ay0);
    vstore8(y1 >> L, 0, ay1);
    for (int l = 0; l < 8; ++l) {
        __global const float *p = pyr + levels[4 * Ls[l]];
        int lw = levels[4 * Ls[l] + 1];
        zm[l] = far4(p[ay0[l] * lw + ax0[l]], p[ay0[l] * lw + ax1[l]],
                     p[ay1[l] * lw + ax0[l]], p[ay1[l] * lw + ax1[l]]);
    }
    float8 zmax = vload8(0, zm);
    /* in the z-buffer's key (zoff = 0.5: window depth; -0.5: minus reversed-Z depth, see
     * setup.cl value_planes); either way one rounding of <= 2^-26, inside the slack */
    float8 dnear = (zl * 0.5f + zoff) - HIZ_DEPTH_SLACK;
    int8 r = select((int8)OCC_VISIBLE, (int8)OCC_OCCLUDED, dnear > zmax);
    r = select(r, (int8)OCC_OCCLUDED, empty > zero);
    r = select(r, (int8)OCC_VISIBLE, cross > zero);
    r = select(r, (int8)OCC_VIEW_CULLED, out_and > zero);
    r = select(r, (int8)OCC_VISIBLE, bad > zero);
    vstore8(convert_uchar8(r), g, result);
}
