"""Polygon windows (issue 16, item 4): ``render(..., window=polygon)``.

The mask (`clraster.window.window_mask`) is checked against a point-in-polygon test of the
nudged centres and for the tiling property; the render against the unwindowed frame
restricted to the mask, and against the twin (images and fragment counts).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_frames_equal, assert_same_image, get_renderer, load_shared_mesh

from clraster import Camera, RasterConfig, Renderer
from clraster.clip.clip2d import as_polygon
from clraster.clip.window import window_mask
from clraster.pipeline import reference as twin
from clraster.world.generators import random_scene

W, H = 96, 72


def _star(rng: np.random.Generator, cx: float, cy: float, n: int, r0: float, r1: float):
    """A star-shaped (simple) polygon around (cx, cy): n vertices at increasing angles
    spread over the whole turn, radii in [r0, r1], snapped to 1/256 px."""
    ang = (np.arange(n) + rng.uniform(0.1, 0.9, n)) * (2 * np.pi / n)
    r = rng.uniform(r0, r1, n)
    ring = np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], axis=1)
    return np.rint(ring * 256) / 256


def test_mask_is_point_in_polygon_of_the_nudged_centres():
    rng = np.random.default_rng(16)
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    nudged = np.stack([xs + 1e-7, ys + 1e-12], -1)
    for _ in range(20):
        ring = _star(rng, 48, 36, int(rng.integers(5, 14)), 6, 40)
        np.testing.assert_array_equal(window_mask(ring, W, H),
                                      as_polygon(ring).contains(nudged))
    # with a hole
    hole = _star(rng, 48, 36, 7, 3, 8)
    outer = _star(rng, 48, 36, 9, 25, 34)
    np.testing.assert_array_equal(window_mask((outer, [hole]), W, H),
                                  as_polygon((outer, [hole])).contains(nudged))


def test_windows_that_tile_the_screen_cover_every_pixel_once():
    """Four windows sharing edges through pixel centres, corners and rows (the cases the
    top-left rule decides) tile the image: every pixel is let through exactly once."""
    c = (40.5, 30.5)   # a pixel centre
    zig = [(W + 1.0, 20.5), (70.5, 30.5), c, (20.0, 40.5), (-1.0, 40.5)]
    top = [(-1.0, -1.0), (W + 1.0, -1.0), *zig]
    bottom = [*zig[::-1], (W + 1.0, H + 1.0), (-1.0, H + 1.0)]
    # split the bottom by a vertical line through a column of centres, the top by a
    # diagonal through centres
    b_left = [(-1.0, 40.5), (20.0, 40.5), (40.5, 30.5), (40.5, H + 1.0), (-1.0, H + 1.0)]
    b_right = [(40.5, 30.5), (70.5, 30.5), (W + 1.0, 20.5), (W + 1.0, H + 1.0),
               (40.5, H + 1.0)]
    t_left = [(-1.0, -1.0), (12.5, -1.0), (40.5, 30.5), (20.0, 40.5), (-1.0, 40.5)]
    t_right = [(12.5, -1.0), (W + 1.0, -1.0), (W + 1.0, 20.5), (70.5, 30.5), (40.5, 30.5)]
    count = sum(window_mask(p, W, H).astype(int) for p in (b_left, b_right, t_left, t_right))
    np.testing.assert_array_equal(count, np.ones((H, W), int))
    assert as_polygon(top).area > 0 and as_polygon(bottom).area > 0


def _spot_frame(r, **kw):
    mesh = load_shared_mesh("spot.ply")
    lo, hi = mesh.bounds()
    cam = Camera.framing(lo, hi, direction=(0.4, 0.3, 1.0), aspect=W / H)
    return mesh, cam, r.render(mesh, cam, **kw)


@pytest.mark.parametrize("shape", ["star", "u", "holed"])
def test_windowed_frame_is_the_frame_restricted_to_the_window(shape):
    rng = np.random.default_rng(3)
    if shape == "star":
        win = _star(rng, 50, 30, 11, 8, 30)
    elif shape == "u":   # concave, two prongs
        win = [(10.3, 5.2), (30.7, 5.2), (30.7, 50.1), (60.2, 50.1), (60.2, 5.2), (85.9, 5.2),
               (85.9, 66.6), (10.3, 66.6)]
    else:
        win = (_star(rng, 48, 36, 9, 28, 34), [_star(rng, 48, 36, 7, 6, 12)])
    r = get_renderer(W, H)
    mesh, cam, full = _spot_frame(r)
    _, _, f = _spot_frame(r, window=win)
    m = window_mask(win, W, H)
    assert 0 < (m & (full.triangle_id >= 0)).sum() < (full.triangle_id >= 0).sum()
    np.testing.assert_array_equal(f.triangle_id, np.where(m, full.triangle_id, -1))
    np.testing.assert_array_equal(f.depth, np.where(m, full.depth, np.float32(1.0)))
    np.testing.assert_array_equal(f.barycentrics,
                                  np.where(m[..., None], full.barycentrics, np.float32(0)))
    assert f.stats.fragments_passed < full.stats.fragments_passed
    b = twin.render(mesh, cam, W, H, window=win)
    assert_frames_equal(f, b, f"window {shape} (OpenCL vs twin)")
    assert (f.stats.fragments_tested, f.stats.fragments_passed) == (
        b.stats.fragments_tested, b.stats.fragments_passed)


def test_window_with_occlusion_streaming_clip_planes_and_reversed_z():
    scene = random_scene(9, 50, extent=5.0)
    cam = Camera.look_at((0.0, 3.0, 16.0), (0.0, 0.0, 0.0), fov_y=55.0, near=0.1, far=60.0)
    win = [(5.5, 3.25), (90.0, 10.0), (70.0, 68.0), (30.0, 40.0), (8.0, 60.0)]
    kw = dict(window=win, clip_planes=[[0.0, -1.0, 0.0, 1.0]], reversed_z=True)
    ref = get_renderer(W, H).render(scene, cam, **kw)
    plain = get_renderer(W, H).render(scene, cam, clip_planes=kw["clip_planes"],
                                      reversed_z=True)
    m = window_mask(win, W, H)
    np.testing.assert_array_equal(ref.triangle_id, np.where(m, plain.triangle_id, -1))
    np.testing.assert_array_equal(ref.depth, np.where(m, plain.depth, np.float32(0.0)))
    r = Renderer(W, H)
    for _ in range(2):
        assert_same_image(r.render(scene, cam, occlusion=True, **kw), ref, "occlusion",
                          "occlusion culling with a window")
    small = Renderer(W, H, config=RasterConfig(batch_triangles=128, batch_entries=64))
    assert_same_image(small.render(scene, cam, **kw), ref, "streamed", "batching with a window")
    assert_frames_equal(ref, twin.render(scene, cam, W, H, **kw), "window + planes (twin)")


def test_a_window_off_screen_draws_nothing_and_bad_windows_are_refused():
    r = get_renderer(W, H)
    _, _, f = _spot_frame(r, window=[(200.0, 10.0), (260.0, 10.0), (230.0, 50.0)])
    assert (f.triangle_id == -1).all() and (f.depth == 1.0).all()
    assert f.stats.fragments_tested == 0
    for bad in ([(0, 0), (1, 1)], [(0, 0), (10, 0), (0, 10), (10, 10)], [(0, 0), (1e9, 0),
                                                                          (0, 5)]):
        with pytest.raises(ValueError):
            _spot_frame(r, window=bad)


def test_the_window_culls_and_rejects_what_it_cannot_show_but_clips_nothing():
    """A small window over part of a dragon: its bounding planes (through the eye, one pixel
    outside its hull) cull clusters and reject triangles wholly outside it before binning,
    but never clip (clipped counts equal the unwindowed frame's), and the image is still
    the unwindowed one restricted to the window."""
    mesh = load_shared_mesh("stanford_dragon_res2.ply")
    lo, hi = mesh.bounds()
    cam = Camera.framing(lo, hi, direction=(0.3, 0.2, 1.0), aspect=W / H)
    win = [(30.25, 20.5), (52.0, 18.0), (60.5, 40.0), (34.0, 44.75)]
    r = get_renderer(W, H)
    full, f = r.render(mesh, cam), r.render(mesh, cam, window=win)
    m = window_mask(win, W, H)
    np.testing.assert_array_equal(f.triangle_id, np.where(m, full.triangle_id, -1))
    np.testing.assert_array_equal(f.depth, np.where(m, full.depth, np.float32(1.0)))
    assert f.stats.clusters_drawn < 0.5 * full.stats.clusters_drawn
    assert f.stats.clipped == full.stats.clipped
    assert f.stats.fragments_tested < 0.5 * full.stats.fragments_tested
    b = twin.render(mesh, cam, W, H, window=win)
    assert_frames_equal(f, b, "dragon window (OpenCL vs twin)")
