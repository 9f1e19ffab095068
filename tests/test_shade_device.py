"""Shading on the device (kernels/resolve.cl shade_pixels) against its twin, the NumPy path
of `clraster.output.shade.shade` on the same frame: equal within 1/255 per channel in every
mode the kernel takes; the modes it does not take (colour sources, callable tints) shade on
the host."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import get_renderer

from clraster import Camera, Mesh
from clraster.output import shade as shade_mod
from clraster.output.frame import Frame
from clraster.output.shade import render_shaded, shade
from clraster.world.scene import Scene

W, H = 83, 61


@pytest.fixture(scope="module")
def scene() -> Scene:
    """A sphere, a mirrored copy (glTF rule: outward normals) and a sheared box."""
    sphere = Mesh.from_trimesh(trimesh.creation.icosphere(subdivisions=2, radius=0.9))
    box = Mesh.from_trimesh(trimesh.creation.box(extents=(1.2, 1.6, 1.0)))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = (1.3, 0.0, 0.0)
    left = np.eye(4)
    left[:3, 3] = (-1.3, 0.0, 0.0)
    shear = np.eye(4)
    shear[0, 1] = 0.4
    shear[:3, 3] = (0.0, 0.2, -2.0)
    return Scene([(sphere, left), (sphere, mirror), (box, shear)])


def camera() -> Camera:
    return Camera.look_at((0.8, 1.9, 5.0), (0.0, 0.0, -0.5), fov_y=55.0, near=0.5, far=20.0)


def host_twin(frame: Frame) -> Frame:
    """The same buffers without a device to shade on: `shade` takes its NumPy path."""
    return Frame(frame.depth, frame.triangle_id, frame.barycentrics, frame.stats)


MODES = [{}, {"smooth": True}, {"two_sided": False}, {"light_dir": (-0.4, 0.2, 0.9)},
         {"alpha": True, "background": (10, 200, 30)},
         {"per_instance_colors": np.array([[230, 50, 20], [40, 120, 250], [128, 128, 128]],
                                          np.uint8)},
         {"per_instance_colors": [[0.9, 0.2, 0.1], [0.1, 0.9, 0.2], [0.3, 0.3, 1.0]],
          "smooth": True, "alpha": True, "two_sided": False}]


@pytest.mark.parametrize("kw", MODES, ids=lambda kw: ",".join(kw) or "flat")
@pytest.mark.parametrize("target", ["mesh", "scene"])
def test_device_shading_equals_the_host_path(scene, kw, target, monkeypatch):
    geom = scene if target == "scene" else scene.instances[2].mesh
    if target == "mesh" and "per_instance_colors" in kw:
        kw = {**kw, "per_instance_colors": kw["per_instance_colors"][:1]}
    frame = get_renderer(W, H).render(geom, camera(), cull="none")
    assert frame.source is not None and frame.source() is not None
    want = shade(host_twin(frame), geom, **kw)

    def no_host(*a, **k):
        raise AssertionError("shaded on the host")

    monkeypatch.setattr(shade_mod, "_shade_covered", no_host)
    got = shade(frame, geom, **kw)
    assert got.dtype == np.uint8 and got.shape == want.shape
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    covered = frame.triangle_id >= 0
    assert covered.any() and (~covered).any()
    if "background" in kw:
        assert (got[~covered, :3] == kw["background"]).all() and (got[~covered, 3] == 0).all()
        assert (got[covered, 3] == 255).all()


def test_render_shaded_uses_the_device(scene, monkeypatch):
    r = get_renderer(W, H)
    want = render_shaded(r, scene, camera(), smooth=True)   # before the patch: any path

    def no_host(*a, **k):
        raise AssertionError("shaded on the host")

    monkeypatch.setattr(shade_mod, "_shade_covered", no_host)
    got = render_shaded(r, scene, camera(), smooth=True)
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


def test_colour_sources_shade_on_the_host(scene):
    """Vertex colours (and textures, face colours, callable tints) are the host's: the
    device is not asked, the image is the host path's exactly."""
    mesh = scene.instances[0].mesh
    colors = np.linspace(0.1, 0.9, mesh.n_vertices * 3).reshape(-1, 3)
    frame = get_renderer(W, H).render(mesh, camera())
    np.testing.assert_array_equal(shade(frame, mesh, colors=colors),
                                  shade(host_twin(frame), mesh, colors=colors))
    tint = shade(frame, scene.instances[0].mesh, per_instance_colors=lambda i, inst: (1, 0, 0))
    assert (tint[frame.triangle_id >= 0][:, 1:] == 0).all()


def test_bad_ids_are_refused_as_on_the_host(scene):
    frame = get_renderer(W, H).render(scene, camera())
    small = Mesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(ValueError, match="ids outside"):
        shade(frame, small)
