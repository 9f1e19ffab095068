/* Exact occlusion queries ("samples passed", as GL_SAMPLES_PASSED with GL_LESS, but each pixel
 * counted at most once per box): per box, the number of pixels at which some fragment of the
 * box's 12 triangles would pass the depth test LESS against a given depth buffer, which is
 * only read.
 *
 * The boxes went through the renderer's own vertex, setup (cull "none", clipping at near) and
 * binning stages, so coverage follows the same rules as a rendered frame: 8 sub-pixel bits,
 * top-left rule, exact 64-bit edge functions, and the depth of a fragment is the very float32
 * value kernels/raster.cl would compute. Box b is faces 12b .. 12b+11 and the boxes were
 * submitted in order, so within a tile list the entries of one box are contiguous and box
 * numbers never decrease (clipped pieces keep their parent's place); a tile keeps one private
 * byte per pixel ("the current box passed here") and, when the next box starts, adds their
 * count over the run's pixel rectangle to the box's global counter and clears them. The
 * counter sum is order-independent, so the result is deterministic. A decreasing box number
 * (a broken ordering assumption) sets order_error instead of silently double-counting.
 *
 * clraster/pipeline/reference/query.py is the NumPy twin.
 */
#include "common.h"

/* QUERY_SPAN: columns per branch-free span of the pixel loop, a -D option from
 * clraster/base/config.py (speed only); a power of two that divides TILE_SIZE. */
#if !defined(QUERY_SPAN) || (QUERY_SPAN & (QUERY_SPAN - 1)) || QUERY_SPAN > TILE_SIZE
#error "QUERY_SPAN (clraster.base.config) must be a power of two <= TILE_SIZE"
#endif
/* BOX_TRIS (12, clraster/base/layout.py): box b is faces BOX_TRIS·b .. BOX_TRIS·b + 11. */

__kernel void query_tiles(__global const int *tile_start, __global const Piece *entries,
                          const int width, const int height, const int tiles_x,
                          __global const float *depth, __global uint *samples,
                          __global int *order_error)
{
    int tile = get_global_id(0);
    int tiles_y = (height + TILE_SIZE - 1) >> TILE_LOG2;
    if (tile >= tiles_x * tiles_y) return;
    int e0 = tile_start[tile], e1 = tile_start[tile + 1];
    if (e0 == e1) return;
    int tx0 = (tile % tiles_x) << TILE_LOG2, ty0 = (tile / tiles_x) << TILE_LOG2;
    int tw = min(TILE_SIZE, width - tx0), th = min(TILE_SIZE, height - ty0);

    /* the tile's depth (0 outside the image: masked lanes may read it, never use it) and
     * a byte per pixel: "the current box passed here" */
    float zt[TILE_PIXELS];
    uchar hit[TILE_PIXELS];
    for (int ly = 0; ly < TILE_SIZE; ++ly)
        for (int lx = 0; lx < TILE_SIZE; ++lx) {
            int i = (ly << TILE_LOG2) + lx;
            zt[i] = (lx < tw && ly < th) ? depth[(size_t)(ty0 + ly) * width + tx0 + lx] : 0.0f;
            hit[i] = 0;
        }

    int run = -1;                                   /* box whose entries are being walked */
    int rx0 = TILE_SIZE, rx1 = -1, ry0 = TILE_SIZE, ry1 = -1;   /* its pixels so far */
    for (int k = e0; k <= e1; ++k) {
        int box = k < e1 ? entries[k].id / BOX_TRIS : -2;
        if (box != run) {
            /* the run ends: count its pixels once, clear them, add to the box's total */
            uint count = 0;
            for (int ly = ry0; ly <= ry1; ++ly)
                for (int lx = rx0; lx <= rx1; ++lx) {
                    int i = (ly << TILE_LOG2) + lx;
                    count += hit[i];
                    hit[i] = 0;
                }
            if (count) atomic_add(&samples[run], count);
            if (box < run && box != -2) order_error[0] = 1;
            run = box;
            rx0 = ry0 = TILE_SIZE;
            rx1 = ry1 = -1;
        }
        if (k == e1) break;
        __global const Piece *pc = &entries[k];
        int lx0 = max(bb_x(pc->bb_min) - tx0, 0), lx1 = min(bb_x(pc->bb_max) - tx0, tw - 1);
        int ly0 = max(bb_y(pc->bb_min) - ty0, 0), ly1 = min(bb_y(pc->bb_max) - ty0, th - 1);
        if (lx0 > lx1 || ly0 > ly1) continue;
        rx0 = min(rx0, lx0); rx1 = max(rx1, lx1);
        ry0 = min(ry0, ly0); ry1 = max(ry1, ly1);
        /* coverage and depth exactly as raster_tiles (kernels/raster.cl): the same edges
         * (common.h piece_edges, set up at the tile's first column of row ly0) and the same
         * float32 depth (depth_row, depth_at) at each pixel centre; walked in branch-free
         * spans of QUERY_SPAN columns, lanes outside [lx0, lx1] masked */
        PieceEdges E;
        piece_edges(pc->x[0], pc->y[0], pc->x[1], pc->y[1], pc->x[2], pc->y[2], tx0,
                    ty0 + ly0, &E);
        DepthPlane P;
        depth_plane(pc, &P);
        for (int ly = ly0; ly <= ly1; ++ly) {
            int row = ly << TILE_LOG2;
            float zrow = depth_row(&P, ty0 + ly);
            for (int cx = lx0 & ~(QUERY_SPAN - 1); cx <= lx1; cx += QUERY_SPAN)
            for (int j = 0; j < QUERY_SPAN; ++j) {
                int lx = cx + j;
                bool in = lx >= lx0 && lx <= lx1 && edges_inside(&E, lx, 0);
                float z = depth_at(&P, zrow, tx0 + lx);
                int i = row + lx;
                hit[i] |= (uchar)(in && z < zt[i]);   /* LESS: equal depth does not pass */
            }
            edges_down(&E, 1);
        }
    }
}
