"""The NumPy twin of the OpenCL pipeline.

Each module mirrors one kernel file with the same inputs, outputs, integer rules and float32
operation order (vertex ↔ kernels/vertex.cl, setup ↔ setup.cl, bin ↔ bin.cl, raster ↔
raster.cl), so for the same input it produces the same triangle ids and depths. It is the
test oracle and the benchmark baseline, vectorized throughout (no per-pixel Python loops).
"""

from __future__ import annotations

import numpy as np

from ..config import RasterConfig, guard_band_factors
from ..frame import Frame, FrameStats
from ..inputs import check_cull, check_mesh, check_size, mvp_matrix
from . import bin as bin_
from . import raster as raster_
from . import setup as setup_
from . import vertex as vertex_

__all__ = ["render"]


def render(mesh, camera, width: int, height: int, *, cull: str = "back",
           config: RasterConfig | None = None) -> Frame:
    """Render ``mesh`` with the NumPy twin; same arguments and outputs as `Renderer.render`.

    ``config`` only matters for the tile size used by binning; like on the device, it never
    changes the image.
    """
    width, height = check_size(width, height)
    check_cull(cull)
    config = config or RasterConfig()
    mvp = mvp_matrix(camera, width, height)
    verts, faces = check_mesh(mesh)
    m = faces.shape[0]
    if m == 0:
        return Frame.empty(width, height)
    kx, ky = guard_band_factors(width, height)
    clip, oc, win = vertex_.transform(verts, mvp, kx, ky, width, height)
    st = setup_.setup(clip, oc, win, faces, width, height, cull, kx, ky)
    order = bin_.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = bin_.bin_pieces(allp, order, width, height, config)
    depth, ids, bary, tested, passed = raster_.raster(st.clip_bary, tile_start, entries, width,
                                                      height, config)
    stats = FrameStats.from_status(st.status, clip_pieces=int(st.clip_pieces.size),
                                   binned_entries=int(entries.size), fragments_tested=tested,
                                   fragments_passed=passed)
    return Frame(depth, ids, bary, stats)
