"""NumPy twin of kernels/lines.cl: line segments, bit-identical to the OpenCL path.

The same float32 transform, float64 Cohen–Sutherland clipper, viewport snap
(`clraster.reference.vertex.viewport`, the twin of common.h's viewport_vertex) and exact
integer raster rule as the kernel; see kernels/lines.cl and `clraster.lines` for the rules.
Vectorized over segments (the clipper loops over the 6 planes only) and over fragments
(processed in chunks, so memory stays bounded); the atomic-min resolve of the kernels is a
lexicographic (depth bits, segment index) minimum per pixel here.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from ...base.checks import check_clip_planes, check_size
from ...base.layout import (
    LINE_DTYPE,
    LS_ACCEPTED,
    LS_ACCEPTED_DEGENERATE,
    LS_CLIPPED,
    LS_CLIPPED_AWAY,
    LS_CLIPPED_DEGENERATE,
    LS_INVALID,
    LS_REJECTED,
    OC_X_NEG,
    OC_X_POS,
    OC_Y_NEG,
    OC_Y_POS,
    OC_Z_NEG,
    OC_Z_POS,
    SUBPIXEL_BITS,
    ZMIN_CLEAR,
)
from ..segments import (
    LineFrame,
    check_bias,
    check_depth,
    check_segments,
    check_view_proj,
    clip_to_planes,
    stats_from_status,
    undo_plane_compaction,
)
from .vertex import viewport

__all__ = ["LINE_DTYPE", "raster", "render_lines", "setup"]

F32 = np.float32
SUB_HALF = 1 << (SUBPIXEL_BITS - 1)
#: Smallest normal float32 (FLT_MIN): endpoints with w below it have no window position.
FLT_MIN = F32(np.finfo(np.float32).tiny)
#: Clipping order of kernels/lines.cl LPLANE_BIT: near, far, left, right, bottom, top.
PLANE_BITS = (OC_Z_NEG, OC_Z_POS, OC_X_NEG, OC_X_POS, OC_Y_NEG, OC_Y_POS)
#: Fragments per chunk of the raster (bounds the twin's memory, not its result).
CHUNK_FRAGMENTS = 1 << 21


def clip_positions(seg: np.ndarray, mvp: np.ndarray) -> np.ndarray:
    """float32 (N, 2, 4) clip positions of float32 (N, 2, 3) endpoints (seg_clip)."""
    m = mvp.reshape(16)
    x, y, z = seg[..., 0], seg[..., 1], seg[..., 2]
    c = np.empty(seg.shape[:-1] + (4,), F32)
    with np.errstate(all="ignore"):
        for r in range(4):
            c[..., r] = ((m[4 * r] * x + m[4 * r + 1] * y) + m[4 * r + 2] * z) + m[4 * r + 3]
    return c


def outcodes(c: np.ndarray) -> np.ndarray:
    """6-bit frustum outcodes (uint32) of clip positions (..., 4), float32 or float64."""
    x, y, z, w = c[..., 0], c[..., 1], c[..., 2], c[..., 3]
    oc = np.zeros(c.shape[:-1], np.uint32)
    with np.errstate(all="ignore"):
        for bit, d in ((OC_X_NEG, x + w), (OC_X_POS, w - x), (OC_Y_NEG, y + w),
                       (OC_Y_POS, w - y), (OC_Z_NEG, z + w), (OC_Z_POS, w - z)):
            oc |= np.where(d < 0, np.uint32(bit), np.uint32(0))
    return oc


def _plane_dist(k: int, v: np.ndarray) -> np.ndarray:
    x, y, z, w = v[..., 0], v[..., 1], v[..., 2], v[..., 3]
    return (z + w, w - z, x + w, w - x, y + w, w - y)[k]


def _on_plane(k: int, v: np.ndarray) -> None:
    """Put the points v (K, 4) exactly on plane k, in place."""
    coord = (2, 2, 0, 0, 1, 1)[k]
    v[:, coord] = -v[:, 3] if k % 2 == 0 else v[:, 3]


def clip_segments(p0: np.ndarray, p1: np.ndarray, o0: np.ndarray, o1: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cohen–Sutherland clip (clip_segment in lines.cl), vectorized over K segments.

    Args: float32 (K, 4) endpoints and their outcodes (o0 & o1 == 0, o0 | o1 != 0).
    Returns: alive bool (K,) and the clipped float32 endpoints (K, 4) each (rows of dead
    segments are meaningless).
    """
    a, b = p0.astype(np.float64), p1.astype(np.float64)
    oa, ob = o0.astype(np.uint32).copy(), o1.astype(np.uint32).copy()
    alive = np.ones(a.shape[0], bool)
    with np.errstate(all="ignore"):
        for k, bit in enumerate(PLANE_BITS):
            alive &= (oa & ob) == 0
            act = alive & (((oa | ob) & bit) != 0)
            if not act.any():
                continue
            move0 = act & ((oa & bit) != 0)
            move1 = act & ~move0
            pin = np.where(move0[:, None], b, a)[act]
            pout = np.where(move0[:, None], a, b)[act]
            din, dout = _plane_dist(k, pin), _plane_dist(k, pout)
            t = din / (din - dout)
            r = pin + t[:, None] * (pout - pin)
            _on_plane(k, r)
            oc = outcodes(r)
            m0 = move0[act]
            a[move0], oa[move0] = r[m0], oc[m0]
            b[move1], ob[move1] = r[~m0], oc[~m0]
    alive &= (oa & ob) == 0
    return alive, a.astype(F32), b.astype(F32)


def _into_view(c: np.ndarray) -> np.ndarray:
    x, y, z, w = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
    nw = -w
    out = c.copy()
    for j, v in ((0, x), (1, y), (2, z)):
        out[:, j] = np.where(v < nw, nw, np.where(v > w, w, v))
    return out


def setup(seg: np.ndarray, mvp: np.ndarray, width: int, height: int) -> np.ndarray:
    """line_setup over float32 (N, 2, 3) segments with the float32 (4, 4) matrix: returns
    LINE_DTYPE (N,) records (status always set; positions only for LS_ACCEPTED/LS_CLIPPED)."""
    n = seg.shape[0]
    rec = np.zeros(n, LINE_DTYPE)
    c = clip_positions(seg, mvp)
    c0, c1 = c[:, 0].copy(), c[:, 1].copy()
    finite = np.all(np.isfinite(c.reshape(n, 8)), axis=1)
    o0, o1 = outcodes(c0), outcodes(c1)
    status = np.full(n, LS_INVALID, np.int32)
    rejected = finite & ((o0 & o1) != 0)
    status[rejected] = LS_REJECTED
    live = finite & ~rejected
    clipped = live & ((o0 | o1) != 0)
    idx = np.nonzero(clipped)[0]
    ok, q0, q1 = clip_segments(c0[idx], c1[idx], o0[idx], o1[idx])
    c0[idx], c1[idx] = q0, q1
    away = np.zeros(n, bool)
    away[idx[~ok]] = True
    status[live & away] = LS_CLIPPED_AWAY
    pos = live & ~away
    degenerate = pos & ~((c0[:, 3] >= FLT_MIN) & (c1[:, 3] >= FLT_MIN))
    status[degenerate] = np.where(clipped[degenerate], LS_CLIPPED_DEGENERATE,
                                  LS_ACCEPTED_DEGENERATE)
    draw = np.nonzero(pos & ~degenerate)[0]
    status[draw] = np.where(clipped[draw], LS_CLIPPED, LS_ACCEPTED)
    v0 = viewport(_into_view(c0[draw]), width, height)
    v1 = viewport(_into_view(c1[draw]), width, height)
    dx = v1["x"].astype(np.int64) - v0["x"]
    dy = v1["y"].astype(np.int64) - v0["y"]
    xmajor = np.abs(dx) >= np.abs(dy)
    sw = np.where(xmajor, dx < 0, dy < 0)
    v0[sw], v1[sw] = v1[sw], v0[sw].copy()
    r = rec[draw]
    r["xs"], r["ys"], r["xe"], r["ye"] = v0["x"], v0["y"], v1["x"], v1["y"]
    r["zs"] = v0["z"]
    with np.errstate(all="ignore"):
        r["dz"] = v1["z"] - v0["z"]
    rec[draw] = r
    rec["status"] = status
    return rec


def _fragments(rec: np.ndarray, seg_ids: np.ndarray, width: int, height: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fragments of the records (walk in lines.cl): segment index, pixel index (y·W + x) and
    float32 depth of every fragment inside the image, in segment order."""
    xs, ys = rec["xs"].astype(np.int64), rec["ys"].astype(np.int64)
    xe, ye = rec["xe"].astype(np.int64), rec["ye"].astype(np.int64)
    xmajor = np.abs(xe - xs) >= np.abs(ye - ys)
    ms, me = np.where(xmajor, xs, ys), np.where(xmajor, xe, ye)
    ns, ne = np.where(xmajor, ys, xs), np.where(xmajor, ye, xe)
    p0 = (ms + SUB_HALF - 1) >> SUBPIXEL_BITS
    p1 = (me + SUB_HALF - 1) >> SUBPIXEL_BITS
    cnt = np.maximum(p1 - p0, 0)
    owner = np.repeat(np.arange(rec.size), cnt)
    p = np.arange(owner.size) - np.repeat(np.cumsum(cnt) - cnt, cnt) + p0[owner]
    c = (p << SUBPIXEL_BITS) + SUB_HALF
    d = (me - ms)[owner]
    num = ns[owner] * d + (c - ms[owner]) * (ne - ns)[owner]
    m = num // (d << SUBPIXEL_BITS)   # floor; num >= 0
    xm = xmajor[owner]
    lim_major = np.where(xm, width, height)
    lim_minor = np.where(xm, height, width)
    inside = (p >= 0) & (p < lim_major) & (m >= 0) & (m < lim_minor)
    x = np.where(xm, p, m)[inside]
    y = np.where(xm, m, p)[inside]
    owner, c, d = owner[inside], c[inside], d[inside]
    with np.errstate(all="ignore"):
        t = (c - ms[owner]).astype(F32) / d.astype(F32)
        z = rec["zs"][owner] + t * rec["dz"][owner]
    z = np.where(z > 0, z, F32(0))
    z = np.where(z > 1, F32(1), z).astype(F32)
    return seg_ids[owner], y * width + x, z


def raster(rec: np.ndarray, width: int, height: int, depth: np.ndarray | None,
           bias: np.float32) -> tuple[np.ndarray, np.ndarray, int, int]:
    """line_depth + line_id over the records: returns line_id int32 (H, W), depth float32
    (H, W), fragments and fragments passed."""
    drawn = np.nonzero((rec["status"] == LS_ACCEPTED) | (rec["status"] == LS_CLIPPED))[0]
    npix = width * height
    zmin = np.full(npix, ZMIN_CLEAR, np.uint32)
    idmin = np.full(npix, ZMIN_CLEAR, np.uint32)
    dflat = None if depth is None else depth.reshape(-1)
    # chunk the segments so that each chunk holds at most ~CHUNK_FRAGMENTS fragments
    r = rec[drawn]
    span = np.maximum(np.abs(r["xe"].astype(np.int64) - r["xs"]),
                      np.abs(r["ye"].astype(np.int64) - r["ys"])) >> SUBPIXEL_BITS
    cum = np.cumsum(span + 1)   # bounds the fragments of each segment
    total = int(cum[-1]) if cum.size else 0
    cuts = np.searchsorted(cum, np.arange(CHUNK_FRAGMENTS, total, CHUNK_FRAGMENTS))
    starts = np.unique(np.concatenate([[0], cuts, [drawn.size]]))
    frags = passed = 0
    for s0, s1 in zip(starts[:-1], starts[1:], strict=True):
        seg, pix, z = _fragments(r[s0:s1], drawn[s0:s1], width, height)
        frags += seg.size
        if dflat is not None:
            ok = z <= dflat[pix] + bias
            seg, pix, z = seg[ok], pix[ok], z[ok]
        passed += seg.size
        zb = z.view(np.uint32)
        order = np.lexsort((seg, zb, pix))
        pix, zb, seg = pix[order], zb[order], seg[order].astype(np.uint32)
        first = np.ones(pix.size, bool)
        first[1:] = pix[1:] != pix[:-1]
        pix, zb, seg = pix[first], zb[first], seg[first]
        better = (zb < zmin[pix]) | ((zb == zmin[pix]) & (seg < idmin[pix]))
        zmin[pix[better]] = zb[better]
        idmin[pix[better]] = seg[better]
    hit = idmin != ZMIN_CLEAR
    line_id = np.where(hit, idmin, np.uint32(0)).astype(np.int32)
    line_id[~hit] = -1
    out_depth = np.where(hit, zmin, np.float32(1).view(np.uint32)).view(np.float32)
    return (line_id.reshape(height, width), out_depth.reshape(height, width).astype(np.float32),
            frags, passed)


def render_lines(segments: npt.ArrayLike, view_proj: Any, width: int, height: int, *,
                 depth: np.ndarray | None = None, depth_bias: float = 0.0,
                 clip_planes: Any = None) -> LineFrame:
    """NumPy twin of `clraster.lines.render_lines`: same arguments (no context), identical
    line_id, depth and stats."""
    width, height = check_size(width, height)
    seg = check_segments(segments)
    m = check_view_proj(view_proj, width, height)
    dbuf = check_depth(depth, width, height)
    bias = check_bias(depth_bias)
    planes = check_clip_planes(clip_planes)
    if seg.shape[0] == 0:
        return LineFrame.empty(width, height)
    drawn, keep, pre = clip_to_planes(seg, planes)   # shared with the OpenCL path
    if drawn.shape[0] == 0:
        return LineFrame.empty(width, height, stats_from_status(pre, 0, 0))
    rec = setup(drawn, m, width, height)
    line_id, zbuf, frags, passed = raster(rec, width, height, dbuf, bias)
    status = rec["status"]
    if planes is not None:
        line_id, status = undo_plane_compaction(line_id, status, keep, pre)
    return LineFrame(line_id, zbuf, stats_from_status(status, frags, passed))
