"""NumPy twin of kernels/setup.cl: trivial reject, clipping, culling, fixed-point snap.

Vectorized over triangles; the clipper is vectorized over the (few) triangles that need it,
looping only over the 6 planes and the ≤ 16 polygon vertex positions, exactly as the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from ...base.layout import (
    COVER_KNOWN,
    COVER_SPAN,
    CULL_MODES,
    DRAW_MIRRORED,
    OC_FRUSTUM,
    OC_GB_X_NEG,
    OC_GB_X_POS,
    OC_GB_Y_NEG,
    OC_GB_Y_POS,
    OC_INVALID,
    OC_NEEDS_CLIP,
    OC_W_NONPOS,
    OC_Z_NEG,
    OC_Z_POS,
    PF_CLIPPED,
    PF_INDEX_SHIFT,
    PF_SWAPPED,
    PIECE_DTYPE,
    POLY_MAX,  # vertex slots of the clipper's polygon (kernels/setup.cl)
    ST_BACKFACE,
    ST_CLIPPED,
    ST_DEGENERATE,
    ST_INVALID,
    ST_NO_SAMPLE,
    ST_RASTER,
    ST_TRIVIAL_REJECT,
    SUBPIXEL_BITS,
    SUBPIXEL_ONE,
    WINVERT_DTYPE,
)
from .vertex import viewport

PLANE_BITS = (OC_Z_NEG, OC_Z_POS, OC_GB_X_NEG, OC_GB_X_POS, OC_GB_Y_NEG, OC_GB_Y_POS)
F32 = np.float32


@dataclass
class SetupResult:
    """Mirror of stages.setup.SetupBuffers (M triangles, P clipped pieces).

    pieces: PIECE_DTYPE (M,), valid where status == ST_RASTER (zeros elsewhere).
    status: uint8 (M,). clip_count, clip_offset: int32 (M,).
    clip_pieces: PIECE_DTYPE (P,). clip_bary: float32 (P, 3, 3).
    """

    pieces: np.ndarray
    status: np.ndarray
    clip_count: np.ndarray
    clip_offset: np.ndarray
    clip_pieces: np.ndarray
    clip_bary: np.ndarray


def plane_dist(p: int, v: np.ndarray, kx: F32, ky: F32) -> np.ndarray:
    """Signed distance of clip-space points v (..., 4) to plane p; >= 0 inside."""
    x, y, z, w = v[..., 0], v[..., 1], v[..., 2], v[..., 3]
    return (z + w, w - z, x + kx * w, kx * w - x, y + ky * w, ky * w - y)[p]


def facing(c: np.ndarray, cull: int, mirrored: np.ndarray | None = None) -> np.ndarray:
    """Facing of clip-space triangles c float32 (K, 3, 4) from det[x y w], as FACING_DET and
    setup_triangles in setup.cl: ST_RASTER (keep), ST_BACKFACE or ST_DEGENERATE (det == 0)
    per triangle. The determinant is taken in float64 (as the kernel does in double): exact
    products, no under- or overflow at any scene scale. ``mirrored`` bool (K,): triangles of
    mirroring instances (DRAW_MIRRORED), whose back and front swap (draw_cull in setup.cl)."""
    c = c.astype(np.float64)
    a, b, d = c[:, 0], c[:, 1], c[:, 2]
    with np.errstate(all="ignore"):
        det = ((a[:, 0] * (b[:, 1] * d[:, 3] - b[:, 3] * d[:, 1])
                - a[:, 1] * (b[:, 0] * d[:, 3] - b[:, 3] * d[:, 0]))
               + a[:, 3] * (b[:, 0] * d[:, 1] - b[:, 1] * d[:, 0]))
    if mirrored is not None:
        det = np.where(mirrored, -det, det)
    st = np.full(c.shape[0], ST_RASTER, np.uint8)
    if cull == CULL_MODES["back"]:
        st[det < 0] = ST_BACKFACE
    elif cull == CULL_MODES["front"]:
        st[det > 0] = ST_BACKFACE
    st[det == 0] = ST_DEGENERATE
    return st


def value_planes(c: np.ndarray, X: np.ndarray, Y: np.ndarray, area2: np.ndarray,
                 width: int, height: int, px0: np.ndarray, py0: np.ndarray,
                 pc: np.ndarray, zs: float = 0.5, zo: float = 0.5) -> None:
    """Fill the value planes of pieces pc PIECE_DTYPE (K,) in place, as value_planes in
    setup.cl (see there why): the same float64 operations in the same order, each stored
    value rounded to float32 once.

    Args:
        c: float64 (K, 3, 4) unsnapped clip-space vertices (z: the depth
            numerator, kernels/setup.cl ClipIn) in the pieces' (swapped) order.
        X, Y: int64 (K, 3) their snapped 24.8 window positions. area2: int64 (K,) > 0.
        px0, py0: int64 (K,) reference pixel (the box's first column and row).
        zs, zo: depth key = (z/w)·zs + zo, with z the depth numerator (c[..., 2]): 0.5, 0.5
            for window depth; -0.5, 0 for minus the reversed-Z depth (DEPTH_MODE).
    """
    hw, hh = 0.5 * np.float64(width), 0.5 * np.float64(height)
    with np.errstate(all="ignore"):
        iw = 1.0 / c[..., 3]
        x = (c[..., 0] * iw + 1.0) * hw
        y = (1.0 - c[..., 1] * iw) * hh
        z = (c[..., 2] * iw) * zs + zo
        a_s = area2.astype(np.float64) * (1.0 / 65536.0)
        ar = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
        snap = ~((ar >= 0.5 * a_s) & (ar <= 2.0 * a_s))
        x = np.where(snap[:, None], X.astype(np.float64) * (1.0 / 256.0), x)
        y = np.where(snap[:, None], Y.astype(np.float64) * (1.0 / 256.0), y)
        ar = np.where(snap, a_s, ar)
        inv = 1.0 / ar
        rx, ry = px0.astype(np.float64) + 0.5, py0.astype(np.float64) + 0.5
        x0, x1, x2 = x[:, 0], x[:, 1], x[:, 2]
        y0, y1, y2 = y[:, 0], y[:, 1], y[:, 2]
        l1 = ((x0 - x2) * (ry - y2) - (y0 - y2) * (rx - x2)) * inv
        l1x, l1y = -(y0 - y2) * inv, (x0 - x2) * inv
        l2 = ((x1 - x0) * (ry - y0) - (y1 - y0) * (rx - x0)) * inv
        l2x, l2y = -(y1 - y0) * inv, (x1 - x0) * inv
        dz10, dz20 = z[:, 1] - z[:, 0], z[:, 2] - z[:, 0]
        pc["z0"] = (z[:, 0] + l1 * dz10) + l2 * dz20
        pc["dzdx"] = l1x * dz10 + l2x * dz20
        pc["dzdy"] = l1y * dz10 + l2y * dz20
        pc["l1"], pc["l1x"], pc["l1y"] = l1, l1x, l1y
        pc["l2"], pc["l2x"], pc["l2y"] = l2, l2x, l2y
        pc["r1"] = c[:, 0, 3] / c[:, 1, 3]
        pc["r2"] = c[:, 0, 3] / c[:, 2, 3]
        pc["zlo"] = z.min(axis=1)


def make_pieces(wv: np.ndarray, c: np.ndarray, width: int, height: int, zs: float = 0.5,
                zo: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Set up triangles from window-space vertices (coverage) and the same vertices in clip
    space (values), as make_piece in setup.cl.

    Args:
        wv: WINXY_DTYPE or WINVERT_DTYPE (K, 3) (x, y are read). c: float64 (K, 3, 4)
            unsnapped clip positions (z: the depth numerator). zs, zo: as `value_planes`.

    Returns (status uint8 (K,), pieces PIECE_DTYPE (K,) valid where status == ST_RASTER,
    swapped bool (K,)).
    """
    k = wv.shape[0]
    X, Y = wv["x"].astype(np.int64), wv["y"].astype(np.int64)
    status = np.full(k, ST_RASTER, np.uint8)
    area2 = (X[:, 1] - X[:, 0]) * (Y[:, 2] - Y[:, 0]) - (Y[:, 1] - Y[:, 0]) * (X[:, 2] - X[:, 0])
    status[area2 == 0] = ST_DEGENERATE
    # y points down in window space: counter-clockwise in NDC is area2 < 0; every piece is
    # rasterized with positive area (facing was decided before, by `facing`)
    swapped = area2 < 0
    perm = np.where(swapped[:, None], [0, 2, 1], [0, 1, 2])
    wv = wv[np.arange(k)[:, None], perm]
    c = np.asarray(c, np.float64)[np.arange(k)[:, None], perm]
    X, Y = wv["x"].astype(np.int64), wv["y"].astype(np.int64)
    area2 = np.abs(area2)
    half, one = SUBPIXEL_ONE // 2, SUBPIXEL_ONE
    px0 = np.maximum((X.min(1) - half + one - 1) >> SUBPIXEL_BITS, 0)
    px1 = np.minimum((X.max(1) - half) >> SUBPIXEL_BITS, width - 1)
    py0 = np.maximum((Y.min(1) - half + one - 1) >> SUBPIXEL_BITS, 0)
    py1 = np.minimum((Y.max(1) - half) >> SUBPIXEL_BITS, height - 1)
    alive = status == ST_RASTER
    status[alive & ((px0 > px1) | (py0 > py1))] = ST_NO_SAMPLE
    # a box of at most COVER_SPAN x COVER_SPAN pixel centres that covers none of them (exact
    # edge functions, top-left rule): no sample either (setup.cl piece_cover)
    span = COVER_SPAN - 1
    small = np.flatnonzero((status == ST_RASTER) & (px1 - px0 <= span) & (py1 - py0 <= span))
    cover = np.zeros(k, np.int32)   # PIECE_DTYPE cover (layout.COVER_KNOWN)
    if small.size:
        Xs, Ys = X[small], Y[small]

        def edge(a, b, qx, qy):
            ax, ay, bx, by = Xs[:, a], Ys[:, a], Xs[:, b], Ys[:, b]
            dx, dy = bx - ax, by - ay
            bias = np.where((dy < 0) | ((dy == 0) & (dx > 0)), 0, 1)
            return dx * (qy - ay) - dy * (qx - ax) >= bias

        bits = np.zeros(small.size, np.int32)
        for oy in range(COVER_SPAN):
            for ox in range(COVER_SPAN):
                qxp, qyp = px0[small] + ox, py0[small] + oy
                inbox = (qxp <= px1[small]) & (qyp <= py1[small])
                qx = (qxp << SUBPIXEL_BITS) + half
                qy = (qyp << SUBPIXEL_BITS) + half
                hit = inbox & edge(1, 2, qx, qy) & edge(2, 0, qx, qy) & edge(0, 1, qx, qy)
                bits |= hit.astype(np.int32) << (COVER_SPAN * oy + ox)
        status[small[bits == 0]] = ST_NO_SAMPLE
        cover[small] = np.where(bits != 0, bits | COVER_KNOWN, 0)
    ok = status == ST_RASTER
    pc = np.zeros(k, PIECE_DTYPE)
    pc["x"][ok] = X[ok]
    pc["y"][ok] = Y[ok]
    pc["bb_min"][ok] = (px0 | (py0 << 16))[ok]
    pc["bb_max"][ok] = (px1 | (py1 << 16))[ok]
    pc["cover"][ok] = cover[ok]
    vals = pc[ok]
    value_planes(c[ok], X[ok], Y[ok], area2[ok], width, height, px0[ok], py0[ok], vals,
                 zs, zo)
    pc[ok] = vals
    pc["flags"] = np.where(swapped, PF_SWAPPED, 0)
    return status, pc, swapped


def clip_polygons(c: np.ndarray, planes: np.ndarray, kx: F32, ky: F32,
                  ud: np.ndarray | None = None, umask: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sutherland–Hodgman in clip space, vectorized over triangles.

    In float64, as the kernel (see the comment on ClipVert in setup.cl).

    Args:
        c: float64 (K, 3, 5) clip-space triangles and their depth numerators
            (`object_clip`: recomputed in double from object space; with 4 columns the
            numerator is z). planes: (K,) OC_* bits to clip against.
        ud: float64 (K, 3, U) the triangles' vertex distances to the U user clip planes
            (`user_distances`), umask: (K,) bit k = clip against user plane k (after the
            frustum planes, as clip_and_emit; distances at polygon vertices from their parent
            barycentrics: user_plane_dist).

    Returns:
        poly float64 (K, POLY_MAX, 7) — x, y, z, w and the parent barycentrics —, the
        vertex counts n int (K,), orig int (K, POLY_MAX): which of the triangle's own
        vertices each polygon vertex is, −1 for one made by the clipper, and the depth
        numerators r float64 (K, POLY_MAX), interpolated like the barycentrics (ClipVert.r).
    """
    k = c.shape[0]
    kx, ky = np.float64(kx), np.float64(ky)
    # column 7: the original vertex (as ClipVert.orig), column 8 the depth numerator
    # (ClipVert.r), carried along with the rest
    poly = np.zeros((k, POLY_MAX, 9), np.float64)
    poly[:, :3, :4] = c[..., :4]
    poly[:, :3, 8] = c[..., 4] if c.shape[-1] > 4 else c[..., 2]
    poly[:, :3, 4:7] = np.eye(3)
    poly[:, :3, 7] = [0, 1, 2]
    n = np.full(k, 3, np.int64)
    rows = np.arange(k)
    with np.errstate(all="ignore"):
        n_user = 0 if ud is None else ud.shape[2]
        for p in range(len(PLANE_BITS) + n_user):
            user = p >= len(PLANE_BITS)
            if user:
                k_u = p - len(PLANE_BITS)
                act = ((np.asarray(umask) & (1 << k_u)) != 0) & (n >= 3)
            else:
                act = ((planes & PLANE_BITS[p]) != 0) & (n >= 3)
            if not act.any():
                continue

            def dist(v: np.ndarray, p: int = p, user: bool = user) -> np.ndarray:
                if not user:
                    return plane_dist(p, v, kx, ky)
                u = cast(np.ndarray, ud)[:, :, p - len(PLANE_BITS)]
                return (v[:, 4] * u[:, 0] + v[:, 5] * u[:, 1]) + v[:, 6] * u[:, 2]

            tmp = poly.copy()
            m = np.zeros(k, np.int64)
            for i in range(POLY_MAX):
                cont = act & (i < n) & (m < POLY_MAX)
                if not cont.any():
                    break
                j = np.where(i + 1 == n, 0, i + 1)
                a = tmp[:, i]
                b = tmp[rows, np.minimum(j, POLY_MAX - 1)]
                da, db = dist(a), dist(b)
                ain, bin_ = da >= 0, db >= 0
                e1 = cont & ain
                poly[rows[e1], m[e1]] = a[e1]
                m += e1
                e2 = cont & (ain != bin_) & (m < POLY_MAX)
                if e2.any():
                    vi = np.where(ain[:, None], a, b)[e2]
                    vo = np.where(ain[:, None], b, a)[e2]
                    di = np.where(ain, da, db)[e2]
                    do = np.where(ain, db, da)[e2]
                    t = (di / (di - do))[:, None]
                    r = vi + t * (vo - vi)
                    if not user:
                        r[:, :4] = onto_plane(p, r[:, :4], kx, ky)
                    r[:, 7] = -1
                    poly[rows[e2], m[e2]] = r
                    m += e2
            n = np.where(act, m, n)
    return poly[..., :7], n, poly[..., 7].astype(np.int64), poly[..., 8]


def onto_plane(p: int, v: np.ndarray, kx: np.floating, ky: np.floating) -> np.ndarray:
    """Float64 clip positions v (K, 4) cut by plane p, put exactly on it (onto_plane in
    setup.cl)."""
    v = v.copy()
    x, y, z, w = 0, 1, 2, 3
    axis, value = ((z, -v[:, w]), (z, v[:, w]), (x, -kx * v[:, w]), (x, kx * v[:, w]),
                   (y, -ky * v[:, w]), (y, ky * v[:, w]))[p]
    v[:, axis] = value
    return v


def object_clip(pool, fd, reversed_z: bool = False) -> np.ndarray:
    """Float64 (N, 5) per vertex of the frame's vertex stream: its clip position (x, y, z,
    w) recomputed from the pool's object-space positions and the float64 matrices
    (`FrameDraws.mvps64`), and the depth numerator r (z; with reversed_z, the depth row
    `FrameDraws.zrows` w − z times the position), summed in the kernel's order
    (object_clip / ClipIn in setup.cl): the clipper's and the value planes' inputs."""
    from .vertex import draw_vertices

    pv, inst, _ = draw_vertices(pool, fd)
    p = pool.positions[pv].astype(np.float64)
    m = fd.mvps64[inst].reshape(-1, 4, 4)
    out = np.empty((p.shape[0], 5))
    with np.errstate(all="ignore"):   # NaN/Inf vertices: OC_INVALID, never clipped
        out[:, :4] = (((m[:, :, 0] * p[:, 0:1] + m[:, :, 1] * p[:, 1:2])
                       + m[:, :, 2] * p[:, 2:3]) + m[:, :, 3])
        out[:, 4] = out[:, 2]
        if reversed_z:
            q = fd.zrows[inst]
            out[:, 4] = ((q[:, 0] * p[:, 0] + q[:, 1] * p[:, 1]) + q[:, 2] * p[:, 2]) + q[:, 3]
    return out


def user_distances(pool, fd) -> np.ndarray | None:
    """Float64 (N, U) distances of the frame's vertex stream to its U user clip planes
    (`FrameDraws.uplanes`, object space per instance), as user_dist in common.h: the vertex
    stage's ucode bits are ``< 0``, setup's clipper starts from these. None without planes."""
    if fd.n_user == 0:
        return None
    from .vertex import draw_vertices

    pv, inst, _ = draw_vertices(pool, fd)
    p = pool.positions[pv].astype(np.float64)
    q = fd.uplanes[inst]                                         # (N, U, 4)
    with np.errstate(all="ignore"):
        return ((q[:, :, 0] * p[:, 0:1] + q[:, :, 1] * p[:, 1:2]) + q[:, :, 2] * p[:, 2:3]
                ) + q[:, :, 3]


def draw_mirrored(pool, fd) -> np.ndarray:
    """bool (M,): per slot of the frame's triangle stream, whether its draw has the
    DRAW_MIRRORED flag (setup.cl: setup_triangles' draw flags, dr.flags)."""
    d = fd.draws
    nt = pool.clusters[d["cluster"]][:, 1].astype(np.int64)
    return np.repeat((d["flags"] & DRAW_MIRRORED) != 0, nt)


def draw_triangles(pool, fd) -> tuple[np.ndarray, np.ndarray]:
    """The frame's triangle stream (mirrors setup_triangles' slots, dr.tri_base + local
    triangle, and clipped_triangle in setup.cl): per slot, the three vertex-stream indices
    int64 (M, 3) and the triangle id int64 (M,)."""
    d = fd.draws
    info = pool.clusters[d["cluster"]].astype(np.int64)
    nt = info[:, 1]
    owner = np.repeat(np.arange(d.size), nt)
    local = np.arange(owner.size) - np.repeat(d["tri_base"].astype(np.int64), nt)
    t = info[owner, 0] + local
    tri_verts = d["vert_base"][owner].astype(np.int64)[:, None] + pool.local_tris[t, :3]
    ids = d["face_base"][owner].astype(np.int64) + pool.face_ids[t]
    return tri_verts, ids


def setup(clip: np.ndarray, outcode: np.ndarray, win: np.ndarray, tri_verts: np.ndarray,
          ids: np.ndarray, width: int, height: int, cull: str, kx: F32, ky: F32,
          clip64: np.ndarray | None = None, mirrored: np.ndarray | None = None,
          reversed_z: bool = False, udist: np.ndarray | None = None,
          uclip: int = 0xFF) -> SetupResult:
    """Triangle setup over the vertex stage's outputs (clip float32 (N, 4), outcode uint16
    (N,), win WINXY_DTYPE (N,)) for the triangle stream tri_verts int (M, 3) with ids
    int (M,). clip64: float64 (N, 5) the clipper's and value planes' inputs
    (`object_clip`; None: ``clip`` itself, depth numerator z). mirrored: bool (M,)
    triangles of mirroring draws (`draw_mirrored`; None: none). reversed_z: the depth
    convention (`clraster.pipeline.params.FrameParams.reversed_z`; clip64 must then hold the
    reversed numerators). udist: float64 (N, U) each vertex's distances to the U user clip
    planes (`user_distances`; None: none): a triangle with all three vertices outside one
    is rejected (ST_TRIVIAL_REJECT), one with any outside a clipping one (bit set in
    ``uclip``, `FrameDraws.uclip`) is clipped."""
    zs, zo = (-0.5, 0.0) if reversed_z else (0.5, 0.5)   # DEPTH_MODE in setup.cl
    cull_i = CULL_MODES[cull]
    faces = tri_verts
    m = faces.shape[0]
    oc = outcode[faces].astype(np.uint32)  # (M, 3)
    o_or = oc[:, 0] | oc[:, 1] | oc[:, 2]
    o_and = oc[:, 0] & oc[:, 1] & oc[:, 2]
    status = np.full(m, ST_RASTER, np.uint8)
    invalid = (o_or & OC_INVALID) != 0
    u_or = np.zeros(m, np.int64)
    u_and = np.zeros(m, np.int64)
    if udist is not None and udist.shape[1]:
        with np.errstate(invalid="ignore"):
            ucode = ((udist < 0.0) * (1 << np.arange(udist.shape[1]))).sum(axis=1)  # (N,)
        uc = ucode[faces]
        u_or = uc[:, 0] | uc[:, 1] | uc[:, 2]
        u_and = uc[:, 0] & uc[:, 1] & uc[:, 2]
    reject = ~invalid & (((o_and & OC_FRUSTUM) != 0) | (u_and != 0))
    status[invalid] = ST_INVALID
    status[reject] = ST_TRIVIAL_REJECT
    rest = np.nonzero(~invalid & ~reject)[0]
    status[rest] = facing(clip[faces[rest]], cull_i,
                          None if mirrored is None else mirrored[rest])
    live = status == ST_RASTER
    u_or = u_or & uclip   # planes that only reject (a window's) never clip
    needs = live & (((o_or & OC_NEEDS_CLIP) != 0) | (u_or != 0))
    wzero = live & ~needs & ((o_or & OC_W_NONPOS) != 0)
    plain = live & ~needs & ~wzero
    status[needs] = ST_CLIPPED
    status[wzero] = ST_DEGENERATE
    pieces = np.zeros(m, PIECE_DTYPE)
    idx = np.nonzero(plain)[0]
    # values from the float64 clip positions (object_clip) with z replaced by the depth
    # numerator, as the kernel (value_vertex)
    c64 = clip.astype(np.float64) if clip64 is None else clip64
    if c64.shape[1] == 4:
        c64 = np.concatenate([c64, c64[:, 2:3]], axis=1)
    cval = c64[:, [0, 1, 4, 3]]
    st, pc, _ = make_pieces(win[faces[idx]], cval[faces[idx]], width, height, zs, zo)
    status[idx] = st
    pc["id"] = ids[idx]
    ok = st == ST_RASTER
    pieces[idx[ok]] = pc[ok]

    cidx = np.nonzero(needs)[0]
    clip_count = np.zeros(m, np.int32)
    poly, n, orig, rnum = clip_polygons(
        c64[faces[cidx]], o_or[cidx] & OC_NEEDS_CLIP, kx, ky,
        None if udist is None or not udist.shape[1] else udist[faces[cidx]], u_or[cidx])
    # fan (0, k, k+1) for k = 1..n-2, ordered by triangle then k
    nfan = np.maximum(n - 2, 0)
    owner = np.repeat(np.arange(cidx.size), nfan)
    kk = np.arange(owner.size) - np.repeat(np.cumsum(nfan) - nfan, nfan) + 1
    v0, v1, v2 = poly[owner, 0], poly[owner, kk], poly[owner, kk + 1]
    c3 = np.stack([v0[:, :4], v1[:, :4], v2[:, :4]], axis=1).astype(F32)
    # the triangle's own vertices are emitted as the vertex stage's float32 positions
    for j, kj in enumerate((np.zeros_like(kk), kk, kk + 1)):
        o = orig[owner, kj]
        own = o >= 0
        c3[own, j] = clip[faces[cidx[owner[own]], o[own]]]
    wpos = np.all(c3[:, :, 3] > 0, axis=1)  # pieces with a vertex at w <= 0 are dropped
    wv = np.zeros(c3.shape[:2], WINVERT_DTYPE)
    wv[wpos] = viewport(c3[wpos], width, height)
    # values from the clipper's float64 vertices with z replaced by the interpolated depth
    # numerator (as the kernel passes value_vertex(poly[].p, poly[].r))
    cpc = np.stack([v0[:, :4], v1[:, :4], v2[:, :4]], axis=1)
    cpc[:, :, 2] = np.stack([rnum[owner, 0], rnum[owner, kk], rnum[owner, kk + 1]], axis=1)
    st, pc, sw = make_pieces(wv, cpc, width, height, zs, zo)
    ok = (st == ST_RASTER) & wpos
    clip_count[cidx] = np.bincount(owner[ok], minlength=cidx.size)
    clip_pieces = pc[ok]
    clip_pieces["id"] = ids[cidx[owner[ok]]]
    clip_pieces["flags"] = (PF_CLIPPED | np.where(sw[ok], PF_SWAPPED, 0)
                            | (np.arange(clip_pieces.size) << PF_INDEX_SHIFT))
    b1 = np.where(sw[:, None], v2[:, 4:], v1[:, 4:])
    b2 = np.where(sw[:, None], v1[:, 4:], v2[:, 4:])
    clip_bary = np.stack([v0[:, 4:], b1, b2], axis=1)[ok].astype(F32)
    clip_offset = (np.cumsum(clip_count) - clip_count).astype(np.int32)
    return SetupResult(pieces, status, clip_count, clip_offset, clip_pieces, clip_bary)
