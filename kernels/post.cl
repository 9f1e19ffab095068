/* Per-pixel passes over a finished frame: screen-space ambient occlusion (two kernels) and
 * FXAA 3.11. The NumPy twins are in clraster/output/post.py (`ssao_inputs`,
 * `ssao_taps_pass`, `fxaa`), whose module docstring gives the methods; the float
 * expressions here are written in their order (FP contraction off, common.h).
 */
#include "common.h"

/* -- SSAO ---------------------------------------------------------------------------------
 * Three passes, the first two at half resolution: low-res pixel (lx, ly) of the
 * (⌈H/2⌉, ⌈W/2⌉) grid stands for full-res pixel (2lx, 2ly).
 * ssao_prepare: per low-res pixel, in double, the world point from the window depth through
 * inv_vp (P[0..15], row-major) relative to `origin` (P[16..18]) and the projected radius in
 * low-res pixels (radius · ‖vp[1, :3]‖ · H/4 / clip w; vp row 3 in P[19..22], P[23] =
 * radius · ‖vp[1, :3]‖ · H/4), and the normal turned against the pixel's view ray, with
 * the pixel's linear depth as w (INFINITY on the background) for ssao_upsample.
 * Linear depth: the clip w, 1 / (ivp · ndc) in float32, ivp the last row of inv(vp);
 * sx = 2/W, sy = 2/H (float32, host). */
static double4 unproject(__global const double *m, double x, double y, double z)
{
    double hx = ((m[0] * x + m[1] * y) + m[2] * z) + m[3];
    double hy = ((m[4] * x + m[5] * y) + m[6] * z) + m[7];
    double hz = ((m[8] * x + m[9] * y) + m[10] * z) + m[11];
    double hw = ((m[12] * x + m[13] * y) + m[14] * z) + m[15];
    return (double4)(hx / hw, hy / hw, hz / hw, 1.0);
}

static float lin_depth(float d, float4 ivp, int x, int y, float sx, float sy,
                       int reversed_z)
{
    float nx = ((float)x + 0.5f) * sx - 1.0f;
    float ny = 1.0f - ((float)y + 0.5f) * sy;
    float nz = reversed_z ? 1.0f - 2.0f * d : 2.0f * d - 1.0f;
    return 1.0f / (((ivp.x * nx + ivp.y * ny) + ivp.z * nz) + ivp.w);
}

__kernel void ssao_prepare(__global const float *depth, __global const float *normals,
                           __global const double *P, __global float4 *pos,
                           __global float4 *nrm, const int width, const int height,
                           const int reversed_z, const float4 ivp, const float sx,
                           const float sy)
{
    int lx = get_global_id(0), ly = get_global_id(1);
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    if (lx >= w2 || ly >= h2) return;
    int px = 2 * lx, py = 2 * ly;
    size_t i = (size_t)py * width + px, o = (size_t)ly * w2 + lx;
    float d = depth[i];
    if (reversed_z ? !(d > 0.0f) : !(d < 1.0f)) {
        pos[o] = (float4)(0.0f);
        nrm[o] = (float4)(0.0f, 0.0f, 0.0f, INFINITY);
        return;
    }
    double x = (px + 0.5) * (2.0 / width) - 1.0;
    double y = 1.0 - (py + 0.5) * (2.0 / height);
    double z = reversed_z ? 1.0 - 2.0 * (double)d : 2.0 * (double)d - 1.0;
    double4 p = unproject(P, x, y, z);
    double4 pn = unproject(P, x, y, -1.0);
    double3 ray = p.xyz - pn.xyz;
    double3 n = (double3)(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
    if ((n.x * ray.x + n.y * ray.y) + n.z * ray.z > 0.0) n = -n;
    double cw = ((p.x * P[19] + p.y * P[20]) + p.z * P[21]) + P[22];
    pos[o] = (float4)((float)(p.x - P[16]), (float)(p.y - P[17]), (float)(p.z - P[18]),
                      (float)(P[23] / cw));
    nrm[o] = (float4)((float)n.x, (float)n.y, (float)n.z,
                      lin_depth(d, ivp, px, py, sx, sy, reversed_z));
}

/* ssao: the taps (float32) on the low-res grid (w, h here are its size). taps: (samples, 2)
 * offsets as fractions of the radius; a low-res pixel's centre is (lx + 1/4, ly + 1/4)
 * (its full-res pixel's); kscale = strength / samples (float32, host). */
__kernel void ssao(__global const float4 *pos, __global const float4 *nrm,
                   __global const float2 *taps, __global float *out, const int width,
                   const int height, const int samples, const float r2, const float inv_r2,
                   const float bias, const float kscale)
{
    int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height) return;
    size_t i = (size_t)py * width + px;
    float4 p = pos[i];
    if (!(p.w > 0.0f)) { out[i] = 1.0f; return; }
    float4 n = nrm[i];
    float fx = (float)px + 0.25f, fy = (float)py + 0.25f;
    float occ = 0.0f;
    for (int k = 0; k < samples; ++k) {
        float2 o = taps[k];
        /* floor as truncation corrected below zero: exact, and no libm call in PoCL */
        float ux = fx + p.w * o.x, uy = fy + p.w * o.y;
        int qx = (int)ux, qy = (int)uy;
        qx -= ux < (float)qx;
        qy -= uy < (float)qy;
        if (qx < 0 || qx >= width || qy < 0 || qy >= height || (qx == px && qy == py))
            continue;
        float4 q = pos[(size_t)qy * width + qx];
        if (!(q.w > 0.0f)) continue;
        float vx = q.x - p.x, vy = q.y - p.y, vz = q.z - p.z;
        float vv = (vx * vx + vy * vy) + vz * vz;
        if (!(vv < r2)) continue;
        float vn = ((vx * n.x + vy * n.y) + vz * n.z) / sqrt(vv);
        float term = (1.0f - vv * inv_r2) * fmax(vn - bias, 0.0f);
        occ = occ + term;
    }
    float ao = 1.0f - kscale * occ;
    out[i] = clamp(ao, 0.0f, 1.0f);
}

/* ssao_upsample: full resolution, from the low-res factor and the low-res linear depths
 * (nrm.w); `ssao_upsample` in clraster/output/post.py says the rule. tol =
 * SSAO_UPSAMPLE_DEPTH. */
__kernel void ssao_upsample(__global const float *depth, __global const float4 *nrm,
                            __global const float *ao_low, __global float *out,
                            const float4 ivp, const int width, const int height,
                            const float sx, const float sy, const int reversed_z,
                            const float tol)
{
    int x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height) return;
    int w2 = (width + 1) >> 1, h2 = (height + 1) >> 1;
    size_t i = (size_t)y * width + x;
    float d = depth[i];
    if (reversed_z ? !(d > 0.0f) : !(d < 1.0f)) { out[i] = 1.0f; return; }
    float z = lin_depth(d, ivp, x, y, sx, sy, reversed_z);
    int x0 = x >> 1, y0 = y >> 1;
    float tx = (float)(x & 1) * 0.5f, ty = (float)(y & 1) * 0.5f;
    float zt = z * tol;
    float num = 0.0f, den = 0.0f, best = INFINITY, best_ao = 1.0f;
    for (int a = 0; a < 2; ++a) {
        for (int b = 0; b < 2; ++b) {
            size_t q = (size_t)min(y0 + a, h2 - 1) * w2 + min(x0 + b, w2 - 1);
            float zq = nrm[q].w;
            float aq = ao_low[q];
            float wy = a ? ty : 1.0f - ty, wx = b ? tx : 1.0f - tx;
            float wgt = wy * wx;
            float dz = fabs(zq - z);
            if (dz <= zt) { num = num + wgt * aq; den = den + wgt; }
            if (dz < best) { best = dz; best_ao = aq; }
        }
    }
    out[i] = den > 0.0f ? num / den : best_ao;
}

/* -- FXAA 3.11, quality preset 12 -----------------------------------------------------------
 * rgb: float (H, W, 3); lum: float (H, W) luma (0.299 R + 0.587 G + 0.114 B). Reads clamp to
 * the edge; bilinear reads as the twin's `_bilinear`. */
__kernel void luma(__global const float *rgb, __global float *lum, const int n)
{
    int i = get_global_id(0);
    if (i >= n) return;
    lum[i] = (rgb[3 * i] * 0.299f + rgb[3 * i + 1] * 0.587f) + rgb[3 * i + 2] * 0.114f;
}

__constant float FXAA_P[5] = {1.0f, 1.5f, 2.0f, 4.0f, 12.0f};

static float lum_at(__global const float *lum, int x, int y, int w, int h)
{
    x = clamp(x, 0, w - 1);
    y = clamp(y, 0, h - 1);
    return lum[(size_t)y * w + x];
}

static float lum_bilinear(__global const float *lum, float x, float y, int w, int h)
{
    float fx = x - 0.5f, fy = y - 0.5f;
    float x0 = floor(fx), y0 = floor(fy);
    float tx = fx - x0, ty = fy - y0;
    int c0 = (int)x0, r0 = (int)y0;
    float a = lum_at(lum, c0, r0, w, h), b = lum_at(lum, c0 + 1, r0, w, h);
    float c = lum_at(lum, c0, r0 + 1, w, h), d = lum_at(lum, c0 + 1, r0 + 1, w, h);
    float top = a + (b - a) * tx;
    float bot = c + (d - c) * tx;
    return top + (bot - top) * ty;
}

/* One pixel of FXAA (the twin's order of operations). */
static void fxaa_pixel(__global const float *rgb, __global const float *lum,
                       __global float *out, const int x, const int y, const int w, const int h)
{
    size_t i = (size_t)y * w + x;
    float lM = lum[i];
    float lN = lum_at(lum, x, y - 1, w, h), lS = lum_at(lum, x, y + 1, w, h);
    float lW = lum_at(lum, x - 1, y, w, h), lE = lum_at(lum, x + 1, y, w, h);
    float rmax = fmax(fmax(lN, lW), fmax(lE, fmax(lS, lM)));
    float rmin = fmin(fmin(lN, lW), fmin(lE, fmin(lS, lM)));
    float range = rmax - rmin;
    if (range < fmax(0.0833f, rmax * 0.166f)) {
        out[3 * i] = rgb[3 * i];
        out[3 * i + 1] = rgb[3 * i + 1];
        out[3 * i + 2] = rgb[3 * i + 2];
        return;
    }
    float lNW = lum_at(lum, x - 1, y - 1, w, h), lSE = lum_at(lum, x + 1, y + 1, w, h);
    float lNE = lum_at(lum, x + 1, y - 1, w, h), lSW = lum_at(lum, x - 1, y + 1, w, h);
    float rcp_range = 1.0f / range;
    float ns = lN + lS, we = lW + lE;
    float subpix_nswe = ns + we;
    float eh1 = -2.0f * lM + ns, ev1 = -2.0f * lM + we;
    float nese = lNE + lSE, nwne = lNW + lNE;
    float eh2 = -2.0f * lE + nese, ev2 = -2.0f * lN + nwne;
    float nwsw = lNW + lSW, swse = lSW + lSE;
    float eh4 = fabs(eh1) * 2.0f + fabs(eh2), ev4 = fabs(ev1) * 2.0f + fabs(ev2);
    float eh3 = -2.0f * lW + nwsw, ev3 = -2.0f * lS + swse;
    float eh = fabs(eh3) + eh4, ev = fabs(ev3) + ev4;
    float subpix_nwswnese = nwsw + nese;
    bool horz = eh >= ev;
    float subpix_a = subpix_nswe * 2.0f + subpix_nwswnese;
    if (!horz) { lN = lW; lS = lE; }
    float subpix_b = subpix_a * (1.0f / 12.0f) - lM;
    float gn = lN - lM, gs = lS - lM;
    float lNN = lN + lM, lSS = lS + lM;
    bool pair_n = fabs(gn) >= fabs(gs);
    float gradient = fmax(fabs(gn), fabs(gs));
    float sign = pair_n ? -1.0f : 1.0f;
    float subpix_c = clamp(fabs(subpix_b) * rcp_range, 0.0f, 1.0f);
    float pmx = (float)x + 0.5f, pmy = (float)y + 0.5f;
    float pbx = horz ? pmx : pmx + sign * 0.5f;
    float pby = horz ? pmy + sign * 0.5f : pmy;
    float offx = horz ? 1.0f : 0.0f, offy = horz ? 0.0f : 1.0f;
    float pnx = pbx - offx * FXAA_P[0], pny = pby - offy * FXAA_P[0];
    float ppx = pbx + offx * FXAA_P[0], ppy = pby + offy * FXAA_P[0];
    float subpix_d = -2.0f * subpix_c + 3.0f;
    float end_n = lum_bilinear(lum, pnx, pny, w, h);
    float subpix_e = subpix_c * subpix_c;
    float end_p = lum_bilinear(lum, ppx, ppy, w, h);
    if (!pair_n) lNN = lSS;
    float grad_scaled = gradient * (1.0f / 4.0f);
    float lMM = lM - lNN * 0.5f;
    float subpix_f = subpix_d * subpix_e;
    bool mlt_zero = lMM < 0.0f;
    end_n = end_n - lNN * 0.5f;
    end_p = end_p - lNN * 0.5f;
    bool done_n = fabs(end_n) >= grad_scaled, done_p = fabs(end_p) >= grad_scaled;
    for (int k = 1; k < 5; ++k) {
        float st = FXAA_P[k];
        if (!done_n) { pnx = pnx - offx * st; pny = pny - offy * st; }
        if (!done_p) { ppx = ppx + offx * st; ppy = ppy + offy * st; }
        if (k == 4 || (done_n && done_p)) break;
        if (!done_n) end_n = lum_bilinear(lum, pnx, pny, w, h) - lNN * 0.5f;
        if (!done_p) end_p = lum_bilinear(lum, ppx, ppy, w, h) - lNN * 0.5f;
        done_n = fabs(end_n) >= grad_scaled;
        done_p = fabs(end_p) >= grad_scaled;
    }
    float dst_n = horz ? pmx - pnx : pmy - pny;
    float dst_p = horz ? ppx - pmx : ppy - pmy;
    bool good_n = (end_n < 0.0f) != mlt_zero, good_p = (end_p < 0.0f) != mlt_zero;
    float span_rcp = 1.0f / (dst_p + dst_n);
    bool dir_n = dst_n < dst_p;
    float dst = fmin(dst_n, dst_p);
    bool good = dir_n ? good_n : good_p;
    float subpix_g = subpix_f * subpix_f;
    float pixel_offset = dst * (-span_rcp) + 0.5f;
    float subpix_h = subpix_g * 0.75f;
    float offset = fmax(good ? pixel_offset : 0.0f, subpix_h);
    float fx = horz ? pmx : pmx + offset * sign;
    float fy = horz ? pmy + offset * sign : pmy;
    /* bilinear colour read at (fx, fy) */
    float bx = fx - 0.5f, by = fy - 0.5f;
    float x0 = floor(bx), y0 = floor(by);
    float tx = bx - x0, ty = by - y0;
    int c0 = clamp((int)x0, 0, w - 1), c1 = clamp((int)x0 + 1, 0, w - 1);
    int r0 = clamp((int)y0, 0, h - 1), r1 = clamp((int)y0 + 1, 0, h - 1);
    for (int ch = 0; ch < 3; ++ch) {
        float a = rgb[3 * ((size_t)r0 * w + c0) + ch], b = rgb[3 * ((size_t)r0 * w + c1) + ch];
        float c = rgb[3 * ((size_t)r1 * w + c0) + ch], d = rgb[3 * ((size_t)r1 * w + c1) + ch];
        float top = a + (b - a) * tx;
        float bot = c + (d - c) * tx;
        out[3 * i + ch] = top + (bot - top) * ty;
    }
}

/* fxaa: one work-item per 8 pixels of a row. Most pixels are no edge: the span's local
 * contrast test runs in float8 lanes (rows y−1, y, y+1 loaded as vectors) and a span with
 * no edge pixel copies its 24 floats; spans with edges, and spans at the left/right border
 * (whose neighbours clamp), run fxaa_pixel per pixel, which repeats the test. */
__kernel void fxaa(__global const float *rgb, __global const float *lum,
                   __global float *out, const int w, const int h)
{
    int x0 = get_global_id(0) * 8, y = get_global_id(1);
    if (x0 >= w || y >= h) return;
    if (x0 >= 1 && x0 + 9 <= w) {
        size_t r = (size_t)y * w;
        size_t rn = (size_t)max(y - 1, 0) * w, rs = (size_t)min(y + 1, h - 1) * w;
        float8 lM = vload8(0, lum + r + x0);
        float8 lN = vload8(0, lum + rn + x0), lS = vload8(0, lum + rs + x0);
        float8 lW = vload8(0, lum + r + x0 - 1), lE = vload8(0, lum + r + x0 + 1);
        float8 rmax = fmax(fmax(lN, lW), fmax(lE, fmax(lS, lM)));
        float8 rmin = fmin(fmin(lN, lW), fmin(lE, fmin(lS, lM)));
        int8 skip = (rmax - rmin) < fmax((float8)(0.0833f), rmax * 0.166f);
        size_t o = 3 * (r + x0);
        if (all(skip)) {
            vstore8(vload8(0, rgb + o), 0, out + o);
            vstore8(vload8(1, rgb + o), 1, out + o);
            vstore8(vload8(2, rgb + o), 2, out + o);
            return;
        }
    }
    int x1 = min(x0 + 8, w);
    for (int x = x0; x < x1; ++x) fxaa_pixel(rgb, lum, out, x, y, w, h);
}
