/* clraster — resolve: per-pixel outputs from the finished frame's triangle ids and
 * barycentrics and the scene's geometry already on the device (clraster/pipeline/resolving.py
 * describes the inputs and the arithmetic; clraster/pipeline/reference/resolve.py is the twin,
 * the same float64 operations in the same order).
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

/* Lambert shading of the finished frame (the device side of clraster.output.shade.shade for
 * surfaces without colour sources; its NumPy path is the twin, equal within 1/255): per
 * covered pixel, albedo · (ambient + (1 − ambient) · lam) with lam = |n · l| (two-sided) or
 * max(n · l, 0), n the world normal of the resolve outputs "normals" / "smooth_normals"
 * (flat_raw: a Mesh's face normal as it is, as the host lights it), albedo the instance's
 * tint (tints) or the default; rounded to uint8 as NumPy's rint; background and alpha as
 * given. shade: float (8,) light (3), ambient, albedo (3), two_sided. */
__kernel void shade_pixels(
    __global const int *ids, __global const float *bary, int npx, int span,
    __global const int *inst_base, int n_inst, __global const int *inst_mesh,
    __global const int *mesh_fbase, __global const int *face_verts,
    __global const float *face_nrm, __global const float *vnormals,
    __global const double *inst_nrm, __global const double *shade, __global const double *tints,
    int use_tints, int smooth, int flat_raw, int channels, uchar bg_r, uchar bg_g, uchar bg_b,
    __global uchar *out)
{
    int p0 = get_global_id(0) * span;
    int p1 = imin(p0 + span, npx);
    int lo = 1, hi = 0, inst = 0;
    for (int p = p0; p < p1; ++p) {
        int id = ids[p];
        __global uchar *o = out + channels * p;
        if (id < 0) {
            o[0] = bg_r; o[1] = bg_g; o[2] = bg_b;
            if (channels == 4) o[3] = 0;
            continue;
        }
        if (!(id >= lo && id < hi)) {
            int a = 0, b = n_inst;
            while (b - a > 1) {
                int m = (a + b) >> 1;
                if (inst_base[m] <= id) a = m; else b = m;
            }
            inst = a;
            lo = inst_base[a];
            hi = b < n_inst ? inst_base[b] : INT_MAX;
        }
        int row = mesh_fbase[inst_mesh[inst]] + (id - lo);
        double3 n = load3(face_nrm, row);
        if (smooth) {
            double b0 = (double)bary[3 * p], b1 = (double)bary[3 * p + 1];
            double b2 = (double)bary[3 * p + 2];
            double3 s = blend3(b0, b1, b2, load3(vnormals, face_verts[3 * row]),
                               load3(vnormals, face_verts[3 * row + 1]),
                               load3(vnormals, face_verts[3 * row + 2]));
            if (sqrt((s.x * s.x + s.y * s.y) + s.z * s.z) >= 1e-6) n = s;
        }
        if (!flat_raw) n = round32(unit3(mat3(inst_nrm + 9 * inst, n)));
        double lam = (n.x * shade[0] + n.y * shade[1]) + n.z * shade[2];
        lam = shade[7] != 0.0 ? fabs(lam) : (lam > 0.0 ? lam : 0.0);
        double k = shade[3] + (1.0 - shade[3]) * lam;
        for (int c = 0; c < 3; ++c) {
            double base = use_tints ? tints[3 * inst + c] : shade[4 + c];
            double v = rint(base * k * 255.0);
            o[c] = (uchar)(v < 0.0 ? 0.0 : (v > 255.0 ? 255.0 : v));
        }
        if (channels == 4) o[3] = 255;
    }
}
