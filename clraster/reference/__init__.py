"""The NumPy twin of the OpenCL pipeline.

Each module mirrors one kernel file with the same inputs, outputs, integer rules and float32
operation order (vertex ↔ kernels/vertex.cl, setup ↔ setup.cl, bin ↔ bin.cl, raster ↔
raster.cl), so for the same input it produces the same triangle ids and depths. It is the
test oracle and the benchmark baseline, vectorized throughout (no per-pixel Python loops).
"""

from __future__ import annotations

import time

import numpy as np

from ..config import RasterConfig, guard_band_factors
from ..drawlist import PlanCache, plan_frame
from ..frame import Frame, FrameStats
from ..inputs import check_cull, check_size
from . import bin as bin_
from . import raster as raster_
from . import setup as setup_
from . import vertex as vertex_

__all__ = ["render"]


def render(target, camera, width: int, height: int, *, cull: str = "back",
           frustum: bool = True, cones: bool = True, config: RasterConfig | None = None
           ) -> Frame:
    """Render ``target`` (Mesh or Scene) with the NumPy twin; same arguments and outputs as
    `Renderer.render` (the same culling code decides what is drawn).

    ``config`` only matters for the tile size used by binning; like on the device, it never
    changes the image.
    """
    width, height = check_size(width, height)
    check_cull(cull)
    config = config or RasterConfig()
    t0 = time.perf_counter()
    plan = plan_frame(target, camera, width, height, cull=cull, frustum=frustum, cones=cones,
                      cache=PlanCache())
    t_cull = (time.perf_counter() - t0) * 1e3
    pool, fd = plan.pool, plan.frame
    counts = plan.draw_list.counts
    if fd.n_tris == 0:
        return Frame.empty(width, height, FrameStats.from_counts(counts, np.zeros(0, np.uint8)))
    kx, ky = guard_band_factors(width, height)
    t = {}
    t0 = time.perf_counter()
    clip, oc, win = vertex_.transform_draws(pool, fd, kx, ky, width, height)
    t1 = time.perf_counter()
    tri_verts, ids = setup_.draw_triangles(pool, fd)
    st = setup_.setup(clip, oc, win, tri_verts, ids, width, height, cull, kx, ky)
    t2 = time.perf_counter()
    order = bin_.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = bin_.bin_pieces(allp, order, width, height, config)
    t3 = time.perf_counter()
    depth, ids_img, bary, tested, passed = raster_.raster(st.clip_bary, tile_start, entries,
                                                          width, height, config)
    t4 = time.perf_counter()
    t = {"cull (host)": t_cull, "vertex": (t1 - t0) * 1e3, "setup": (t2 - t1) * 1e3,
         "bin": (t3 - t2) * 1e3, "raster": (t4 - t3) * 1e3}
    stats = FrameStats.from_counts(counts, st.status, clip_pieces=int(st.clip_pieces.size),
                                   binned_entries=int(entries.size), fragments_tested=tested,
                                   fragments_passed=passed)
    stats.timings_ms = t
    return Frame(depth, ids_img, bary, stats)
