/* Vertex stage: object space -> clip space, and outcodes, for the vertices of this frame's
 * draws (instance, cluster): one work-item per (draw, cluster-local vertex). Each instance has
 * its own row-major float32 matrix (clip = M · [x y z 1]ᵀ) in mvps[16 * instance].
 * Output vertex i = draw.vert_base + local index; a vertex shared by two clusters is
 * transformed once per cluster, bit-identically.
 * Also the viewport transform (WinVert) of every vertex that can be drawn unclipped.
 * Outcode bit k is set iff the signed distance to plane k is negative; the distances are the
 * same expressions the clipper uses (setup.cl plane_dist), so the two never disagree.
 * User clip planes (n_user of them): ucode bit k is set iff the vertex's distance to plane
 * k, in double from its object-space position and the instance's object-space plane
 * (uplanes[(instance·n_user + k)·4 ..]), is negative: user_dist, the expression setup.cl
 * evaluates for the same vertex. */
#include "common.h"

__kernel void vertex_transform(__global const float *restrict pos,
                               __global const int *restrict vert_ids,
                               __global const int4 *restrict clusters,
                               __global const Draw *restrict draws, const uint n_draws,
                               __global const float *restrict mvps, const float kx,
                               const float ky, const int width, const int height,
                               __global float4 *restrict clip,
                               __global ushort *restrict outcode,
                               __global WinVert *restrict win,
                               __global const double *restrict uplanes, const int n_user,
                               __global uchar *restrict ucode,
                               __global const double *restrict mvps64,
                               __global const double *restrict zrows, const int reversed,
                               __global double4 *restrict clip64,
                               __global double *restrict rnum)
{
    /* launched with work-groups of CLUSTER_MAX: the group is the draw, so everything read
     * per draw (record, cluster, matrix) is uniform over the group and PoCL hoists it */
    uint d = get_group_id(0), lv = get_local_id(0);
    if (d >= n_draws) return;
    Draw dr = draws[d];
    int4 ci = clusters[dr.cluster];   /* tri_offset, n_tris, vert_offset, n_verts */
    if ((int)lv >= ci.w) return;
    int vi = vert_ids[ci.z + lv];
    uint i = (uint)dr.vert_base + lv;
    __global const float *mvp = mvps + 16 * dr.instance;
    float4 c = clip_transform(mvp, pos[3 * vi], pos[3 * vi + 1], pos[3 * vi + 2]);
    uint oc = 0;
    if (!(finite_f(c.x) && finite_f(c.y) && finite_f(c.z) && finite_f(c.w))) {
        oc = OC_INVALID;
    } else if (!(dr.flags & DRAW_INSIDE)) {
        /* clusters inside the frustum by a margin skip the tests: all bits would be 0 */
        oc = frustum_outcode(c);
        oc |= (c.x + kx * c.w < 0.0f) ? OC_GB_X_NEG : 0;
        oc |= (kx * c.w - c.x < 0.0f) ? OC_GB_X_POS : 0;
        oc |= (c.y + ky * c.w < 0.0f) ? OC_GB_Y_NEG : 0;
        oc |= (ky * c.w - c.y < 0.0f) ? OC_GB_Y_POS : 0;
        oc |= (c.w > 0.0f) ? 0 : OC_W_NONPOS;
    }
    /* The viewport transform is done once per vertex here rather than once per triangle
     * corner in setup. Only meaningful for vertices that triangles use unclipped (inside the
     * guard band, near and far, w > 0); others are left as zeros and never read. */
    WinVert v = {0, 0, 0.0f, 0.0f};
    if (!(oc & (OC_INVALID | OC_W_NONPOS | OC_NEEDS_CLIP)))
        v = viewport_vertex(c, 0.5f * (float)width, 0.5f * (float)height);
    uint uc = 0;
    if (n_user > 0 && !(oc & OC_INVALID)) {
        __global const double *q = uplanes + 4 * n_user * dr.instance;
        for (int k = 0; k < n_user; ++k)
            uc |= user_dist(q + 4 * k, pos[3 * vi], pos[3 * vi + 1], pos[3 * vi + 2]) < 0.0
                  ? 1u << k : 0u;
    }
    /* the double position setup's value planes and clipper use (common.h vertex_clip64) */
    double r;
    clip64[i] = vertex_clip64(mvps64 + 16 * dr.instance, zrows + 4 * dr.instance, reversed,
                              pos[3 * vi], pos[3 * vi + 1], pos[3 * vi + 2], &r);
    rnum[i] = r;
    clip[i] = c;
    outcode[i] = (ushort)oc;
    win[i] = v;
    ucode[i] = (uchar)uc;
}
