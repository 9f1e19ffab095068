"""Reversed-Z depth (issue 14, item 4): ``render(..., reversed_z=True)``.

The depth test runs on the key −(1 − z/w)/2 computed per triangle in double from a depth
row w − z formed in float64 (setup.cl ClipIn, DEPTH_MODE), so the frame's depth (1 − z/w)/2
keeps float32's relative precision far from the camera, where window depth (z/w + 1)/2
rounds to 1. Checked: the
OpenCL path equals the twin (random soups with clipping, occlusion paths); the reversed depth
is 1 − the ordinary one where both see the same triangle; two quads 1000 and 1000.5 units
away, which ordinary depth cannot tell apart (z-fighting: the first drawn wins), resolve to
the nearer one; metric depth, compositing and the empty frame follow the convention.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MatrixCamera, assert_frames_equal, get_renderer, load_shared_mesh
from random_scenes import Lens, random_soup, random_view, to_world

from clraster import Camera, Mesh, RasterConfig, Renderer, Scene
from clraster.pipeline import reference as twin
from clraster.scale.composite import composite
from clraster.world.generators import (
    plant,
    plant_inside_camera,
    plant_overview_camera,
    random_scene,
)


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_random_soups_match_twin(seed):
    """Soups with near/far crossings, slivers, huge and degenerate triangles: OpenCL and
    twin agree exactly with reversed-Z (ids, depth, counts)."""
    rng = np.random.default_rng(seed)
    w, h = 67, 45
    lens = Lens(60.0, (0.01, 0.5, 2.0)[seed % 3], 1000.0)
    v, f, _ = random_soup(rng, 1500, w, h, lens)
    view = random_view(rng)
    mesh = Mesh(to_world(v, view), f)
    cam = MatrixCamera(lens.projection(w / h) @ view)
    for cull in ("back", "none"):
        a = get_renderer(w, h).render(mesh, cam, cull=cull, frustum=False, cones=False,
                                      reversed_z=True)
        b = twin.render(mesh, cam, w, h, cull=cull, frustum=False, cones=False,
                        reversed_z=True)
        assert a.reversed_z and b.reversed_z
        assert a.stats.clipped > 0
        assert_frames_equal(a, b, f"seed {seed} cull {cull} reversed-Z")


def test_reversed_is_one_minus_ordinary_on_a_real_mesh():
    mesh = load_shared_mesh("stanford_bunny.ply")
    lo, hi = mesh.bounds()
    cam = Camera.framing(lo, hi, direction=(0.3, 0.4, 1.0), aspect=4 / 3)
    r = get_renderer(160, 120)
    a = r.render(mesh, cam)
    b = r.render(mesh, cam, reversed_z=True)
    same = (a.triangle_id == b.triangle_id) & (a.triangle_id >= 0)
    assert same.mean() > 0.99 * (a.triangle_id >= 0).mean()
    assert np.abs(b.depth[same] - (1.0 - a.depth[same].astype(np.float64))).max() < 1e-6
    assert (b.depth[b.triangle_id < 0] == 0.0).all()
    assert (b.depth[b.triangle_id >= 0] > 0.0).all()
    # metric depth from either convention agrees
    la, lb = a.linear_depth(cam), b.linear_depth(cam)
    both = same
    np.testing.assert_allclose(lb[both], la[both], rtol=1e-4)
    np.testing.assert_array_equal(np.isinf(lb), b.triangle_id < 0)


def _quad(z: float, half: float) -> Mesh:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]))


def test_far_quads_resolve_with_reversed_z_only():
    """Quads at 10001 (drawn first: ids 0, 1) and 10000 (ids 2, 3) units, near plane 0.1,
    far 1e6. Their window depths, ~1 − 1e-5, are 1e-9 apart, far below float32's spacing
    near 1 (6e-8): ordinary depth ties and the first-drawn far quad shows through
    (z-fighting); reversed-Z depths (~5e-6) are 5e-10 apart with spacing 5e-13, so the
    nearer quad wins everywhere, at the depth a float64 computation gives."""
    scene = Scene([(_quad(-10001.0, 3000.0), np.eye(4)), (_quad(-10000.0, 3000.0), np.eye(4))])
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov_y=20.0, near=0.1, far=1e6)
    r = get_renderer(64, 48)
    ordinary = r.render(scene, cam, cull="none")
    rev = r.render(scene, cam, cull="none", reversed_z=True)
    assert (ordinary.triangle_id >= 0).all() and (rev.triangle_id >= 0).all()
    assert (ordinary.triangle_id < 2).mean() > 0.5          # the far quad shows through
    assert (rev.triangle_id >= 2).all()                      # the near quad everywhere
    n, f, d = 0.1, 1e6, 10000.0
    zc = -(f + n) / (f - n) * -d - 2 * f * n / (f - n)       # clip z of eye z = −d
    expect = (1.0 - zc / d) / 2.0
    # to float32's relative precision: the depth row w − z is formed in float64 before it
    # is rounded (from the float32 z and w rows it would cancel to ~3e-8 absolute here)
    assert np.abs(rev.depth.astype(np.float64) - expect).max() < 1e-6 * expect
    twin_rev = twin.render(scene, cam, 64, 48, cull="none", reversed_z=True)
    assert_frames_equal(rev, twin_rev, "far quads")


def test_occlusion_culling_with_reversed_z_is_conservative_and_matches_twin():
    """The Hi-Z pyramid is built over the reversed key buffer and the box test compares in
    that key: occlusion culling still never changes the image, and the twin agrees."""
    scene = plant(20_000)
    cam0 = plant_inside_camera(scene, 160, 120)
    cams = [cam0, cam0, plant_overview_camera(scene, 160, 120)]
    config = RasterConfig()
    r, t = Renderer(160, 120, config=config), twin.Renderer(160, 120, config=config)
    plain = get_renderer(160, 120)
    culled = 0
    for k, cam in enumerate(cams):
        a = r.render(scene, cam, occlusion=True, reversed_z=True)
        b = t.render(scene, cam, occlusion=True, reversed_z=True)
        assert_frames_equal(a, b, f"frame {k} (OpenCL vs twin, reversed-Z occlusion)")
        ref = plain.render(scene, cam, reversed_z=True)
        np.testing.assert_array_equal(a.triangle_id, ref.triangle_id)
        np.testing.assert_array_equal(a.depth, ref.depth)
        culled += a.stats.clusters_occlusion_culled
    assert culled > 0


def test_composite_of_reversed_parts_equals_whole():
    scene = random_scene(8, 12, extent=3.0, degenerate=False)
    cam = Camera.look_at((0.0, 4.0, 14.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=50.0)
    r = get_renderer(80, 60)
    whole = r.render(scene, cam, reversed_z=True)
    insts = scene.instances
    a = r.render(Scene([(i.mesh, i.transform) for i in insts[:6]]), cam, reversed_z=True)
    b = r.render(Scene([(i.mesh, i.transform) for i in insts[6:]]), cam, reversed_z=True)
    c = composite(a, b)
    assert c.reversed_z
    np.testing.assert_array_equal(c.depth, whole.depth)
    covered = whole.triangle_id >= 0
    assert covered.mean() > 0.05
    with pytest.raises(ValueError, match="reversed-Z"):
        composite(a, r.render(Scene([(i.mesh, i.transform) for i in insts[6:]]), cam))


def test_empty_reversed_frame_and_flag_check():
    r = get_renderer(32, 24)
    mesh = _quad(5.0, 1.0)   # behind the camera below
    cam = Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov_y=40.0, near=0.1, far=10.0)
    f = r.render(mesh, cam, reversed_z=True)
    assert f.reversed_z and (f.depth == 0.0).all() and (f.triangle_id == -1).all()
    with pytest.raises(ValueError, match="reversed_z"):
        r.render(mesh, cam, reversed_z="yes")
