"""NumPy twin of kernels/setup.cl: trivial reject, clipping, culling, fixed-point snap.

Vectorized over triangles; the clipper is vectorized over the (few) triangles that need it,
looping only over the 6 planes and the ≤ 16 polygon vertex positions, exactly as the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import (
    CULL_MODES,
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
from ..layout import POLY_MAX  # vertex slots of the clipper's polygon (kernels/setup.cl)
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


def facing(c: np.ndarray, cull: int) -> np.ndarray:
    """Facing of clip-space triangles c float32 (K, 3, 4) from det[x y w], as facing() in
    setup.cl: ST_RASTER (keep), ST_BACKFACE or ST_DEGENERATE (det == 0) per triangle. The
    determinant is taken in float64 (as the kernel does in double): exact products, no
    under- or overflow at any scene scale."""
    c = c.astype(np.float64)
    a, b, d = c[:, 0], c[:, 1], c[:, 2]
    with np.errstate(all="ignore"):
        det = ((a[:, 0] * (b[:, 1] * d[:, 3] - b[:, 3] * d[:, 1])
                - a[:, 1] * (b[:, 0] * d[:, 3] - b[:, 3] * d[:, 0]))
               + a[:, 3] * (b[:, 0] * d[:, 1] - b[:, 1] * d[:, 0]))
    st = np.full(c.shape[0], ST_RASTER, np.uint8)
    if cull == CULL_MODES["back"]:
        st[det < 0] = ST_BACKFACE
    elif cull == CULL_MODES["front"]:
        st[det > 0] = ST_BACKFACE
    st[det == 0] = ST_DEGENERATE
    return st


def make_pieces(wv: np.ndarray, width: int, height: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Set up triangles from window-space vertices, as make_piece in setup.cl.

    Args:
        wv: WINVERT_DTYPE (K, 3).

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
    X, Y, Z, iw = wv["x"].astype(np.int64), wv["y"].astype(np.int64), wv["z"], wv["iw"]
    area2 = np.abs(area2)
    half, one = SUBPIXEL_ONE // 2, SUBPIXEL_ONE
    px0 = np.maximum((X.min(1) - half + one - 1) >> SUBPIXEL_BITS, 0)
    px1 = np.minimum((X.max(1) - half) >> SUBPIXEL_BITS, width - 1)
    py0 = np.maximum((Y.min(1) - half + one - 1) >> SUBPIXEL_BITS, 0)
    py1 = np.minimum((Y.max(1) - half) >> SUBPIXEL_BITS, height - 1)
    alive = status == ST_RASTER
    status[alive & ((px0 > px1) | (py0 > py1))] = ST_NO_SAMPLE
    ok = status == ST_RASTER
    pc = np.zeros(k, PIECE_DTYPE)
    pc["x"][ok] = X[ok]
    pc["y"][ok] = Y[ok]
    pc["bb_min"][ok] = (px0 | (py0 << 16))[ok]
    pc["bb_max"][ok] = (px1 | (py1 << 16))[ok]
    with np.errstate(all="ignore"):
        pc["z0"][ok] = Z[ok, 0]
        pc["dz10"][ok] = (Z[:, 1] - Z[:, 0])[ok]
        pc["dz20"][ok] = (Z[:, 2] - Z[:, 0])[ok]
        pc["inv_area"][ok] = F32(1) / area2[ok].astype(F32)
        pc["r1"][ok] = (iw[:, 1] / iw[:, 0])[ok]
        pc["r2"][ok] = (iw[:, 2] / iw[:, 0])[ok]
    pc["flags"] = np.where(swapped, PF_SWAPPED, 0)
    return status, pc, swapped


def clip_polygons(c: np.ndarray, planes: np.ndarray, kx: F32, ky: F32
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland–Hodgman in clip space, vectorized over triangles.

    In float64, as the kernel (see the comment on ClipVert in setup.cl).

    Args:
        c: float32 (K, 3, 4) clip-space triangles. planes: (K,) OC_* bits to clip against.

    Returns:
        poly float64 (K, POLY_MAX, 7) — x, y, z, w and the parent barycentrics — and the
        vertex counts n int (K,).
    """
    k = c.shape[0]
    kx, ky = np.float64(kx), np.float64(ky)
    poly = np.zeros((k, POLY_MAX, 7), np.float64)
    poly[:, :3, :4] = c
    poly[:, :3, 4:] = np.eye(3)
    n = np.full(k, 3, np.int64)
    rows = np.arange(k)
    with np.errstate(all="ignore"):
        for p, bit in enumerate(PLANE_BITS):
            act = ((planes & bit) != 0) & (n >= 3)
            if not act.any():
                continue
            tmp = poly.copy()
            m = np.zeros(k, np.int64)
            for i in range(POLY_MAX):
                cont = act & (i < n) & (m < POLY_MAX)
                if not cont.any():
                    break
                j = np.where(i + 1 == n, 0, i + 1)
                a = tmp[:, i]
                b = tmp[rows, np.minimum(j, POLY_MAX - 1)]
                da, db = plane_dist(p, a, kx, ky), plane_dist(p, b, kx, ky)
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
                    poly[rows[e2], m[e2]] = vi + t * (vo - vi)
                    m += e2
            n = np.where(act, m, n)
    return poly, n


def draw_triangles(pool, fd) -> tuple[np.ndarray, np.ndarray]:
    """The frame's triangle stream (mirrors triangle_of in setup.cl): per slot, the three
    vertex-stream indices int64 (M, 3) and the triangle id int64 (M,)."""
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
          ids: np.ndarray, width: int, height: int, cull: str, kx: F32, ky: F32
          ) -> SetupResult:
    """Triangle setup over the vertex stage's outputs (clip float32 (N, 4), outcode uint16
    (N,), win WINVERT_DTYPE (N,)) for the triangle stream tri_verts int (M, 3) with ids
    int (M,)."""
    cull_i = CULL_MODES[cull]
    faces = tri_verts
    m = faces.shape[0]
    oc = outcode[faces].astype(np.uint32)  # (M, 3)
    o_or = oc[:, 0] | oc[:, 1] | oc[:, 2]
    o_and = oc[:, 0] & oc[:, 1] & oc[:, 2]
    status = np.full(m, ST_RASTER, np.uint8)
    invalid = (o_or & OC_INVALID) != 0
    reject = ~invalid & ((o_and & OC_FRUSTUM) != 0)
    status[invalid] = ST_INVALID
    status[reject] = ST_TRIVIAL_REJECT
    rest = np.nonzero(~invalid & ~reject)[0]
    status[rest] = facing(clip[faces[rest]], cull_i)
    live = status == ST_RASTER
    needs = live & ((o_or & OC_NEEDS_CLIP) != 0)
    wzero = live & ~needs & ((o_or & OC_W_NONPOS) != 0)
    plain = live & ~needs & ~wzero
    status[needs] = ST_CLIPPED
    status[wzero] = ST_DEGENERATE
    pieces = np.zeros(m, PIECE_DTYPE)
    idx = np.nonzero(plain)[0]
    st, pc, _ = make_pieces(win[faces[idx]], width, height)
    status[idx] = st
    pc["id"] = ids[idx]
    ok = st == ST_RASTER
    pieces[idx[ok]] = pc[ok]

    cidx = np.nonzero(needs)[0]
    clip_count = np.zeros(m, np.int32)
    poly, n = clip_polygons(clip[faces[cidx]], o_or[cidx] & OC_NEEDS_CLIP, kx, ky)
    # fan (0, k, k+1) for k = 1..n-2, ordered by triangle then k
    nfan = np.maximum(n - 2, 0)
    owner = np.repeat(np.arange(cidx.size), nfan)
    kk = np.arange(owner.size) - np.repeat(np.cumsum(nfan) - nfan, nfan) + 1
    v0, v1, v2 = poly[owner, 0], poly[owner, kk], poly[owner, kk + 1]
    c3 = np.stack([v0[:, :4], v1[:, :4], v2[:, :4]], axis=1).astype(F32)
    wpos = np.all(c3[:, :, 3] > 0, axis=1)  # pieces with a vertex at w <= 0 are dropped
    wv = np.zeros(c3.shape[:2], WINVERT_DTYPE)
    wv[wpos] = viewport(c3[wpos], width, height)
    st, pc, sw = make_pieces(wv, width, height)
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
