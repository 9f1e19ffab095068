"""The per-pixel passes on the device (kernels/post.cl, kernels/shadow.cl through
`clraster.pipeline.stages.post`) against their NumPy twins, and render_shaded running them
for an OpenCL renderer."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import clraster
from clraster.output import post
from clraster.output.lights import Light, frame_points, shadow_lookup, shadow_map
from clraster.output.shade import pixel_normals, render_shaded
from clraster.pipeline.stages.post import DevicePasses, device_passes

W, H = 160, 120


def scene() -> clraster.Mesh:
    floor = trimesh.creation.box(extents=(8, 0.02, 8))
    floor.apply_translation((0, -0.01, 0))
    parts = [floor]
    rng = np.random.default_rng(3)
    for _ in range(8):
        b = trimesh.creation.box(extents=rng.uniform(0.2, 0.8, 3))
        b.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        b.apply_translation(rng.uniform(-1.5, 1.5, 3) * (1, 0.3, 1) + (0, 0.5, 0))
        parts.append(b)
    return clraster.Mesh.from_trimesh(trimesh.util.concatenate(parts))


CAMERAS = [clraster.Camera.look_at((3.0, 3.5, 4.5), (0, 0.3, 0), near=0.5, far=30.0),
           clraster.Camera.look_at((-4.0, 2.0, 1.0), (0, 0.3, 0), near=0.5, far=30.0)]


@pytest.fixture(scope="module")
def renderer():
    return clraster.Renderer(W, H)


def test_device_passes_registered_for_opencl_renderers(renderer):
    assert isinstance(post.passes_for(renderer), DevicePasses)
    assert device_passes(clraster.reference.Renderer(W, H)) is None
    assert post.passes_for(clraster.reference.Renderer(W, H)) is post.NUMPY_PASSES


@pytest.mark.parametrize("cam", range(len(CAMERAS)))
def test_fxaa_kernel_equals_twin(renderer, cam):
    img = render_shaded(renderer, scene(), CAMERAS[cam])
    dev = device_passes(renderer)
    want = post.fxaa(img)
    assert np.mean(np.any(want != img, axis=-1)) > 0.01   # edges to compare
    np.testing.assert_array_equal(dev.fxaa(img), want)


@pytest.mark.parametrize("reversed_z", [False, True])
@pytest.mark.parametrize("size", [(W, H), (203, 97)])
def test_ssao_kernel_equals_twin(reversed_z, size):
    """All three passes run in float32 in the twin's order: the same bits, at a size whose
    rows fill the 8-pixel lanes and at one whose rows end in a partial lane group."""
    w, h = size
    r = clraster.Renderer(w, h)
    mesh = scene()
    cam = CAMERAS[0]
    frame = r.render(mesh, cam, reversed_z=reversed_z)
    n = pixel_normals(frame, mesh)
    vp = cam.view_projection(w, h)
    params = post.SSAO(radius=0.4).checked(1.0)
    dev = device_passes(r)
    got = dev.ssao(frame.depth, n, vp, reversed_z, params)
    want = post.ssao(frame.depth, n, vp, reversed_z, params)
    np.testing.assert_array_equal(got, want)
    assert want.min() < 0.9   # there is occlusion to compare


def bumpy_ground(n: int = 24, seed: int = 5) -> clraster.Mesh:
    """A height field over [-2, 2]² with random heights in [0, 0.35): its taps' directions
    spread over every angle to the normal, so every bias has lanes on both sides of it."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(-2.0, 2.0, n)
    gx, gz = np.meshgrid(xs, xs)
    verts = np.stack([gx, rng.random((n, n)) * 0.35, gz], axis=-1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, :-1], i[1:, 1:]
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([b, c, d], -1).reshape(-1, 3)])
    return clraster.Mesh.from_trimesh(trimesh.Trimesh(verts, faces, process=False))


@pytest.mark.parametrize("bias", [0.0, 0.3, 0.8])
def test_ssao_kernel_equals_twin_on_a_bumpy_ground_for_any_bias(bias):
    """The taps kernel skips a tap's square root and division where its 8 lanes' terms are
    provably 0 (vd² below bias² · |v|² less a margin): the same bits as the twin, which
    always divides, whatever the bias, on a surface whose taps lie at every angle."""
    w, h = 203, 97
    r = clraster.Renderer(w, h)
    cam = clraster.Camera.look_at((0.5, 3.0, 2.5), (0.0, 0.0, 0.0), near=0.5, far=30.0)
    frame = r.render(bumpy_ground(), cam, cull="none")
    n = pixel_normals(frame, bumpy_ground())
    vp = cam.view_projection(w, h)
    params = post.SSAO(radius=0.5, bias=bias).checked(1.0)
    got = device_passes(r).ssao(frame.depth, n, vp, False, params)
    want = post.ssao(frame.depth, n, vp, False, params)
    np.testing.assert_array_equal(got, want)
    covered = frame.triangle_id >= 0
    assert covered.mean() > 0.5
    # pixels with occluding taps (terms > 0, divided) and pixels with none (all skipped)
    assert 0.2 < np.mean(want[covered] < 1.0) < 0.99


def test_ssao_kernel_fallbacks_equal_twin(monkeypatch):
    """With every Clang builtin's fallback (CLRASTER_FALLBACKS=all: the transposes and the
    contiguous tap loads lane by lane, OpenCL's sqrt, vload8...) the same bits."""
    monkeypatch.setenv("CLRASTER_FALLBACKS", "all")
    w, h = 203, 97
    r = clraster.Renderer(w, h)
    cam = CAMERAS[0]
    frame = r.render(scene(), cam)
    n = pixel_normals(frame, scene())
    vp = cam.view_projection(w, h)
    params = post.SSAO(radius=0.4).checked(1.0)
    got = DevicePasses(r.context).ssao(frame.depth, n, vp, False, params)
    np.testing.assert_array_equal(got, post.ssao(frame.depth, n, vp, False, params))


@pytest.mark.parametrize("shape", [(41, 77), (30, 50), (9, 5)])
def test_fxaa_kernel_equals_twin_on_edge_heavy_odd_sizes(renderer, shape):
    """Random hard edges nearly everywhere (every lane group takes the edge path), widths
    that end in a partial lane group and one narrower than a lane group."""
    rng = np.random.default_rng(sum(shape))
    img = np.where(rng.random(shape + (3,)) > 0.5, 255, 0).astype(np.uint8)
    img[::3] = (img[::3] * 0.6).astype(np.uint8)
    want = post.fxaa(img)
    assert np.mean(np.any(want != img, axis=-1)) > 0.3
    np.testing.assert_array_equal(device_passes(renderer).fxaa(img), want)


@pytest.mark.parametrize("light", [
    Light.directional((0.4, -1.0, 0.3), shadow_size=512),
    Light.spot((-1.0, 3.0, -1.0), (0.3, -1.0, 0.3), cone=45.0, shadow_size=512)])
def test_shadow_kernel_matches_twin(renderer, light):
    mesh = scene()
    cam = CAMERAS[0]
    frame = renderer.render(mesh, cam)
    n = pixel_normals(frame, mesh)
    vp = cam.view_projection(W, H)
    covered = frame.triangle_id >= 0
    smap = shadow_map(renderer, mesh, light, frame_points(frame.depth, covered, vp, False))
    got = device_passes(renderer).shadow(smap, light, frame.depth, n, vp, False)
    want = shadow_lookup(smap, light, frame.depth, n, vp, False)
    diff = np.abs(got - want)
    assert np.mean(diff > 1e-6) < 0.002 and (want[covered] < 0.5).sum() > 200


def test_render_shaded_on_device_equals_numpy_passes(renderer, monkeypatch):
    mesh = scene()
    kw = dict(lights=[Light.directional((0.4, -1.0, 0.3), shadow_size=512)], shadows=True,
              ssao=0.4, aa="fxaa", return_layers=True)
    img_dev, lay_dev = render_shaded(renderer, mesh, CAMERAS[1], **kw)
    monkeypatch.setattr(post, "_FACTORIES", [])
    img_np, lay_np = render_shaded(renderer, mesh, CAMERAS[1], **kw)
    assert np.mean(np.abs(img_dev.astype(int) - img_np) > 1) < 0.005
    assert np.mean(np.abs(lay_dev.ao - lay_np.ao) > 1e-4) < 0.005
