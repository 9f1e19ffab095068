"""Line segments, the part shared by the OpenCL line renderer (`clraster.lines`) and its NumPy
twin (`clraster.reference.lines`): the checks of their inputs, the clipping against user
clip planes both do on the host, the statistics and the `LineFrame` both return. The rules
themselves are in `clraster.lines`' docstring (and kernels/lines.cl). Plain NumPy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..base.checks import check_mat4
from ..base.layout import (
    LS_ACCEPTED,
    LS_ACCEPTED_DEGENERATE,
    LS_CLIPPED,
    LS_CLIPPED_AWAY,
    LS_CLIPPED_DEGENERATE,
    LS_INVALID,
    LS_REJECTED,
)

__all__ = ["MAX_SEGMENTS", "STAT_KEYS", "LineFrame", "check_bias", "check_depth",
           "check_segments", "check_view_proj", "clip_to_planes", "merge_plane_status",
           "stats_from_status", "undo_plane_compaction"]

#: Segment indices are int32 in ``line_id``, and 0xFFFFFFFF clears the resolve buffer.
MAX_SEGMENTS = int(np.iinfo(np.int32).max)

STAT_KEYS = ("segments", "invalid", "trivially_rejected", "trivially_accepted", "clipped",
             "clipped_away", "degenerate", "rasterized", "fragments", "fragments_passed")


def clip_to_planes(seg: np.ndarray, planes: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clip world-space segments against user clip planes before the view volume (both
    renderers call this, so they see the same segments), as OpenGL clips lines against
    gl_ClipDistance: the part of each segment with a·x + b·y + c·z + d >= 0 for every plane.

    Per segment, the kept parameter range [t0, t1] of p0 + t·(p1 − p0) is narrowed plane by
    plane (Liang–Barsky) with distances in float64 from the float32 endpoints; a clipped
    endpoint is formed in float64 and rounded to float32 once.

    Args:
        seg: float32 (N, 2, 3) (`check_segments`). planes: float64 (K, 4) or None.

    Returns:
        (segments float32 (M, 2, 3) to draw, their indices into ``seg`` int64 (M,),
        status uint8 (N,): LS_REJECTED where both endpoints lie outside one plane,
        LS_CLIPPED_AWAY where the planes together leave nothing, LS_CLIPPED where a plane
        cut the segment (refined by the view-volume result, `merge_plane_status`), 255
        where no plane touched it).
    """
    n = seg.shape[0]
    status = np.full(n, 255, np.uint8)
    if planes is None or n == 0:
        return seg, np.arange(n, dtype=np.int64), status
    p = seg.astype(np.float64)
    with np.errstate(all="ignore"):   # NaN/Inf endpoints: no plane test, the kernel says
        d = np.einsum("nej,kj->nek", p, planes[:, :3]) + planes[:, 3]   # (N, 2, K)
        out0, out1 = d[:, 0] < 0.0, d[:, 1] < 0.0
        t = d[:, 0] / (d[:, 0] - d[:, 1])
        t0 = np.where(out0 & ~out1, t, 0.0).max(axis=1)
        t1 = np.where(out1 & ~out0, t, 1.0).min(axis=1)
    rejected = (out0 & out1).any(axis=1)
    cut = (out0 | out1).any(axis=1) & ~rejected
    away = cut & ~(t0 <= t1)
    status[cut] = LS_CLIPPED
    status[away] = LS_CLIPPED_AWAY
    status[rejected] = LS_REJECTED
    keep = np.flatnonzero((status == 255) | (status == LS_CLIPPED))
    out = seg[keep].copy()
    c = np.flatnonzero(status[keep] == LS_CLIPPED)
    if c.size:
        a, b = p[keep[c], 0], p[keep[c], 1]
        out[c, 0] = (a + t0[keep[c], None] * (b - a)).astype(np.float32)
        out[c, 1] = (a + t1[keep[c], None] * (b - a)).astype(np.float32)
    return np.ascontiguousarray(out), keep, status


def undo_plane_compaction(line_id: np.ndarray, status: np.ndarray, keep: np.ndarray,
                          pre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line ids and statuses of the segments `clip_to_planes` drew (``keep``) back in terms
    of the caller's segments: ids int32 (H, W) mapped to input indices, statuses merged
    (`merge_plane_status`)."""
    line_id = np.where(line_id >= 0, keep[np.maximum(line_id, 0)], -1).astype(np.int32)
    return line_id, merge_plane_status(pre, keep, status)


def merge_plane_status(pre: np.ndarray, keep: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Per-segment status (uint8 (N,)) from `clip_to_planes`' ``pre`` and the view-volume
    status ``kernel`` of the drawn segments ``keep``: untouched segments take the kernel's;
    a segment a user plane cut counts as clipped (its view-volume result moved to the
    clipped codes: accepted → LS_CLIPPED, degenerate → LS_CLIPPED_DEGENERATE, rejected or
    clipped away → LS_CLIPPED_AWAY)."""
    st = pre.copy()
    k = np.asarray(kernel, np.uint8)
    cut = st[keep] == LS_CLIPPED
    moved = np.select([k == LS_ACCEPTED, k == LS_ACCEPTED_DEGENERATE,
                       (k == LS_REJECTED) | (k == LS_CLIPPED_AWAY)],
                      [LS_CLIPPED, LS_CLIPPED_DEGENERATE, LS_CLIPPED_AWAY],
                      k.astype(np.int64)).astype(np.uint8)
    st[keep] = np.where(cut, moved, k).astype(np.uint8)
    return st


def stats_from_status(status: np.ndarray, fragments: int, passed: int) -> dict[str, int]:
    """Stats dict from the per-segment status codes (uint8/int (N,)) and fragment counts."""
    c = np.bincount(np.asarray(status, np.int64), minlength=8)
    return {
        "segments": int(status.size),
        "invalid": int(c[LS_INVALID]),
        "trivially_rejected": int(c[LS_REJECTED]),
        "trivially_accepted": int(c[LS_ACCEPTED] + c[LS_ACCEPTED_DEGENERATE]),
        "clipped": int(c[LS_CLIPPED] + c[LS_CLIPPED_AWAY] + c[LS_CLIPPED_DEGENERATE]),
        "clipped_away": int(c[LS_CLIPPED_AWAY]),
        "degenerate": int(c[LS_ACCEPTED_DEGENERATE] + c[LS_CLIPPED_DEGENERATE]),
        "rasterized": int(c[LS_ACCEPTED] + c[LS_CLIPPED]),
        "fragments": int(fragments),
        "fragments_passed": int(passed),
    }


@dataclass
class LineFrame:
    """Rendered line segments.

    Attributes:
        line_id: (H, W) int32 index of the segment drawn at each pixel, −1 where none.
        depth: (H, W) float32 window depth of that segment's fragment, 1.0 where none.
        stats: counts (see the module docstring): segments, invalid, trivially_rejected,
            trivially_accepted, clipped, clipped_away, degenerate, rasterized, fragments,
            fragments_passed.
    """

    line_id: np.ndarray
    depth: np.ndarray
    stats: dict[str, int] = field(default_factory=dict)

    @classmethod
    def empty(cls, width: int, height: int, stats: dict[str, int] | None = None) -> LineFrame:
        return cls(np.full((height, width), -1, np.int32), np.ones((height, width), np.float32),
                   stats if stats is not None else stats_from_status(np.zeros(0, np.uint8), 0, 0))

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels where some segment is drawn."""
        return self.line_id >= 0

    @property
    def width(self) -> int:
        return int(self.line_id.shape[1])

    @property
    def height(self) -> int:
        return int(self.line_id.shape[0])


# -- input validation ------------------------------------------------------------------------

def check_segments(segments: npt.ArrayLike) -> np.ndarray:
    """``segments`` as a C-contiguous float32 (N, 2, 3) array (never modified); values beyond
    float32 range become ±Inf (and those segments count as invalid)."""
    try:
        arr = np.asarray(segments)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"segments must be an (N, 2, 3) array of world-space endpoints; "
                         f"could not convert {type(segments).__name__} ({exc})") from exc
    if arr.size == 0 and arr.ndim == 1:
        arr = arr.reshape(0, 2, 3)
    if arr.ndim != 3 or arr.shape[1:] != (2, 3):
        raise ValueError(f"segments must have shape (N, 2, 3) (N segments, 2 endpoints, "
                         f"x y z), got shape {arr.shape}; one segment is segments[None]")
    if arr.dtype.kind not in "iuf" and not (arr.size == 0 and not isinstance(segments,
                                                                             np.ndarray)):
        raise ValueError(f"segments must have a real numeric dtype (float or integer), got "
                         f"{arr.dtype}")
    if arr.shape[0] > MAX_SEGMENTS - 1:
        raise ValueError(f"too many segments ({arr.shape[0]}): line ids are int32, so at most "
                         f"{MAX_SEGMENTS - 1} per call; draw them in several calls")
    with np.errstate(over="ignore", invalid="ignore"):
        return np.ascontiguousarray(arr, dtype=np.float32)


def check_view_proj(view_proj: Any, width: int, height: int) -> np.ndarray:
    """Row-major float32 (4, 4) view-projection from a matrix or a camera (anything with
    ``view_projection(width, height)``, e.g. `clraster.Camera`), validated."""
    if hasattr(view_proj, "view_projection"):
        view_proj = view_proj.view_projection(width, height)
    m = check_mat4(view_proj, "view_proj (projection @ view, or a clraster.Camera)")
    with np.errstate(over="ignore"):
        m32 = m.astype(np.float32)
    if not np.all(np.isfinite(m32)):
        raise ValueError("view_proj overflows float32 (an entry above ~3.4e38); rescale it")
    return np.ascontiguousarray(m32)


def check_depth(depth: Any, width: int, height: int) -> np.ndarray | None:
    """The optional depth buffer: None, or a C-contiguous float32 (H, W) array without NaN."""
    if depth is None:
        return None
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"depth must be a float32 (H, W) NumPy array (e.g. Frame.depth) or "
                         f"None, got {type(depth).__name__}")
    if depth.dtype != np.float32:
        raise ValueError(f"depth must have dtype float32 (window depth, e.g. Frame.depth), got "
                         f"{depth.dtype}; convert with depth.astype(np.float32)")
    if depth.shape != (height, width):
        raise ValueError(f"depth must have shape (height, width) = ({height}, {width}) to "
                         f"match the image, got {depth.shape}")
    if np.isnan(depth).any():
        raise ValueError("depth contains NaN; a depth buffer holds window depths in [0, 1] "
                         "(1.0 = nothing drawn)")
    return np.ascontiguousarray(depth)


def check_bias(depth_bias: Any) -> np.float32:
    if isinstance(depth_bias, bool) or not isinstance(depth_bias, (int, float, np.integer,
                                                                   np.floating)):
        raise ValueError(f"depth_bias must be a real number, got {depth_bias!r}")
    with np.errstate(over="ignore"):
        b = np.float32(depth_bias)
    if not np.isfinite(b):
        raise ValueError(f"depth_bias must be finite in float32, got {depth_bias!r}")
    return b
