"""Streamed frames: a frame's draws cut into bounded batches, each run through the stage chain
into the same frame buffers. Shared by the OpenCL renderer and the NumPy twin (plain NumPy over
the draw records and the passes' parameters).

Why the image cannot depend on where the batches are cut: the batches are consecutive runs
of the frame's draws in draw order, so every tile still sees its pieces in submission order;
each pass after the first loads the depth and ids written so far and tests against them as
if drawn in the same pass, and on equal depth the lower triangle id wins whatever the order.
The counts add up too: a triangle is set up, binned and rasterized once, in exactly one
pass, and the depth tests at a pixel happen in the same order (so fragments passed is the
same number).

The budget (`clraster.RasterConfig.batch_triangles` / ``batch_entries``) bounds both the
triangles of a pass and the entries of its bin list. The triangles are known before a pass;
the entries only after binning's count → scan step, so a pass whose list would be too long
reports its count instead of drawing (nothing drawn, nothing counted) and `stream_draws`
draws the same draws again in smaller batches. A single draw (one cluster, ≤ CLUSTER_MAX
triangles) is the smallest unit: alone, it is drawn whatever its bin list needs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .draws import FrameDraws
from .params import BinBudgetExceeded

__all__ = ["PassDraw", "draw_range", "stream_draws"]


#: pass_draw(batch, max_entries, into) → the frame buffers with ``batch`` drawn into
#: ``into`` (None: fresh cleared buffers); raises `BinBudgetExceeded` when its bin list
#: would exceed ``max_entries`` (None: draw whatever the bin list needs — a single draw).
PassDraw = Callable[[FrameDraws, "int | None", Any], Any]


def draw_range(fd: FrameDraws, d0: int, d1: int) -> FrameDraws:
    """Draws ``d0:d1`` of ``fd`` as a frame of their own: the same records with their places
    in the vertex and triangle streams rebased to start at 0 (the draws of a frame are laid
    out consecutively, so a run of them is one contiguous range of each stream)."""
    d = fd.draws[d0:d1].copy()
    if d.size == 0:
        return FrameDraws(d, 0, 0, fd.mvps, fd.mvps64, fd.zrows, fd.uplanes, fd.uclip)
    v_end = int(fd.draws["vert_base"][d1]) if d1 < fd.draws.size else fd.n_verts
    t_end = int(fd.draws["tri_base"][d1]) if d1 < fd.draws.size else fd.n_tris
    v0, t0 = int(d["vert_base"][0]), int(d["tri_base"][0])
    d["vert_base"] -= v0
    d["tri_base"] -= t0
    return FrameDraws(d, v_end - v0, t_end - t0, fd.mvps, fd.mvps64, fd.zrows, fd.uplanes,
                      fd.uclip)


def stream_draws(fd: FrameDraws, max_triangles: int, max_entries: int, pass_draw: PassDraw,
                 into: Any = None) -> Any:
    """Draw ``fd`` into ``into`` in consecutive batches of at most ``max_triangles``
    triangles and ``max_entries`` bin entries each (see the module docstring); returns the
    frame buffers of the last pass (``pass_draw(fd, None, into)`` once when ``fd`` has no
    draws, so an empty frame still gets its cleared buffers).

    A batch whose bin list would be too long is cut to a triangle count proportional to
    the entries it needed (so a dense region converges in a pass or two, not by halving),
    and the limit grows back by 2x after each pass that fits, up to ``max_triangles``, so
    a sparse region after a dense one is drawn in big batches again.
    """
    n = int(fd.draws.size)
    if n == 0:
        return pass_draw(fd, None, into)
    # triangle stream position of each draw's end: ends[i] = first triangle after draw i
    ends = np.empty(n, np.int64)
    ends[:-1] = fd.draws["tri_base"][1:]
    ends[-1] = fd.n_tris
    cap = max_triangles
    d0 = 0
    while d0 < n:
        start = int(fd.draws["tri_base"][d0])
        d1 = max(int(np.searchsorted(ends, start + cap, side="right")), d0 + 1)
        batch = fd if (d0 == 0 and d1 == n) else draw_range(fd, d0, d1)
        try:
            into = pass_draw(batch, None if d1 - d0 == 1 else max_entries, into)
        except BinBudgetExceeded as e:
            # strictly fewer triangles than this batch (it needed > max_entries): progress
            cap = max(1, (int(ends[d1 - 1]) - start) * max_entries // e.entries)
            continue
        d0 = d1
        cap = min(max_triangles, 2 * cap)
    return into
