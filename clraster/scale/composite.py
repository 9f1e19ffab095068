"""Sort-last compositing: frames of disjoint parts of one scene merged into the frame of the
whole (plain NumPy; no Dask, no OpenCL).

The operator. Per pixel, keep the fragment with the lexicographically smallest
``(depth, triangle id)``, comparing ids as unsigned 32-bit integers so that the background
id −1 (0xFFFFFFFF) is larger than every drawn id. Its barycentrics come with it. Overdraw
(fragments tested per pixel), where both frames have it, is summed.

Why this is exactly the single-machine frame. The raster stage replaces a pixel's
``(zb, wd)`` by a fragment's ``(z, id)`` iff ``z < zb or (z == zb and id < wd)``, against a
clear value that nothing beats (kernels/raster.cl; streamed and two-phase passes load what
earlier passes wrote and test the same way). So a frame's pixel holds the minimum, in this
order, of all the fragments that cover it, whatever order they are drawn in. A fragment's
values (depth, barycentrics) depend only on its own triangle, its instance's matrix and the
frame size, not on what else is drawn; and culling (frustum, normal cones, Hi-Z occlusion)
is conservative, so a part's frame is the minimum over exactly that part's fragments. The
minimum over the parts of the minima over their fragments is the minimum over all
fragments: the single-machine frame, bit for bit.

Why any reduction tree (or binary-swap, radix-k) gives that same frame. ``min`` under a
total order is associative and commutative. The order here is total on what frames hold:
depths are finite and in [0, 1] (no NaN reaches a frame: triangles with a NaN/Inf vertex are
dropped), and two drawn fragments of different parts never have equal keys, because the
parts partition the triangles, so their ids differ. (Equal float depths with different
bit patterns, −0.0 and +0.0, are then still ordered by the id, the same way the raster
stage orders them.) The background ``(1.0, 0xFFFFFFFF)`` is the identity element: a drawn
fragment has depth < 1.0 (the LESS test against the clear value 1.0 never lets z = 1.0
through), and even at depth 1.0 its id would win the tie. So a drawn pixel is never lost to
background, and background never invents a pixel.

Frames here are `clraster.Frame` objects with the renderer's dtypes: depth float32 (H, W),
triangle_id int32 (H, W), barycentrics float32 (H, W, 3), overdraw int32 (H, W) or None.

Cropped frames. A part of a spatially split scene covers a small rectangle of the screen; the
rest of its frame is background, the operator's identity. `Crop` keeps only the bounding
rectangle of the covered pixels and `composite_crops` merges two of them into their union
rectangle, so what moves between workers and what the operator touches scales with the
parts' screen footprints, not with W × H (IceT's bounding-box culling of empty regions does
the same). `uncrop` restores the full frame. Results are the same as full frames', bit for
bit: outside a crop every pixel is background.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..output.frame import Frame, FrameStats

__all__ = ["Crop", "composite", "composite_crops", "composite_into", "composite_tree", "crop",
           "merge_stats", "uncrop"]


def _check_pair(a: Frame, b: Frame) -> None:
    if a.depth.shape != b.depth.shape:
        raise ValueError(f"cannot composite a {a.width}x{a.height} frame with a "
                         f"{b.width}x{b.height} one: render every part at the same size")
    for f in (a, b):
        bary = f.need_barycentrics()   # frames rendered with outputs including "bary"
        if (f.depth.dtype != np.float32 or f.triangle_id.dtype != np.int32
                or bary.dtype != np.float32
                or bary.shape != f.depth.shape + (3,)
                or f.triangle_id.shape != f.depth.shape):
            raise ValueError("frames to composite need depth float32 (H, W), triangle_id "
                             "int32 (H, W) and barycentrics float32 (H, W, 3), got "
                             f"{f.depth.dtype} {f.depth.shape}, {f.triangle_id.dtype} "
                             f"{f.triangle_id.shape}, {bary.dtype} {bary.shape}")
    if a.reversed_z != b.reversed_z:
        raise ValueError("cannot composite a reversed-Z frame with an ordinary one: render "
                         "every part with the same reversed_z")


def _b_wins(a: Frame, b: Frame) -> np.ndarray:
    """bool (H, W): where ``(b.depth, b.id)`` is lexicographically below ``(a.depth, a.id)``,
    ids compared as uint32 (background −1 is the largest). Reversed-Z frames (nearer is
    larger) compare −depth, the renderer's own depth-test key."""
    da, db = (-a.depth, -b.depth) if a.reversed_z else (a.depth, b.depth)
    ia = a.triangle_id.view(np.uint32)
    ib = b.triangle_id.view(np.uint32)
    return (db < da) | ((db == da) & (ib < ia))


def merge_stats(a: FrameStats, b: FrameStats) -> FrameStats:
    """Counts of two parts added field by field; timings added per key (the work of both).

    Triangle counts of the parts of a scene add up to the whole scene's (each triangle is
    in one part). Instance and cluster counts are the parts' own: a part re-clusters its
    share of a mesh, and an instance split across parts counts once per part."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(FrameStats):
        if f.name == "timings_ms":
            t = dict(a.timings_ms)
            for k, v in b.timings_ms.items():
                t[k] = t.get(k, 0.0) + v
            out[f.name] = t
        else:
            out[f.name] = getattr(a, f.name) + getattr(b, f.name)
    return FrameStats(**out)


def composite_into(a: Frame, b: Frame) -> Frame:
    """Composite ``b`` into ``a`` in place (``a``'s arrays are overwritten; they must be
    writeable) and return ``a``. Same result as `composite`; saves the copies of ``a``."""
    _check_pair(a, b)
    take = _b_wins(a, b)
    np.copyto(a.depth, b.depth, where=take)
    np.copyto(a.triangle_id, b.triangle_id, where=take)
    np.copyto(a.need_barycentrics(), b.need_barycentrics(), where=take[..., None])
    if a.overdraw is not None and b.overdraw is not None:
        a.overdraw += b.overdraw
    else:
        a.overdraw = None
    a.stats = merge_stats(a.stats, b.stats)
    a.fates = None
    return a


def composite(a: Frame, b: Frame) -> Frame:
    """The sort-last compositing operator: a new frame, per pixel the fragment of ``a`` or
    ``b`` with the smaller ``(depth, uint32(triangle id))`` (see the module docstring for why
    this is associative, commutative and equal to the single-machine frame).

    Args:
        a, b: frames of the same size (depth float32 (H, W), triangle_id int32 (H, W),
            barycentrics float32 (H, W, 3)) of disjoint sets of triangles with their final
            (scene) ids.

    Returns:
        A new `Frame`: depth, triangle_id and barycentrics of the winner per pixel;
        overdraw int32 (H, W) = a.overdraw + b.overdraw where both have it, else None;
        stats = `merge_stats` of both; fates None. Neither input is changed.
    """
    _check_pair(a, b)
    out = Frame(a.depth.copy(), a.triangle_id.copy(), a.need_barycentrics().copy(), a.stats,
                overdraw=None if a.overdraw is None else a.overdraw.copy(),
                reversed_z=a.reversed_z)
    return composite_into(out, b)


def composite_tree(frames: Sequence[Frame]) -> Frame:
    """Composite ``frames`` by a pairwise tree: level by level, frame 2k with frame 2k + 1
    (an odd one out goes up unchanged), ceil(log2 N) levels and N − 1 operations. Equals a
    left-to-right fold, or any other order (the operator is associative and commutative).

    The input frames are not changed. One frame is returned as a copy. Raises ValueError
    on an empty sequence or frames of different sizes.
    """
    level = list(frames)
    if not level:
        raise ValueError("composite_tree needs at least one frame")
    if len(level) == 1:
        f = level[0]
        return Frame(f.depth.copy(), f.triangle_id.copy(), f.need_barycentrics().copy(), f.stats,
                     overdraw=None if f.overdraw is None else f.overdraw.copy(),
                     reversed_z=f.reversed_z)
    owned = [False] * len(level)   # a result of this function may be composited in place
    while len(level) > 1:
        nxt, nxt_owned = [], []
        for k in range(0, len(level) - 1, 2):
            a, b = level[k], level[k + 1]
            nxt.append(composite_into(a, b) if owned[k] else composite(a, b))
            nxt_owned.append(True)
        if len(level) % 2:
            nxt.append(level[-1])
            nxt_owned.append(owned[-1])
        level, owned = nxt, nxt_owned
    return level[0]


@dataclass
class Crop:
    """The covered rectangle of a ``width`` × ``height`` frame: ``frame`` holds its pixels
    (rows ``y0:y0 + frame.height``, columns ``x0:x0 + frame.width`` of the full image, same
    dtypes and conventions); every pixel outside is background (depth 1.0, id −1,
    barycentrics 0, overdraw 0). An empty crop has a 0 × 0 frame."""

    frame: Frame
    x0: int
    y0: int
    width: int
    height: int

    @property
    def rect(self) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1), end-exclusive."""
        return (self.x0, self.y0, self.x0 + self.frame.width, self.y0 + self.frame.height)


def _sub(f: Frame, x0: int, y0: int, x1: int, y1: int, copy: bool) -> Frame:
    def take(a):
        if a is None:
            return None
        v = a[y0:y1, x0:x1]
        return v.copy() if copy else v

    return Frame(take(f.depth), take(f.triangle_id), take(f.barycentrics), f.stats,
                 overdraw=take(f.overdraw), reversed_z=f.reversed_z)


def crop(frame: Frame) -> Crop:
    """``frame`` cut to the bounding rectangle of its non-background pixels (a drawn id, or
    with overdraw, any fragment tested); copies, so the crop does not keep the full frame."""
    used = frame.triangle_id >= 0
    if frame.overdraw is not None:
        used = used | (frame.overdraw != 0)
    rows = np.flatnonzero(used.any(axis=1))
    if rows.size == 0:
        return Crop(_sub(frame, 0, 0, 0, 0, True), 0, 0, frame.width, frame.height)
    cols = np.flatnonzero(used[rows[0]:rows[-1] + 1].any(axis=0))
    x0, x1, y0, y1 = int(cols[0]), int(cols[-1]) + 1, int(rows[0]), int(rows[-1]) + 1
    return Crop(_sub(frame, x0, y0, x1, y1, True), x0, y0, frame.width, frame.height)


def _blank(width: int, height: int, overdraw: bool, stats: FrameStats,
           reversed_z: bool = False) -> Frame:
    f = Frame.empty(width, height, stats, reversed_z=reversed_z)
    if overdraw:
        f.overdraw = np.zeros((height, width), np.int32)
    return f


def uncrop(c: Crop) -> Frame:
    """The full ``c.width`` × ``c.height`` frame of a `Crop` (background outside it)."""
    out = _blank(c.width, c.height, c.frame.overdraw is not None, c.frame.stats,
                 c.frame.reversed_z)
    x0, y0, x1, y1 = c.rect
    v = _sub(out, x0, y0, x1, y1, False)
    for dst, src in ((v.depth, c.frame.depth), (v.triangle_id, c.frame.triangle_id),
                     (v.barycentrics, c.frame.barycentrics), (v.overdraw, c.frame.overdraw)):
        if dst is not None:
            dst[...] = src
    return out


def composite_crops(a: Crop, b: Crop) -> Crop:
    """`composite` of two cropped frames of the same image size: a new `Crop` over the union
    of their rectangles (neither input is changed). Equal to cropping the composite of the
    two full frames, except that the rectangle may include background rows and columns."""
    if (a.width, a.height) != (b.width, b.height):
        raise ValueError(f"cannot composite crops of a {a.width}x{a.height} and a "
                         f"{b.width}x{b.height} frame")
    for c in (a, b):
        _check_pair(c.frame, c.frame)
    if a.frame.reversed_z != b.frame.reversed_z:
        raise ValueError("cannot composite a reversed-Z frame with an ordinary one: render "
                         "every part with the same reversed_z")
    empty_a, empty_b = a.frame.depth.size == 0, b.frame.depth.size == 0
    od = a.frame.overdraw is not None and b.frame.overdraw is not None
    if empty_a or empty_b:
        keep = b if empty_a else a
        f = keep.frame
        out = Frame(f.depth.copy(), f.triangle_id.copy(), f.need_barycentrics().copy(),
                    merge_stats(a.frame.stats, b.frame.stats),
                    overdraw=f.overdraw.copy() if od and f.overdraw is not None else None,
                    reversed_z=f.reversed_z)
        return Crop(out, keep.x0, keep.y0, keep.width, keep.height)
    ra, rb = a.rect, b.rect
    x0, y0 = min(ra[0], rb[0]), min(ra[1], rb[1])
    x1, y1 = max(ra[2], rb[2]), max(ra[3], rb[3])
    out = _blank(x1 - x0, y1 - y0, od, a.frame.stats, a.frame.reversed_z)
    va = _sub(out, ra[0] - x0, ra[1] - y0, ra[2] - x0, ra[3] - y0, False)
    va.depth[...] = a.frame.depth
    va.triangle_id[...] = a.frame.triangle_id
    va.need_barycentrics()[...] = a.frame.barycentrics
    if od and va.overdraw is not None:   # od: both parts (so the blank) have overdraw
        va.overdraw[...] = a.frame.overdraw
    vb = _sub(out, rb[0] - x0, rb[1] - y0, rb[2] - x0, rb[3] - y0, False)
    composite_into(vb, b.frame)   # writes through the views into out's arrays
    out.stats = vb.stats
    if not od:
        out.overdraw = None
    return Crop(out, x0, y0, a.width, a.height)
