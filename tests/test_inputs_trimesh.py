"""trimesh objects as render targets: a `trimesh.Trimesh` renders as the `clraster.Mesh` made
from it and a `trimesh.Scene` as the `clraster.Scene` made from it (node transforms kept),
ids map back to the right geometry names, and the conversion is done once per object."""

from __future__ import annotations

import gc
import warnings

import numpy as np
import pytest
import trimesh
from conftest import assert_frames_equal

import clraster
from clraster import Camera, Mesh, Scene
from clraster.pipeline import reference
from clraster.world.inputs import _CONVERTED, as_target

W, H = 80, 60


def _camera() -> Camera:
    return Camera.look_at((2.5, 2.0, 4.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), fov_y=50.0,
                          near=0.5, far=20.0)


def _trimesh_scene() -> trimesh.Scene:
    """Three nodes over two geometries: a box (twice: one moved, one mirrored) and a sphere,
    with asymmetric offsets so a swapped node or transform moves pixels."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.8))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.45)
    sc = trimesh.Scene()
    sc.add_geometry(box, node_name="box_left", geom_name="crate",
                    transform=trimesh.transformations.translation_matrix((-1.1, 0.0, 0.2)))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = (1.0, -0.4, -0.3)
    sc.graph.update("box_right", frame_from=sc.graph.base_frame, matrix=mirror,
                    geometry="crate")   # a second node of the same geometry
    sc.add_geometry(ball, node_name="ball", geom_name="ball",
                    transform=trimesh.transformations.translation_matrix((0.1, 0.7, 0.6)))
    return sc


def test_top_level_names():
    assert clraster.Scene is Scene
    assert clraster.Instance is clraster.scene.Instance
    assert callable(clraster.shade.shade)
    for name in clraster.__all__:
        assert getattr(clraster, name) is not None, name


def test_trimesh_mesh_renders_as_its_mesh(renderer_for):
    tm = trimesh.creation.icosphere(subdivisions=3, radius=1.2)
    tm.apply_translation((0.2, -0.1, 0.0))
    mesh = Mesh.from_trimesh(tm)
    cam = _camera()
    r = renderer_for(W, H)
    got, want = r.render(tm, cam), r.render(mesh, cam)
    assert (want.triangle_id >= 0).any()
    assert_frames_equal(got, want, "trimesh.Trimesh vs Mesh (OpenCL)", bary_atol=0.0)
    assert_frames_equal(reference.render(tm, cam, W, H), want, "twin", bary_atol=1e-5)


def test_trimesh_scene_renders_as_its_scene_and_names_ids(renderer_for):
    tm = _trimesh_scene()
    cam = _camera()
    scene = Scene.from_trimesh(tm)
    assert scene.n_instances == 3
    assert scene.instance_names == ("box_left", "box_right", "ball")
    assert scene.geometry_names == ("crate", "crate", "ball")
    assert scene.instances[0].mesh is scene.instances[1].mesh   # one Mesh per geometry
    r = renderer_for(W, H)
    got = r.render(tm, cam)
    assert_frames_equal(got, r.render(scene, cam), "trimesh.Scene vs Scene", bary_atol=0.0)
    assert_frames_equal(reference.render(tm, cam, W, H), got, "twin", bary_atol=1e-5)

    # node transforms kept: the scene covers what trimesh's own baked copy covers, at the
    # same depth (float32 rounding apart: baked vertices vs per-instance matrices), with
    # the same ids (trimesh concatenates in node order too). cull="none": how a mirrored
    # node's winding meets back-face culling is the renderer's rule, not this test's
    baked = Mesh.from_trimesh(tm.to_geometry())
    a, b = r.render(tm, cam, cull="none"), r.render(baked, cam, cull="none")
    np.testing.assert_array_equal(a.triangle_id, b.triangle_id)
    np.testing.assert_allclose(a.depth, b.depth, rtol=0, atol=1e-6)

    # ids back to geometry names: each pixel's geometry is the one whose own render
    # covers it there at the same depth
    names = as_target(tm).geometry_of(got.triangle_id)
    assert names.shape == (H, W) and names.dtype == object
    assert set(names[got.triangle_id < 0].tolist()) == {None}
    inst, _ = scene.split_ids(got.triangle_id)
    seen = set()
    for i, node in enumerate(scene.instance_names):
        alone = r.render(Scene([(scene.instances[i].mesh, scene.instances[i].transform)]),
                         cam)
        mine = inst == i
        assert mine.any(), node
        assert np.all(alone.triangle_id[mine] >= 0)
        assert np.all(alone.depth[mine] <= got.depth[mine])
        assert set(names[mine].tolist()) == {scene.geometry_names[i]}
        seen.add(scene.geometry_names[i])
    assert seen == {"crate", "ball"}


def test_render_many_takes_trimesh(renderer_for):
    tm = _trimesh_scene()
    cams = [_camera(), Camera.look_at((-3, 1, 3), (0, 0, 0), (0, 1, 0), near=0.5, far=20)]
    r = renderer_for(W, H)
    for cam, frame in zip(cams, r.render_many(tm, cams), strict=True):
        assert_frames_equal(frame, r.render(Scene.from_trimesh(tm), cam), "render_many",
                            bary_atol=0.0)


def test_conversion_cached_weakly_and_refreshed_on_change():
    tm = trimesh.creation.box()
    first = as_target(tm)
    assert as_target(tm) is first            # repeated frames: no new conversion
    sc = _trimesh_scene()
    assert as_target(sc) is as_target(sc)

    # the renderer's plan cache sees one target, so its scene and pool are kept
    r = reference.Renderer(W, H)
    r.render(tm, _camera())
    key = r._plans._key
    r.render(tm, _camera())
    assert r._plans._key == key and r._plans._value[0] is first

    tm.vertices = tm.vertices * 2.0           # changed content: converted again
    second = as_target(tm)
    assert second is not first
    np.testing.assert_allclose(second.vertices, first.vertices * 2.0)

    n = len(_CONVERTED)
    del tm, sc, first, second
    gc.collect()
    assert len(_CONVERTED) <= n - 2           # entries go with their trimesh objects


def test_bad_targets():
    cam = _camera()
    with pytest.raises(ValueError, match="trimesh.Trimesh or trimesh.Scene"):
        reference.render("not a mesh", cam, W, H)
    cloud = trimesh.Trimesh(vertices=np.random.default_rng(0).random((10, 3)),
                            faces=np.zeros((0, 3), np.int64), process=False)
    with pytest.raises(ValueError, match="no faces"):
        reference.render(cloud, cam, W, H)
    only_points = trimesh.Scene([trimesh.PointCloud(np.zeros((4, 3)))])
    with pytest.raises(ValueError, match="no triangle mesh"):
        reference.render(only_points, cam, W, H)
    with pytest.raises(TypeError, match="trimesh.Scene or trimesh.Trimesh"):
        Scene.from_trimesh(Mesh(np.zeros((3, 3)), [[0, 1, 2]]))
    # an empty clraster Mesh still renders an empty frame (tests/test_bad_input.py)
    empty = reference.render(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32)), cam, W, H)
    assert (empty.triangle_id == -1).all()


def test_hidden_nodes_warn_and_names_by_hand():
    sc = _trimesh_scene()
    sc.graph.update("ball", matrix=np.diag([0.0, 0.0, 0.0, 1.0]))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = Scene.from_trimesh(sc)
    assert scene.instance_names == ("box_left", "box_right")
    assert any(issubclass(w.category, clraster.SceneWarning) and w.filename == __file__
               for w in caught)
    hand = Scene()
    hand.add(scene.instances[0].mesh, name="a", geometry="g")
    hand.add(scene.instances[0].mesh)
    assert hand.instance_names == ("a", None)
    ids = np.array([[-1, 0], [12, 13]])
    assert hand.geometry_of(ids).tolist() == [[None, "g"], [None, None]]
    with pytest.raises(ValueError, match="name must be a string"):
        hand.add(scene.instances[0].mesh, name=3)  # type: ignore[arg-type]
