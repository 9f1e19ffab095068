/* clraster — types and constants shared by every stage.
 *
 * The constants and records the host shares with the kernels (outcode bits, status codes,
 * piece flags, Piece, Draw, WinVert, LineRec...) are not written here: clraster/base/layout.py is
 * their one source, and the host puts its generated C (clraster.layout.c_header) in place of
 * the `#include "layout.h"` line below (there is no layout.h file). tests/test_layout.py
 * checks that the compiler sees the same values, sizes and offsets as NumPy. Stage sources
 * say `#include "common.h"`; the host inlines this file (clraster.device.kernel_source).
 *
 * Every float expression here is written out operation by operation and FP contraction is
 * off, so the NumPy twin (clraster/pipeline/reference), doing the same IEEE float32 operations
 * in the same order, gets bit-identical clip positions, fixed-point vertices and depths — that is
 * what lets the tests compare triangle ids exactly.
 *
 * Pointer arguments of the vertex, setup and bin kernels are `restrict`: no two buffers of
 * one launch alias, and saying so lets LLVM keep per-draw loads in registers across the
 * stores instead of reloading them per work-item. (raster.cl does not: its unused overdraw
 * argument is bound to the id buffer.)
 */
#pragma OPENCL FP_CONTRACT OFF
#pragma OPENCL EXTENSION cl_khr_fp64 : enable   /* the clipper and user clip distances */

#ifndef TILE_LOG2
#error "TILE_LOG2 must be defined (see clraster/base/config.py RasterConfig.build_options)"
#endif
#include "layout.h"   /* generated from clraster/base/layout.py: SUBPIXEL_BITS, OC_*, ST_*... */

#define TILE_SIZE (1 << TILE_LOG2)
#define TILE_PIXELS (TILE_SIZE * TILE_SIZE)
#define SUB_ONE (1 << SUBPIXEL_BITS)          /* 256: one pixel in 24.8 fixed point */
#define SUB_HALF (1 << (SUBPIXEL_BITS - 1))   /* pixel centres sit at +0.5 */

/* Records (typedefs generated from the clraster.layout dtypes named in brackets):
 *
 * Piece [PIECE_DTYPE]: one triangle setup record, 96 bytes. Window coordinates are 24.8
 * fixed point with y down (row 0 at the top) and the vertex order makes the doubled area
 * positive; they decide coverage only. bb_min/bb_max are the inclusive pixel ranges of pixel
 * centres inside the bounding box, clamped to the viewport, packed x | y << 16. Depth and
 * screen-space weights are planes set up from the unsnapped vertices, relative to pixel
 * bb_min (setup.cl value_planes); r1, r2 = w0/w1, w0/w2: perspective correction of the
 * weights.
 *
 * Draw [DRAW_DTYPE]: one drawn cluster of one instance. tri_base: where its triangles start
 * in this frame's triangle stream (vert_base, where its vertices start in the twin's vertex
 * stream, is not read here: setup makes each draw's vertices itself); face_base: triangle
 * id of the instance's face 0; flags: DRAW_INSIDE = cluster inside the frustum by a margin,
 * no clip tests needed.
 *
 * Clusters (meshlets) hold at most CLUSTER_MAX triangles and CLUSTER_MAX vertices.
 * setup_triangles runs a work-item per draw (its vertices VERTEX_LANES at a time, then its
 * triangles SETUP_LANES at a time), the clipper's kernels one
 * work-item per (draw, local triangle): work-item g serves draw g >> CLUSTER_LOG2, local
 * index g & (CLUSTER_MAX - 1).
 *
 * WinVert [WINVERT_DTYPE]: a vertex after the viewport transform (viewport_vertex below).
 * int2 [WINXY_DTYPE]: its 24.8 fixed-point x, y alone: a vertex's window position as
 * setup keeps it (win_xy below).
 *
 * LineRec [LINE_DTYPE]: one set-up line segment (lines.cl).
 */

/* Compiler builtins, each with a portable OpenCL C fallback that gives the same bits. The
 * fast paths are Clang builtins, which PoCL's and Intel's compilers take and others may not
 * (GPU drivers; Oclgrind's interpreter builds some it cannot run). The host probes the
 * device's compiler once (clraster.pipeline.features: each builtin built and run on known
 * inputs) and passes -DCLRASTER_NO_<FEATURE> for each one it lacks; -DCLRASTER_PORTABLE
 * forces every fallback (always on Oclgrind, which also needs the workarounds of its own
 * in setup.cl and raster.cl; CLRASTER_FALLBACKS=all). */
#ifdef CLRASTER_PORTABLE
#define CLRASTER_NO_RINTF
#define CLRASTER_NO_SQRTF
#define CLRASTER_NO_CTZ
#define CLRASTER_NO_NONTEMPORAL_STORE
#define CLRASTER_NO_PREFETCH
#define CLRASTER_NO_CONVERTVECTOR
#define CLRASTER_NO_SHUFFLEVECTOR
#define CLRASTER_NO_ROUNDEVEN
#define CLRASTER_NO_EXT_VECTOR_TYPE
#endif

/* Round to nearest, ties to even (rint). On PoCL, __builtin_rintf is LLVM's rint intrinsic,
 * one roundss on x86; PoCL's OpenCL rint() is a software routine that is not inlined and
 * was half the vertex stage's time. Fallback: rint(), which rounds the same, bit for bit. */
#ifdef CLRASTER_NO_RINTF
#define RINTF(x) rint(x)
#else
#define RINTF(x) __builtin_rintf(x)
#endif

/* Correctly rounded float square root, a scalar: clang's builtin is one sqrtss, and eight
 * in a row one vsqrtps (PoCL's sqrt() is a call, not inlined). Fallback: OpenCL's sqrt, the
 * same bits where the runtime rounds it correctly: CPU runtimes do, a GPU driver with
 * -cl-fp32-correctly-rounded-divide-sqrt (clraster.pipeline.features.precision_options). */
#ifdef CLRASTER_NO_SQRTF
#define SQRTF(x) sqrt(x)
#else
#define SQRTF(x) __builtin_sqrtf(x)
#endif

/* The same for a double (one sqrtsd; PoCL's double sqrt() is a call too), under the same
 * probe: a compiler with one builtin has the other. Only for kernels with cl_khr_fp64. */
#ifdef CLRASTER_NO_SQRTF
#define SQRTD(x) sqrt(x)
#else
#define SQRTD(x) __builtin_sqrt(x)
#endif

/* Index of the lowest set bit of x != 0 (uint). PoCL's clz() is a call into its library,
 * not inlined; clang's builtin is one tzcnt. Fallback: OpenCL 1.2's clz. */
#ifdef CLRASTER_NO_CTZ
#define CTZ(x) (31 - clz((x) & -(x)))
#else
#define CTZ(x) __builtin_ctz(x)
#endif

/* A non-temporal store of value v to *p (p aligned to v's size): the line is written
 * without being read into the cache first, half the memory traffic of an ordinary store
 * for outputs written once and read much later (the frame arrays, bin entries, setup
 * records). Fallback: a plain store. */
#ifdef CLRASTER_NO_NONTEMPORAL_STORE
#define NT_STORE(v, p) (*(p) = (v))
#else
#define NT_STORE(v, p) __builtin_nontemporal_store((v), (p))
#endif

/* Ask for the cache line at p (any address space) ahead of its use: prefetcht0 on x86 from
 * clang's builtin (a hint: it never faults, so an address past the end of a buffer is
 * harmless). Fallback: nothing (OpenCL's prefetch() takes a global pointer and an element
 * count within the buffer, so it cannot stand in for a hint past the end). The raster reads
 * its bin entries, written non-temporally by bin_scatter, from memory in list order. */
#ifdef CLRASTER_NO_PREFETCH
#define PREFETCH(p) ((void)0)
#else
#define PREFETCH(p) __builtin_prefetch((__global const char *)(p))
#endif

/* Vector v converted element by element to the vector type T (int <-> float rounds to
 * nearest even, as a C cast; the lane masks -1/0 keep their value). PoCL's convert_T() is
 * a library call per vector; clang's builtin is one instruction. Fallback: convert_T(). */
#ifdef CLRASTER_NO_CONVERTVECTOR
#define CONVERT_VEC(v, T) convert_##T(v)
#else
#define CONVERT_VEC(v, T) __builtin_convertvector(v, T)
#endif
/* 8 lanes converted to float or double (from double, float or int lanes; setup's and the
 * resolve's lanes): clang's builtin, or lane by lane where that falls back (the pip PoCL
 * 3.0 built setup.cl with convert_float8(double8), a library call taking an 8-lane 64-bit
 * vector, and resolve.cl with convert_double8 / convert_float8, into programs without
 * their kernels; see MASK_INT8). */
#ifdef CLRASTER_NO_CONVERTVECTOR
#define LANES8_AS(T, v) ((T##8)((T)(v).s0, (T)(v).s1, (T)(v).s2, (T)(v).s3, (T)(v).s4,     \
                                (T)(v).s5, (T)(v).s6, (T)(v).s7))
#define TO_FLOAT8(v) LANES8_AS(float, v)
#define TO_DOUBLE8(v) LANES8_AS(double, v)
#else
#define TO_FLOAT8(v) __builtin_convertvector((v), float8)
#define TO_DOUBLE8(v) __builtin_convertvector((v), double8)
#endif
/* Vectors at their element's alignment (a draw's first vertex, a pixel row at any column):
 * Clang's ext_vector_type typedefs, one unaligned vector load or store each. Where the
 * compiler lacks them (CLRASTER_NO_EXT_VECTOR_TYPE) the kernels use their fallbacks (the
 * same values); LOAD_I8 / LOAD_F8 / LOAD_UC8 and STORE_I8 / STORE_UC8 fall back to OpenCL's
 * vload8 and vstore8 (calls in PoCL). */
#ifndef CLRASTER_NO_EXT_VECTOR_TYPE
typedef float float8u __attribute__((ext_vector_type(8), aligned(4)));
typedef float float16u __attribute__((ext_vector_type(16), aligned(4)));
typedef double double8u __attribute__((ext_vector_type(8), aligned(8)));
typedef int int8u __attribute__((ext_vector_type(8), aligned(4)));
typedef ushort ushort8u __attribute__((ext_vector_type(8), aligned(2)));
typedef uchar uchar8u __attribute__((ext_vector_type(8), aligned(1)));
#define LOAD_I8(p) (*(__global const int8u *)(p))
#define LOAD_F8(p) (*(__global const float8u *)(p))
#define LOAD_UC8(p) (*(__global const uchar8u *)(p))
#define STORE_I8(v, p) (*(__global int8u *)(p) = (v))
#define STORE_UC8(v, p) (*(__global uchar8u *)(p) = (v))
#else
#define LOAD_I8(p) vload8(0, (p))
#define LOAD_F8(p) vload8(0, (p))
#define LOAD_UC8(p) vload8(0, (p))
#define STORE_I8(v, p) vstore8((v), 0, (p))
#define STORE_UC8(v, p) vstore8((v), 0, (p))
#endif

/* Are the 16 ids from ids[0] all the background (-1)? -1 is all ones: they all are iff
 * their AND is (int8 halves, not int16: PoCL 3.0's cached binaries of programs passing
 * 16-wide int vectors to its library lost their kernels). The resolve and shading kernels
 * skip such runs with vector stores. */
inline bool background16(__global const int *ids)
{
    int8 v = LOAD_I8(ids) & LOAD_I8(ids + 8);
    int4 v4 = v.lo & v.hi;
    int2 v2 = v4.lo & v4.hi;
    return (v2.x & v2.y) == -1;
}

/* any lane of an int8 comparison mask set (-1: OpenCL's any() is a call in PoCL) */
inline bool any8(int8 m)
{
    return (((m.s0 | m.s1) | (m.s2 | m.s3)) | ((m.s4 | m.s5) | (m.s6 | m.s7))) < 0;
}

/* A lane mask m (a long8 variable of -1/0) as the int8 of the same -1/0. Fallback: lane by
 * lane (the pip PoCL 3.0 built raster.cl with convert_int8(long8), a library call taking a
 * long8, into a program without its kernel). */
#ifdef CLRASTER_NO_CONVERTVECTOR
#define MASK_INT8(m) ((int8)((int)(m).s0, (int)(m).s1, (int)(m).s2, (int)(m).s3,          \
                             (int)(m).s4, (int)(m).s5, (int)(m).s6, (int)(m).s7))
#else
#define MASK_INT8(m) __builtin_convertvector(m, int8)
#endif

/* setup.cl's vertex lanes (draw_vertices) need three Clang features at once: vector
 * shuffles, elementwise roundeven and ext_vector_type typedefs of element alignment.
 * Fallback: vertex by vertex, the same values. */
#if !defined(CLRASTER_NO_SHUFFLEVECTOR) && !defined(CLRASTER_NO_ROUNDEVEN) &&              \
    !defined(CLRASTER_NO_EXT_VECTOR_TYPE)
#define CLRASTER_VERTEX_LANES
#endif

/* A helper PoCL must inline. Its inliner left some larger helpers called once per triangle
 * or vertex as real calls (perf shows them as symbols of their own in the kernel's .so:
 * make_piece, value_planes, rect_outside, row_span), their struct and double4 arguments
 * passed through the stack. */
#define ALWAYS_INLINE __attribute__((always_inline)) inline

/* Integer min/max and a finiteness test written out: PoCL's OpenCL min(), max() and
 * isfinite() are calls into its builtin library that are not inlined. */
inline int imin(int a, int b) { return a < b ? a : b; }
inline int imax(int a, int b) { return a > b ? a : b; }
inline bool finite_f(float x) { return (as_uint(x) & 0x7f800000u) != 0x7f800000u; }
/* max / min of non-NaN values as NumPy's maximum / minimum (the twin's): the first
 * argument on a tie (PoCL's fmax and fmin are library calls too) */
inline float maxf(float a, float b) { return a >= b ? a : b; }
inline double mind(double a, double b) { return a <= b ? a : b; }

/* Face r of the resolve and shading kernels' face table `rows` (FACE_ROW_WORDS words a
 * face, clraster.pipeline.resolving ResolveTables.face_rows): FACE_V its pool vertex k
 * (0..2), FACE_N component k of its unit object-space normal (offsets in long: a table of
 * over 2^28 faces). */
#define FACE_V(rows, r, k) ((rows)[(long)FACE_ROW_WORDS * (r) + (k)])
#define FACE_N(rows, r, k) as_float((rows)[(long)FACE_ROW_WORDS * (r) + 3 + (k)])

/* Row r of M · [x y z 1]ᵀ for a row-major 4 × 4 matrix m (float or double), in the order
 * the NumPy twin sums (setup.cl's vertices for triangles, lines.cl for line endpoints, user
 * planes and depth rows too). x, y, z are scalars or vectors (setup's vertex lanes): the same
 * operations per lane. Products are rounded, so it matters that nothing is fused
 * (FP_CONTRACT is off). */
#define MAT_ROW(m, r, x, y, z)                                                              \
    ((((m)[4 * (r)] * (x) + (m)[4 * (r) + 1] * (y)) + (m)[4 * (r) + 2] * (z)) + (m)[4 * (r) + 3])

/* clip = M · [x y z 1]ᵀ for a row-major float32 matrix M (lines.cl, setup.cl's vertex_of;
 * setup.cl's draw_vertices does the same per lane with MAT_ROW). */
inline float4 clip_transform(__global const float *m, float px, float py, float pz)
{
    return (float4)(MAT_ROW(m, 0, px, py, pz), MAT_ROW(m, 1, px, py, pz),
                    MAT_ROW(m, 2, px, py, pz), MAT_ROW(m, 3, px, py, pz));
}

/* Signed distance of an object-space vertex to a user clip plane q (a, b, c, d, already in
 * the instance's object space: world plane · model, float64 on the host), >= 0 kept. The
 * vertex stage (ucode bits) and setup's clipper (vertex distances) evaluate exactly this,
 * so the two never disagree on a vertex's side. */
inline double user_dist(__global const double *q, float px, float py, float pz)
{
    return MAT_ROW(q, 0, (double)px, (double)py, (double)pz);
}

/* The classic 6-bit frustum outcode of clip coordinates x, y, z, w: bit k set iff the
 * signed distance to plane k is negative (the clipper's plane_dist expressions), compared
 * with `zero` of their type. One body for every variant: float (frustum_outcode), double
 * (frustum_outcode_d: the line clipper's recomputed endpoints) and the vertex stage's
 * float8 lanes; BIT(test, bit) makes one test's bit in the result's type (OC_BIT: bit or 0).
 * The sign of a rounded sum is the sign of the exact sum, so float and double outcodes of
 * one point agree. */
#define FRUSTUM_OUTCODE(x, y, z, w, zero, BIT)                                              \
    (BIT((x) + (w) < (zero), OC_X_NEG) | BIT((w) - (x) < (zero), OC_X_POS)                   \
     | BIT((y) + (w) < (zero), OC_Y_NEG) | BIT((w) - (y) < (zero), OC_Y_POS)                 \
     | BIT((z) + (w) < (zero), OC_Z_NEG) | BIT((w) - (z) < (zero), OC_Z_POS))
#define OC_BIT(test, bit) ((test) ? (bit) : 0)

inline uint frustum_outcode(float4 c)
{
    return FRUSTUM_OUTCODE(c.x, c.y, c.z, c.w, 0.0f, OC_BIT);
}

inline uint frustum_outcode_d(double4 c)
{
    return FRUSTUM_OUTCODE(c.x, c.y, c.z, c.w, 0.0, OC_BIT);
}

/* The viewport transform of clip x, y, z given iw = 1/w (floats or float vectors): window x
 * and y in 1/256 px before rounding (y down), and window depth (z/w + 1)/2. viewport_vertex
 * and the vertex stage's lanes both use these, so their results are bit-identical. */
#define WIN_X_SUB(x, iw, hw) ((((x) * (iw) + 1.0f) * (hw)) * (float)SUB_ONE)
#define WIN_Y_SUB(y, iw, hh) (((1.0f - (y) * (iw)) * (hh)) * (float)SUB_ONE)
#define WIN_Z(z, iw) (((z) * (iw)) * 0.5f + 0.5f)

/* A vertex after the viewport transform (WinVert): 24.8 fixed-point window x/y (y down),
 * window depth (z/w + 1)/2 and 1/w. Computed for the vertices inside the guard band by
 * setup.cl's draw_vertices (8 lanes at a time, with the same WIN_* expressions and
 * rounding) and per clipped vertex by its clipper, so both are bit-identical. */
inline WinVert viewport_vertex(float4 c, float hw, float hh)
{
    WinVert v;
    float iw = 1.0f / c.w;
    /* round half to even (rint in the default rounding mode); the guard band keeps the
     * values in range */
    v.x = (int)RINTF(WIN_X_SUB(c.x, iw, hw));
    v.y = (int)RINTF(WIN_Y_SUB(c.y, iw, hh));
    v.z = WIN_Z(c.z, iw);
    v.iw = iw;
    return v;
}

/* The window position of a WinVert as the vertex stream holds it: an int2 (x, y), half the
 * bytes of a WinVert (setup reads x and y only), and not a struct of two ints, which PoCL
 * loads and stores field by field. */
inline int2 win_xy(WinVert v)
{
    return (int2)(v.x, v.y);
}

/* Edge function of the directed edge a->b at fixed-point point p, exact in 64 bits:
 * E(p) = (bx-ax)(py-ay) - (by-ay)(px-ax). Positive inside a positive-area triangle. */
inline long edge_fn(int ax, int ay, int bx, int by, int px, int py)
{
    return (long)(bx - ax) * (long)(py - ay) - (long)(by - ay) * (long)(px - ax);
}

/* D3D11 top-left rule for positive-area (clockwise on screen, y down) triangles: a top edge
 * is horizontal and runs left-to-right; a left edge runs upwards. A pixel centre exactly on
 * an edge is covered only if that edge is top or left, so a shared edge covers it once.
 * Returned as the minimum edge value that counts as inside: 0 for top-left, 1 otherwise. */
inline long edge_bias(int ax, int ay, int bx, int by)
{
    int dx = bx - ax, dy = by - ay;
    return (dy < 0 || (dy == 0 && dx > 0)) ? 0 : 1;
}

/* floor(a / d) for d > 0, exact in 64 bits (bin.cl, raster.cl; C division truncates towards
 * zero). */
inline long floor_div(long a, long d) { return a >= 0 ? a / d : -((-a + d - 1) / d); }

/* Does the frame's bin list (summary from bin.cl bin_scan_tiles: [0] its length, [1] set
 * when that overflowed) not fit the cap records of the entry buffer it was scattered
 * into? Then bin_scatter wrote nothing and raster_tiles draws nothing; the host scatters
 * and draws again with a larger buffer (clraster/pipeline/stages/bin.py BinStage.run, defer). */
#define BIN_LIST_OVER(summary, cap) ((summary)[1] != 0 || (summary)[0] > (cap))

inline int bb_x(int packed) { return packed & 0xFFFF; }
inline int bb_y(int packed) { return packed >> 16; }

/* A piece's three edge functions, set up at one pixel centre to be walked pixel by pixel.
 * Edge i is the edge opposite vertex i (v1 -> v2, v2 -> v0, v0 -> v1), so E_i / area is
 * vertex i's screen-space weight. e[i]: E_i at the centre minus the edge's top-left bias
 * (edge_bias), so that a centre is inside edge i iff its e[i] >= 0; sx[i] / sy[i]: what one
 * pixel right / down adds (-dy·256, dx·256). All exact in 64 bits. Setup's coverage bits of
 * small boxes, the raster and the occlusion queries set up their edges here, so they take
 * exactly the same centres. */
typedef struct { long e[3], sx[3], sy[3]; } PieceEdges;

ALWAYS_INLINE void set_edge(PieceEdges *E, int i, int ax, int ay, int bx, int by, int px,
                            int py)
{
    E->e[i] = edge_fn(ax, ay, bx, by, px, py) - edge_bias(ax, ay, bx, by);
    E->sx[i] = -(long)(by - ay) << SUBPIXEL_BITS;
    E->sy[i] = (long)(bx - ax) << SUBPIXEL_BITS;
}

/* The edges of the piece with 24.8 vertices (X0, Y0), (X1, Y1), (X2, Y2) at the centre of
 * pixel (x, y). */
ALWAYS_INLINE void piece_edges(int X0, int Y0, int X1, int Y1, int X2, int Y2, int x, int y,
                               PieceEdges *E)
{
    int px = (x << SUBPIXEL_BITS) + SUB_HALF, py = (y << SUBPIXEL_BITS) + SUB_HALF;
    set_edge(E, 0, X1, Y1, X2, Y2, px, py);
    set_edge(E, 1, X2, Y2, X0, Y0, px, py);
    set_edge(E, 2, X0, Y0, X1, Y1, px, py);
}

/* Is the centre k pixels right of and j pixels below the set-up one inside all three edges?
 * 0 or 1, the three tests combined with & (no branches). */
ALWAYS_INLINE int edges_inside(const PieceEdges *E, long k, long j)
{
    return (E->e[0] + k * E->sx[0] + j * E->sy[0] >= 0)
           & (E->e[1] + k * E->sx[1] + j * E->sy[1] >= 0)
           & (E->e[2] + k * E->sx[2] + j * E->sy[2] >= 0);
}

/* Move the set-up centre j pixels down. */
ALWAYS_INLINE void edges_down(PieceEdges *E, long j)
{
    E->e[0] += j * E->sy[0];
    E->e[1] += j * E->sy[1];
    E->e[2] += j * E->sy[2];
}

/* Piece.cover's bits (layout.py COVER_SPAN, COVER_KNOWN: bit k + 4j is column k, row j of
 * the piece's pixel box) of columns k0 .. k1 and rows j0 .. j1, all within 0 .. 3: setup
 * masks a box's centres with it, the raster the part of a box inside a tile. */
#if COVER_SPAN != 4
#error "cover_mask is written for COVER_SPAN == 4"
#endif
inline uint cover_mask(int k0, int k1, int j0, int j1)
{
    uint cols = ((0xFu << k0) & (0xFu >> (3 - k1))) * 0x1111u;
    return cols & (0xFFFFu << (4 * j0)) & (0xFFFFu >> (4 * (3 - j1)));
}

/* A piece's depth plane (setup.cl value_planes, from the unsnapped vertices): window depth
 * z0 at its reference pixel (x0, y0), the first column and row of its pixel box; dzdx, dzdy
 * per pixel; zlo, its nearest vertex's depth. */
typedef struct { float z0, dzdx, dzdy, zlo; int x0, y0; } DepthPlane;

ALWAYS_INLINE void depth_plane(__global const Piece *pc, DepthPlane *P)
{
    P->z0 = pc->z0; P->dzdx = pc->dzdx; P->dzdy = pc->dzdy; P->zlo = pc->zlo;
    P->x0 = bb_x(pc->bb_min); P->y0 = bb_y(pc->bb_min);
}

/* A fragment's depth in two steps, in this order wherever a fragment is depth-tested (the
 * raster's lanes, raster.cl depth_block8, too; and clraster/pipeline/reference/raster.py): the
 * plane's value at the start of row y, then at column x of that row, raised to zlo: a
 * covered centre up to 1/512 px outside the unsnapped triangle must not extrapolate past
 * its nearest vertex (the tile Hi-Z and the Hi-Z test rely on it). */
ALWAYS_INLINE float depth_row(const DepthPlane *P, int y)
{
    return P->z0 + P->dzdy * (float)(y - P->y0);
}

ALWAYS_INLINE float depth_at(const DepthPlane *P, float zrow, int x)
{
    return maxf(zrow + P->dzdx * (float)(x - P->x0), P->zlo);
}

/* Can edge a->b (with its top-left bias) be satisfied by some pixel centre of the pixel
 * rectangle [x0, x1] × [y0, y1]? The edge function is linear, so its maximum over the
 * rectangle is at the corner its gradient points to. */
inline bool edge_reaches(int ax, int ay, int bx, int by, int x0, int y0, int x1, int y1)
{
    int dx = bx - ax, dy = by - ay;          /* E = dx·(py − ay) − dy·(px − ax) */
    int px = ((dy < 0 ? x1 : x0) << SUBPIXEL_BITS) + SUB_HALF;
    int py = ((dx > 0 ? y1 : y0) << SUBPIXEL_BITS) + SUB_HALF;
    return edge_fn(ax, ay, bx, by, px, py) >= edge_bias(ax, ay, bx, by);
}

/* Does the piece cover no pixel centre of the rectangle for sure? (Exact test per edge,
 * conservative overall: a rectangle that passes all three may still be empty.) Binning
 * uses it to keep a thin diagonal triangle out of the tiles its box crosses but it does
 * not touch; the raster uses it per span. */
ALWAYS_INLINE bool rect_outside(int X0, int Y0, int X1, int Y1, int X2, int Y2,
                         int x0, int y0, int x1, int y1)
{
    return !edge_reaches(X1, Y1, X2, Y2, x0, y0, x1, y1)
        || !edge_reaches(X2, Y2, X0, Y0, x0, y0, x1, y1)
        || !edge_reaches(X0, Y0, X1, Y1, x0, y0, x1, y1);
}

/* Setup's word per triangle slot for binning (setup.cl writes it, bin.cl reads it):
 *   >= 0         the one tile of an ST_RASTER piece whose pixel box lies in one tile;
 *   TILE1_NONE   nothing to bin;
 *   TILE1_WALK   a piece or pieces whose tiles binning finds from the records;
 *   <= TILE1_FEW a piece whose box spans 2 x 1, 1 x 2 or 2 x 2 tiles: TILE1_FEW minus
 *                (top-left tile << 4 | mask), mask bit j set iff the piece's edges reach
 *                tile (tx0 + (j & 1), ty0 + (j >> 1)) (few_tile_mask: the test binning
 *                made per tile from the record, tile_missed), so binning counts such a
 *                piece without reading its record. (n_tiles <= 2^22, so the code fits.) */
#define TILE1_NONE (-1)
#define TILE1_WALK (-2)
#define TILE1_FEW (-3)

/* Whether a piece with 24.8 vertices (X0, Y0), (X1, Y1), (X2, Y2) and pixel box
 * [bx0, bx1] x [by0, by1] misses every pixel centre of tile (tx, ty) ∩ its box:
 * rect_outside on that rectangle (binning's per-tile test: bin.cl tile_missed on a record,
 * few_tile_mask in setup). */
ALWAYS_INLINE bool tile_box_outside(int X0, int Y0, int X1, int Y1, int X2, int Y2, int bx0,
                                    int by0, int bx1, int by1, int tx, int ty)
{
    int x0 = imax(bx0, tx << TILE_LOG2), x1 = imin(bx1, ((tx + 1) << TILE_LOG2) - 1);
    int y0 = imax(by0, ty << TILE_LOG2), y1 = imin(by1, ((ty + 1) << TILE_LOG2) - 1);
    return rect_outside(X0, Y0, X1, Y1, X2, Y2, x0, y0, x1, y1);
}

/* The TILE1_FEW mask of a piece with 24.8 vertices x, y and pixel box [bx0, bx1] x
 * [by0, by1] over tiles [tx0, tx1] x [ty0, ty1] (at most 2 x 2): bit j for the tile
 * (tx0 + (j & 1), ty0 + (j >> 1)) when it is inside the span and not tile_box_outside. */
ALWAYS_INLINE uint few_tile_mask(const int *x, const int *y, int bx0, int by0, int bx1,
                                 int by1, int tx0, int ty0, int tx1, int ty1)
{
    uint mask = 0;
    for (int j = 0; j < 4; ++j) {
        int tx = tx0 + (j & 1), ty = ty0 + (j >> 1);
        if (tx > tx1 || ty > ty1) continue;
        if (!tile_box_outside(x[0], y[0], x[1], y[1], x[2], y[2], bx0, by0, bx1, by1, tx, ty))
            mask |= 1u << j;
    }
    return mask;
}
