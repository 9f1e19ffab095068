"""Per-pixel passes (`clraster.output.post`): SSAO, FXAA 3.11, cel bands and outlines, and
render_shaded's layers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from lit_scenes import FLOOR, box, mesh_of, quad

import clraster
from clraster.output.effects import CEL_LEVELS
from clraster.output.post import (
    SSAO,
    Outlines,
    PostError,
    cel_quantize,
    fxaa,
    luma,
    outline_mask,
)
from clraster.output.shade import render_shaded

W, H = 160, 120
CAMERA = clraster.Camera.look_at((2.5, 3.0, 4.0), (0.0, 0.3, -0.5), near=0.5, far=30.0)


class ShiftedCamera:
    """`camera` moved by (dx, dy) pixels on the screen (a shear of clip space)."""

    def __init__(self, camera, dx, dy):
        self.camera, self.dx, self.dy = camera, dx, dy

    def view_projection(self, width, height):
        t = np.eye(4)
        t[0, 2] = 0.0
        t[0, 3] = 0.0
        shift = np.eye(4)
        shift[0, 3] = 2.0 * self.dx / width
        shift[1, 3] = -2.0 * self.dy / height
        vp = self.camera.view_projection(width, height)
        # x_ndc += 2dx/W after the divide: add 2dx/W · w to x_clip
        out = vp.copy()
        out[0] += shift[0, 3] * vp[3]
        out[1] += shift[1, 3] * vp[3]
        return out


@pytest.fixture(scope="module")
def renderer():
    return clraster.Renderer(W, H)


def _ao(renderer, mesh, camera, radius):
    frame = renderer.render(mesh, camera, cull="none")
    _, layers = render_shaded(renderer, mesh, camera, ssao=SSAO(radius=radius),
                              return_layers=True, render_kwargs={"cull": "none"})
    return frame, layers.ao


def test_ssao_open_plane_is_unoccluded_and_a_corner_is_occluded(renderer):
    radius = 0.4
    lo, hi = np.array([-0.5, 0.0, -0.5]), np.array([0.5, 0.7, 0.5])
    wall = quad((0.0, 1.0, -1.5), (4.0, 0.0, 0.0), (0.0, 1.0, 0.0))   # z = −1.5, faces +z
    mesh = mesh_of(FLOOR, box(lo, hi), wall)
    frame, ao = _ao(renderer, mesh, CAMERA, radius)
    covered = frame.triangle_id >= 0
    pts = frame.points(mesh).points
    # distance from each point to the box and to the wall's plane / the floor
    gap = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
    d_box = np.linalg.norm(gap, axis=1)
    d_wall = np.abs(pts[:, 2] + 1.5)
    d_floor = np.abs(pts[:, 1])
    a = ao[covered]
    on_floor = d_floor < 1e-4
    open_floor = on_floor & (d_box >= radius) & (d_wall >= radius)
    assert open_floor.sum() > 2000
    assert a[open_floor].min() >= 0.97
    # the inside corner where the floor meets the wall, away from the box
    crease = on_floor & (d_box >= radius) & (np.abs(pts[:, 0]) < 2.0)
    at, near = crease & (d_wall < 0.05), crease & (d_wall < 0.2)
    assert at.sum() > 20
    assert a[at].mean() < 0.75 and a[near].mean() < 0.9, (a[at].mean(), a[near].mean())
    # the floor right by the box's foot too
    foot = on_floor & (d_box < 0.05) & (d_wall >= radius)
    assert a[foot].mean() < 0.9


def test_ssao_is_stable_under_sub_pixel_camera_moves(renderer):
    mesh = mesh_of(FLOOR, box((-0.5, 0.0, -0.5), (0.5, 0.7, 0.5)))
    _, ao0 = _ao(renderer, mesh, CAMERA, 0.4)
    diffs = []
    for dx, dy in ((0.3, 0.0), (0.0, 0.45), (0.25, 0.25)):
        f1, ao1 = _ao(renderer, mesh, ShiftedCamera(CAMERA, dx, dy), 0.4)
        cov = f1.triangle_id >= 0
        # compare pixels whose 3×3 neighbourhood is all covered (not silhouettes)
        inner = cov.copy()
        for sy in (-1, 0, 1):
            for sx in (-1, 0, 1):
                inner &= np.roll(np.roll(cov, sy, 0), sx, 1)
        diffs.append(np.abs(ao1 - ao0)[inner])
    d = np.concatenate(diffs)
    assert d.mean() < 0.01, d.mean()
    assert np.quantile(d, 0.999) < 0.15


def test_ssao_bad_options(renderer):
    mesh = mesh_of(FLOOR)
    for bad, match in ((SSAO(radius=-1.0), "radius"), (SSAO(samples=0), "samples"),
                       ("lots", "ssao")):
        with pytest.raises(PostError, match=match):
            render_shaded(renderer, mesh, CAMERA, ssao=bad)


# -- FXAA ----------------------------------------------------------------------------------------

def test_luma_weights():
    rgb = np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], np.uint8)
    np.testing.assert_allclose(luma(rgb)[0], [0.299 * 255, 0.587 * 255, 0.114 * 255],
                               rtol=1e-6)


def test_fxaa_leaves_flat_and_gently_varying_images_alone():
    y, x = np.mgrid[0:40, 0:50]
    ramp = np.stack([x, y, np.full(x.shape, 80)], axis=-1).astype(np.uint8)
    np.testing.assert_array_equal(fxaa(ramp), ramp)


@pytest.mark.parametrize("bad", [np.zeros((4, 5, 3), np.float32), np.zeros((4, 5, 4), np.uint8),
                                 np.zeros((4, 5), np.uint8), np.zeros((0, 5, 3), np.uint8)])
def test_fxaa_takes_8_bit_rgb_only(bad):
    with pytest.raises(PostError, match=r"uint8 \(H, W, 3\)"):
        fxaa(bad)


def test_fxaa_blends_a_staircase_edge_by_its_coverage():
    """A near-horizontal edge of slope 1/8, drawn with hard pixels: FXAA's output along it
    follows the true coverage more closely than the aliased input."""
    h, w = 24, 64
    y, x = np.mgrid[0:h, 0:w] + 0.5
    edge = 8.0 + x / 8.0
    hard = (y > edge).astype(np.float64)
    # exact coverage of each pixel by the half-plane y > edge (the edge crosses at most
    # one pixel row per column within a pixel's width: supersample finely)
    ss = 16
    yy, xx = np.mgrid[0:h * ss, 0:w * ss] + 0.5
    cov = (yy / ss > 8.0 + (xx / ss) / 8.0).reshape(h, ss, w, ss).mean(axis=(1, 3))
    img = np.repeat((hard * 255).astype(np.uint8)[..., None], 3, axis=2)
    out = fxaa(img)[..., 0] / 255.0
    near = np.abs(cov - hard) > 0.02
    err_in = np.abs(hard - cov)[near].mean()
    err_out = np.abs(out - cov)[near].mean()
    assert err_out < 0.6 * err_in, (err_in, err_out)


def _edge_rich_scene():
    rng = np.random.default_rng(7)
    parts = []
    for _ in range(14):
        c = rng.uniform(-1.6, 1.6, 3) * [1, 0.6, 1] + [0, 0.8, 0]
        s = rng.uniform(0.15, 0.4, 3)
        b = trimesh.creation.box(extents=2 * s)
        b.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        b.apply_translation(c)
        parts.append((np.asarray(b.vertices), np.asarray(b.faces)))
    return mesh_of(*parts)


def test_fxaa_lowers_the_error_against_4x4_supersampling_near_edges(renderer):
    mesh = _edge_rich_scene()
    cams = [clraster.Camera.look_at(e, (0, 0.6, 0), near=0.5, far=30.0)
            for e in ((3.0, 2.5, 4.0), (-4.0, 1.5, 2.0), (0.5, 5.0, 1.0))]
    kw = dict(smooth=False, background=(20, 20, 30))
    e_none, e_fx = [], []
    for cam in cams:
        ref = render_shaded(renderer, mesh, cam, ssaa=4, **kw).astype(float)
        none = render_shaded(renderer, mesh, cam, **kw).astype(float)
        fx = render_shaded(renderer, mesh, cam, aa="fxaa", **kw).astype(float)
        ids = renderer.render(mesh, cam).triangle_id
        edge = np.zeros(ids.shape, bool)
        edge[:, 1:] |= ids[:, 1:] != ids[:, :-1]
        edge[:, :-1] |= ids[:, 1:] != ids[:, :-1]
        edge[1:] |= ids[1:] != ids[:-1]
        edge[:-1] |= ids[1:] != ids[:-1]
        e_none.append(np.abs(none - ref)[edge].mean())
        e_fx.append(np.abs(fx - ref)[edge].mean())
    ratio = sum(e_fx) / sum(e_none)
    assert ratio <= 0.75, ratio


def test_bad_aa(renderer):
    with pytest.raises(PostError, match="aa"):
        render_shaded(renderer, mesh_of(FLOOR), CAMERA, aa="msaa")


# -- cel and outlines ------------------------------------------------------------------------------

def test_cel_quantize_bands():
    d = np.array([0.0, 0.2, 0.33, 0.34, 0.5, 0.66, 0.67, 0.99, 1.0])
    np.testing.assert_allclose(cel_quantize(d, 3), [0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 1])
    with pytest.raises(PostError, match="levels"):
        cel_quantize(d, 1)


def test_cel_sphere_has_at_most_the_band_colours(renderer):
    sphere = trimesh.creation.icosphere(subdivisions=4)
    cam = clraster.Camera.look_at((0, 0, 4), (0, 0, 0))
    smooth = render_shaded(renderer, sphere, cam, smooth=True)
    cel = render_shaded(renderer, sphere, cam, smooth=True, style="cel")
    ids = renderer.render(sphere, cam).triangle_id
    cov = ids >= 0
    assert len(np.unique(smooth[cov].reshape(-1, 3), axis=0)) > 50
    assert len(np.unique(cel[cov].reshape(-1, 3), axis=0)) == CEL_LEVELS


def test_outline_mask_hand_drawn():
    covered = np.zeros((6, 7), bool)
    covered[1:5, 1:6] = True
    z = np.full((6, 7), 5.0)
    z[2:4, 3:5] = 2.0          # a nearer block inside
    n = np.zeros((6, 7, 3))
    n[..., 2] = 1.0
    n[1, 1:6] = (0.0, 1.0, 0.0)  # a crease along row 1
    got = outline_mask(covered, z, n, Outlines(depth=0.02, normal_deg=50.0))
    want = np.zeros((6, 7), bool)
    want[1, 1:6] = want[4, 1:6] = True      # silhouette rows (row 1 also a crease)
    want[1:5, 1] = want[1:5, 5] = True      # silhouette columns
    want[2:4, 3:5] = True                   # the near block's border (its 4 pixels)
    want[2, 1:6] = True                     # below the crease
    np.testing.assert_array_equal(got, want)


def test_outlines_in_the_image(renderer):
    mesh = mesh_of(FLOOR, box((-0.5, 0.0, -0.5), (0.5, 0.7, 0.5)))
    img, layers = render_shaded(renderer, mesh, CAMERA, outlines=True, return_layers=True,
                                background=(255, 255, 255))
    black = np.all(img == 0, axis=-1)
    cov = layers.covered > 0
    # every covered pixel next to the background is black
    border = cov & ~(np.roll(cov, 1, 0) & np.roll(cov, -1, 0) & np.roll(cov, 1, 1)
                     & np.roll(cov, -1, 1))
    border[0] = border[-1] = False
    border[:, 0] = border[:, -1] = False
    assert black[border].all()
    assert black.sum() > border.sum() + 30   # the box's edges too


# -- layers ----------------------------------------------------------------------------------------

def test_layers_shapes_and_ssaa_means(renderer):
    mesh = mesh_of(FLOOR, box((-0.5, 0.0, -0.5), (0.5, 0.7, 0.5)))
    lights = [clraster.shade.Light.directional((0.3, -1.0, 0.2), shadow_size=512),
              clraster.shade.Light.directional((-0.5, -1.0, 0.1), shadow_size=512)]
    img, lay = render_shaded(renderer, mesh, CAMERA, lights=lights, shadows=True, ssao=0.3,
                             return_layers=True)
    assert img.shape == (H, W, 3)
    assert lay.lit.shape == (H, W, 2) and lay.lit.dtype == np.float32
    assert lay.ao.shape == (H, W) and lay.normals.shape == (H, W, 3)
    assert len(lay.shadow_maps) == 2 and lay.shadow_maps[0].depth.shape == (512, 512)
    cov = lay.covered > 0
    np.testing.assert_allclose(np.linalg.norm(lay.normals[cov], axis=-1), 1.0, atol=1e-5)
    assert np.all(lay.normals[~cov] == 0) and np.all(lay.lit[~cov] == 0)
    small = clraster.Renderer(W // 2, H // 2)
    img2, lay2 = render_shaded(small, mesh, CAMERA, ssaa=2, lights=lights, shadows=True,
                               return_layers=True)
    assert img2.shape == (H // 2, W // 2, 3) and lay2.lit.shape == (H // 2, W // 2, 2)
    # the mean of 2×2 samples: the pixel's lit fraction is one of 0, 1/4, ..., 1 times
    # PCF levels; bounded and in [0, 1]
    assert lay2.lit.min() >= 0 and lay2.lit.max() <= 1


def test_ssao_upsample_keeps_the_samples_and_does_not_blend_across_depth_jumps():
    from clraster.output.post import ssao_linear_depth, ssao_upsample
    h, w = 6, 8
    cam = clraster.Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), near=1.0, far=10.0)
    vp = cam.view_projection(w, h)
    depth = np.full((h, w), 0.9, np.float32)
    depth[:, 5:] = 0.99                      # far from column 5 on
    depth[0, 0] = 1.0                        # one background pixel
    z = ssao_linear_depth(depth, np.linalg.inv(vp)[3].astype(np.float32), False)
    assert z[0, 4] < z[0, 5]                 # farther is deeper, by far more than the gate
    assert (z[0, 5] - z[0, 4]) > 0.1 * z[0, 4]
    z_low = np.where(depth[::2, ::2] < 1.0, z[::2, ::2], np.float32(np.inf))
    ao_low = np.arange(12, dtype=np.float32).reshape(3, 4) / 16.0
    out = ssao_upsample(depth, z_low, ao_low, vp, False)
    assert out[0, 0] == 1.0                                  # background
    np.testing.assert_array_equal(out[::2, ::2][1:], ao_low[1:])   # own samples, exactly
    # (1, 1): the mean of its 4 neighbours' samples, all at the near depth, except the
    # background one at (0, 0), which the gate drops
    np.testing.assert_allclose(out[1, 1], ao_low[[0, 1, 1], [1, 0, 1]].mean(), rtol=1e-6)
    # column 5 (far) takes only far samples: low-res column 3 (full-res column 6)
    np.testing.assert_allclose(out[2, 5], ao_low[1, 3], rtol=1e-6)
    # column 3 (near) blends low-res columns 1 and 2 (full-res 2 and 4, both near)
    np.testing.assert_allclose(out[2, 3], ao_low[1, 1:3].mean(), rtol=1e-6)
