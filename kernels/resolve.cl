/* clraster — resolve: per-pixel outputs (and shaded images, below) from the finished frame's
 * triangle ids and barycentrics and the scene's geometry already on the device
 * (clraster/pipeline/resolving.py describes the inputs and the arithmetic;
 * clraster/pipeline/reference/resolve.py is the twin, the same float64 operations in the same
 * order).
 *
 * One work-item per span of `span` consecutive pixels (row-major), looping: neighbouring
 * pixels mostly share an instance, so the instance found last is tried first before the
 * binary search over the instances' first ids. Only the outputs whose RS_* bit is in `want`
 * are written (the others' arguments are some other buffer, untouched).
 *
 * Values are float64 from the float32 pool positions and barycentrics, FP_CONTRACT off
 * (common.h), and every sum is written in the order the twin sums it, so both give the same
 * bits; sqrt and division are correctly rounded in OpenCL's double precision.
 */
#include "common.h"

/* RS_MASK, RS_LINEAR, RS_DISTANCE, RS_POINTS, RS_NORMALS, RS_SMOOTH, RS_CAM_NORMALS,
 * RS_CAM_SMOOTH: the `want` bits, -D options from clraster/pipeline/resolving.py
 * (OUTPUT_BITS). */
#define RS_NEED_POINT (RS_LINEAR | RS_DISTANCE | RS_POINTS)
#define RS_NEED_NORMAL (RS_NORMALS | RS_SMOOTH | RS_CAM_NORMALS | RS_CAM_SMOOTH)

/* v scaled to unit length (times the reciprocal of its length: one division, not three);
 * zero when its length is zero or not finite (a degenerate face) */
inline double3 unit3(double3 v)
{
    double len = sqrt((v.x * v.x + v.y * v.y) + v.z * v.z);
    if (!(len > 0.0 && len <= DBL_MAX))
        return (double3)(0.0, 0.0, 0.0);
    double r = 1.0 / len;
    return (double3)(v.x * r, v.y * r, v.z * r);
}

/* row-major 3 × 3 matrix m (9 doubles) times v */
inline double3 mat3(__global const double *m, double3 v)
{
    return (double3)((m[0] * v.x + m[1] * v.y) + m[2] * v.z,
                     (m[3] * v.x + m[4] * v.y) + m[5] * v.z,
                     (m[6] * v.x + m[7] * v.y) + m[8] * v.z);
}

inline double3 load3(__global const float *p, int k)
{
    return (double3)((double)p[3 * k], (double)p[3 * k + 1], (double)p[3 * k + 2]);
}

/* v rounded to float32 and back: the world normals the host keeps in float32 before the
 * camera rotation, rounded where the host rounds them */
inline double3 round32(double3 v)
{
    return (double3)((double)(float)v.x, (double)(float)v.y, (double)(float)v.z);
}

inline void store3f(__global float *p, int k, double3 v)
{
    p[3 * k] = (float)v.x;
    p[3 * k + 1] = (float)v.y;
    p[3 * k + 2] = (float)v.z;
}

/* (b0·a + b1·b) + b2·c per component: the barycentric blend, in the twin's order */
inline double3 blend3(double b0, double b1, double b2, double3 a, double3 b, double3 c)
{
    return (double3)((b0 * a.x + b1 * b.x) + b2 * c.x, (b0 * a.y + b1 * b.y) + b2 * c.y,
                     (b0 * a.z + b1 * b.z) + b2 * c.z);
}

__kernel void resolve_pixels(
    __global const int *ids,           /* (H·W) triangle ids, −1 background */
    __global const float *bary,        /* (H·W, 3) barycentrics (any buffer without them) */
    int npx, int span, int want,
    __global const int *inst_base,     /* (I,) first triangle id of each instance */
    int n_inst,
    __global const int *inst_mesh,     /* (I,) unique mesh of each instance */
    __global const int *mesh_fbase,    /* (U,) first face_verts row of each unique mesh */
    __global const int *face_verts,    /* (F, 3) pool vertex indices of each face */
    __global const float *face_nrm,    /* (F, 3) unit object-space face normals */
    __global const float *positions,   /* (V, 3) pool positions */
    __global const float *vnormals,    /* (V, 3) pool vertex normals (smooth outputs) */
    __global const double *inst_model, /* (I, 12) [M3 | t] row-major: object → world */
    __global const double *inst_nrm,   /* (I, 9) M⁻ᵀ row-major */
    __global const double *cam,        /* fwd (3), eye (3), V⁻ᵀ (9), orthographic */
    __global uchar *mask, __global float *lin, __global float *dist, __global double *pts,
    __global float *n_face, __global float *n_smooth, __global float *n_cam,
    __global float *n_cam_smooth)
{
    int p0 = get_global_id(0) * span;
    int p1 = imin(p0 + span, npx);
    int lo = 1, hi = 0, inst = 0;   /* the last instance's id range [lo, hi) */
    for (int p = p0; p < p1; ++p) {
        int id = ids[p];
        if (id < 0) {
            if (want & RS_MASK) mask[p] = 0;
            if (want & RS_LINEAR) lin[p] = INFINITY;
            if (want & RS_DISTANCE) dist[p] = INFINITY;
            if (want & RS_POINTS) { pts[3 * p] = 0.0; pts[3 * p + 1] = 0.0; pts[3 * p + 2] = 0.0; }
            double3 z = (double3)(0.0, 0.0, 0.0);
            if (want & RS_NORMALS) store3f(n_face, p, z);
            if (want & RS_SMOOTH) store3f(n_smooth, p, z);
            if (want & RS_CAM_NORMALS) store3f(n_cam, p, z);
            if (want & RS_CAM_SMOOTH) store3f(n_cam_smooth, p, z);
            continue;
        }
        if (want & RS_MASK) mask[p] = 1;
        if (!(id >= lo && id < hi)) {
            /* the last instance whose first id is <= id (empty instances share their
             * successor's first id: the last of equals is the one with faces) */
            int a = 0, b = n_inst;   /* inst_base[a] <= id < inst_base[b] (b = I: none) */
            while (b - a > 1) {
                int m = (a + b) >> 1;
                if (inst_base[m] <= id) a = m; else b = m;
            }
            inst = a;
            lo = inst_base[a];
            hi = b < n_inst ? inst_base[b] : INT_MAX;
        }
        int row = mesh_fbase[inst_mesh[inst]] + (id - lo);
        int ia = face_verts[3 * row], ib = face_verts[3 * row + 1], ic = face_verts[3 * row + 2];
        double b0 = 0.0, b1 = 0.0, b2 = 0.0;
        if (want & (RS_NEED_POINT | RS_SMOOTH | RS_CAM_SMOOTH)) {
            b0 = (double)bary[3 * p];
            b1 = (double)bary[3 * p + 1];
            b2 = (double)bary[3 * p + 2];
        }
        if (want & RS_NEED_POINT) {
            double3 q = blend3(b0, b1, b2, load3(positions, ia), load3(positions, ib),
                               load3(positions, ic));
            __global const double *m = inst_model + 12 * inst;
            double3 wp = (double3)(MAT_ROW(m, 0, q.x, q.y, q.z), MAT_ROW(m, 1, q.x, q.y, q.z),
                                   MAT_ROW(m, 2, q.x, q.y, q.z));
            double3 off = (double3)(wp.x - cam[3], wp.y - cam[4], wp.z - cam[5]);
            double along = (cam[0] * off.x + cam[1] * off.y) + cam[2] * off.z;
            if (want & RS_LINEAR) lin[p] = (float)along;
            if (want & RS_DISTANCE) {
                double d = cam[15] != 0.0 ? along
                                          : sqrt((off.x * off.x + off.y * off.y) + off.z * off.z);
                dist[p] = (float)d;
            }
            if (want & RS_POINTS) {
                pts[3 * p] = wp.x;
                pts[3 * p + 1] = wp.y;
                pts[3 * p + 2] = wp.z;
            }
        }
        if (want & RS_NEED_NORMAL) {
            double3 fn = load3(face_nrm, row);
            __global const double *nm = inst_nrm + 9 * inst;
            if (want & (RS_NORMALS | RS_CAM_NORMALS)) {
                double3 w = round32(unit3(mat3(nm, fn)));
                if (want & RS_NORMALS) store3f(n_face, p, w);
                if (want & RS_CAM_NORMALS) store3f(n_cam, p, unit3(mat3(cam + 6, w)));
            }
            if (want & (RS_SMOOTH | RS_CAM_SMOOTH)) {
                double3 s = blend3(b0, b1, b2, load3(vnormals, ia), load3(vnormals, ib),
                                   load3(vnormals, ic));
                /* vertex normals that cancel give no direction: the face's own there */
                if (!(sqrt((s.x * s.x + s.y * s.y) + s.z * s.z) >= 1e-6)) s = fn;
                double3 w = round32(unit3(mat3(nm, s)));
                if (want & RS_SMOOTH) store3f(n_smooth, p, w);
                if (want & RS_CAM_SMOOTH) store3f(n_cam_smooth, p, unit3(mat3(cam + 6, w)));
            }
        }
    }
}

/* ---- Shading (the device side of clraster.output.shade.shade and render_shaded's ssaa;
 * its NumPy path is the twin, equal within 1/255 per channel). Float arithmetic: 1/255 is
 * ~1.6e5 float32 ulps of a colour in [0, 1], so the order of the sums does not matter here;
 * texture coordinates are doubles (u · width loses too many bits in float for large UVs).
 *
 * Per covered pixel: instance i (bucket table, then a short forward scan), face row
 * id + inst_row[i]; normal n = the float32 face normal, or (SH_SMOOTH) the barycentric blend
 * of the pool vertex normals (the face normal where it is shorter than 1e-6); unless
 * SH_IDENTITY, n = normalize(M⁻ᵀ n) (inst_nrm float (I, 12), rows of 4); smooth normals
 * are normalized either way. lam = |n · l| (SH_TWO_SIDED) or max(n · l, 0); the albedo is
 * inst_col[i].xyz (tint · texture factor, or the default albedo) times the colour sources
 * of inst_src[i] (int (I, 8): bits, vertex colour offset, face colour offset, uv offset,
 * texel offset, texture width, height): face colour colours[face + off], the blend of
 * vertex colours colours[v + off] (v a pool vertex), the bilinear texel blend at the
 * blended uv (uvs[v + off]; clraster.output.textures.sample_bilinear: v up, texel centres,
 * repeat). Colour = albedo · (ambient + (1 − ambient) · lam). */
#define SH_SMOOTH 1
#define SH_TWO_SIDED 2
#define SH_IDENTITY 4
#define SH_SOURCES 8
#define SRC_VCOL 1
#define SRC_FCOL 2
#define SRC_TEX 4

/* the scene's and the call's tables, the same for every kernel below */
#define SHADE_ARGS                                                                            \
    __global const int *inst_bucket, int bshift, __global const int *inst_base, int n_inst,   \
    __global const int *inst_row, __global const int *face_verts,                             \
    __global const float *face_nrm, __global const float *vnormals,                           \
    __global const float4 *inst_nrm, __global const float4 *inst_col,                         \
    __global const int *inst_src, __global const float4 *colours,                             \
    __global const float2 *uvs, __global const float4 *texels, float4 light, int flags
#define SHADE_PASS inst_bucket, bshift, inst_base, n_inst, inst_row, face_verts, face_nrm,   \
    vnormals, inst_nrm, inst_col, inst_src, colours, uvs, texels, light, flags

inline float3 load3f(__global const float *p, int k)
{
    return (float3)(p[3 * k], p[3 * k + 1], p[3 * k + 2]);
}

/* v / |v|; zero where |v| is zero or not finite (a degenerate face), as unit3 */
inline float3 unit3f(float3 v)
{
    float len = sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    if (!(len > 0.0f && len <= FLT_MAX))
        return (float3)(0.0f, 0.0f, 0.0f);
    return v * (1.0f / len);
}

/* floor of a double whose magnitude is below 2^62 (PoCL's floor() is a library call) */
inline double floor_d(double x)
{
    double t = (double)(long)x;
    return t > x ? t - 1.0 : t;
}

/* a in [0, m) for a whole number a (numpy.mod of the float) */
inline int wrap_i(double a, int m)
{
    double r = a - floor_d(a / (double)m) * (double)m;
    int i = (int)r;
    return i < 0 ? 0 : (i >= m ? m - 1 : i);
}

/* bilinear sample of an (h, w) texture at (u, v) (textures.sample_bilinear) */
inline float3 sample_tex(__global const float4 *tex, int w, int h, float2 uv)
{
    double x = (double)uv.x * (double)w - 0.5;
    double y = (1.0 - (double)uv.y) * (double)h - 0.5;
    double x0 = floor_d(x), y0 = floor_d(y);
    float fx = (float)(x - x0), fy = (float)(y - y0);
    int c0 = wrap_i(x0, w), r0 = wrap_i(y0, h);
    int c1 = c0 + 1 == w ? 0 : c0 + 1, r1 = r0 + 1 == h ? 0 : r0 + 1;
    float3 top = tex[r0 * w + c0].xyz * (1.0f - fx) + tex[r0 * w + c1].xyz * fx;
    float3 bot = tex[r1 * w + c0].xyz * (1.0f - fx) + tex[r1 * w + c1].xyz * fx;
    return top * (1.0f - fy) + bot * fy;
}

/* The unquantized colour (0..1) of the covered pixel p with id `id`; *inst, *lo, *hi: the
 * last instance found and its id range [lo, hi), tried first. */
__attribute__((always_inline)) inline float3 shade_one(int id, int p, __global const float *bary, int *inst, int *lo, int *hi,
                        SHADE_ARGS)
{
    if (!(id >= *lo && id < *hi)) {
        int i = inst_bucket[id >> bshift];
        while (i + 1 < n_inst && inst_base[i + 1] <= id)
            ++i;
        *inst = i;
        *lo = inst_base[i];
        *hi = i + 1 < n_inst ? inst_base[i + 1] : INT_MAX;
    }
    int i = *inst;
    int row = id + inst_row[i];
    float3 n = load3f(face_nrm, row);
    float b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
    int va = 0, vb = 0, vc = 0;
    if (flags & (SH_SMOOTH | SH_SOURCES)) {
        b0 = bary[3 * p];
        b1 = bary[3 * p + 1];
        b2 = bary[3 * p + 2];
        va = face_verts[3 * row];
        vb = face_verts[3 * row + 1];
        vc = face_verts[3 * row + 2];
    }
    if (flags & SH_SMOOTH) {
        float3 s = b0 * load3f(vnormals, va) + b1 * load3f(vnormals, vb)
                   + b2 * load3f(vnormals, vc);
        if (sqrt(s.x * s.x + s.y * s.y + s.z * s.z) >= 1e-6f) n = s;
    }
    if (!(flags & SH_IDENTITY)) {
        __global const float4 *m = inst_nrm + 3 * i;
        float4 m0 = m[0], m1 = m[1], m2 = m[2];
        n = (float3)(m0.x * n.x + m0.y * n.y + m0.z * n.z, m1.x * n.x + m1.y * n.y + m1.z * n.z,
                     m2.x * n.x + m2.y * n.y + m2.z * n.z);
    }
    if ((flags & SH_SMOOTH) || !(flags & SH_IDENTITY)) n = unit3f(n);
    float lam = n.x * light.x + n.y * light.y + n.z * light.z;
    /* (not fabs/fmax: PoCL calls its library for them) */
    lam = (flags & SH_TWO_SIDED) ? (lam < 0.0f ? -lam : lam) : (lam > 0.0f ? lam : 0.0f);
    float3 base = inst_col[i].xyz;
    if (flags & SH_SOURCES) {
        __global const int *src = inst_src + 8 * i;
        int bits = src[0];
        if (bits & SRC_FCOL) base *= colours[id - *lo + src[2]].xyz;
        if (bits & SRC_VCOL) {
            int o = src[1];
            base *= b0 * colours[va + o].xyz + b1 * colours[vb + o].xyz
                    + b2 * colours[vc + o].xyz;
        }
        if (bits & SRC_TEX) {
            int o = src[3];
            float2 uv = b0 * uvs[va + o] + b1 * uvs[vb + o] + b2 * uvs[vc + o];
            base *= sample_tex(texels + src[4], src[5], src[6], uv);
        }
    }
    return base * (light.w + (1.0f - light.w) * lam);
}

inline uchar to_u8(float v)
{
    float r = RINTF(v * 255.0f);
    return (uchar)(r < 0.0f ? 0.0f : (r > 255.0f ? 255.0f : r));
}

/* Ask for the face rows (and, with the barycentrics, the vertex normals) of the covered
 * pixels in [a, b) whose id is in the last instance's range: a chunk's table rows are
 * random accesses into tables of megabytes (the dragon's 871K faces), each a cache miss;
 * asked for together, they are fetched in parallel instead of one per pixel. */
inline void prefetch_rows(__global const int *ids, int a, int b, int lo, int hi, int inst,
                          SHADE_ARGS)
{
    int off = inst_row[inst];
    for (int q = a; q < b; ++q) {
        int id = ids[q];
        if (id >= lo && id < hi) {
            int row = id + off;
            PREFETCH(face_nrm + 3 * row);
            if (flags & (SH_SMOOTH | SH_SOURCES)) PREFETCH(face_verts + 3 * row);
        }
    }
}

inline void prefetch_verts(__global const int *ids, int a, int b, int lo, int hi, int inst,
                           SHADE_ARGS)
{
    int off = inst_row[inst];
    for (int q = a; q < b; ++q) {
        int id = ids[q];
        if (id >= lo && id < hi) {
            __global const int *fv = face_verts + 3 * (id + off);
            PREFETCH(vnormals + 3 * fv[0]);
            PREFETCH(vnormals + 3 * fv[1]);
            PREFETCH(vnormals + 3 * fv[2]);
        }
    }
}

/* One work-item per `span` pixels (row-major). Runs of 16 background pixels (the common
 * case away from the surface) are one vector compare and 48 (RGB) or 64 (RGBA) bytes of
 * vector stores; the rest pixel by pixel. An id below −1 or above max_id sets *bad (the
 * host raises; those pixels' colour is undefined). bg: R | G << 8 | B << 16. */
__kernel void shade_pixels(__global const int *ids, __global const float *bary, int npx,
                           int span, int max_id, uint bg, int channels,
                           __global int *bad, __global uchar *out, SHADE_ARGS)
{
    int p0 = get_global_id(0) * span;
    int p1 = imin(p0 + span, npx);
    int lo = 1, hi = 0, inst = 0;
    uchar bgc[3] = {(uchar)bg, (uchar)(bg >> 8), (uchar)(bg >> 16)};
    uchar pat[48];
    for (int j = 0; j < 48; ++j)
        pat[j] = bgc[j % 3];
    uchar16 q0 = vload16(0, pat), q1 = vload16(1, pat), q2 = vload16(2, pat);
    int pref = p0;   /* the rows of pixels below it were asked for */
    for (int p = p0; p < p1;) {
        if (p + 16 <= p1) {
            /* -1 is all ones: both halves are all −1 iff their AND is (int8, not int16:
             * PoCL 3.0's cached binaries of programs passing 16-wide int vectors to its
             * library lost their kernels) */
            int8 v = vload8(0, ids + p) & vload8(1, ids + p);
            int4 v4 = v.lo & v.hi;
            int2 v2 = v4.lo & v4.hi;
            if ((v2.x & v2.y) == -1) {
                /* p is a multiple of 16 (p0 is, and so is every step) and out is 64-byte
                 * aligned (the host's page-aligned arrays): aligned vector stores */
                if (channels == 3) {
                    __global uchar16 *o = (__global uchar16 *)(out + 3 * p);
                    o[0] = q0;
                    o[1] = q1;
                    o[2] = q2;
                } else {
                    __global uint8 *o = (__global uint8 *)(out + 4 * p);
                    o[0] = (uint8)(bg & 0xffffffu);
                    o[1] = (uint8)(bg & 0xffffffu);
                }
                p += 16;
                continue;
            }
        }
        int e = imin(p + 16, p1);
        if (p >= pref) prefetch_rows(ids, p, e, lo, hi, inst, SHADE_PASS);
        pref = imin(e + 16, p1);
        prefetch_rows(ids, e, pref, lo, hi, inst, SHADE_PASS);
        if (flags & SH_SMOOTH) prefetch_verts(ids, p, e, lo, hi, inst, SHADE_PASS);
        for (; p < e; ++p) {
            int id = ids[p];
            __global uchar *o = out + channels * p;
            if (id < 0 || id > max_id) {
                if (id != -1) atomic_or(bad, 1);
                o[0] = bgc[0]; o[1] = bgc[1]; o[2] = bgc[2];
                if (channels == 4) o[3] = 0;
                continue;
            }
            float3 c = shade_one(id, p, bary, &inst, &lo, &hi, SHADE_PASS);
            o[0] = to_u8(c.x); o[1] = to_u8(c.y); o[2] = to_u8(c.z);
            if (channels == 4) o[3] = 255;
        }
    }
}

/* render_shaded's supersampling: output pixel (x, y) of an out_w-wide image is the box
 * filter of the k × k samples of the k× frame under it (row-major ids of k·out_w columns),
 * background samples bg/255; with alpha (channels 4) the colour is the mean over the
 * covered samples only (bg/255 where none) and alpha their fraction. */
__kernel void shade_ssaa(__global const int *ids, __global const float *bary, int n_out,
                         int span, int out_w, int k, int max_id, uint bg, int channels,
                         __global int *bad, __global uchar *out, SHADE_ARGS)
{
    int o0 = get_global_id(0) * span;
    int o1 = imin(o0 + span, n_out);
    int lo = 1, hi = 0, inst = 0;
    int fw = out_w * k;
    float3 bgf = (float3)((float)(bg & 255u), (float)((bg >> 8) & 255u),
                          (float)((bg >> 16) & 255u)) / 255.0f;
    for (int op = o0; op < o1; ++op) {
        int x = op % out_w, y = op / out_w;
        float3 sum = (float3)(0.0f, 0.0f, 0.0f);
        int cnt = 0;
        for (int sy = 0; sy < k; ++sy) {
            int q = (y * k + sy) * fw + x * k;
            for (int sx = 0; sx < k; ++sx, ++q) {
                int id = ids[q];
                if (id < 0 || id > max_id) {
                    if (id != -1) atomic_or(bad, 1);
                    if (channels == 3) sum += bgf;
                    continue;
                }
                sum += shade_one(id, q, bary, &inst, &lo, &hi, SHADE_PASS);
                ++cnt;
            }
        }
        __global uchar *o = out + channels * op;
        float3 c;
        if (channels == 3)
            c = sum / (float)(k * k);
        else {
            c = cnt > 0 ? sum / (float)cnt : bgf;
            o[3] = to_u8((float)cnt / (float)(k * k));
        }
        o[0] = to_u8(c.x); o[1] = to_u8(c.y); o[2] = to_u8(c.z);
    }
}

/* seen[i] = 1 for each instance i with a pixel in the frame (callable per-instance colours
 * are evaluated for those only); an id below −1 or above max_id sets *bad. */
__kernel void seen_instances(__global const int *ids, int npx, int span, int max_id,
                             __global int *bad, __global uchar *seen,
                             __global const int *inst_bucket, int bshift,
                             __global const int *inst_base, int n_inst)
{
    int p0 = get_global_id(0) * span;
    int p1 = imin(p0 + span, npx);
    int lo = 1, hi = 0;
    for (int p = p0; p < p1; ++p) {
        int id = ids[p];
        if (id < 0 || id > max_id) {
            if (id != -1) atomic_or(bad, 1);
            continue;
        }
        if (!(id >= lo && id < hi)) {
            int i = inst_bucket[id >> bshift];
            while (i + 1 < n_inst && inst_base[i + 1] <= id)
                ++i;
            lo = inst_base[i];
            hi = i + 1 < n_inst ? inst_base[i + 1] : INT_MAX;
            seen[i] = 1;
        }
    }
}
