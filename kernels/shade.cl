/* clraster — device shading: the RGB(A)8 image of a finished frame from its triangle ids
 * and barycentrics and the scene's tables already on the device (the device side of
 * clraster.output.shade.shade and render_shaded's ssaa; the tables are the resolve stage's,
 * clraster/pipeline/resolving.py; host side clraster/pipeline/stages/resolve.py). Its twin
 * is the NumPy path of clraster/output/shade.py, equal within 1/255 per channel.
 */
#include "common.h"

/* v scaled to unit length (times the reciprocal of its length: one division, not three);
 * zero when its length is zero or not finite (a degenerate face) */
/* ---- Shading (the device side of clraster.output.shade.shade and render_shaded's ssaa;
 * its NumPy path is the twin, equal within 1/255 per channel). Float arithmetic: 1/255 is
 * ~1.6e5 float32 ulps of a colour in [0, 1], so the order of the sums does not matter here;
 * texture coordinates are doubles (u · width loses too many bits in float for large UVs).
 *
 * Per covered pixel: instance i (bucket table, then a short forward scan), face row
 * id + inst_row[i]; normal n = the float32 face normal, or (SH_SMOOTH) the barycentric blend
 * of the pool vertex normals (the lanes below: of their int16 copies in face_vn; the face
 * normal where it is shorter than 1e-6); unless
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

/* face_vn: per face row, its three vertex normals (the pool's, in the face's vertex order)
 * as int16 snorm, round(32767 · n), x y z of a, b, c, then 7 zeros: 32 bytes, one cache line
 * a pixel on a large mesh instead of its face row and three vertex normals, none of them
 * waiting on another (clraster.pipeline.resolving.ResolveTables.face_vertex_normals). The
 * direction error, ~3e-5, is far below 1/255. FACE_VN_WEAK: (1e-6 · 32767)², the 1e-6 of
 * vertex normals that cancel, in those units. */
#define FACE_VN_ROW 16
#define FACE_VN_WEAK 1.0736e-3f

/* the scene's and the call's tables, the same for every kernel below */
#define SHADE_ARGS                                                                            \
    __global const int *inst_bucket, int bshift, __global const int *inst_base, int n_inst,   \
    __global const int *inst_row, __global const int *face_rows,                              \
    __global const float *vnormals,                                                           \
    __global const short *face_vn,                                                            \
    __global const float4 *inst_nrm, __global const float4 *inst_col,                         \
    __global const int *inst_src, __global const float4 *colours,                             \
    __global const float2 *uvs, __global const float4 *texels, float4 light, int flags
#define SHADE_PASS inst_bucket, bshift, inst_base, n_inst, inst_row, face_rows,              \
    vnormals, face_vn, inst_nrm, inst_col, inst_src, colours, uvs, texels, light, flags

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
ALWAYS_INLINE float3 shade_one(int id, int p, __global const float *bary, int *inst, int *lo,
                               int *hi, SHADE_ARGS)
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
    float3 n = (float3)(FACE_N(face_rows, row, 0), FACE_N(face_rows, row, 1),
                        FACE_N(face_rows, row, 2));
    float b0 = 0.0f, b1 = 0.0f, b2 = 0.0f;
    int va = 0, vb = 0, vc = 0;
    if (flags & (SH_SMOOTH | SH_SOURCES)) {
        b0 = bary[3 * p];
        b1 = bary[3 * p + 1];
        b2 = bary[3 * p + 2];
        va = FACE_V(face_rows, row, 0);
        vb = FACE_V(face_rows, row, 1);
        vc = FACE_V(face_rows, row, 2);
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
            /* what the lanes read (smooth: the face's row of vertex normals; no face
             * normal), or the per-pixel path (colour sources: the face's vertices) */
            if (!(flags & SH_SMOOTH) || (flags & SH_SOURCES))
                PREFETCH(face_rows + (long)FACE_ROW_WORDS * row);   /* normal, vertices */
            else
                PREFETCH(face_vn + FACE_VN_ROW * row);
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
            __global const int *fv = face_rows + (long)FACE_ROW_WORDS * (id + off);
            PREFETCH(vnormals + 3 * fv[0]);
            PREFETCH(vnormals + 3 * fv[1]);
            PREFETCH(vnormals + 3 * fv[2]);
        }
    }
}

/* ---- 8 covered pixels at a time, in float8 lanes (the common modes: no colour sources).
 * PoCL does not vectorize the per-pixel code across work-items, so a work-item shades 8
 * consecutive pixels with explicit vectors: their ids in one load, the table rows gathered
 * lane by lane, then normal, Lambert and quantization once for the 8. The same operations
 * as shade_one up to float rounding (lam = (n · l) / |n| instead of n scaled to unit length
 * first; |s| ≥ 1e-6 tested as s · s ≥ 1e-12), so within the twin's 1/255. */


inline int hmax8(int8 v)
{
    return imax(imax(imax(v.s0, v.s1), imax(v.s2, v.s3)), imax(imax(v.s4, v.s5),
                                                             imax(v.s6, v.s7)));
}

/* v · 255 rounded half to even and clamped to 0..255, as to_u8, per lane: adding and
 * taking away 2^23 rounds a float in [0, 2^23) to an integer in the current (nearest-even)
 * rounding mode, with no builtin; NaN gives 0 */
inline int8 to_u8_lanes(float8 v)
{
    float8 t = v * 255.0f;
    t = t > 0.0f ? t : (float8)(0.0f);
    t = t < 255.0f ? t : (float8)(255.0f);
    t = (t + 8388608.0f) - 8388608.0f;
    return CONVERT_VEC(t, int8);
}

/* the instance of a covered id (the bucket table, then a short forward scan), kept in
 * *inst with its id range [*lo, *hi) */
ALWAYS_INLINE void find_instance(int id, int *inst, int *lo, int *hi,
                                 __global const int *inst_bucket, int bshift,
                                 __global const int *inst_base, int n_inst)
{
    if (id >= *lo && id < *hi)
        return;
    int i = inst_bucket[id >> bshift];
    while (i + 1 < n_inst && inst_base[i + 1] <= id)
        ++i;
    *inst = i;
    *lo = inst_base[i];
    *hi = i + 1 < n_inst ? inst_base[i + 1] : INT_MAX;
}

/* Pixels [p, p + 8) (p a multiple of 8) written as packed colours: RGB8 (channels 3: six
 * 32-bit words, byte order as the image's on a little-endian device) or RGBA8 (one uint8
 * store). c: R | G << 8 | B << 16 per lane. */
ALWAYS_INLINE void store_lanes(__global uchar *out, int p, int channels, uint8 c)
{
#ifdef __ENDIAN_LITTLE__
    if (channels == 4) {
        *(__global uint8 *)(out + 4 * p) = c;   /* 32-byte aligned: see shade_pixels */
        return;
    }
    __global uint2 *o = (__global uint2 *)(out + 3 * p);   /* 8-byte aligned */
    o[0] = (uint2)(c.s0 | c.s1 << 24, c.s1 >> 8 | c.s2 << 16);
    o[1] = (uint2)(c.s2 >> 16 | c.s3 << 8, c.s4 | c.s5 << 24);
    o[2] = (uint2)(c.s5 >> 8 | c.s6 << 16, c.s6 >> 16 | c.s7 << 8);
#else
    uint w[8];
    vstore8(c, 0, w);
    for (int j = 0; j < 8; ++j) {
        __global uchar *o = out + channels * (p + j);
        o[0] = (uchar)w[j]; o[1] = (uchar)(w[j] >> 8); o[2] = (uchar)(w[j] >> 16);
        if (channels == 4) o[3] = (uchar)(w[j] >> 24);
    }
#endif
}

/* Shade pixels [p, p + 8) (p a multiple of 8, no colour sources) in float8 lanes; false,
 * with nothing written, when an id of theirs is out of range (the per-pixel path then
 * flags it). *inst, *lo, *hi as shade_one's. */
ALWAYS_INLINE bool shade_lanes(__global const int *ids, __global const float *bary, int p,
                               int max_id, uint bg, int channels, __global uchar *out,
                               int *inst, int *lo, int *hi, SHADE_ARGS)
{
    int8 v = LOAD_I8(ids + p);
    if (any8((v < -1) | (v > (int8)(max_id))))
        return false;
    int8 cov = v >= 0;
    uint8 bgw = (uint8)(channels == 4 ? bg & 0xffffffu : bg);
    if (!any8(cov)) {
        store_lanes(out, p, channels, bgw);
        return true;
    }
    /* background lanes borrow a covered lane's id: every gather stays inside the tables */
    v = cov ? v : (int8)(hmax8(v));
    int8 iv;
    int uni = !any8(~((v >= (int8)(*lo)) & (v < (int8)(*hi))));
    if (uni) {
        iv = (int8)(*inst);
    } else {
#define FIND(k)                                                                              \
        find_instance(v.s##k, inst, lo, hi, inst_bucket, bshift, inst_base, n_inst);        \
        iv.s##k = *inst;
        FIND(0) FIND(1) FIND(2) FIND(3) FIND(4) FIND(5) FIND(6) FIND(7)
#undef FIND
        uni = !any8(iv != (int8)(iv.s0));
    }
    /* per lane: face row, albedo, normal matrix (broadcast when the 8 share an instance) */
    int8 row;
    float8 cr, cg, cb, m00, m01, m02, m10, m11, m12, m20, m21, m22;
    int ident = flags & SH_IDENTITY;
    if (uni) {
        int i = iv.s0;
        row = v + (int8)(inst_row[i]);
        float4 c = inst_col[i];
        cr = (float8)(c.x); cg = (float8)(c.y); cb = (float8)(c.z);
        if (!ident) {
            float4 r0 = inst_nrm[3 * i], r1 = inst_nrm[3 * i + 1], r2 = inst_nrm[3 * i + 2];
            m00 = (float8)(r0.x); m01 = (float8)(r0.y); m02 = (float8)(r0.z);
            m10 = (float8)(r1.x); m11 = (float8)(r1.y); m12 = (float8)(r1.z);
            m20 = (float8)(r2.x); m21 = (float8)(r2.y); m22 = (float8)(r2.z);
        }
    } else {
#define GATHER_INST(k)                                                                       \
        {                                                                                    \
            int i = iv.s##k;                                                                 \
            row.s##k = v.s##k + inst_row[i];                                                 \
            float4 c = inst_col[i];                                                          \
            cr.s##k = c.x; cg.s##k = c.y; cb.s##k = c.z;                                     \
            if (!ident) {                                                                    \
                float4 r0 = inst_nrm[3 * i], r1 = inst_nrm[3 * i + 1];                       \
                float4 r2 = inst_nrm[3 * i + 2];                                             \
                m00.s##k = r0.x; m01.s##k = r0.y; m02.s##k = r0.z;                           \
                m10.s##k = r1.x; m11.s##k = r1.y; m12.s##k = r1.z;                           \
                m20.s##k = r2.x; m21.s##k = r2.y; m22.s##k = r2.z;                           \
            }                                                                                \
        }
        GATHER_INST(0) GATHER_INST(1) GATHER_INST(2) GATHER_INST(3)
        GATHER_INST(4) GATHER_INST(5) GATHER_INST(6) GATHER_INST(7)
#undef GATHER_INST
    }
    float8 nx, ny, nz;
#define GATHER_FN(k)                                                                         \
    { nx.s##k = FACE_N(face_rows, row.s##k, 0); ny.s##k = FACE_N(face_rows, row.s##k, 1);    \
      nz.s##k = FACE_N(face_rows, row.s##k, 2); }
#define GATHER_FNS                                                                           \
    GATHER_FN(0) GATHER_FN(1) GATHER_FN(2) GATHER_FN(3)                                      \
    GATHER_FN(4) GATHER_FN(5) GATHER_FN(6) GATHER_FN(7)
    if (!(flags & SH_SMOOTH)) {
        GATHER_FNS
    } else {
        /* the 8 pixels' barycentrics are 24 consecutive floats: three loads, deinterleaved;
         * the vertex normals from the face's row of face_vn (FACE_VN_*), which the scale
         * of leaves the normalized direction as it is */
        float8 x0 = LOAD_F8(bary + 3 * p), x1 = LOAD_F8(bary + 3 * p + 8);
        float8 x2 = LOAD_F8(bary + 3 * p + 16);
        float8 w0 = (float8)(x0.s036, x1.s147, x2.s25);
        float8 w1 = (float8)(x0.s147, x1.s25, x2.s036);
        float8 w2 = (float8)(x0.s25, x1.s036, x2.s147);
        float8 sx, sy, sz;
#define GATHER_VN(k)                                                                         \
        {                                                                                    \
            __global const short *q = face_vn + FACE_VN_ROW * row.s##k;                      \
            short8 h = *(__global const short8 *)q;   /* 16-byte aligned */                  \
            float u0 = w0.s##k, u1 = w1.s##k, u2 = w2.s##k;                                  \
            sx.s##k = (u0 * (float)h.s0 + u1 * (float)h.s3) + u2 * (float)h.s6;               \
            sy.s##k = (u0 * (float)h.s1 + u1 * (float)h.s4) + u2 * (float)h.s7;               \
            sz.s##k = (u0 * (float)h.s2 + u1 * (float)h.s5) + u2 * (float)q[8];               \
        }
        GATHER_VN(0) GATHER_VN(1) GATHER_VN(2) GATHER_VN(3)
        GATHER_VN(4) GATHER_VN(5) GATHER_VN(6) GATHER_VN(7)
#undef GATHER_VN
        /* vertex normals that cancel give no direction: the face's own there (read only
         * then: a face normal is one more cache miss a pixel on a large mesh) */
        int8 strong = (sx * sx + sy * sy) + sz * sz >= FACE_VN_WEAK;
        if (any8(~strong)) {
            GATHER_FNS
            nx = strong ? sx : nx;
            ny = strong ? sy : ny;
            nz = strong ? sz : nz;
        } else {
            nx = sx; ny = sy; nz = sz;
        }
    }
#undef GATHER_FNS
#undef GATHER_FN
    if (!ident) {
        float8 tx = (m00 * nx + m01 * ny) + m02 * nz;
        float8 ty = (m10 * nx + m11 * ny) + m12 * nz;
        float8 tz = (m20 * nx + m21 * ny) + m22 * nz;
        nx = tx; ny = ty; nz = tz;
    }
    float8 lam = (nx * light.x + ny * light.y) + nz * light.z;
    if ((flags & SH_SMOOTH) || !ident) {
        float8 ss = (nx * nx + ny * ny) + nz * nz;
        float8 len = (float8)(SQRTF(ss.s0), SQRTF(ss.s1), SQRTF(ss.s2), SQRTF(ss.s3),
                              SQRTF(ss.s4), SQRTF(ss.s5), SQRTF(ss.s6), SQRTF(ss.s7));
        int8 ok = (len > 0.0f) & (len <= FLT_MAX);
        lam = ok ? lam / len : (float8)(0.0f);
    }
    lam = (flags & SH_TWO_SIDED) ? as_float8(as_int8(lam) & 0x7fffffff)
                                 : (lam > 0.0f ? lam : (float8)(0.0f));
    float8 k = light.w + (1.0f - light.w) * lam;
    int8 rgb = to_u8_lanes(cr * k) | to_u8_lanes(cg * k) << 8 | to_u8_lanes(cb * k) << 16;
    uint8 opaque = as_uint8(rgb) | (uint8)(channels == 4 ? 0xff000000u : 0u);
    store_lanes(out, p, channels, cov ? opaque : bgw);
    return true;
}

/* How far ahead of the 16-pixel chunk being shaded its successors' table rows are asked
 * for (pixels): far enough for a cache miss to be served before the row is read (the
 * vertex normals' prefetch reads the face rows), near enough that they are still in the
 * cache. Speed only (bench/README.md's log). */
#define ROWS_AHEAD 32
#define VERTS_AHEAD 16

/* One work-item per `span` pixels (row-major). Runs of 16 background pixels (the common
 * case away from the surface) are one vector compare and 48 (RGB) or 64 (RGBA) bytes of
 * vector stores; the rest 8 pixels at a time in lanes (shade_lanes), or pixel by pixel
 * with colour sources, at the span's ragged end and around a bad id. An id below −1 or
 * above max_id sets *bad (the
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
    int pref = p0, prefv = p0;   /* the rows (vertex normals) of pixels below them were asked for */
    /* whole groups of 8 in lanes (shade_lanes) unless colour sources need the per-pixel path */
    bool lanes = !(flags & SH_SOURCES);
    for (int p = p0; p < p1;) {
        if (p + 16 <= p1) {
            if (background16(ids + p)) {
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
        /* face rows asked for ROWS_AHEAD pixels ahead, the vertex normals VERTS_AHEAD
         * (finding them reads the face rows, asked for a chunk earlier) */
        int want = imin(e + ROWS_AHEAD, p1);
        if (pref < want) {
            prefetch_rows(ids, imax(pref, p), want, lo, hi, inst, SHADE_PASS);
            pref = want;
        }
        if ((flags & SH_SMOOTH) && (flags & SH_SOURCES)) {   /* (the lanes read face_vn) */
            want = imin(e + VERTS_AHEAD, p1);
            if (prefv < want) {
                prefetch_verts(ids, imax(prefv, p), want, lo, hi, inst, SHADE_PASS);
                prefv = want;
            }
        }
        for (; p < e; p = imin(p + 8, e)) {
            int g = imin(p + 8, e);
            if (lanes && g == p + 8
                && shade_lanes(ids, bary, p, max_id, bg, channels, out, &inst, &lo, &hi,
                               SHADE_PASS))
                continue;
            for (int q = p; q < g; ++q) {
                int id = ids[q];
                __global uchar *o = out + channels * q;
                if (id < 0 || id > max_id) {
                    if (id != -1) atomic_or(bad, 1);
                    o[0] = bgc[0]; o[1] = bgc[1]; o[2] = bgc[2];
                    if (channels == 4) o[3] = 0;
                    continue;
                }
                float3 c = shade_one(id, q, bary, &inst, &lo, &hi, SHADE_PASS);
                o[0] = to_u8(c.x); o[1] = to_u8(c.y); o[2] = to_u8(c.z);
                if (channels == 4) o[3] = 255;
            }
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
