/* Vertex stage: object space -> clip space, and outcodes, for the vertices of this frame's
 * draws (instance, cluster): one work-item per VERTEX_LANES consecutive cluster-local
 * vertices of a draw (a work-group per draw). Each instance has
 * its own row-major float32 matrix (clip = M · [x y z 1]ᵀ) in mvps[16 * instance].
 * Output vertex i = draw.vert_base + local index; a vertex shared by two clusters is
 * transformed once per cluster, bit-identically.
 * Also the viewport transform (win_xy: the snapped window x, y, all setup reads) of every
 * vertex that can be drawn unclipped.
 * Outcode bit k is set iff the signed distance to plane k is negative; the distances are the
 * same expressions the clipper uses (setup.cl plane_dist), so the two never disagree.
 * User clip planes (n_user of them): ucode bit k is set iff the vertex's distance to plane
 * k, in double from its object-space position and the instance's object-space plane
 * (uplanes[(instance·n_user + k)·4 ..]), is negative: user_dist, the expression setup.cl
 * evaluates for the same vertex. */
#include "common.h"

/* Lanes per work-item: VERTEX_LANES vertices of one cluster go through the transforms as
 * float8 vectors (the same operations per lane as scalar code, so the same bits);
 * a full set of lanes without user clip planes also gets its outcodes, rounding and
 * stores in lanes (store_lanes), the rest per vertex. PoCL does not vectorize this kernel
 * across work-items itself (ARCHITECTURE.md, "Writing kernels for PoCL's CPU device"), so
 * the lanes are written out. Outcodes as vector compares ORed into int8 masks came out
 * wrong on Oclgrind (tests/test_oclgrind.py), so under CLRASTER_PORTABLE they are per
 * vertex. The host launches CLUSTER_MAX / VERTEX_LANES work-items per draw
 * (clraster/pipeline/stages/vertex.py); VERTEX_LANES (8, clraster/base/layout.py) must match
 * the vector types below. */
typedef float8 fvec;
/* one value per lane in private memory, aligned for the vector loads and stores above */
typedef float flanes[VERTEX_LANES] __attribute__((aligned(32)));

/* The stores of a full set of lanes use common.h's element-aligned vector types (a draw's
 * first vertex has no particular alignment; only with CLRASTER_LANE_STORES, common.h). */

/* Outcodes, window positions and every store of a full set of VERTEX_LANES lanes without
 * user clip planes, in lanes: the same values as the per-vertex loop of vertex_transform
 * (the same compares; roundeven is rint in the default rounding mode), written as whole
 * vectors, the float4 positions interleaved from the lanes by shuffles. The
 * per-vertex loop (eight rounds of scalar compares, rounding and five stores — four since
 * the double positions went to setup — from the
 * lanes spilled to private arrays) was most of the kernel. Only with CLRASTER_LANE_STORES
 * (common.h: the compiler has the Clang builtins; never under CLRASTER_PORTABLE, as on
 * Oclgrind, which has no roundeven and whose vector masks differed before: see above);
 * otherwise the loop. */
#ifdef CLRASTER_LANE_STORES
/* Lanes 0-3 / 4-7 of a and b interleaved (a0 b0 a1 b1 ...), and pairs of them interleaved
 * (a0 a1 b0 b1 ...): with these, eight lanes of x, y, z, w become eight consecutive
 * (x, y, z, w) records, stored as four 8-vectors through d (STORE_XYZW8). */
#define ZIP_LO(a, b) __builtin_shufflevector(a, b, 0, 8, 1, 9, 2, 10, 3, 11)
#define ZIP_HI(a, b) __builtin_shufflevector(a, b, 4, 12, 5, 13, 6, 14, 7, 15)
#define PAIRS_LO(a, b) __builtin_shufflevector(a, b, 0, 1, 8, 9, 2, 3, 10, 11)
#define PAIRS_HI(a, b) __builtin_shufflevector(a, b, 4, 5, 12, 13, 6, 7, 14, 15)
#define STORE_XYZW8(d, x, y, z, w) do {                                                   \
        (d)[0] = PAIRS_LO(ZIP_LO(x, y), ZIP_LO(z, w));                                    \
        (d)[1] = PAIRS_HI(ZIP_LO(x, y), ZIP_LO(z, w));                                    \
        (d)[2] = PAIRS_LO(ZIP_HI(x, y), ZIP_HI(z, w));                                    \
        (d)[3] = PAIRS_HI(ZIP_HI(x, y), ZIP_HI(z, w));                                    \
    } while (0)

/* One test's outcode bit per lane (common.h FRUSTUM_OUTCODE's BIT). */
#define LANE_BIT(test, bit) ((test) ? (int8)(bit) : (int8)0)

ALWAYS_INLINE void store_lanes(fvec cx, fvec cy, fvec cz, fvec cw, fvec xs, fvec ys,
                               int flags, float kx, float ky,
                               __global float4 *clip, __global ushort *outcode,
                               __global int2 *win, __global uchar *ucode)
{
    const int8 exp_mask = (int8)0x7f800000;
    int8 finite = ((as_int8(cx) & exp_mask) != exp_mask)
                  & ((as_int8(cy) & exp_mask) != exp_mask)
                  & ((as_int8(cz) & exp_mask) != exp_mask)
                  & ((as_int8(cw) & exp_mask) != exp_mask);   /* finite_f, per lane */
    int8 o = (int8)0;
    if (!(flags & DRAW_INSIDE)) {   /* common.h frustum_outcode per lane, then the loop's bits */
        o |= FRUSTUM_OUTCODE(cx, cy, cz, cw, 0.0f, LANE_BIT);
        o |= (cx + kx * cw < 0.0f) ? (int8)OC_GB_X_NEG : (int8)0;
        o |= (kx * cw - cx < 0.0f) ? (int8)OC_GB_X_POS : (int8)0;
        o |= (cy + ky * cw < 0.0f) ? (int8)OC_GB_Y_NEG : (int8)0;
        o |= (ky * cw - cy < 0.0f) ? (int8)OC_GB_Y_POS : (int8)0;
        o |= (cw > 0.0f) ? (int8)0 : (int8)OC_W_NONPOS;
    }
    o = finite ? o : (int8)OC_INVALID;
    int8 drawn = (o & (int8)(OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP)) == 0;
    /* 0 chosen before the conversion: a non-finite or out-of-range lane converted to int
     * would be undefined (LLVM's poison), even where the choice then drops it */
    int8 wx = convert_int8(__builtin_elementwise_roundeven(drawn ? xs : (fvec)0.0f));
    int8 wy = convert_int8(__builtin_elementwise_roundeven(drawn ? ys : (fvec)0.0f));
    STORE_XYZW8((__global float8u *)clip, cx, cy, cz, cw);
    *(__global ushort8u *)outcode = convert_ushort8(o);
    __global int8u *w8 = (__global int8u *)win;
    w8[0] = ZIP_LO(wx, wy);
    w8[1] = ZIP_HI(wx, wy);
    *(__global uchar8u *)ucode = (uchar8)0;
}
#endif

__kernel void vertex_transform(__global const float *restrict pos,
                               __global const int4 *restrict clusters,
                               __global const Draw *restrict draws, const uint n_draws,
                               __global const float *restrict mvps, const float kx,
                               const float ky, const int width, const int height,
                               __global float4 *restrict clip,
                               __global ushort *restrict outcode,
                               __global int2 *restrict win,
                               __global const double *restrict uplanes, const int n_user,
                               __global uchar *restrict ucode)
{
    /* work-groups of CLUSTER_MAX / VERTEX_LANES: the group is the draw, so everything read
     * per draw (record, cluster, matrix) is uniform over the group */
    uint d = get_group_id(0);
    if (d >= n_draws) return;
    Draw dr = draws[d];
    int4 ci = clusters[dr.cluster];   /* tri_offset, n_tris, vert_offset, n_verts */
    int lv0 = (int)get_local_id(0) * VERTEX_LANES;
    if (lv0 >= ci.w) return;
    int n = imin(VERTEX_LANES, ci.w - lv0);
    /* The pool stores a cluster's positions side by side (clusters[c].z is the first):
     * read in place, straight for a full set of lanes, not gathered through an index
     * array (the gathers' completions were a fifth of this kernel's time). */
    __global const float *p0 = pos + 3 * (ci.z + lv0);
    flanes px, py, pz;
    if (n == VERTEX_LANES) {
        for (int l = 0; l < VERTEX_LANES; ++l) {
            px[l] = p0[3 * l]; py[l] = p0[3 * l + 1]; pz[l] = p0[3 * l + 2];
        }
    } else {
        for (int l = 0; l < VERTEX_LANES; ++l) {
            int k = l < n ? l : 0;   /* spare lanes: a real vertex */
            px[l] = p0[3 * k]; py[l] = p0[3 * k + 1]; pz[l] = p0[3 * k + 2];
        }
    }
    fvec x = *(fvec *)px, y = *(fvec *)py, z = *(fvec *)pz;
    __global const float *m = mvps + 16 * dr.instance;
    /* clip_transform, per lane */
    fvec cx = MAT_ROW(m, 0, x, y, z), cy = MAT_ROW(m, 1, x, y, z);
    fvec cz = MAT_ROW(m, 2, x, y, z), cw = MAT_ROW(m, 3, x, y, z);
    /* viewport_vertex's arithmetic, per lane (used below only for the vertices drawn
     * unclipped; a lane with w = 0 gets inf here, never stored) */
    fvec iw = 1.0f / cw;
    float hw = 0.5f * (float)width, hh = 0.5f * (float)height;
    fvec xs = WIN_X_SUB(cx, iw, hw), ys = WIN_Y_SUB(cy, iw, hh);
    uint i0 = (uint)dr.vert_base + (uint)lv0;
#ifdef CLRASTER_LANE_STORES
    if (n == VERTEX_LANES && n_user == 0) {
        store_lanes(cx, cy, cz, cw, xs, ys, dr.flags, kx, ky, clip + i0, outcode + i0,
                    win + i0, ucode + i0);
        return;
    }
#endif
    flanes acx, acy, acz, acw, axs, ays;
    *(fvec *)acx = cx; *(fvec *)acy = cy; *(fvec *)acz = cz; *(fvec *)acw = cw;
    *(fvec *)axs = xs; *(fvec *)ays = ys;
    for (int l = 0; l < n; ++l) {
        uint i = i0 + l;
        float4 c = (float4)(acx[l], acy[l], acz[l], acw[l]);
        /* outcodes per vertex (vector compares ORed into masks came out wrong on
         * Oclgrind, tests/test_oclgrind.py) */
        uint o = 0;
        if (!(finite_f(c.x) && finite_f(c.y) && finite_f(c.z) && finite_f(c.w))) {
            o = OC_INVALID;
        } else if (!(dr.flags & DRAW_INSIDE)) {
            /* clusters inside the frustum by a margin skip the tests: all bits would be 0 */
            o = frustum_outcode(c);
            o |= (c.x + kx * c.w < 0.0f) ? OC_GB_X_NEG : 0;
            o |= (kx * c.w - c.x < 0.0f) ? OC_GB_X_POS : 0;
            o |= (c.y + ky * c.w < 0.0f) ? OC_GB_Y_NEG : 0;
            o |= (ky * c.w - c.y < 0.0f) ? OC_GB_Y_POS : 0;
            o |= (c.w > 0.0f) ? 0 : OC_W_NONPOS;
        }
        int2 v = (int2)(0, 0);   /* win_xy's layout, as a vector: see common.h win_xy */
        if (!(o & (OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP))) {
            /* round half to even, as common.h viewport_vertex */
            v.x = (int)RINTF(axs[l]);
            v.y = (int)RINTF(ays[l]);
        }
        uint uc = 0;
        if (n_user > 0 && !(o & OC_INVALID)) {
            __global const double *q = uplanes + 4 * n_user * dr.instance;
            for (int k = 0; k < n_user; ++k)
                uc |= user_dist(q + 4 * k, px[l], py[l], pz[l]) < 0.0 ? 1u << k : 0u;
        }
        clip[i] = c;
        outcode[i] = (ushort)o;
        win[i] = v;
        ucode[i] = (uchar)uc;
    }
}
