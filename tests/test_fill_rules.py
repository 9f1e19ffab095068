"""Rasterization rules: image orientation, the D3D11 top-left fill rule, 8 sub-pixel bits,
and the conformance patterns (fans, shared-edge quads, clipped fans) that must cover each
pixel centre exactly once.

Conventions pinned here (DESIGN.md): row 0 is the top row; pixel (x, y) is sampled at
(x + 0.5, y + 0.5); x_win = (x_ndc + 1)/2·W, y_win = (1 − y_ndc)/2·H. Hand-made triangles are
given in window pixels and mapped to NDC with an identity clip matrix (w = 1), with
power-of-two sizes so that the mapping is exact in float32.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import (
    NDC_CAMERA,
    MatrixCamera,
    assert_frames_equal,
    perspective,
    pixel_centres,
    render_both,
    render_cl,
    window_mesh,
)

from clraster import Mesh, RasterConfig, Renderer


def mask_from(rows: list[str]) -> np.ndarray:
    return np.array([[c == "1" for c in r] for r in rows], dtype=bool)


def single_masks(mesh: Mesh, camera, w: int, h: int, tile_log2: int = 4) -> list[np.ndarray]:
    """Coverage mask of each face of ``mesh`` rendered alone (cull none)."""
    out = []
    for f in mesh.faces:
        one = Mesh(mesh.vertices[f], [[0, 1, 2]])
        fr = render_cl(one, camera, w, h, cull="none", tile_log2=tile_log2)
        out.append(fr.triangle_id == 0)
    return out


# --- orientation: hand-drawn masks -------------------------------------------------------

# Right triangle in the top-left corner of an 8×6 image: legs 6 px along the top and 3 px
# down the left side. A pixel centre (xc, yc) is inside iff xc/6 + yc/3 < 1 (no centre lies
# on an edge), worked out by hand:
#   row 0 (yc = 0.5): xc < 5   → x = 0..4
#   row 1 (yc = 1.5): xc < 3   → x = 0..2
#   row 2 (yc = 2.5): xc < 1   → x = 0
CORNER_8x6 = mask_from([
    "11111000",
    "11100000",
    "10000000",
    "00000000",
    "00000000",
    "00000000",
])


@pytest.mark.parametrize("order", [(0, 1, 2), (0, 2, 1)])
@pytest.mark.parametrize("tile_log2", [3, 6])
def test_corner_triangle_orientation(order, tile_log2):
    tri = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, 3.0]])[list(order)]
    mesh = window_mesh([tri], 8, 6)
    a, b = render_both(mesh, NDC_CAMERA, 8, 6, cull="none", tile_log2=tile_log2)
    np.testing.assert_array_equal(a.triangle_id >= 0, CORNER_8x6)
    np.testing.assert_array_equal(b.triangle_id >= 0, CORNER_8x6)
    assert set(np.unique(a.triangle_id)) == {-1, 0}
    assert a.stats.fragments_tested == CORNER_8x6.sum() == 9


def test_corner_triangle_in_ndc_directly():
    """The same corner triangle written in NDC by hand (top-left is x = −1, y = +1)."""
    # window (0,0) → NDC (−1, 1); (6,0) → (0.5, 1); (0,3) → (−1, 0)
    mesh = Mesh([[-1.0, 1.0, 0.0], [0.5, 1.0, 0.0], [-1.0, 0.0, 0.0]], [[0, 2, 1]])
    fr = render_cl(mesh, NDC_CAMERA, 8, 6, cull="back")  # (0, 2, 1) is CCW in NDC
    np.testing.assert_array_equal(fr.triangle_id >= 0, CORNER_8x6)


# Triangle A: horizontal TOP edge through the pixel centres of row 2 (y = 2.5) from x = 1 to
# x = 7, apex below at (4, 6.5). Its slanted edges pass exactly through (2.5, 4.5) (left
# edge: covered) and (5.5, 4.5) (right edge: not covered). Worked out by hand per row:
#   row 2: on the top edge, xc in (1, 7)        → x = 1..6   (top edge covers)
#   row 3: inside x in (1.75, 6.25)             → x = 2..5
#   row 4: x in [2.5, 5.5): 2.5 on left edge ✓, 5.5 on right edge ✗ → x = 2..4
#   row 5: x in (3.25, 4.75)                    → x = 3, 4
#   row 6: only the apex (4, 6.5), no centre
TOP_EDGE_A = mask_from([
    "00000000",
    "00000000",
    "01111110",
    "00111100",
    "00111000",
    "00011000",
    "00000000",
    "00000000",
])
# Triangle B: A mirrored: horizontal BOTTOM edge on row 6's centres, apex at (4, 2.5).
#   row 3: (3.25, 4.75) → 3, 4;  row 4: [2.5, 5.5) → 2..4;  row 5: (1.75, 6.25) → 2..5
#   row 6: on the bottom edge → nothing
BOTTOM_EDGE_B = mask_from([
    "00000000",
    "00000000",
    "00000000",
    "00011000",
    "00111000",
    "00111100",
    "00000000",
    "00000000",
])


@pytest.mark.parametrize("order", [(0, 1, 2), (0, 2, 1), (1, 2, 0), (2, 1, 0)])
def test_top_left_rule_hand_masks(order):
    o = list(order)
    a_tri = np.array([[1.0, 2.5], [7.0, 2.5], [4.0, 6.5]])[o]
    b_tri = np.array([[1.0, 6.5], [7.0, 6.5], [4.0, 2.5]])[o]
    for tri, expected in ((a_tri, TOP_EDGE_A), (b_tri, BOTTOM_EDGE_B)):
        cl_f, ref_f = render_both(window_mesh([tri], 8, 8), NDC_CAMERA, 8, 8, cull="none")
        np.testing.assert_array_equal(cl_f.triangle_id >= 0, expected)
        np.testing.assert_array_equal(ref_f.triangle_id >= 0, expected)


def test_vertical_edges_left_covered_right_not():
    """Column 3's centres lie on x = 3.5. A rectangle-ish triangle pair to the RIGHT of that
    line (its left edge) covers them; one to the LEFT (its right edge) does not."""
    right_of = [[3.5, 0.0], [3.5, 8.0], [7.0, 8.0]], [[3.5, 0.0], [7.0, 8.0], [7.0, 0.0]]
    left_of = [[0.0, 0.0], [0.0, 8.0], [3.5, 8.0]], [[0.0, 0.0], [3.5, 8.0], [3.5, 0.0]]
    cov_r = render_cl(window_mesh(right_of, 8, 8), NDC_CAMERA, 8, 8).triangle_id >= 0
    cov_l = render_cl(window_mesh(left_of, 8, 8), NDC_CAMERA, 8, 8).triangle_id >= 0
    # right_of covers columns 3..6 (x = 7 edge: centre 6.5 inside, 7.5 outside)
    np.testing.assert_array_equal(cov_r, np.tile(mask_from(["00011110"]), (8, 1)))
    np.testing.assert_array_equal(cov_l, np.tile(mask_from(["11100000"]), (8, 1)))


def test_horizontal_edges_top_covered_bottom_not():
    below = [[0.0, 2.5], [8.0, 2.5], [8.0, 6.0]], [[0.0, 2.5], [8.0, 6.0], [0.0, 6.0]]
    above = [[0.0, 0.0], [8.0, 0.0], [8.0, 2.5]], [[0.0, 0.0], [8.0, 2.5], [0.0, 2.5]]
    cov_b = render_cl(window_mesh(below, 8, 8), NDC_CAMERA, 8, 8).triangle_id >= 0
    cov_a = render_cl(window_mesh(above, 8, 8), NDC_CAMERA, 8, 8).triangle_id >= 0
    rows = np.arange(8)
    np.testing.assert_array_equal(cov_b, np.repeat(((rows >= 2) & (rows <= 5))[:, None], 8, 1))
    np.testing.assert_array_equal(cov_a, np.repeat((rows <= 1)[:, None], 8, 1))


# --- 8 sub-pixel bits --------------------------------------------------------------------

@pytest.mark.parametrize("offset, covered", [
    (1.0 / 1024, True),   # 0.25 sub-pixel: snaps back onto x = 3.5 → left edge → covered
    (-1.0 / 1024, True),  # the same from the other side
    (1.0 / 128, False),   # 2 sub-pixels right of the centres: column 3 outside
    (-1.0 / 128, True),   # 2 sub-pixels left: column 3 strictly inside
])
def test_vertices_snap_to_eighth_bit(offset, covered):
    x = 3.5 + offset
    tris = [[x, 0.0], [x, 8.0], [7.0, 8.0]], [[x, 0.0], [7.0, 8.0], [7.0, 0.0]]
    cov = render_cl(window_mesh(tris, 8, 8), NDC_CAMERA, 8, 8).triangle_id >= 0
    assert cov[:, 3].all() == covered and cov[:, 3].any() == covered
    assert cov[:, 4:7].all() and not cov[:, :3].any() and not cov[:, 7].any()


# --- an independent top-left reference on random snapped triangles -----------------------

def top_left_coverage(tri: np.ndarray, w: int, h: int) -> np.ndarray:
    """Coverage of one window-space triangle (vertices already on the 1/256 grid), written
    from the D3D11 rule text, independently of clraster: a centre is covered iff it is
    strictly inside every edge, or exactly on an edge that is a *top* edge (exactly
    horizontal, the third vertex below it) or a *left* edge (not horizontal, the triangle to
    its right), and inside the others. Exact integer arithmetic in 1/256 px."""
    p = np.rint(np.asarray(tri, dtype=np.float64) * 256).astype(np.int64)
    xc, yc = pixel_centres(w, h)
    px = np.rint(xc * 256).astype(np.int64)
    py = np.rint(yc * 256).astype(np.int64)
    cov = np.ones((h, w), bool)
    for i in range(3):
        a, b, c = p[i], p[(i + 1) % 3], p[(i + 2) % 3]
        ex, ey = b[0] - a[0], b[1] - a[1]
        side_c = ex * (c[1] - a[1]) - ey * (c[0] - a[0])
        if side_c == 0:
            return np.zeros((h, w), bool)  # degenerate: covers nothing
        e = ex * (py - a[1]) - ey * (px - a[0])
        if ey == 0:
            special = c[1] > a[1]  # top: horizontal, interior below (y grows downwards)
        else:
            # the interior is on the side of the line where x is larger: a left edge
            special = side_c * ey < 0
        inside = (np.sign(e) == np.sign(side_c)) | ((e == 0) & special)
        cov &= inside
    return cov


def spec_checked(tris, w: int, h: int, tile_log2: int = 4) -> int:
    """Each triangle of ``tris`` (window space) rendered alone has the rule text's coverage
    (`top_left_coverage`); returns the covered centres checked."""
    got = single_masks(window_mesh(tris, w, h), NDC_CAMERA, w, h, tile_log2=tile_log2)
    checked = 0
    for i, (tri, cov) in enumerate(zip(tris, got, strict=True)):
        exp = top_left_coverage(tri, w, h)
        assert np.array_equal(cov, exp), f"triangle {i} {tri.tolist()}:\n{cov.astype(int)}"
        checked += int(exp.sum())
    return checked


def test_random_small_triangles_against_spec_reference():
    rng = np.random.default_rng(7)
    w, h = 16, 16
    tris = []
    for _ in range(300):
        base = rng.uniform(-1, 17, 2)
        # half on the pixel-centre grid (edges through many centres), half anywhere
        if rng.random() < 0.5:
            pts = np.floor(base + rng.integers(-6, 7, (3, 2))) + 0.5
        else:
            pts = base + rng.normal(0, 4, (3, 2))
        tris.append(np.rint(pts * 256) / 256)
    assert spec_checked(tris, w, h) > 2000


@pytest.mark.parametrize("tile_log2", [3, 4])
def test_tiny_triangles_on_centres_against_spec_reference(tile_log2):
    """Triangles whose boxes hold at most 4 x 4 pixel centres (setup tests those centres
    itself: layout.COVER_SPAN, and the raster takes its bits), with vertices on pixel centres
    or quarter pixels off them, so that edges run through centres: each one's coverage is the
    rule text's. With 8-pixel tiles many boxes cross a tile seam. Also: right triangles
    whose right angle lies a quarter pixel beyond a 4 x 4 box's corner centre (every centre
    of the box, the far corner included, in play), and large triangles whose box is cut to
    at most 4 x 4 centres by the image's corner (setup's 64-bit path for wide spans)."""
    rng = np.random.default_rng(11)
    w, h = 16, 16
    tris = []
    while len(tris) < 400:
        base = np.floor(rng.uniform(-1, 17, 2)) + 0.5
        pts = base + rng.integers(-2, 3, (3, 2)) + rng.choice([0.0, 0.0, 0.25, -0.25], (3, 2))
        ext = pts.max(0) - pts.min(0)
        if ext.max() > 3.5 or ext.min() < 1.0:   # boxes of 2..4 centres a side
            continue
        tris.append(pts)
    for _ in range(40):
        o = np.floor(rng.uniform(-1, 14, 2)) + 0.25   # the box's centres: o + 0.25 .. o + 3.25
        sx, sy = rng.choice([0, 1], 2)   # the corner of the right angle
        c = o + 3.5 * np.array([sx, sy])
        tris.append(np.array([c, [o[0] + 3.5 * (1 - sx), c[1]], [c[0], o[1] + 3.5 * (1 - sy)]]))
    for corner in ((0, 0), (1, 0), (0, 1), (1, 1)):
        for far in (37.0, 300.0, 1234.5, 4000.0):
            cx = 3.75 if corner[0] == 0 else w - 3.75
            cy = 3.75 if corner[1] == 0 else h - 3.75
            far_x = -far if corner[0] == 0 else w + far
            far_y = -0.7 * far if corner[1] == 0 else h + 0.7 * far
            tris.append(np.array([[far_x, cy], [cx, cy], [cx, far_y]]))
            tris.append(np.array([[far_x, cy + (1 if corner[1] == 0 else -1) * 2.25],
                                  [cx, cy], [cx - (1 if corner[0] == 0 else -1) * 2.5, far_y]]))
    assert spec_checked(tris, w, h, tile_log2) > 400


# --- fans, quads, grids: each pixel centre covered exactly once --------------------------

def fan_window(centre, ring) -> list[np.ndarray]:
    ring = np.asarray(ring, dtype=np.float64)
    return [np.array([centre, ring[i], ring[(i + 1) % len(ring)]]) for i in range(len(ring))]


def inside_convex(poly: np.ndarray, w: int, h: int, margin: float) -> np.ndarray:
    """Pixel centres inside the convex CCW-or-CW polygon by more than `margin` pixels."""
    xc, yc = pixel_centres(w, h)
    n = len(poly)
    area = sum(poly[i, 0] * poly[(i + 1) % n, 1] - poly[(i + 1) % n, 0] * poly[i, 1]
               for i in range(n))
    sgn = 1.0 if area > 0 else -1.0
    ok = np.ones((h, w), bool)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        d = b - a
        dist = sgn * (d[0] * (yc - a[1]) - d[1] * (xc - a[0])) / np.hypot(*d)
        ok &= dist > margin
    return ok


def check_exactly_once(tris, w, h, interior: np.ndarray, camera=NDC_CAMERA,
                       mesh: Mesh | None = None) -> np.ndarray:
    mesh = mesh if mesh is not None else window_mesh(tris, w, h)
    masks = single_masks(mesh, camera, w, h)
    total = np.sum(masks, axis=0)
    assert total.max() <= 1, f"double hits at {np.argwhere(total > 1)[:10].tolist()}"
    holes = interior & (total == 0)
    assert not holes.any(), f"holes at {np.argwhere(holes)[:10].tolist()}"
    # all faces at one depth in one draw: every covered centre is tested exactly once
    a, b = render_both(mesh, camera, w, h, cull="none")
    assert_frames_equal(a, b, "fan")
    np.testing.assert_array_equal(a.triangle_id >= 0, total == 1)
    assert a.stats.fragments_tested == int(total.sum()) == a.stats.fragments_passed
    return total


@pytest.mark.parametrize("seed", range(6))
def test_fan_non_integer_vertices(seed):
    rng = np.random.default_rng(seed)
    w = h = 64
    n = int(rng.integers(5, 24))
    centre = rng.uniform(24, 40, 2)
    ang = np.sort(rng.uniform(0, 2 * math.pi, n))
    radius = rng.uniform(18, 26)
    ring = centre + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    # random winding per fan; vertex coordinates arbitrary (not on the sub-pixel grid)
    tris = fan_window(centre, ring if seed % 2 else ring[::-1])
    interior = inside_convex(ring, w, h, margin=0.01)
    total = check_exactly_once(tris, w, h, interior)
    assert total.sum() > 500


@pytest.mark.parametrize("n", [4, 8, 16])
def test_fan_on_pixel_centres(n):
    """Centre and ring vertices exactly on pixel centres, including axis-aligned spokes that
    run along a row and a column of centres (the top-left rule decides every one)."""
    w = h = 32
    c = np.array([15.5, 16.5])
    ang = 2 * math.pi * np.arange(n) / n
    ring = np.floor(c + 12 * np.stack([np.cos(ang), -np.sin(ang)], axis=1)) + 0.5
    tris = fan_window(c, ring)
    interior = inside_convex(ring, w, h, margin=1e-9)
    total = check_exactly_once(tris, w, h, interior)
    assert total[16, 15] == 1  # the fan centre itself


def test_quads_split_on_shared_diagonal():
    w = h = 32
    rng = np.random.default_rng(3)
    for _ in range(8):
        # a convex quad with arbitrary corners; split along either diagonal
        ang = np.sort(rng.uniform(0, 2 * math.pi, 4))
        q = rng.uniform(12, 20, 2) + rng.uniform(6, 14) * np.stack(
            [np.cos(ang), np.sin(ang)], axis=1)
        if rng.random() < 0.5:
            q = np.floor(q) + 0.5  # corners on pixel centres: the diagonal hits centres
        for split in ((0, 1, 2, 0, 2, 3), (1, 2, 3, 1, 3, 0)):
            tris = [q[list(split[:3])], q[list(split[3:])]]
            interior = inside_convex(q, w, h, margin=1e-9)
            check_exactly_once(tris, w, h, interior)


def test_jittered_grid_exactly_once():
    """A 6×6 grid of jittered quads (shared vertices, mixed diagonals) covering the image."""
    w, h = 32, 32
    rng = np.random.default_rng(5)
    g = 6
    lin = np.linspace(-4, 36, g + 1)
    gx, gy = np.meshgrid(lin, lin)
    pts = np.stack([gx, gy], axis=-1) + rng.uniform(-2, 2, (g + 1, g + 1, 2))
    pts[3, 3] = [16.5, 16.5]  # one grid vertex exactly on a pixel centre
    tris = []
    for j in range(g):
        for i in range(g):
            a, b, c, d = pts[j, i], pts[j, i + 1], pts[j + 1, i + 1], pts[j + 1, i]
            tris += [[a, b, c], [a, c, d]] if (i + j) % 2 else [[a, b, d], [b, c, d]]
    total = check_exactly_once(tris, w, h, np.ones((h, w), bool))
    assert (total == 1).all()


def test_fan_beyond_guard_band_covers_window_once():
    """A fan whose ring is a circle of radius 2**21 px around a point inside the window:
    every triangle leaves the guard band (2**19 px) and is clipped in clip space; the clipped
    pieces still cover every pixel exactly once."""
    w, h = 32, 16
    c = np.array([13.3, 7.7])
    n = 9
    ang = 2 * math.pi * (np.arange(n) + 0.25) / n
    ring = c + 2.0**21 * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    tris = fan_window(c, ring)
    mesh = window_mesh(tris, w, h)
    total = check_exactly_once(tris, w, h, np.ones((h, w), bool), mesh=mesh)
    assert (total == 1).all()
    st = render_cl(mesh, NDC_CAMERA, w, h, cull="none").stats
    assert st.clipped == n and st.clip_pieces >= n


@pytest.mark.parametrize("tilt", [0.3, 1.2])
def test_tilted_fan_through_near_plane(tilt):
    """A fan on a tilted eye-space plane, with a huge ring (some ring vertices behind the
    eye, w < 0): near-plane clipping must leave no hole and no double hit. Every pixel whose
    ray meets the plane inside the ring, in front of the near plane (with margin), is
    covered exactly once."""
    w, h = 48, 32
    near, far = 0.5, 1e4
    cam = MatrixCamera(perspective(70.0, w / h, near, far))
    # plane through (0, 0, −3) with normal n tilted about the x axis
    nrm = np.array([0.0, math.cos(tilt), math.sin(tilt)])
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(nrm, u)
    p0 = np.array([0.1, -0.05, -3.0])
    n = 11
    ang = 2 * math.pi * (np.arange(n) + 0.1) / n
    radius = 50.0
    ring = p0 + radius * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
    verts = np.concatenate([p0[None], ring])
    faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    mesh = Mesh(verts, faces)
    assert (ring[:, 2] > 0).any(), "some ring vertex must be behind the eye"
    # analytic: ray through each pixel centre, intersect the plane
    xc, yc = pixel_centres(w, h)
    t_y = math.tan(math.radians(35.0))
    dx = (xc / w * 2 - 1) * t_y * w / h
    dy = (1 - yc / h * 2) * t_y
    d = np.stack([dx, dy, -np.ones_like(dx)], axis=-1)
    s = (p0 @ nrm) / (d @ nrm)
    hit = d * s[..., None]
    depth_ok = (s > near * 1.05) & (s < far * 0.95)
    rel = hit - p0
    # inside the n-gon (inscribed radius cos(pi/n)·R) with margin
    inside = np.hypot(rel @ u, rel @ v) < radius * math.cos(math.pi / n) * 0.99
    interior = depth_ok & inside
    assert interior.sum() > w * h // 4
    total = check_exactly_once(None, w, h, interior, camera=cam, mesh=mesh)
    assert not (total[~(s > near * 0.95)] > 0).any(), "covered where the plane is behind"


# --- fragments tested per pixel -------------------------------------------------------------


@pytest.mark.parametrize("tile_log2", [3, 4])
def test_overdraw_counts_every_covering_face(tile_log2):
    """Without the tile Hi-Z every covered centre of every face is tested: the overdraw of a
    soup equals, per pixel, the number of faces whose lone rendering covers it — through
    each of the raster's paths (boxes of up to 4 × 4 centres from setup's coverage bits,
    narrow pieces' edge lanes, wide pieces' runs), across tile seams and at the image's cut
    edge."""
    w, h = 61, 37   # tiles cut by the right and bottom edges
    rng = np.random.default_rng(11)
    tris = []
    for size in [1.5] * 40 + [3.0] * 30 + [9.0] * 20 + [30.0] * 8:
        c = rng.uniform([-4, -4], [w + 4, h + 4])
        tris.append(c + rng.uniform(-size, size, (3, 2)))
    tris = np.round(np.array(tris) * 256) / 256   # on the 1/256 grid: exact snapping
    mesh = window_mesh(tris, w, h)
    r = Renderer(w, h, config=RasterConfig(tile_log2=tile_log2, tile_hiz=False))
    fr = r.render(mesh, NDC_CAMERA, cull="none", frustum=False, cones=False, overdraw=True)
    expect = np.zeros((h, w), np.int64)
    for m in single_masks(mesh, NDC_CAMERA, w, h, tile_log2):
        expect += m
    assert expect.max() >= 3 and (expect > 0).sum() > 300   # overlaps, real coverage
    np.testing.assert_array_equal(fr.overdraw, expect)
    assert fr.stats.fragments_tested == expect.sum()
