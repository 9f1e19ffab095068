/* Line segments: world -> clip space, Cohen–Sutherland clipping in homogeneous clip space,
 * aliased rasterization with exact integer arithmetic, depth test and a deterministic
 * resolve. The NumPy twin (clraster/pipeline/reference/lines.py) does the same float32 / float64
 * operations in the same order and the same integer rules, so both give bit-identical
 * line ids, depths and counts. Host side: clraster/pipeline/stages/lines.py.
 *
 * Three launches, one work-item per segment each:
 *
 * line_setup   clip = M·[x y z 1]ᵀ in float32 (setup.cl's vertex operation order), 6-bit outcodes
 *              (x<-w, x>w, y<-w, y>w, z<-w, z>w; OC_INVALID for a NaN/Inf clip position).
 *              Cohen–Sutherland: c0 | c1 == 0 -> trivial accept; c0 & c1 != 0 -> trivial
 *              reject; otherwise clip. The clipper (double, as in setup.cl) visits the
 *              planes near, far, left, right, bottom, top once each, so it ends after at
 *              most 6 clips. Before each plane it rejects the segment if both current
 *              outcodes share a bit (nothing of it is left inside); if one endpoint is
 *              outside the plane it moves that endpoint to the crossing, interpolating from
 *              the inside endpoint (t = d_in / (d_in − d_out)), puts the clipped coordinate
 *              exactly on the plane (x = ±w ...) and recomputes that endpoint's outcode. Both
 *              endpoints are treated alike (per plane, the one outside moves), so the result
 *              does not depend on which one the caller listed first. In exact arithmetic
 *              this leaves both endpoints inside; double rounding can leave one a hair
 *              outside a plane visited earlier, so the float32 result is put back into the
 *              view volume (x, y, z clamped to [−w, w]; a no-op for every point that
 *              already is inside). An endpoint with w < FLT_MIN after clipping (only the
 *              clip-space origin: |x|, |y|, |z| <= w) has no window position: the segment is
 *              dropped and counted (LS_*_DEGENERATE). With every endpoint in the view volume,
 *              |x/w| <= 1 holds in float32 too (|x · fl(1/w)| <= 1 + 2^-24 rounds to <= 1;
 *              for w > 2^126, where 1/w is subnormal, it can round to 1 + 2^-23, i.e. at
 *              most 1/256 px beyond the border), so viewport_vertex (common.h, the
 *              triangles' own transform) maps it into [0, 256·W + 1] × [0, 256·H + 1] in
 *              24.8 fixed point, depth into [0, 1]: no guard band, every loop below is
 *              bounded by max(W, H) pixels, and every major pixel index is in the image.
 *
 * line_depth   pass 1: walk the fragments (rule below), depth-test each against the optional
 *              input depth buffer (z <= depth[y, x] + bias, LEQUAL), atomic_min the passing
 *              depth's bit pattern into zmin (non-negative floats order like uints; cleared
 *              to 0xFFFFFFFF so that a fragment at depth 1.0 still counts). Also counts the
 *              segment's fragments and passing fragments.
 * line_id      pass 2: walk again; a passing fragment whose depth bits equal zmin at its pixel
 *              atomic_mins its segment index into idmin. The nearest fragment wins, ties go to
 *              the lower index, whatever order the work-items run in.
 *
 * Rasterization rule (aliased lines, close to D3D11/GL): window positions snapped to 1/256 px
 * (X, Y integers, y down, row 0 on top, pixel (x, y) has its centre at (x + 0.5, y + 0.5)).
 * dx = X1 − X0, dy = Y1 − Y0; the line is x-major if |dx| >= |dy|, else y-major. Endpoints
 * are ordered canonically along the major axis (start = smaller major coordinate), and the
 * segment lights every pixel column (row, for y-major) whose centre c lies in the half-open
 * interval [start, end): the canonical start pixel is included, the end pixel excluded
 * (like GL's diamond-exit rule for the last pixel), so chained segments do not double-hit
 * their joints and a zero-length segment lights nothing. The minor coordinate at c is the
 * exact rational m = (N_s·D + (c − M_s)·(N_e − N_s)) / D (D = M_e − M_s > 0); the pixel lit is
 * floor(m / 256), the pixel whose half-open square [k, k+1) contains m: a tie (m exactly on
 * a pixel boundary) goes to the larger index (down / right). Since m lies between the
 * endpoints, in [0, 256·size (+1)], the only pixel index that can fall outside the image is
 * size itself, when m is on the bottom (right) image border; that point belongs to no pixel
 * of the image and lights nothing. The major pixel range is always inside the image. Both
 * are still checked before every access.
 *
 * Depth: linear in screen space along the major axis, t = float(c − M_s) / float(D),
 * z = z_s + t·(z_e − z_s) in float32, clamped to [0, 1] (as GL clamps to the depth range;
 * only rounding can leave it).
 */
#include "common.h"

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

/* Segment status LS_* (accepted, clipped, invalid, rejected, clipped away, accepted /
 * clipped but degenerate), the resolve buffers' clear values ZMIN_CLEAR / IDMIN_CLEAR
 * (0xFFFFFFFFu) and LineRec come from clraster/base/layout.py (common.h). LineRec is one set-up
 * segment (clraster.layout.LINE_DTYPE), 32 bytes: 24.8 fixed-point window endpoints in
 * canonical order along the major axis (xs/ys the start), the start's window depth and
 * (end − start) depth. Only status is meaningful unless status is LS_ACCEPTED or LS_CLIPPED. */

/* Clipping order: near, far, left, right, bottom, top (near first: it is the plane that
 * removes w <= 0, where the other planes' distances are least meaningful). */
__constant uint LPLANE_BIT[6] = {OC_Z_NEG, OC_Z_POS, OC_X_NEG, OC_X_POS, OC_Y_NEG, OC_Y_POS};

inline float4 seg_clip(__global const float *mvp, __global const float *p)
{
    return clip_transform(mvp, p[0], p[1], p[2]);   /* common.h, as for triangle vertices */
}

/* Signed distance to plane k of LPLANE_BIT, >= 0 inside. */
inline double lplane_dist(int k, double4 v)
{
    switch (k) {
    case 0: return v.z + v.w;
    case 1: return v.w - v.z;
    case 2: return v.x + v.w;
    case 3: return v.w - v.x;
    case 4: return v.y + v.w;
    default: return v.w - v.y;
    }
}

/* Put the point exactly on plane k (its distance becomes 0). */
inline double4 on_plane(int k, double4 v)
{
    switch (k) {
    case 0: v.z = -v.w; break;
    case 1: v.z = v.w; break;
    case 2: v.x = -v.w; break;
    case 3: v.x = v.w; break;
    case 4: v.y = -v.w; break;
    default: v.y = v.w; break;
    }
    return v;
}

/* Cohen–Sutherland clip of (*a, *b) with outcodes oa, ob (oa & ob == 0, oa | ob != 0), see
 * the header comment. Returns 0 if nothing is left inside the view volume. */
inline int clip_segment(float4 *a, float4 *b, uint oa, uint ob)
{
    double4 p0 = convert_double4(*a), p1 = convert_double4(*b);
    for (int k = 0; k < 6; ++k) {
        if (oa & ob) return 0;
        uint bit = LPLANE_BIT[k];
        if (!((oa | ob) & bit)) continue;
        bool move0 = (oa & bit) != 0;   /* the other endpoint is inside: oa & ob == 0 */
        double4 pin = move0 ? p1 : p0, pout = move0 ? p0 : p1;
        double din = lplane_dist(k, pin), dout = lplane_dist(k, pout);
        double t = din / (din - dout);
        double4 r = on_plane(k, pin + t * (pout - pin));
        if (move0) { p0 = r; oa = frustum_outcode_d(r); }
        else { p1 = r; ob = frustum_outcode_d(r); }
    }
    if (oa & ob) return 0;
    *a = convert_float4(p0);
    *b = convert_float4(p1);
    return 1;
}

/* x, y, z into [−w, w] (w > 0); see the header comment. */
inline float4 into_view(float4 c)
{
    float nw = -c.w;
    c.x = c.x < nw ? nw : (c.x > c.w ? c.w : c.x);
    c.y = c.y < nw ? nw : (c.y > c.w ? c.w : c.y);
    c.z = c.z < nw ? nw : (c.z > c.w ? c.w : c.z);
    return c;
}

__kernel void line_setup(__global const float *pos, const uint n, __global const float *mvp,
                         const int width, const int height, __global LineRec *rec)
{
    uint i = get_global_id(0);
    if (i >= n) return;
    float4 c0 = seg_clip(mvp, pos + 6 * (size_t)i), c1 = seg_clip(mvp, pos + 6 * (size_t)i + 3);
    LineRec r = {0, 0, 0, 0, 0.0f, 0.0f, LS_INVALID, 0};
    bool finite = finite_f(c0.x) && finite_f(c0.y) && finite_f(c0.z) && finite_f(c0.w)
                  && finite_f(c1.x) && finite_f(c1.y) && finite_f(c1.z) && finite_f(c1.w);
    if (finite) {
        uint o0 = frustum_outcode(c0), o1 = frustum_outcode(c1);
        if (o0 & o1) {
            r.status = LS_REJECTED;
        } else {
            bool clipped = (o0 | o1) != 0;
            if (clipped && !clip_segment(&c0, &c1, o0, o1)) {
                r.status = LS_CLIPPED_AWAY;
            } else if (!(c0.w >= FLT_MIN && c1.w >= FLT_MIN)) {
                r.status = clipped ? LS_CLIPPED_DEGENERATE : LS_ACCEPTED_DEGENERATE;
            } else {
                float hw = 0.5f * (float)width, hh = 0.5f * (float)height;
                WinVert v0 = viewport_vertex(into_view(c0), hw, hh);
                WinVert v1 = viewport_vertex(into_view(c1), hw, hh);
                int dx = v1.x - v0.x, dy = v1.y - v0.y;
                bool xmajor = abs(dx) >= abs(dy);
                if (xmajor ? dx < 0 : dy < 0) {
                    WinVert tv = v0; v0 = v1; v1 = tv;
                }
                r.xs = v0.x; r.ys = v0.y; r.xe = v1.x; r.ye = v1.y;
                r.zs = v0.z;
                r.dz = v1.z - v0.z;
                r.status = clipped ? LS_CLIPPED : LS_ACCEPTED;
            }
        }
    }
    rec[i] = r;
}

/* Walk the fragments of one set-up segment (rule: header comment). pass 1: atomic_min of the
 * depth bits into zmin, fragment counts into *nfrag / *npass; pass 2: atomic_min of the
 * segment index into idmin where the depth bits equal zmin. The minor pixel index is
 * floor(num / DD), num = N_s·D + (c − M_s)·(N_e − N_s), DD = 256·D, kept exactly as quotient
 * q and remainder rem (0 <= rem < DD) and stepped by S = 256·(N_e − N_s) per pixel (all in
 * 64 bits: |num| < 2^22 · 2^23). */
inline void walk(LineRec r, uint seg, int width, int height, int pass,
                 __global const float *depth_in, int has_depth, float bias,
                 volatile __global uint *zmin, volatile __global uint *idmin,
                 int *nfrag, int *npass)
{
    int dx = r.xe - r.xs, dy = r.ye - r.ys;
    bool xmajor = abs(dx) >= abs(dy);
    int ms = xmajor ? r.xs : r.ys, me = xmajor ? r.xe : r.ye;   /* ms <= me */
    int ns = xmajor ? r.ys : r.xs, ne = xmajor ? r.ye : r.xe;
    int lim_major = xmajor ? width : height, lim_minor = xmajor ? height : width;
    /* pixels p with centre 256p + 128 in [ms, me) */
    int p0 = (ms + SUB_HALF - 1) >> SUBPIXEL_BITS, p1 = (me + SUB_HALF - 1) >> SUBPIXEL_BITS;
    if (p0 >= p1) return;
    long D = (long)(me - ms), DD = D << SUBPIXEL_BITS;
    long c0 = ((long)p0 << SUBPIXEL_BITS) + SUB_HALF;
    long num = (long)ns * D + (c0 - ms) * (long)(ne - ns);
    long q = num / DD, rem = num - q * DD;   /* num >= 0: ns, ne >= 0 */
    long S = (long)(ne - ns) << SUBPIXEL_BITS;   /* |S| <= DD */
    long qs = S / DD, rs = S - qs * DD;
    if (rs < 0) { rs += DD; qs -= 1; }
    float fD = (float)D;
    for (int p = p0; p < p1; ++p) {
        int m = (int)q;
        if (p >= 0 && p < lim_major && m >= 0 && m < lim_minor) {
            int x = xmajor ? p : m, y = xmajor ? m : p;
            int idx = y * width + x;
            float t = (float)((p << SUBPIXEL_BITS) + SUB_HALF - ms) / fD;
            float z = r.zs + t * r.dz;
            if (!(z > 0.0f)) z = 0.0f;   /* also turns −0 into +0 for the bit order */
            if (z > 1.0f) z = 1.0f;
            bool ok = !has_depth || z <= depth_in[idx] + bias;
            if (pass == 1) {
                *nfrag += 1;
                if (ok) {
                    *npass += 1;
                    atomic_min(&zmin[idx], as_uint(z));
                }
            } else if (ok && as_uint(z) == zmin[idx]) {
                atomic_min(&idmin[idx], seg);
            }
        }
        q += qs;
        rem += rs;
        if (rem >= DD) { rem -= DD; q += 1; }
    }
}

inline bool drawn(int status) { return status == LS_ACCEPTED || status == LS_CLIPPED; }

__kernel void line_depth(__global const LineRec *rec, const uint n, const int width,
                         const int height, __global const float *depth_in, const int has_depth,
                         const float bias, volatile __global uint *zmin,
                         __global int2 *counts)
{
    uint i = get_global_id(0);
    if (i >= n) return;
    LineRec r = rec[i];
    int nfrag = 0, npass = 0;
    if (drawn(r.status))
        walk(r, i, width, height, 1, depth_in, has_depth, bias, zmin, zmin, &nfrag, &npass);
    counts[i] = (int2)(nfrag, npass);
}

__kernel void line_id(__global const LineRec *rec, const uint n, const int width,
                      const int height, __global const float *depth_in, const int has_depth,
                      const float bias, volatile __global uint *zmin,
                      volatile __global uint *idmin)
{
    uint i = get_global_id(0);
    if (i >= n) return;
    LineRec r = rec[i];
    int nfrag = 0, npass = 0;
    if (drawn(r.status))
        walk(r, i, width, height, 2, depth_in, has_depth, bias, zmin, idmin, &nfrag, &npass);
}
