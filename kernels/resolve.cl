/* clraster — resolve: per-pixel outputs from the finished frame's
 * triangle ids and barycentrics and the scene's geometry already on the device
 * (clraster/pipeline/resolving.py describes the inputs and the arithmetic;
 * clraster/pipeline/reference/resolve.py is the twin, the same float64 operations in the same
 * order).
 *
 * One work-item per span of `span` consecutive pixels (row-major), looping: neighbouring
 * pixels mostly share an instance, so the instance found last is tried first before the
 * binary search over the instances' first ids; a group of 8 covered pixels all of that
 * instance is resolved in double8 lanes (resolve_lanes), the others pixel by pixel. Only
 * the outputs whose RS_* bit is in `want` are written (the others' arguments are some
 * other buffer, untouched). Device shading from the same tables: kernels/shade.cl.
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

/* The face row of triangle `id` of instance `inst` (first id lo): its row of face_rows
 * (common.h FACE_V, FACE_N). */
#define FACE_ROW(id) (mesh_fbase[inst_mesh[inst]] + ((id) - lo))

/* Ask for the face rows of the covered pixels in [a, b) whose id is in the last instance's
 * range [lo, hi) (vert = 0), or for the vertices those rows name (vert = 1): random
 * accesses into tables of megabytes; asked for together, a chunk's are fetched in parallel
 * instead of one dependent miss after another. Asked for right before the chunk is
 * resolved: asking 8–32 pixels ahead, or the vertices a chunk before their use, was slower
 * (bench/README.md's log). */
inline void resolve_prefetch(__global const int *ids, int a, int b, int lo, int hi, int inst,
                             int want, int vert, __global const int *inst_mesh,
                             __global const int *mesh_fbase, __global const int *face_rows,
                             __global const float *positions, __global const float *vnormals)
{
    for (int q = a; q < b; ++q) {
        int id = ids[q];
        if (!(id >= lo && id < hi)) continue;
        int row = FACE_ROW(id);
        if (!vert) {
            PREFETCH(face_rows + (long)FACE_ROW_WORDS * row);   /* vertices and normal */
            continue;
        }
        __global const int *fv = face_rows + (long)FACE_ROW_WORDS * row;
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
/* (lane by lane: PoCL 3.0 cached the program built with vstore8 here without its kernels;
 * the conversions are common.h's TO_DOUBLE8 / TO_FLOAT8) */
#define STORE_F8(v, p)                                                                      \
    { float8 s_ = (v); __global float *d_ = (p);                                           \
      d_[0] = s_.s0; d_[1] = s_.s1; d_[2] = s_.s2; d_[3] = s_.s3;                           \
      d_[4] = s_.s4; d_[5] = s_.s5; d_[6] = s_.s6; d_[7] = s_.s7; }
#define STORE_C8(v, p)                                                                      \
    for (int c_ = 0; c_ < 8; ++c_) (p)[c_] = (v).s0
#else
#define STORE_F8(v, p) (*(__global float8u *)(p) = (v))
#define STORE_C8(v, p) (*(__global uchar8u *)(p) = (v))
#endif

/* lane k of x, y, z (double8) from the float triple at t + 3 · idx.sk */
#define GATHER3(x, y, z, t, idx, k)                                                         \
    { __global const float *g_ = (t) + 3 * (idx).s##k;                                     \
      x.s##k = (double)g_[0]; y.s##k = (double)g_[1]; z.s##k = (double)g_[2]; }
#define GATHER3_ALL(x, y, z, t, idx)                                                        \
    GATHER3(x, y, z, t, idx, 0) GATHER3(x, y, z, t, idx, 1) GATHER3(x, y, z, t, idx, 2)     \
    GATHER3(x, y, z, t, idx, 3) GATHER3(x, y, z, t, idx, 4) GATHER3(x, y, z, t, idx, 5)     \
    GATHER3(x, y, z, t, idx, 6) GATHER3(x, y, z, t, idx, 7)

/* The double8 helpers below are macros or take pointers: a double8 passed by value makes
 * LLVM 14 warn on every build, on CPUs without AVX-512, that the argument "changes the
 * ABI" (always-inlined or not), which a cold build printed on the user's stderr. */

/* out = the square root of each lane of s (SQRTD per lane: one vsqrtpd where the compiler
 * joins them) */
#define SQRT8_INTO(out, s)                                                                  \
    { double8 t_ = (s);                                                                     \
      (out) = (double8)(SQRTD(t_.s0), SQRTD(t_.s1), SQRTD(t_.s2), SQRTD(t_.s3),            \
                        SQRTD(t_.s4), SQRTD(t_.s5), SQRTD(t_.s6), SQRTD(t_.s7)); }

/* v's bits where mask m (-1/0 per lane) is set, +0.0 elsewhere */
#define KEEP8(v, m) as_double8(as_long8(v) & (m))

/* unit3 per lane: *x, *y, *z scaled by the reciprocal of their length, zero where the
 * length is zero or not finite */
ALWAYS_INLINE void unit8(double8 *x, double8 *y, double8 *z)
{
    double8 len;
    SQRT8_INTO(len, (*x * *x + *y * *y) + *z * *z);
    long8 ok = (len > 0.0) & (len <= DBL_MAX);
    double8 r = 1.0 / len;
    *x = KEEP8(*x * r, ok);
    *y = KEEP8(*y * r, ok);
    *z = KEEP8(*z * r, ok);
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
ALWAYS_INLINE void store_n8(__global float *p3, const double8 *x, const double8 *y,
                            const double8 *z)
{
    float8 a = TO_FLOAT8(*x), b = TO_FLOAT8(*y), c = TO_FLOAT8(*z);
    STORE_F8(((float8)(a.s0, b.s0, c.s0, a.s1, b.s1, c.s1, a.s2, b.s2)), p3);
    STORE_F8(((float8)(c.s2, a.s3, b.s3, c.s3, a.s4, b.s4, c.s4, a.s5)), p3 + 8);
    STORE_F8(((float8)(b.s5, c.s5, a.s6, b.s6, c.s6, a.s7, b.s7, c.s7)), p3 + 16);
}

/* blend3 per lane: x, y, z = (b0·a + b1·b) + b2·c of the float triples at t + 3·ia, 3·ib,
 * 3·ic (the lanes' three vertices) */
#define BLEND8(x, y, z, t, ia, ib, ic)                                                      \
    { double8 ax_, ay_, az_, bx_, by_, bz_, cx_, cy_, cz_;                                  \
      GATHER3_ALL(ax_, ay_, az_, t, ia) GATHER3_ALL(bx_, by_, bz_, t, ib)                   \
      GATHER3_ALL(cx_, cy_, cz_, t, ic)                                                     \
      (x) = (b0 * ax_ + b1 * bx_) + b2 * cx_;                                               \
      (y) = (b0 * ay_ + b1 * by_) + b2 * cy_;                                               \
      (z) = (b0 * az_ + b1 * bz_) + b2 * cz_; }

/* The scalar body's normal outputs per lane from the object-space normal (x, y, z): the
 * world normal unit3(M⁻ᵀ n) (nm) rounded to float (round32) into `world` (if not 0), and
 * its camera-frame one (V⁻ᵀ rows cam6) into `camera` (if not 0), 8 pixels from p3's */
ALWAYS_INLINE void normals8(__global const double *nm, __global const double *cam6,
                            double8 *x, double8 *y, double8 *z, __global float *world,
                            __global float *camera)
{
    mat3_8(nm, x, y, z);
    unit8(x, y, z);
    /* round32 */
    *x = TO_DOUBLE8(TO_FLOAT8(*x)); *y = TO_DOUBLE8(TO_FLOAT8(*y));
    *z = TO_DOUBLE8(TO_FLOAT8(*z));
    if (world) store_n8(world, x, y, z);
    if (camera) {
        mat3_8(cam6, x, y, z);
        unit8(x, y, z);
        store_n8(camera, x, y, z);
    }
}

/* Resolve pixels [p, p + 8) in lanes when all eight ids are in the last instance's range
 * [lo, hi) (so covered: lo >= 0); false, with nothing written, otherwise (the scalar path
 * takes them). `want` asks for a point or a normal. */
ALWAYS_INLINE bool resolve_lanes(
    __global const int *ids, __global const float *bary, int p, int want, int lo, int hi,
    int inst, __global const int *inst_mesh, __global const int *mesh_fbase,
    __global const int *face_rows,
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
    { __global const int *f_ = face_rows + (long)FACE_ROW_WORDS * row.s##k;                 \
      ia.s##k = f_[0]; ib.s##k = f_[1]; ic.s##k = f_[2]; }
    GATHER_FV(0) GATHER_FV(1) GATHER_FV(2) GATHER_FV(3)
    GATHER_FV(4) GATHER_FV(5) GATHER_FV(6) GATHER_FV(7)
#undef GATHER_FV
    double8 b0 = 0.0, b1 = 0.0, b2 = 0.0;
    if (want & (RS_NEED_POINT | RS_SMOOTH | RS_CAM_SMOOTH)) {
        /* 24 consecutive floats: three loads, deinterleaved */
        float8 x0 = LOAD_F8(bary + 3 * p), x1 = LOAD_F8(bary + 3 * p + 8);
        float8 x2 = LOAD_F8(bary + 3 * p + 16);
        b0 = TO_DOUBLE8(((float8)(x0.s036, x1.s147, x2.s25)));
        b1 = TO_DOUBLE8(((float8)(x0.s147, x1.s25, x2.s036)));
        b2 = TO_DOUBLE8(((float8)(x0.s25, x1.s036, x2.s147)));
    }
    if (want & RS_MASK) STORE_C8((uchar8)(1), mask + p);
    if (want & RS_NEED_POINT) {
        double8 qx, qy, qz;
        BLEND8(qx, qy, qz, positions, ia, ib, ic)
        __global const double *m = inst_model + 12 * inst;
        double8 wx = MAT_ROW(m, 0, qx, qy, qz), wy = MAT_ROW(m, 1, qx, qy, qz);
        double8 wz = MAT_ROW(m, 2, qx, qy, qz);
        double8 ox = wx - cam[3], oy = wy - cam[4], oz = wz - cam[5];
        double8 along = (cam[0] * ox + cam[1] * oy) + cam[2] * oz;
        if (want & RS_LINEAR) STORE_F8(TO_FLOAT8(along), lin + p);
        if (want & RS_DISTANCE) {
            double8 d = along;
            if (cam[15] == 0.0) SQRT8_INTO(d, (ox * ox + oy * oy) + oz * oz);
            STORE_F8(TO_FLOAT8(d), dist + p);
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
#define GATHER_FN(k)                                                                        \
    { fx.s##k = (double)FACE_N(face_rows, row.s##k, 0);                                     \
      fy.s##k = (double)FACE_N(face_rows, row.s##k, 1);                                     \
      fz.s##k = (double)FACE_N(face_rows, row.s##k, 2); }
        GATHER_FN(0) GATHER_FN(1) GATHER_FN(2) GATHER_FN(3)
        GATHER_FN(4) GATHER_FN(5) GATHER_FN(6) GATHER_FN(7)
#undef GATHER_FN
        __global const double *nm = inst_nrm + 9 * inst;
        if (want & (RS_NORMALS | RS_CAM_NORMALS)) {
            double8 x = fx, y = fy, z = fz;
            normals8(nm, cam + 6, &x, &y, &z, (want & RS_NORMALS) ? n_face + 3 * p : 0,
                     (want & RS_CAM_NORMALS) ? n_cam + 3 * p : 0);
        }
        if (want & (RS_SMOOTH | RS_CAM_SMOOTH)) {
            double8 x, y, z;
            BLEND8(x, y, z, vnormals, ia, ib, ic)
            /* vertex normals that cancel give no direction: the face's own there */
            double8 len;
            SQRT8_INTO(len, (x * x + y * y) + z * z);
            long8 strong = len >= 1e-6;
            x = as_double8((as_long8(x) & strong) | (as_long8(fx) & ~strong));
            y = as_double8((as_long8(y) & strong) | (as_long8(fy) & ~strong));
            z = as_double8((as_long8(z) & strong) | (as_long8(fz) & ~strong));
            normals8(nm, cam + 6, &x, &y, &z, (want & RS_SMOOTH) ? n_smooth + 3 * p : 0,
                     (want & RS_CAM_SMOOTH) ? n_cam_smooth + 3 * p : 0);
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
    __global const int *mesh_fbase,    /* (U,) first face row of each unique mesh */
    __global const int *face_rows,     /* (F, FACE_ROW_WORDS) vertices and normal of each face */
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
             * the ids and vector stores */
            if (background16(ids + p)) {
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
                             face_rows, positions, vnormals);
        if (want & (RS_NEED_POINT | RS_SMOOTH | RS_CAM_SMOOTH))
            resolve_prefetch(ids, p, e, lo, hi, inst, want, 1, inst_mesh, mesh_fbase,
                             face_rows, positions, vnormals);
        for (int g = p; p < e; ++p) {
            /* at each group of 8 (from the chunk's start): all eight at once where they
             * are covered pixels of the last instance (resolve_lanes), else one by one */
            if (p == g) {
                g = imin(p + 8, e);
                if (g == p + 8 && (want & (RS_NEED_POINT | RS_NEED_NORMAL))
                    && resolve_lanes(ids, bary, p, want, lo, hi, inst, inst_mesh, mesh_fbase,
                                     face_rows, positions, vnormals, inst_model,
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
            int ia = FACE_V(face_rows, row, 0), ib = FACE_V(face_rows, row, 1);
            int ic = FACE_V(face_rows, row, 2);
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
                double3 fn = (double3)((double)FACE_N(face_rows, row, 0),
                                       (double)FACE_N(face_rows, row, 1),
                                       (double)FACE_N(face_rows, row, 2));
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
