"""Reliability of the shading helpers: pixel-space render keywords follow `render_shaded`'s
supersampling (a window given in output pixels draws the same region at every ssaa), and
the depth pictures (`shade.depth_image`, `demo.depth_picture`) read a reversed-Z frame by
its own convention (same picture as the frame rendered with standard depth)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MatrixCamera

from clraster import Camera
from clraster.clip.clip2d import Polygon2D
from clraster.demo import depth_picture
from clraster.output.shade import depth_image, render_shaded
from clraster.pipeline import reference
from clraster.world.mesh import Mesh

W, H = 40, 30
# the quad [-1, 1]² at z = 0 fills the image exactly under the identity clip matrix
QUAD = Mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
IDENTITY = MatrixCamera(np.eye(4))
HEAD_ON = (0.0, 0.0, 1.0)

# Windows in output pixels (x right, y down). Vertices at non-half-integer positions
# (x.3, x.7...) so that no pixel centre or 2× sample lies on an edge: Polygon2D.contains
# then gives the exact coverage without the top-left rule.
RECT = [[5.2, 4.3], [25.7, 4.3], [25.7, 20.6], [5.2, 20.6]]
CONCAVE = [[3.3, 2.2], [36.6, 3.7], [20.2, 13.4], [35.1, 27.3], [4.4, 26.1]]
WITH_HOLE = ([[2.3, 2.3], [37.7, 2.3], [37.7, 27.7], [2.3, 27.7]],
             [[[12.2, 9.3], [27.6, 9.3], [27.6, 20.7], [12.2, 20.7]]])
WINDOWS = {"rectangle": RECT, "concave": CONCAVE, "with_hole": WITH_HOLE,
           "polygon2d": Polygon2D(np.asarray(CONCAVE))}


def _coverage(window, k: int) -> np.ndarray:
    """float (H, W): the fraction of each output pixel's k × k sample centres inside the
    window, by point-in-polygon on the sample positions (independent of the renderer's
    mask code)."""
    poly = window if isinstance(window, Polygon2D) else (
        Polygon2D(window[0], tuple(window[1])) if isinstance(window, tuple)
        else Polygon2D(window))
    s = (np.arange(k) + 0.5) / k
    ys = (np.arange(H)[:, None] + s[None, :]).reshape(-1)
    xs = (np.arange(W)[:, None] + s[None, :]).reshape(-1)
    pts = np.stack(np.meshgrid(xs, ys), axis=-1)            # (k·H, k·W, 2) as (x, y)
    inside = poly.contains(pts).astype(np.float64)
    return inside.reshape(H, k, W, k).mean(axis=(1, 3))


def _renderers(renderer_for):
    return {"reference": reference.Renderer(W, H), "opencl": renderer_for(W, H)}


@pytest.mark.parametrize("kind", ["reference", "opencl"])
@pytest.mark.parametrize("name", sorted(WINDOWS))
def test_ssaa_window_draws_the_same_region(renderer_for, kind, name):
    window = WINDOWS[name]
    renderer = _renderers(renderer_for)[kind]
    kw = {"window": window, "cull": "none"}
    one = render_shaded(renderer, QUAD, IDENTITY, ssaa=1, light_dir=HEAD_ON, alpha=True,
                        render_kwargs=kw)
    inside1 = _coverage(window, 1) > 0
    np.testing.assert_array_equal(one[..., 3] == 255, inside1)
    assert inside1.sum() > 100 and (~inside1).sum() > 100
    for k in (2, 3, 4):
        aa = render_shaded(renderer, QUAD, IDENTITY, ssaa=k, light_dir=HEAD_ON, alpha=True,
                           render_kwargs=kw)
        frac = _coverage(window, k)
        # alpha is the covered fraction of each pixel's samples: full inside the window,
        # partial only on pixels its edges cross, zero outside. (The renderer snaps the
        # window to 1/256 of a k× pixel, so a sample within that of an edge may flip: at
        # most one sample, on a few pixels.)
        alpha = aa[..., 3].astype(int)
        diff = np.abs(alpha - np.rint(frac * 255))
        assert diff.max() <= np.ceil(255 / k**2) and np.count_nonzero(diff) <= 3
        # the covered region equals the 1× one up to the edge pixels AA blends
        edge = ((frac > 0) & (frac < 1)) | ((alpha > 0) & (alpha < 255))
        assert edge.sum() < 0.5 * inside1.sum()
        np.testing.assert_array_equal((alpha > 0)[~edge], inside1[~edge])
        # outside the window: background (white), alpha 0
        out = (frac == 0) & (alpha == 0)
        assert out.sum() > 100
        assert np.all(aa[out] == [255, 255, 255, 0])
        # the caller's keywords are not changed
        assert kw["window"] is window


def test_ssaa_window_rgb_and_other_keywords():
    # RGB output blends the edge pixels with the background; clip planes (world space)
    # pass unscaled: the plane x >= 0 keeps the right half of the quad at every ssaa
    renderer = reference.Renderer(W, H)
    kw = {"window": RECT, "clip_planes": [[1.0, 0.0, 0.0, 0.0]], "cull": "none"}
    one = render_shaded(renderer, QUAD, IDENTITY, ssaa=1, light_dir=HEAD_ON,
                        background=(0, 0, 0), render_kwargs=kw)
    two = render_shaded(renderer, QUAD, IDENTITY, ssaa=2, light_dir=HEAD_ON,
                        background=(0, 0, 0), render_kwargs=kw)
    right = np.zeros((H, W), bool)
    right[:, W // 2:] = True
    expected1 = (_coverage(RECT, 1) > 0) & right
    np.testing.assert_array_equal(one[..., 0] > 0, expected1)
    frac2 = _coverage(RECT, 2) * right
    full, empty = frac2 == 1, frac2 == 0
    assert full.sum() > 50 and empty.sum() > 100
    np.testing.assert_array_equal(two[full], one[full])
    assert np.all(two[empty] == 0)


def test_ssaa_window_beyond_the_supersampled_limit():
    from clraster.clip.window import WINDOW_MAX_COORD

    big = WINDOW_MAX_COORD / 2 + 10
    far = [[0.0, 0.0], [big, 0.0], [big, 20.0], [0.0, 20.0]]
    renderer = reference.Renderer(8, 8)
    render_shaded(renderer, QUAD, IDENTITY, ssaa=1, render_kwargs={"window": far})
    with pytest.raises(ValueError, match=r"render_kwargs\['window'\].*ssaa=2"):
        render_shaded(renderer, QUAD, IDENTITY, ssaa=2, render_kwargs={"window": far})
    with pytest.raises(ValueError, match=r"render_kwargs\['window'\]"):
        render_shaded(renderer, QUAD, IDENTITY, ssaa=2,
                      render_kwargs={"window": [[0, 0], [1, 1]]})


# -- depth pictures of reversed-Z frames ----------------------------------------------------

def _sphere_frames(w: int = 48, h: int = 36):
    import trimesh

    s = trimesh.creation.icosphere(3)
    mesh = Mesh(s.vertices, s.faces)
    cam = Camera.look_at(eye=(0.6, 0.8, 3.2), target=(0, 0, 0), fov_y=45.0, near=0.1,
                         far=100.0)
    std = reference.render(mesh, cam, w, h)
    rev = reference.render(mesh, cam, w, h, reversed_z=True)
    assert rev.reversed_z and not std.reversed_z
    # the same surface is visible (no far-depth ties on one sphere)
    np.testing.assert_array_equal(rev.triangle_id, std.triangle_id)
    return std, rev, cam


def test_depth_image_of_a_reversed_z_frame_matches_the_standard_one():
    std, rev, _ = _sphere_frames()
    a, b = depth_image(std), depth_image(rev)
    covered = std.triangle_id >= 0
    assert covered.sum() > 200 and (~covered).sum() > 200
    np.testing.assert_array_equal(a == 255, ~covered)      # background
    np.testing.assert_array_equal(b == 255, ~covered)
    # float32 rounding differs between the two conventions: at most one grey level
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1
    # near dark, far light in both: the nearest covered pixel is 0, the farthest 235
    for img in (a, b):
        assert img[covered].min() == 0 and img[covered].max() == 235
    # the Frame's own buffer with the matching flag gives the same picture
    np.testing.assert_array_equal(depth_image(rev.depth, reversed_z=True), b)
    np.testing.assert_array_equal(depth_image(std.depth, reversed_z=False), a)
    np.testing.assert_array_equal(depth_image(std.depth), a)
    np.testing.assert_array_equal(depth_image(rev, reversed_z=True), b)


def test_depth_image_reversed_array():
    # the existing standard-Z example mirrored: d_rev = 1 − d_std, background 0
    d = np.array([[0.0, 0.8, 0.4], [0.6, 0.0, np.nan]], dtype=np.float32)
    img = depth_image(d, reversed_z=True)
    assert img[0, 1] == 0  # nearest (largest reversed depth): black
    assert img[0, 2] == 235  # farthest covered
    assert 0 < img[1, 0] < 235
    assert img[0, 0] == img[1, 1] == img[1, 2] == 255  # background (and NaN)
    np.testing.assert_array_equal(
        img, depth_image(np.array([[1.0, 0.2, 0.6], [0.4, 1.0, np.nan]], np.float32)))
    # all background (reversed clears to 0)
    np.testing.assert_array_equal(depth_image(np.zeros((2, 2)), reversed_z=True), 255)


def test_depth_image_refuses_a_contradicting_or_bad_flag():
    std, rev, _ = _sphere_frames(8, 6)
    with pytest.raises(ValueError, match="reversed_z"):
        depth_image(rev, reversed_z=False)
    with pytest.raises(ValueError, match="reversed_z"):
        depth_image(std, reversed_z=True)
    with pytest.raises(ValueError, match="reversed_z must be True or False"):
        depth_image(std.depth, reversed_z="yes")


def test_demo_depth_picture_of_a_reversed_z_frame():
    std, rev, cam = _sphere_frames(160, 120)
    proj = cam.projection(std.width, std.height)
    a, b = depth_picture(std, proj), depth_picture(rev, proj)
    # background black in both, surface coloured (above the colour bar's panel, drawn in
    # the lower right corner)
    top = slice(0, 60)
    covered = std.triangle_id[top] >= 0
    assert covered.sum() > 200 and (~covered).sum() > 200
    for img in (a, b):
        assert np.all(img[top][~covered] == 0)
        assert np.all(img[top][covered].max(axis=-1) > 0)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 2
    np.testing.assert_array_equal(depth_picture(rev.depth, proj, reversed_z=True), b)
    np.testing.assert_array_equal(depth_picture(std.depth, proj), a)
    with pytest.raises(ValueError, match="reversed_z"):
        depth_picture(rev, proj, reversed_z=False)
