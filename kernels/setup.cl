/* Triangle setup: trivial reject, clipping, back-face / zero-area cull, fixed-point snap.
 *
 * setup_triangles (one work-item per triangle) writes, for every unclipped survivor, one
 * Piece at the triangle's own slot, a status per triangle and, for triangles that need the
 * clipper, the number of pieces they make. The host scans those counts; setup_clipped then
 * re-runs the clipper for just those triangles and writes their pieces in order. Clipping is
 * rare, so recomputing it beats storing up to 14 pieces per triangle for everyone.
 *
 * Clipping is Sutherland–Hodgman in homogeneous clip space against near, far and — only when
 * a vertex leaves the guard band — the x/y guard-band planes (config.guard_band_factors).
 * Intersections are always interpolated from the inside vertex towards the outside one, so
 * two triangles sharing an edge compute bit-identical new vertices: no cracks.
 */
#include "common.h"

#define POLY_MAX 16   /* > 3 + 6: float rounding can make a clipped polygon a hair non-convex */

typedef struct { float4 p; float b0, b1, b2; } ClipVert;

__constant uint PLANE_BIT[6] = {OC_Z_NEG, OC_Z_POS, OC_GB_X_NEG, OC_GB_X_POS, OC_GB_Y_NEG,
                                OC_GB_Y_POS};

/* Signed distance to clip plane p, >= 0 inside; the same expressions as vertex.cl. */
inline float plane_dist(int p, float4 v, float kx, float ky)
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

/* Set up one triangle from its three window-space vertices. Returns ST_RASTER when it
 * survives, otherwise the reason it was dropped; *swapped says whether vertices 1 and 2 were
 * exchanged to make the doubled area positive. */
inline int make_piece(WinVert v0, WinVert v1, WinVert v2, int width, int height, int cull,
                      Piece *pc, int *swapped)
{
    long area2 = edge_fn(v0.x, v0.y, v1.x, v1.y, v2.x, v2.y);
    if (area2 == 0) return ST_DEGENERATE;
    /* y points down in window space, so counter-clockwise in NDC is area2 < 0. */
    if ((cull == CULL_BACK && area2 > 0) || (cull == CULL_FRONT && area2 < 0))
        return ST_BACKFACE;
    *swapped = area2 < 0;
    if (area2 < 0) {
        WinVert t = v1; v1 = v2; v2 = t;
        area2 = -area2;
    }
    int xmin = min(min(v0.x, v1.x), v2.x), xmax = max(max(v0.x, v1.x), v2.x);
    int ymin = min(min(v0.y, v1.y), v2.y), ymax = max(max(v0.y, v1.y), v2.y);
    /* pixel x is inside iff its centre 256x + 128 lies in [xmin, xmax] */
    int px0 = max((xmin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, 0);
    int px1 = min((xmax - SUB_HALF) >> SUBPIXEL_BITS, width - 1);
    int py0 = max((ymin - SUB_HALF + SUB_ONE - 1) >> SUBPIXEL_BITS, 0);
    int py1 = min((ymax - SUB_HALF) >> SUBPIXEL_BITS, height - 1);
    if (px0 > px1 || py0 > py1) return ST_NO_SAMPLE;
    pc->x[0] = v0.x; pc->x[1] = v1.x; pc->x[2] = v2.x;
    pc->y[0] = v0.y; pc->y[1] = v1.y; pc->y[2] = v2.y;
    pc->bb_min = px0 | (py0 << 16);
    pc->bb_max = px1 | (py1 << 16);
    pc->z0 = v0.z;
    pc->dz10 = v1.z - v0.z;
    pc->dz20 = v2.z - v0.z;
    pc->inv_area = 1.0f / (float)area2;
    pc->r1 = v1.iw / v0.iw;
    pc->r2 = v2.iw / v0.iw;
    return ST_RASTER;
}

/* Clip triangle (c0, c1, c2) against the planes in `planes`, fan the polygon and snap each
 * piece. Returns the number of surviving pieces; with write != 0 also stores them (and their
 * parent barycentrics, 9 floats per piece) at index base, base+1, ... */
inline int clip_and_emit(float4 c0, float4 c1, float4 c2, uint planes, float kx, float ky,
                         int width, int height, int cull, int id, int write,
                         __global Piece *out, __global float *out_bary, int base)
{
    ClipVert poly[POLY_MAX], tmp[POLY_MAX];
    poly[0].p = c0; poly[0].b0 = 1.0f; poly[0].b1 = 0.0f; poly[0].b2 = 0.0f;
    poly[1].p = c1; poly[1].b0 = 0.0f; poly[1].b1 = 1.0f; poly[1].b2 = 0.0f;
    poly[2].p = c2; poly[2].b0 = 0.0f; poly[2].b1 = 0.0f; poly[2].b2 = 1.0f;
    int n = 3;
    for (int p = 0; p < 6 && n >= 3; ++p) {
        if (!(planes & PLANE_BIT[p])) continue;
        for (int i = 0; i < n; ++i) tmp[i] = poly[i];
        int m = 0;
        for (int i = 0; i < n && m < POLY_MAX; ++i) {
            ClipVert a = tmp[i], b = tmp[i + 1 == n ? 0 : i + 1];
            float da = plane_dist(p, a.p, kx, ky), db = plane_dist(p, b.p, kx, ky);
            bool ain = da >= 0.0f, bin = db >= 0.0f;
            if (ain) poly[m++] = a;
            if (ain != bin && m < POLY_MAX) {
                ClipVert vi = ain ? a : b, vo = ain ? b : a;
                float di = ain ? da : db, dout = ain ? db : da;
                float t = di / (di - dout);
                ClipVert r;
                r.p = vi.p + t * (vo.p - vi.p);
                r.b0 = vi.b0 + t * (vo.b0 - vi.b0);
                r.b1 = vi.b1 + t * (vo.b1 - vi.b1);
                r.b2 = vi.b2 + t * (vo.b2 - vi.b2);
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
        /* a piece with a vertex at w <= 0 can only come from a projection matrix that
         * does not put w > 0 on the near plane; it has no window position: dropped */
        if (!(poly[0].p.w > 0.0f && poly[k].p.w > 0.0f && poly[k + 1].p.w > 0.0f))
            continue;
        if (make_piece(viewport_vertex(poly[0].p, hw, hh), viewport_vertex(poly[k].p, hw, hh),
                       viewport_vertex(poly[k + 1].p, hw, hh), width, height, cull, &pc, &sw)
            != ST_RASTER)
            continue;
        if (write) {
            pc.id = id;
            pc.flags = PF_CLIPPED | (sw ? PF_SWAPPED : 0) | ((base + count) << PF_INDEX_SHIFT);
            out[base + count] = pc;
            /* parent barycentrics of the piece's vertices, in the piece's (swapped) order */
            ClipVert v1 = sw ? poly[k + 1] : poly[k], v2 = sw ? poly[k] : poly[k + 1];
            __global float *b = out_bary + 9 * (base + count);
            b[0] = poly[0].b0; b[1] = poly[0].b1; b[2] = poly[0].b2;
            b[3] = v1.b0; b[4] = v1.b1; b[5] = v1.b2;
            b[6] = v2.b0; b[7] = v2.b1; b[8] = v2.b2;
        }
        ++count;
    }
    return count;
}

__kernel void setup_triangles(__global const float4 *clip, __global const ushort *outcode,
                              __global const WinVert *win, __global const int *faces,
                              const uint m,
                              const int width, const int height, const int cull,
                              const float kx, const float ky,
                              __global Piece *pieces, __global uchar *status,
                              __global int *clip_count)
{
    uint t = get_global_id(0);
    if (t >= m) return;
    int i0 = faces[3 * t], i1 = faces[3 * t + 1], i2 = faces[3 * t + 2];
    uint o0 = outcode[i0], o1 = outcode[i1], o2 = outcode[i2];
    uint o_or = o0 | o1 | o2, o_and = o0 & o1 & o2;
    int st, nclip = 0;
    if (o_or & OC_INVALID) {
        st = ST_INVALID;
    } else if (o_and & OC_FRUSTUM) {
        st = ST_TRIVIAL_REJECT;
    } else if (o_or & OC_NEEDS_CLIP) {
        st = ST_CLIPPED;
        nclip = clip_and_emit(clip[i0], clip[i1], clip[i2], o_or & OC_NEEDS_CLIP, kx, ky,
                              width, height, cull, (int)t, 0, pieces, 0, 0);
    } else if (o_or & OC_W_NONPOS) {
        st = ST_DEGENERATE;   /* a vertex at the clip-space origin (w = 0) */
    } else {
        Piece pc;
        int sw = 0;
        st = make_piece(win[i0], win[i1], win[i2], width, height, cull, &pc, &sw);
        if (st == ST_RASTER) {
            pc.id = (int)t;
            pc.flags = sw ? PF_SWAPPED : 0;
            pieces[t] = pc;
        }
    }
    status[t] = (uchar)st;
    clip_count[t] = nclip;
}

__kernel void setup_clipped(__global const float4 *clip, __global const ushort *outcode,
                            __global const WinVert *win, __global const int *faces,
                            const uint m,
                            const int width, const int height, const int cull,
                            const float kx, const float ky,
                            __global const int *clip_count, __global const int *clip_offset,
                            __global Piece *clip_pieces, __global float *clip_bary)
{
    uint t = get_global_id(0);
    if (t >= m || clip_count[t] == 0) return;
    int i0 = faces[3 * t], i1 = faces[3 * t + 1], i2 = faces[3 * t + 2];
    uint o_or = outcode[i0] | outcode[i1] | outcode[i2];
    clip_and_emit(clip[i0], clip[i1], clip[i2], o_or & OC_NEEDS_CLIP, kx, ky, width, height,
                  cull, (int)t, 1, clip_pieces, clip_bary, clip_offset[t]);
}
