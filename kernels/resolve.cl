/* clraster — resolve: per-pixel outputs (and shaded images, below) from the finished frame's
 * triangle ids and barycentrics and the scene's geometry already on the device
 * (clraster/pipeline/resolving.py describes the inputs and the arithmetic;
 * clraster/pipeline/reference/resolve.py is the twin, the same float64 operations in the same
 * order).
 *
 * One work-item per span of `span` consecutive pixels (row-major), looping: neighbouring
 * pixels mostly share an instance, so the instance found last is tried first before the
 * binary search over the instances' first ids; a group of 8 covered pixels all of that
 * instance is resolved in double8 lanes (resolve_lanes), the others pixel by pixel. Only the outputs whose RS_* bit is in `want`
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

/* 8 ints / floats at any int's alignment: Clang's ext_vector_type typedef of element
 * alignment (one vmovups), or OpenCL's vload8 (a call in PoCL) where the compiler lacks it
 * (common.h's probe: the same values). */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE
#define LOAD_I8(p) vload8(0, (p))
#define LOAD_F8(p) vload8(0, (p))
#else
typedef int int8u __attribute__((ext_vector_type(8), aligned(4)));
typedef float float8u __attribute__((ext_vector_type(8), aligned(4)));
#define LOAD_I8(p) (*(__global const int8u *)(p))
#define LOAD_F8(p) (*(__global const float8u *)(p))
#endif

/* any lane of a comparison mask set (OpenCL's any() is a call in PoCL) */
inline bool any8(int8 m)
{
    return (((m.s0 | m.s1) | (m.s2 | m.s3)) | ((m.s4 | m.s5) | (m.s6 | m.s7))) < 0;
}

/* v scaled to unit length (times the reciprocal of its length: one division, not three);
 * zero when its length is zero or not finite (a degenerate face) */
inline double3 unit3(double3 v)
{
    double len = SQRTD((v.x * v.x + v.y * v.y) + v.z * v.z);
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

/* The face row of triangle `id` of instance `inst` (first id lo): its row in face_verts
 * and face_nrm. */
#define FACE_ROW(id) (mesh_fbase[inst_mesh[inst]] + ((id) - lo))

/* Ask for the face rows of the covered pixels in [a, b) whose id is in the last instance's
 * range [lo, hi) (vert = 0), or for the vertices those rows name (vert = 1): random
 * accesses into tables of megabytes; asked for together, a chunk's are fetched in parallel
 * instead of one dependent miss after another. Asked for right before the chunk is
 * resolved: asking 8–32 pixels ahead, or the vertices a chunk before their use, was slower
 * (bench/README.md's log). */
inline void resolve_prefetch(__global const int *ids, int a, int b, int lo, int hi, int inst,
                             int want, int vert, __global const int *inst_mesh,
                             __global const int *mesh_fbase, __global const int *face_verts,
                             __global const float *face_nrm,
                             __global const float *positions, __global const float *vnormals)
{
    for (int q = a; q < b; ++q) {
        int id = ids[q];
        if (!(id >= lo && id < hi)) continue;
        int row = FACE_ROW(id);
        if (!vert) {
            PREFETCH(face_verts + 3 * row);
            if (want & RS_NEED_NORMAL) PREFETCH(face_nrm + 3 * row);
            continue;
        }
        __global const int *fv = face_verts + 3 * row;
        if (want & RS_NEED_POINT) {
            PREFETCH(positions + 3 * fv[0]);
            PREFETCH(positions + 3 * fv[1]);
            PREFETCH(positions + 3 * fv[2]);
        }
        if (want & (RS_SMOOTH | RS_CAM_SMOOTH)) {
            PREFETCH(vnormals + 3 * fv[0]);
            PREFETCH(vnormals + 3 * fv[1]);
            PREFETCH(vnormals + 3 * fv[2]);
        }
    }
}

/* 16 pixels' background values from pixel p (a multiple of 16; the host's arrays are
 * page-aligned): vector stores where the compiler has element-aligned vector types, else
 * pixel by pixel (the same values). */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE
#define FILL_BG(T, ptr, n, v) for (int k_ = 0; k_ < (n); ++k_) (ptr)[k_] = (v)
#else
#define FILL_BG(T, ptr, n, v)                                                              \
    for (int k_ = 0; k_ < (n); k_ += 8) *(__global T##8 *)((ptr) + k_) = (T##8)(v)
#endif

/* ---- resolve_pixels' lanes: 8 consecutive covered pixels of one instance in double8
 * values, the scalar body's double operations in its order lane by lane (FP_CONTRACT is
 * off), so each lane's bits are the scalar path's. Lane masks are long8 of -1/0 from
 * double8 comparisons, applied with & and ~ on the bits: no select() or ?: on them (PoCL
 * 3.0 cached programs with select on 8-lane 64-bit vectors without their kernels; Oclgrind
 * 21.10 computes ?: and ! on integer vector masks wrong). */
#ifdef CLRASTER_NO_EXT_VECTOR_TYPE
/* (lane by lane: PoCL 3.0 cached the program built with convert_double8, convert_float8
 * and vstore8 here without its kernels) */
#define LANES8(f, v) f((v).s0), f((v).s1), f((v).s2), f((v).s3), f((v).s4), f((v).s5),       \
                     f((v).s6), f((v).s7)
#define AS_DOUBLE(x) ((double)(x))
#define AS_FLOAT(x) ((float)(x))
#define STORE_F8(v, p)                                                                      \
    { float8 s_ = (v); __global float *d_ = (p);                                           \
      d_[0] = s_.s0; d_[1] = s_.s1; d_[2] = s_.s2; d_[3] = s_.s3;                           \
      d_[4] = s_.s4; d_[5] = s_.s5; d_[6] = s_.s6; d_[7] = s_.s7; }
#define STORE_C8(v, p)                                                                      \
    for (int c_ = 0; c_ < 8; ++c_) (p)[c_] = (v).s0
#define TO_D8(v) ((double8)(LANES8(AS_DOUBLE, v)))
#define TO_F8(v) ((float8)(LANES8(AS_FLOAT, v)))
#else
typedef uchar uchar8u __attribute__((ext_vector_type(8), aligned(1)));
#define STORE_F8(v, p) (*(__global float8u *)(p) = (v))
#define STORE_C8(v, p) (*(__global uchar8u *)(p) = (v))
#define TO_D8(v) __builtin_convertvector((v), double8)
#define TO_F8(v) __builtin_convertvector((v), float8)
#endif

/* lane k of x, y, z (double8) from the float triple at t + 3 · idx.sk */
#define GATHER3(x, y, z, t, idx, k)                                                         \
    { __global const float *g_ = (t) + 3 * (idx).s##k;                                     \
      x.s##k = (double)g_[0]; y.s##k = (double)g_[1]; z.s##k = (double)g_[2]; }
#define GATHER3_ALL(x, y, z, t, idx)                                                        \
    GATHER3(x, y, z, t, idx, 0) GATHER3(x, y, z, t, idx, 1) GATHER3(x, y, z, t, idx, 2)     \
    GATHER3(x, y, z, t, idx, 3) GATHER3(x, y, z, t, idx, 4) GATHER3(x, y, z, t, idx, 5)     \
    GATHER3(x, y, z, t, idx, 6) GATHER3(x, y, z, t, idx, 7)

/* the square root of each lane (SQRTD per lane: one vsqrtpd where the compiler joins them) */
ALWAYS_INLINE double8 sqrt8(double8 s)
{
    return (double8)(SQRTD(s.s0), SQRTD(s.s1), SQRTD(s.s2), SQRTD(s.s3), SQRTD(s.s4),
                     SQRTD(s.s5), SQRTD(s.s6), SQRTD(s.s7));
}

/* v's bits where mask m (-1/0 per lane) is set, +0.0 elsewhere */
ALWAYS_INLINE double8 keep8(double8 v, long8 m)
{
    return as_double8(as_long8(v) & m);
}

/* unit3 per lane: *x, *y, *z scaled by the reciprocal of their length, zero where the
 * length is zero or not finite */
ALWAYS_INLINE void unit8(double8 *x, double8 *y, double8 *z)
{
    double8 len = sqrt8((*x * *x + *y * *y) + *z * *z);
    long8 ok = (len > 0.0) & (len <= DBL_MAX);
    double8 r = 1.0 / len;
    *x = keep8(*x * r, ok);
    *y = keep8(*y * r, ok);
    *z = keep8(*z * r, ok);
}

/* mat3 per lane: row-major 3 × 3 m times (x, y, z), in place */
ALWAYS_INLINE void mat3_8(__global const double *m, double8 *x, double8 *y, double8 *z)
{
    double8 tx = (m[0] * *x + m[1] * *y) + m[2] * *z;
    double8 ty = (m[3] * *x + m[4] * *y) + m[5] * *z;
    double8 tz = (m[6] * *x + m[7] * *y) + m[8] * *z;
    *x = tx; *y = ty; *z = tz;
}

/* 8 pixels' normals (x, y, z per lane) as 24 interleaved floats at p3 = n + 3 · p */
ALWAYS_INLINE void store_n8(__global float *p3, double8 x, double8 y, double8 z)
{
    float8 a = TO_F8(x), b = TO_F8(y), c = TO_F8(z);
    STORE_F8(((float8)(a.s0, b.s0, c.s0, a.s1, b.s1, c.s1, a.s2, b.s2)), p3);
    STORE_F8(((float8)(c.s2, a.s3, b.s3, c.s3, a.s4, b.s4, c.s4, a.s5)), p3 + 8);
    STORE_F8(((float8)(b.s5, c.s5, a.s6, b.s6, c.s6, a.s7, b.s7, c.s7)), p3 + 16);
}

/* Resolve pixels [p, p + 8) in lanes when all eight ids are in the last instance's range
 * [lo, hi) (so covered: lo >= 0); false, with nothing written, otherwise (the scalar path
 * takes them). `want` asks for a point or a normal. */
ALWAYS_INLINE bool resolve_lanes(
    __global const int *ids, __global const float *bary, int p, int want, int lo, int hi,
    int inst, __global const int *inst_mesh, __global const int *mesh_fbase,
    __global const int *face_verts, __global const float *face_nrm,
    __global const float *positions, __global const float *vnormals,
    __global const double *inst_model, __global const double *inst_nrm,
    __global const double *cam, __global uchar *mask, __global float *lin,
    __global float *dist, __global double *pts, __global float *n_face,
    __global float *n_smooth, __global float *n_cam, __global float *n_cam_smooth)
{
    int8 v = LOAD_I8(ids + p);
    if (any8(~((v >= (int8)(lo)) & (v < (int8)(hi)))))
        return false;
    int8 row = v + (int8)(mesh_fbase[inst_mesh[inst]] - lo);
    int8 ia, ib, ic;
#define GATHER_FV(k)                                                                        \
    { __global const int *f_ = face_verts + 3 * row.s##k;                                  \
      ia.s##k = f_[0]; ib.s##k = f_[1]; ic.s##k = f_[2]; }
    GATHER_FV(0) GATHER_FV(1) GATHER_FV(2) GATHER_FV(3)
    GATHER_FV(4) GATHER_FV(5) GATHER_FV(6) GATHER_FV(7)
#undef GATHER_FV
    double8 b0 = 0.0, b1 = 0.0, b2 = 0.0;
    if (want & (RS_NEED_POINT | RS_SMOOTH | RS_CAM_SMOOTH)) {
        /* 24 consecutive floats: three loads, deinterleaved */
        float8 x0 = LOAD_F8(bary + 3 * p), x1 = LOAD_F8(bary + 3 * p + 8);
        float8 x2 = LOAD_F8(bary + 3 * p + 16);
        b0 = TO_D8(((float8)(x0.s036, x1.s147, x2.s25)));
        b1 = TO_D8(((float8)(x0.s147, x1.s25, x2.s036)));
        b2 = TO_D8(((float8)(x0.s25, x1.s036, x2.s147)));
    }
    if (want & RS_MASK) STORE_C8((uchar8)(1), mask + p);
    if (want & RS_NEED_POINT) {
        double8 ax, ay, az, bx, by, bz, cx, cy, cz;
        GATHER3_ALL(ax, ay, az, positions, ia)
        GATHER3_ALL(bx, by, bz, positions, ib)
        GATHER3_ALL(cx, cy, cz, positions, ic)
        double8 qx = (b0 * ax + b1 * bx) + b2 * cx;
        double8 qy = (b0 * ay + b1 * by) + b2 * cy;
        double8 qz = (b0 * az + b1 * bz) + b2 * cz;
        __global const double *m = inst_model + 12 * inst;
        double8 wx = MAT_ROW(m, 0, qx, qy, qz), wy = MAT_ROW(m, 1, qx, qy, qz);
        double8 wz = MAT_ROW(m, 2, qx, qy, qz);
        double8 ox = wx - cam[3], oy = wy - cam[4], oz = wz - cam[5];
        double8 along = (cam[0] * ox + cam[1] * oy) + cam[2] * oz;
        if (want & RS_LINEAR) STORE_F8(TO_F8(along), lin + p);
        if (want & RS_DISTANCE) {
            double8 d = cam[15] != 0.0 ? along : sqrt8((ox * ox + oy * oy) + oz * oz);
            STORE_F8(TO_F8(d), dist + p);
        }
        if (want & RS_POINTS) {
            __global double *o = pts + 3 * p;
#define STORE_PT(k) o[3 * k] = wx.s##k; o[3 * k + 1] = wy.s##k; o[3 * k + 2] = wz.s##k;
            STORE_PT(0) STORE_PT(1) STORE_PT(2) STORE_PT(3)
            STORE_PT(4) STORE_PT(5) STORE_PT(6) STORE_PT(7)
#undef STORE_PT
        }
    }
    if (want & RS_NEED_NORMAL) {
        double8 fx, fy, fz;
        GATHER3_ALL(fx, fy, fz, face_nrm, row)
        __global const double *nm = inst_nrm + 9 * inst;
        if (want & (RS_NORMALS | RS_CAM_NORMALS)) {
            double8 x = fx, y = fy, z = fz;
            mat3_8(nm, &x, &y, &z);
            unit8(&x, &y, &z);
            x = TO_D8(TO_F8(x)); y = TO_D8(TO_F8(y)); z = TO_D8(TO_F8(z));   /* round32 */
            if (want & RS_NORMALS) store_n8(n_face + 3 * p, x, y, z);
            if (want & RS_CAM_NORMALS) {
                mat3_8(cam + 6, &x, &y, &z);
                unit8(&x, &y, &z);
                store_n8(n_cam + 3 * p, x, y, z);
            }
        }
        if (want & (RS_SMOOTH | RS_CAM_SMOOTH)) {
            double8 ax, ay, az, bx, by, bz, cx, cy, cz;
            GATHER3_ALL(ax, ay, az, vnormals, ia)
            GATHER3_ALL(bx, by, bz, vnormals, ib)
            GATHER3_ALL(cx, cy, cz, vnormals, ic)
            double8 x = (b0 * ax + b1 * bx) + b2 * cx;
            double8 y = (b0 * ay + b1 * by) + b2 * cy;
            double8 z = (b0 * az + b1 * bz) + b2 * cz;
            /* vertex normals that cancel give no direction: the face's own there */
            long8 strong = sqrt8((x * x + y * y) + z * z) >= 1e-6;
            x = as_double8((as_long8(x) & strong) | (as_long8(fx) & ~strong));
            y = as_double8((as_long8(y) & strong) | (as_long8(fy) & ~strong));
            z = as_double8((as_long8(z) & strong) | (as_long8(fz) & ~strong));
            mat3_8(nm, &x, &y, &z);
            unit8(&x, &y, &z);
            x = TO_D8(TO_F8(x)); y = TO_D8(TO_F8(y)); z = TO_D8(TO_F8(z));
            if (want & RS_SMOOTH) store_n8(n_smooth + 3 * p, x, y, z);
            if (want & RS_CAM_SMOOTH) {
                mat3_8(cam + 6, &x, &y, &z);
                unit8(&x, &y, &z);
                store_n8(n_cam_smooth + 3 * p, x, y, z);
            }
        }
    }
    return true;
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
    __global float *n_cam_smooth,
    /* enqueued behind a raster that skips a bin list that did not fit (raster.cl,
     * BIN_LIST_OVER with the same summary and cap), the resolve skips too: its ids were
     * not written (the pass is drawn again, and resolved again behind it); bin_cap < 0:
     * after the frame, nothing to check */
    __global const int *bin_summary, int bin_cap)
{
    if (bin_cap >= 0 && BIN_LIST_OVER(bin_summary, bin_cap)) return;
    int p0 = get_global_id(0) * span;
    int p1 = imin(p0 + span, npx);
    int lo = 1, hi = 0, inst = 0;   /* the last instance's id range [lo, hi) */
    for (int p = p0; p < p1;) {
        if (p + 16 <= p1) {
            /* 16 background pixels (the common case away from the surface): one test of
             * the ids (-1 is all ones: all are −1 iff their AND is) and vector stores */
            int8 v = LOAD_I8(ids + p) & LOAD_I8(ids + p + 8);
            int4 v4 = v.lo & v.hi;
            int2 v2 = v4.lo & v4.hi;
            if ((v2.x & v2.y) == -1) {
                if (want & RS_MASK) FILL_BG(uchar, mask + p, 16, 0);
                if (want & RS_LINEAR) FILL_BG(float, lin + p, 16, INFINITY);
                if (want & RS_DISTANCE) FILL_BG(float, dist + p, 16, INFINITY);
                if (want & RS_POINTS) FILL_BG(double, pts + 3 * p, 48, 0.0);
                if (want & RS_NORMALS) FILL_BG(float, n_face + 3 * p, 48, 0.0f);
                if (want & RS_SMOOTH) FILL_BG(float, n_smooth + 3 * p, 48, 0.0f);
                if (want & RS_CAM_NORMALS) FILL_BG(float, n_cam + 3 * p, 48, 0.0f);
                if (want & RS_CAM_SMOOTH) FILL_BG(float, n_cam_smooth + 3 * p, 48, 0.0f);
                p += 16;
                continue;
            }
        }
        int e = imin(p + 16, p1);
        if (want & (RS_NEED_POINT | RS_NEED_NORMAL))
            resolve_prefetch(ids, p, e, lo, hi, inst, want, 0, inst_mesh, mesh_fbase,
                             face_verts, face_nrm, positions, vnormals);
        if (want & (RS_NEED_POINT | RS_SMOOTH | RS_CAM_SMOOTH))
            resolve_prefetch(ids, p, e, lo, hi, inst, want, 1, inst_mesh, mesh_fbase,
                             face_verts, face_nrm, positions, vnormals);
        for (int g = p; p < e; ++p) {
            /* at each group of 8 (from the chunk's start): all eight at once where they
             * are covered pixels of the last instance (resolve_lanes), else one by one */
            if (p == g) {
                g = imin(p + 8, e);
                if (g == p + 8 && (want & (RS_NEED_POINT | RS_NEED_NORMAL))
                    && resolve_lanes(ids, bary, p, want, lo, hi, inst, inst_mesh, mesh_fbase,
                                     face_verts, face_nrm, positions, vnormals, inst_model,
                                     inst_nrm, cam, mask, lin, dist, pts, n_face, n_smooth,
                                     n_cam, n_cam_smooth)) {
                    p = g - 1;   /* (the loop's ++p moves on to the next group) */
                    continue;
                }
            }
            int id = ids[p];
            if (id < 0) {
                if (want & RS_MASK) mask[p] = 0;
                if (want & RS_LINEAR) lin[p] = INFINITY;
                if (want & RS_DISTANCE) dist[p] = INFINITY;
                if (want & RS_POINTS) {
                    pts[3 * p] = 0.0;
                    pts[3 * p + 1] = 0.0;
                    pts[3 * p + 2] = 0.0;
                }
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
            int ia = face_verts[3 * row], ib = face_verts[3 * row + 1];
            int ic = face_verts[3 * row + 2];
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
                    double d = cam[15] != 0.0
                                   ? along
                                   : SQRTD((off.x * off.x + off.y * off.y) + off.z * off.z);
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
                    if (!(SQRTD((s.x * s.x + s.y * s.y) + s.z * s.z) >= 1e-6)) s = fn;
                    double3 w = round32(unit3(mat3(nm, s)));
                    if (want & RS_SMOOTH) store3f(n_smooth, p, w);
                    if (want & RS_CAM_SMOOTH) store3f(n_cam_smooth, p, unit3(mat3(cam + 6, w)));
                }
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
    __global const int *inst_row, __global const int *face_verts,                             \
    __global const float *face_nrm, __global const float *vnormals,                           \
    __global const short *face_vn,                                                            \
    __global const float4 *inst_nrm, __global const float4 *inst_col,                         \
    __global const int *inst_src, __global const float4 *colours,                             \
    __global const float2 *uvs, __global const float4 *texels, float4 light, int flags
#define SHADE_PASS inst_bucket, bshift, inst_base, n_inst, inst_row, face_verts, face_nrm,   \
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
            /* what the lanes read (smooth: the face's row of vertex normals; no face
             * normal), or the per-pixel path (colour sources: the face's vertices) */
            if (!(flags & SH_SMOOTH)) PREFETCH(face_nrm + 3 * row);
            else if (!(flags & SH_SOURCES)) PREFETCH(face_vn + FACE_VN_ROW * row);
            if (flags & SH_SOURCES) PREFETCH(face_verts + 3 * row);
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
    { int r = 3 * row.s##k; nx.s##k = face_nrm[r]; ny.s##k = face_nrm[r + 1];                \
      nz.s##k = face_nrm[r + 2]; }
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
            /* -1 is all ones: both halves are all −1 iff their AND is (int8, not int16:
             * PoCL 3.0's cached binaries of programs passing 16-wide int vectors to its
             * library lost their kernels) */
            int8 v = LOAD_I8(ids + p) & LOAD_I8(ids + p + 8);
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
