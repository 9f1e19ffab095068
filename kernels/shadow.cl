/* Shadow-map lookups: per pixel of a camera frame, the fraction of one light that reaches
 * its visible point (percentage-closer filtering with a slope-scaled bias), times a spot's
 * cone factor; 0 on the background. The light's map (linear light depth, +inf where
 * nothing was drawn) was rendered through the same pipeline (clraster/output/lights.py
 * says how its frustum is fitted). All geometry in double, in the order of the NumPy twin
 * `clraster.output.lights.shadow_lookup`.
 *
 * P (double): inv_vp[16] (camera clip → world, row-major), lview[16], lproj[16] (row-major),
 * dir[3] (the light's travel direction), pos[3] (spot position), texel, bias, slope,
 * cos_lo, cos_hi (spot cone: smoothstep from cos(cone) to cos(inner)).
 */
#include "common.h"

#define TAN_MAX 10.0

static double3 mat_point(__global const double *m, double x, double y, double z, double *w)
{
    double hx = ((m[0] * x + m[1] * y) + m[2] * z) + m[3];
    double hy = ((m[4] * x + m[5] * y) + m[6] * z) + m[7];
    double hz = ((m[8] * x + m[9] * y) + m[10] * z) + m[11];
    *w = ((m[12] * x + m[13] * y) + m[14] * z) + m[15];
    return (double3)(hx, hy, hz);
}

__kernel void shadow_lookup(__global const float *depth, __global const float *normals,
                            __global const float *smap, __global const double *P,
                            __global float *out, const int width, const int height,
                            const int size, const int pcf, const int perspective,
                            const int spot, const int reversed_z)
{
    int px = get_global_id(0), py = get_global_id(1);
    if (px >= width || py >= height) return;
    size_t i = (size_t)py * width + px;
    float d = depth[i];
    if (reversed_z ? !(d > 0.0f) : !(d < 1.0f)) { out[i] = 0.0f; return; }
    double x = (px + 0.5) * (2.0 / width) - 1.0;
    double y = 1.0 - (py + 0.5) * (2.0 / height);
    double z = reversed_z ? 1.0 - 2.0 * (double)d : 2.0 * (double)d - 1.0;
    double w;
    double3 world = mat_point(P, x, y, z, &w);
    world /= w;
    double lw;
    double3 eye = mat_point(P + 16, world.x, world.y, world.z, &lw);
    double zl = -eye.z;
    double cw;
    double3 clip = mat_point(P + 32, eye.x, eye.y, eye.z, &cw);
    bool front = cw > 0.0;
    double wsafe = front ? cw : 1.0;
    double u = (clip.x / wsafe + 1.0) * 0.5 * size;
    double v = (1.0 - clip.y / wsafe) * 0.5 * size;
    double3 dir = (double3)(P[48], P[49], P[50]);
    double3 tow;
    if (spot) {
        double3 dd = (double3)(P[51], P[52], P[53]) - world;
        double len = sqrt(dd.x * dd.x + dd.y * dd.y + dd.z * dd.z);
        tow = len > 0.0 ? dd / len : (double3)(0.0, 0.0, 0.0);
    } else {
        tow = -dir;
    }
    double3 n = (double3)(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
    double c = fabs((n.x * tow.x + n.y * tow.y) + n.z * tow.z);
    double tanv = sqrt(fmax(1.0 - c * c, 0.0)) / fmax(c, 1.0 / TAN_MAX);
    tanv = fmin(tanv, TAN_MAX);
    double tau = perspective ? P[54] * zl : P[54];
    double bias = tau * (P[55] + P[56] * (pcf + 1) * tanv);
    long ix = (long)floor(u), iy = (long)floor(v);
    double test = zl - bias;
    int count = 0;
    for (int dy = -pcf; dy <= pcf; ++dy)
        for (int dx = -pcf; dx <= pcf; ++dx) {
            long tx = ix + dx, ty = iy + dy;
            bool inside = tx >= 0 && tx < size && ty >= 0 && ty < size;
            count += inside ? (test <= (double)smap[ty * size + tx]) : 1;
        }
    int taps = (2 * pcf + 1) * (2 * pcf + 1);
    double frac = (double)count / (double)taps;
    if (perspective && !(front && u >= 0.0 && u < size && v >= 0.0 && v < size)) frac = 0.0;
    double cone = 1.0;
    if (spot) {
        double cosang = -((tow.x * dir.x + tow.y * dir.y) + tow.z * dir.z);
        double lo = P[57], hi = P[58];
        if (hi - lo < 1e-12) {
            cone = cosang >= lo ? 1.0 : 0.0;
        } else {
            double t = clamp((cosang - lo) / (hi - lo), 0.0, 1.0);
            cone = t * t * (3.0 - 2.0 * t);
        }
    }
    out[i] = (float)(frac * cone);
}
