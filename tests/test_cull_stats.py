"""Back-face culling modes and the per-stage counts, on hand-built cases whose counts are
known in advance; plus the invariants that tie the cull modes and the counts together on
random soups.
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
    render_both,
    render_cl,
    window_mesh,
)
from random_scenes import Lens, random_soup

from clraster import Camera, Mesh, RasterConfig

TRIANGLE_COUNTS = ("invalid", "trivially_rejected", "backface_culled", "degenerate",
                   "no_sample", "clipped")

CCW_NDC = [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]]  # counter-clockwise in NDC


def counts_of(mesh, camera=NDC_CAMERA, w=32, h=32, cull="none", tile_log2=4, hiz=True):
    """Counts of the OpenCL frame, after checking the twin agrees on everything."""
    a, b = render_both(mesh, camera, w, h, cull=cull, tile_log2=tile_log2, hiz=hiz)
    assert_frames_equal(a, b, f"cull={cull}")
    check_partition(a.stats)
    return a, a.stats.counts()


def check_partition(s) -> None:
    c = s.counts()
    unclipped = s.rasterized - s.clip_pieces
    assert unclipped >= 0 and s.clip_pieces >= 0
    assert sum(c[k] for k in TRIANGLE_COUNTS) + unclipped == s.triangles_in, c
    assert 0 <= s.fragments_passed <= s.fragments_tested, c
    # every rasterized piece has a non-empty pixel box inside the viewport: ≥ 1 tile
    # (a rasterized piece can reach no tile: binning skips tiles its edges cannot reach)
    assert s.binned_entries >= 0, c
    if s.rasterized == 0:
        assert s.fragments_tested == 0 and s.binned_entries == 0, c


# --- back-face modes ---------------------------------------------------------------------

@pytest.mark.parametrize("cull, drawn", [("back", True), ("none", True), ("front", False)])
def test_ccw_triangle(cull, drawn):
    fr, c = counts_of(Mesh(CCW_NDC, [[0, 1, 2]]), cull=cull)
    assert fr.mask.any() == drawn
    assert c["backface_culled"] == (0 if drawn else 1)
    assert c["rasterized"] == (1 if drawn else 0)


@pytest.mark.parametrize("cull, drawn", [("back", False), ("none", True), ("front", True)])
def test_cw_triangle(cull, drawn):
    fr, c = counts_of(Mesh(CCW_NDC, [[0, 2, 1]]), cull=cull)
    assert fr.mask.any() == drawn
    assert c["backface_culled"] == (0 if drawn else 1)


def test_winding_seen_through_a_look_at_camera():
    """World-space triangle with its normal towards the eye is front-facing (CCW)."""
    tri = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])  # normal +Z
    front_view = Camera.look_at((0.0, 0.0, 4.0), (0.0, 0.0, 0.0))
    back_view = Camera.look_at((0.0, 0.0, -4.0), (0.0, 0.0, 0.0))
    mesh = Mesh(tri, [[0, 1, 2]])
    assert render_cl(mesh, front_view, 32, 32, cull="back").mask.sum() > 20
    assert not render_cl(mesh, back_view, 32, 32, cull="back").mask.any()
    assert render_cl(mesh, back_view, 32, 32, cull="front").mask.sum() > 20


def test_backface_counts_mixed():
    """7 CCW and 4 CW small triangles in separate places; counts per mode are exact."""
    rng = np.random.default_rng(0)
    tris = []
    for i in range(11):
        cx, cy = 4 + 6 * (i % 5), 4 + 8 * (i // 5)
        t = np.array([[cx - 2.3, cy + 2.1], [cx + 2.2, cy + 2.0], [cx, cy - 2.4]])
        t += rng.uniform(-0.3, 0.3, t.shape)
        # window space y is down: this order is clockwise in window = CCW in NDC
        tris.append(t if i < 7 else t[[0, 2, 1]])
    mesh = window_mesh(tris, 32, 32)
    for cull, culled, visible in (("back", 4, set(range(7))), ("front", 7, set(range(7, 11))),
                                  ("none", 0, set(range(11)))):
        fr, c = counts_of(mesh, cull=cull)
        assert c["backface_culled"] == culled
        assert set(fr.visible_faces().tolist()) == visible
        assert c["rasterized"] == 11 - culled


@pytest.mark.parametrize("ccw", [True, False])
def test_cull_applies_to_clipped_triangles(ccw):
    """A triangle crossing the near plane: facing is decided before clipping (homogeneous
    determinant), so the mode that culls it never clips it; the other clips and draws it."""
    cam = MatrixCamera(perspective(90.0, 1.0, 0.5, 50.0))
    v = np.array([[-2.0, -1.0, -3.0], [2.0, -1.0, -3.0], [0.0, 1.0, 1.0]])  # CCW, v2 behind
    mesh = Mesh(v, [[0, 1, 2]] if ccw else [[0, 2, 1]])
    fb, cb = counts_of(mesh, cam, cull="back")
    ff, cf = counts_of(mesh, cam, cull="front")
    assert (cb["clipped"], cf["clipped"]) == ((1, 0) if ccw else (0, 1))
    assert (cb["backface_culled"], cf["backface_culled"]) == ((0, 1) if ccw else (1, 0))
    drawn, culled = (fb, ff) if ccw else (ff, fb)
    assert drawn.mask.sum() > 50 and not culled.mask.any()
    assert drawn.stats.clip_pieces >= 1 and culled.stats.clip_pieces == 0


# --- counts on constructed cases ---------------------------------------------------------

def test_trivially_rejected_outside_each_plane():
    cam = MatrixCamera(perspective(90.0, 1.0, 1.0, 10.0))
    # at z = −5 the view spans x, y in [−5, 5]; near/far at depth 1 and 10
    tris = [
        [[6, 0, -5], [9, 1, -5], [7, 3, -5]],  # right of x = w
        [[-6, 0, -5], [-7, 3, -5], [-9, 1, -5]],  # left
        [[0, 6, -5], [1, 9, -5], [-2, 7, -5]],  # above
        [[0, -6, -5], [-2, -7, -5], [1, -9, -5]],  # below
        [[0, 0, -11], [1, 0, -12], [0, 1, -11.5]],  # beyond far
        [[0, 0, -0.5], [0.1, 0, -0.6], [0, 0.1, -0.7]],  # between the eye and near
        [[0, 0, 1], [1, 0, 1], [0, 1, 2]],  # behind the eye
    ]
    mesh = Mesh(np.array(tris, dtype=float).reshape(-1, 3), np.arange(21).reshape(7, 3))
    for cull in ("none", "back"):
        fr, c = counts_of(mesh, cam, cull=cull)
        assert c["trivially_rejected"] == 7 and c["rasterized"] == 0 and c["clipped"] == 0
        assert not fr.mask.any() and c["binned_entries"] == 0


def test_three_outside_one_plane():
    mesh = Mesh([[1.5, 0, 0], [2.5, 0.5, 0], [1.2, 0.9, 0], [3.0, -0.2, 0]],
                [[0, 1, 2], [0, 2, 3], [1, 2, 3]])
    _, c = counts_of(mesh)
    assert c["trivially_rejected"] == 3 and c["triangles_in"] == 3


def test_straddling_a_corner_is_not_rejected_but_covers_nothing():
    """Vertices outside different planes (outcode AND = 0) but the triangle misses the
    viewport: it is rasterized (its box holds pixel centres) and tests no fragment."""
    mesh = Mesh([[-3.0, 0.5, 0], [0.5, 3.0, 0], [-3.0, 3.0, 0]], [[0, 1, 2]])
    fr, c = counts_of(mesh)
    assert c["trivially_rejected"] == 0 and c["no_sample"] == 0 and c["rasterized"] == 1
    assert c["fragments_tested"] == 0 and not fr.mask.any()


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_vertex_shared_by_two_faces(bad):
    v = np.array([[-0.9, -0.9, 0], [0.9, -0.9, 0], [0.9, 0.9, 0], [-0.9, 0.9, 0], [0, 0, 0]])
    v[4, 1] = bad
    # faces 0 and 2 use vertex 4; faces 1 and 3 do not
    mesh = Mesh(v, [[0, 1, 4], [0, 1, 2], [2, 3, 4], [0, 2, 3]])
    fr, c = counts_of(mesh)
    assert c["invalid"] == 2 and c["rasterized"] == 2
    assert set(fr.visible_faces().tolist()) == {1, 3}


def test_near_crossing_pieces():
    cam = MatrixCamera(perspective(90.0, 1.0, 1.0, 100.0))
    one_behind = Mesh([[-3, -1, -4], [3, -1, -4], [0, 1, -0.5]], [[0, 1, 2]])
    _, c = counts_of(one_behind, cam)
    # one vertex cut off: a quadrilateral, fanned into 2 pieces
    assert c["clipped"] == 1 and c["clip_pieces"] == 2 and c["rasterized"] == 2
    two_behind = Mesh([[-3, -1, -0.5], [3, -1, -0.5], [0, 1, -4]], [[0, 1, 2]])
    _, c = counts_of(two_behind, cam)
    assert c["clipped"] == 1 and c["clip_pieces"] == 1
    w_zero = Mesh([[-3, -1, -4], [3, -1, -4], [0, 1, 0.0]], [[0, 1, 2]])  # w = 0 exactly
    fr, c = counts_of(w_zero, cam)
    assert c["clipped"] == 1 and c["clip_pieces"] == 2 and fr.mask.sum() > 20
    assert np.isfinite(fr.depth).all() and np.isfinite(fr.barycentrics).all()


def test_degenerate_cases():
    tris = window_mesh([[[2, 2], [10, 10], [6, 6]],  # collinear
                        [[3, 3], [3, 3], [9, 4]],  # two coincident vertices
                        [[5, 5], [5, 5], [5, 5]],  # a point
                        # collinear after the 1/256 snap only
                        [[1, 1], [20, 20], [10.5, 10.5 + 1 / 2048]]], 32, 32)
    fr, c = counts_of(tris)
    assert c["degenerate"] == 4 and c["rasterized"] == 0 and not fr.mask.any()
    repeated_index = Mesh(CCW_NDC, [[0, 0, 1], [1, 2, 2], [0, 1, 2]])
    fr, c = counts_of(repeated_index)
    assert c["degenerate"] == 2 and c["rasterized"] == 1
    assert set(fr.visible_faces().tolist()) == {2}


def test_no_sample_between_pixel_centres():
    # bounding box [3.6, 4.4] × [7.6, 8.4]: no pixel centre (x + 0.5) inside it
    mesh = window_mesh([[[3.6, 7.6], [4.4, 7.7], [3.9, 8.4]],
                        [[10.55, 1.0], [10.9, 9.0], [10.6, 9.0]]], 32, 32)
    fr, c = counts_of(mesh)
    assert c["no_sample"] == 2 and c["rasterized"] == 0 and not fr.mask.any()
    # a sub-pixel triangle that does contain a pixel centre is drawn
    mesh = window_mesh([[[4.3, 8.3], [4.7, 8.35], [4.45, 8.8]]], 32, 32)
    fr, c = counts_of(mesh)
    assert c["no_sample"] == 0 and fr.mask.sum() == 1 and fr.triangle_id[8, 4] == 0


def test_fragment_and_bin_counts_single_triangle():
    """One triangle, its bounding box [3, 20] × [5, 9] in pixels (by hand: centres 3.5..20.5
    and 5.5..9.5): with 8-px tiles its box overlaps tile columns 0..2 and rows 0..1, but
    tile (2, 1) (x ≥ 16, y ≥ 8) lies below its bottom edge, which is at y ≈ 7.6 at x = 16
    and rises to the right → binning skips it: 5 entries; with 16-px tiles columns 0..1,
    row 0 → 2; with 64-px tiles 1. Fragments tested = covered pixels (a single triangle
    over an empty depth buffer passes them all)."""
    tri = [[[3.2, 5.1], [20.9, 6.0], [9.0, 9.8]]]
    mesh = window_mesh(tri, 32, 32)
    for t, entries in ((3, 5), (4, 2), (6, 1)):
        fr, c = counts_of(mesh, tile_log2=t)
        assert c["binned_entries"] == entries
        assert c["fragments_tested"] == c["fragments_passed"] == fr.mask.sum() > 30
        ys, xs = np.nonzero(fr.mask)
        assert xs.min() >= 3 and xs.max() <= 20 and ys.min() >= 5 and ys.max() <= 9


def test_bin_counts_piece_over_two_by_two_tiles():
    """A right triangle A (9.3, 9.4), B (21.6, 9.1), C (9.1, 21.7), by hand: pixel box
    [9, 21] × [9, 21], its hypotenuse BC on x + y ≈ 30.7. With 16-px tiles the box spans
    tiles (0..1) × (0..1), and the first pixel centre of tile (1, 1), (16.5, 16.5), has
    x + y = 33: beyond BC, so the piece goes to 3 tiles (setup's 2 × 2 tile mask, binning
    without its record); with 8-px tiles (1..2) × (1..2), tile (2, 2) skipped the same way:
    3; with 32-px tiles 1. Every covered pixel is drawn (fragments = covered pixels) and
    none lies where both x and y are ≥ 16."""
    mesh = window_mesh([[[9.3, 9.4], [21.6, 9.1], [9.1, 21.7]]], 32, 32)
    for t, entries in ((3, 3), (4, 3), (5, 1)):
        fr, c = counts_of(mesh, tile_log2=t)
        assert c["binned_entries"] == entries, t
        assert c["fragments_tested"] == c["fragments_passed"] == fr.mask.sum() > 50
        ys, xs = np.nonzero(fr.mask)
        assert xs.min() >= 9 and xs.max() <= 21 and ys.min() >= 9 and ys.max() <= 21
        assert not fr.mask[16:, 16:].any()
        assert fr.mask[9:16, 16:].any() and fr.mask[16:, 9:16].any()
    # not symmetric: A (9.3, 9.2), B (22.4, 9.6), C (21.8, 22.3), its edge CA near the
    # diagonal y = x, so of the 16-px tiles it reaches (0, 0), (1, 0) and (1, 1), not
    # (0, 1) (x < 16, y ≥ 16: below CA); its pixels in (1, 0) and (1, 1) are drawn only if
    # the piece is in those tiles' lists
    mesh = window_mesh([[[9.3, 9.2], [22.4, 9.6], [21.8, 22.3]]], 32, 32)
    fr, c = counts_of(mesh, tile_log2=4)
    assert c["binned_entries"] == 3
    assert c["fragments_tested"] == c["fragments_passed"] == fr.mask.sum() > 50
    assert not fr.mask[16:, :16].any()
    assert fr.mask[:16, :16].any() and fr.mask[:16, 16:].any() and fr.mask[16:, 16:].any()


def test_partly_off_screen_triangle_is_clamped():
    mesh = window_mesh([[[-40.0, -30.0], [50.0, 10.0], [10.0, 60.0]]], 32, 32)
    fr, c = counts_of(mesh)
    assert c["clipped"] == 0 and c["rasterized"] == 1
    assert c["fragments_tested"] == fr.mask.sum()


def test_overdraw_counts():
    """Three full-screen layers, drawn far to near then near to far."""
    w = h = 16
    cam = MatrixCamera(perspective(90.0, 1.0, 0.5, 50.0))
    layers = [np.array([[-100, -100, -z], [100, -100, -z], [0, 100, -z]]) for z in (9, 6, 3)]
    far_to_near = Mesh(np.concatenate(layers), np.arange(9).reshape(3, 3))
    near_to_far = Mesh(np.concatenate(layers[::-1]), np.arange(9).reshape(3, 3))
    fr, c = counts_of(far_to_near, cam, w, h)
    assert c["fragments_tested"] == 3 * w * h and c["fragments_passed"] == 3 * w * h
    assert (fr.triangle_id == 2).all()
    fr, c = counts_of(near_to_far, cam, w, h, hiz=False)
    assert c["fragments_tested"] == 3 * w * h and c["fragments_passed"] == w * h
    assert (fr.triangle_id == 0).all()
    # the tile Hi-Z (default): once the near layer fills the one 16-px tile, the two
    # behind it are skipped untested (far to near, above, every layer is nearer than the
    # tile's farthest depth and is tested)
    fr, c = counts_of(near_to_far, cam, w, h)
    assert c["fragments_tested"] == w * h and c["fragments_passed"] == w * h
    assert (fr.triangle_id == 0).all()
    # 8-px tiles: the same, tile by tile
    fr, c = counts_of(near_to_far, cam, w, h, tile_log2=3)
    assert c["fragments_tested"] == w * h and (fr.triangle_id == 0).all()


@pytest.mark.parametrize("v", [1, 0, "yes", None])
def test_tile_hiz_validated(v):
    with pytest.raises(ValueError, match="tile_hiz"):
        RasterConfig(tile_hiz=v)


# --- cull modes and counts on random soups -----------------------------------------------

@pytest.mark.parametrize("seed, size, tile_log2", [(21, (65, 47), 3), (22, (128, 33), 5)])
def test_cull_modes_partition_random_soup(seed, size, tile_log2):
    """On any scene: "none" = "back" ∪ "front". Depth of "none" is the minimum of the two,
    its ids follow (lower id on ties), and the counts add up."""
    w, h = size
    lens = Lens(70.0, 0.5, 200.0)
    v, f, _ = random_soup(np.random.default_rng(seed), 3000, w, h, lens)
    mesh = Mesh(v, f)
    cam = MatrixCamera(lens.projection(w / h))
    # without the tile Hi-Z, so that fragments_tested counts every covered fragment
    fn, cn = counts_of(mesh, cam, w, h, "none", tile_log2, hiz=False)
    fb, cb = counts_of(mesh, cam, w, h, "back", tile_log2, hiz=False)
    ff, cf = counts_of(mesh, cam, w, h, "front", tile_log2, hiz=False)
    np.testing.assert_array_equal(fn.depth, np.minimum(fb.depth, ff.depth))
    exp = np.where(fb.depth < ff.depth, fb.triangle_id,
                   np.where(ff.depth < fb.depth, ff.triangle_id,
                            np.where((fb.triangle_id >= 0) & (ff.triangle_id >= 0),
                                     np.minimum(fb.triangle_id, ff.triangle_id),
                                     np.maximum(fb.triangle_id, ff.triangle_id))))
    np.testing.assert_array_equal(fn.triangle_id, exp)
    for k in ("invalid", "trivially_rejected", "triangles_in"):
        assert cn[k] == cb[k] == cf[k], k
    assert cn["backface_culled"] == 0
    assert cb["backface_culled"] > 100 and cf["backface_culled"] > 100
    # facing is decided first: every triangle past trivial reject is front, back or edge-on
    # (det == 0, "degenerate" in all three modes); what follows splits between the modes
    for k in ("clipped", "clip_pieces", "no_sample", "rasterized"):
        assert cb[k] + cf[k] == cn[k], k
    edge_on = cb["degenerate"] + cf["degenerate"] - cn["degenerate"]
    assert edge_on >= 0
    assert (cb["backface_culled"] + cf["backface_culled"] + edge_on
            == cn["triangles_in"] - cn["invalid"] - cn["trivially_rejected"])
    assert cb["fragments_tested"] + cf["fragments_tested"] == cn["fragments_tested"]
    assert cb["binned_entries"] + cf["binned_entries"] == cn["binned_entries"]
