"""Scene: instances, the triangle-id convention (face_base / split_ids), transform
validation, bounds, and loading (glTF round trip through trimesh)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import clraster.world.scene as scene_mod
from clraster.world.mesh import Mesh
from clraster.world.scene import MAX_SCENE_FACES, Instance, Scene

TRI = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])


def strip(n: int) -> Mesh:
    """n triangles in a strip along x (n + 2 vertices)."""
    v = np.array([[i // 2, i % 2, 0.0] for i in range(n + 2)])
    f = np.array([[i, i + 1, i + 2] for i in range(n)])
    return Mesh(v, f)


def translation(x, y, z) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def test_add_and_ids():
    a, empty, b = strip(3), Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32)), strip(5)
    scene = Scene()
    assert scene.add(a) == 0
    assert scene.add(empty, translation(1, 2, 3)) == 1
    assert scene.add(b, translation(0, 0, 5)) == 2
    assert scene.n_instances == 3 and len(scene) == 3
    assert scene.n_faces == 8 and scene.n_empty == 1
    assert scene.face_base.tolist() == [0, 3, 3] and scene.face_base.dtype == np.int64
    assert not scene.face_base.flags.writeable
    np.testing.assert_array_equal(scene.instances[0].transform, np.eye(4))
    # Id f of instance i is face_base[i] + f: ids 0..2 → instance 0, 3..7 → instance 2.
    ids = np.array([[-1, 0, 2], [3, 7, -1]])
    inst, face = scene.split_ids(ids)
    assert inst.dtype == np.int32 and face.dtype == np.int32 and inst.shape == (2, 3)
    assert inst.tolist() == [[-1, 0, 0], [2, 2, -1]]
    assert face.tolist() == [[-1, 0, 2], [0, 4, -1]]
    # Round trip over every id.
    all_ids = np.arange(-1, 8)
    inst, face = scene.split_ids(all_ids)
    back = np.where(inst >= 0, scene.face_base[np.maximum(inst, 0)] + face, -1)
    np.testing.assert_array_equal(back, all_ids)
    for bad in ([8], [-2], np.array([1.5])):
        with pytest.raises(ValueError, match="ids"):
            scene.split_ids(bad)


def test_empty_first_and_only_empty():
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
    scene = Scene([(empty, None), (TRI, np.eye(4))])
    inst, face = scene.split_ids([0])
    assert inst.tolist() == [1] and face.tolist() == [0]
    only = Scene.from_mesh(empty)
    assert only.n_faces == 0 and only.n_empty == 1
    assert only.split_ids([-1, -1])[0].tolist() == [-1, -1]
    with pytest.raises(ValueError, match="ids"):
        only.split_ids([0])
    with pytest.raises(ValueError, match="no finite geometry"):
        only.bounds()
    with pytest.raises(ValueError, match="no finite geometry"):
        Scene().bounds()


def test_version_and_constructor_forms():
    s = Scene([Instance(TRI, np.eye(4)), (TRI, translation(1, 0, 0))])
    assert s.n_instances == 2 and s.instances[1].mesh is TRI
    v = s.version
    s.add(TRI)
    assert s.version == v + 1
    with pytest.raises(ValueError, match="instance 0"):
        Scene([42])
    with pytest.raises(ValueError, match="clraster.Mesh"):
        Scene().add("not a mesh")


@pytest.mark.parametrize("transform, match", [
    (np.eye(3), r"shape \(4, 4\)"),
    ([[1, 2], [3, 4]], r"shape \(4, 4\)"),
    (np.full((4, 4), np.nan), "NaN or Inf"),
    (np.diag([1.0, 1.0, 0.0, 1.0]), "not invertible"),
    (np.diag([1.0, 1.0, 1e-10, 1.0]), "not invertible"),
    (np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.5, 1]]), "not affine"),
    ("abc", "4×4 real matrix|shape"),
])
def test_transform_validation_names_the_instance(transform, match):
    scene = Scene.from_mesh(TRI)
    with pytest.raises(ValueError, match=match) as info:
        scene.add(TRI, transform)
    assert "instance 1" in str(info.value)
    assert scene.n_instances == 1 and scene.n_faces == 1  # nothing half-added


def test_transform_is_stored_read_only_and_copied():
    t = translation(1, 2, 3)
    scene = Scene.from_mesh(TRI, t)
    t[0, 3] = 99.0
    stored = scene.instances[0].transform
    assert stored[0, 3] == 1.0 and stored.dtype == np.float64 and not stored.flags.writeable
    # Mirroring (negative determinant) is a valid transform.
    Scene.from_mesh(TRI, np.diag([-1.0, 1.0, 1.0, 1.0]))
    # Instances validate on their own too, even from a read-only float64 array.
    bad = np.full((4, 4), np.nan)
    bad.flags.writeable = False
    with pytest.raises(ValueError, match="NaN"):
        Instance(TRI, bad)
    assert (Instance(TRI, None).transform == np.eye(4)).all()


def test_face_limit(monkeypatch):
    assert MAX_SCENE_FACES == 2**31 - 1
    monkeypatch.setattr(scene_mod, "MAX_SCENE_FACES", 10)
    scene = Scene()
    scene.add(strip(6))
    scene.add(strip(4))  # exactly 10: allowed
    with pytest.raises(ValueError, match="int32") as info:
        scene.add(TRI)
    assert "instance 2" in str(info.value)
    assert scene.n_instances == 2 and scene.n_faces == 10


def test_bounds_and_world_aabbs():
    cube = Mesh([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 3)],
                [[0, 1, 3], [4, 5, 7]])
    # Rotation 90° about z (x → y, y → −x), scale 2, then translation (10, 0, 0):
    # object box [0, 1] × [0, 2] × [0, 3] → x in [10 − 4, 10], y in [0, 2], z in [0, 6].
    t = np.array([[0.0, -2, 0, 10], [2, 0, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]])
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
    nan = Mesh([[np.nan, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    scene = Scene([(cube, t), (empty, None), (nan, translation(0, -5, 0)), (TRI, None)])
    lo, hi = scene.world_aabbs()
    np.testing.assert_allclose(lo[0], [6, 0, 0])
    np.testing.assert_allclose(hi[0], [10, 2, 6])
    assert np.isnan(lo[1]).all()
    # The NaN mesh: bounds of its finite vertices (1, 0, 0), (0, 1, 0), moved by −5 in y.
    np.testing.assert_allclose(lo[2], [0, -5, 0])
    np.testing.assert_allclose(hi[2], [1, -4, 0])
    assert scene.has_bounds.tolist() == [True, False, True, True]
    assert scene.bounded.tolist() == [True, False, False, True]
    assert scene.empty.tolist() == [False, True, False, False]
    blo, bhi = scene.bounds()
    np.testing.assert_allclose(blo, [0, -5, 0])
    np.testing.assert_allclose(bhi, [10, 2, 6])


def test_load_single_mesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    tm = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                         faces=[[0, 1, 2], [0, 2, 3]], process=False)
    path = tmp_path / "m.ply"
    tm.export(path)
    scene = Scene.load(path)
    assert scene.n_instances == 1 and scene.n_faces == 2
    np.testing.assert_array_equal(scene.instances[0].transform, np.eye(4))
    with pytest.raises(FileNotFoundError):
        Scene.load(tmp_path / "missing.glb")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a gltf file")
    with pytest.raises(ValueError, match="could not read|no triangle mesh"):
        Scene.load(bad)


def test_gltf_round_trip(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    tf = trimesh.transformations
    a = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3]],
                        faces=[[0, 1, 2], [0, 2, 3], [0, 3, 1]], process=False)
    b = trimesh.Trimesh(vertices=[[0, 0, 0], [4, 0, 0], [0, 5, 0]], faces=[[0, 1, 2]],
                        process=False)
    t1 = tf.translation_matrix([10, 0, 0])
    t2 = tf.rotation_matrix(math.pi / 2, [0, 0, 1]) @ tf.scale_matrix(2.0)
    t3 = tf.translation_matrix([0, -3, 1]) @ tf.rotation_matrix(0.3, [1, 1, 0])
    src = trimesh.Scene()
    src.add_geometry(a, node_name="a1", geom_name="A", transform=t1)
    # A second node of the same geometry (add_geometry would copy it as "A_1").
    src.graph.update(frame_to="a2", frame_from=src.graph.base_frame, matrix=t2, geometry="A")
    src.add_geometry(b, node_name="b1", geom_name="B", transform=t3)
    path = tmp_path / "scene.glb"
    src.export(path)

    scene = Scene.load(path)
    assert scene.n_instances == 3 and scene.n_faces == 3 + 3 + 1
    # The two nodes of geometry A share one Mesh.
    meshes = [inst.mesh for inst in scene.instances]
    assert len({id(m) for m in meshes}) == 2

    def world(mesh_v, t):
        v = np.asarray(mesh_v, np.float64)
        return v @ t[:3, :3].T + t[:3, 3]

    expected = sorted([world(a.vertices, t1), world(a.vertices, t2), world(b.vertices, t3)],
                      key=lambda w: tuple(np.round(w.mean(axis=0), 6)))
    got = sorted([world(inst.mesh.vertices, inst.transform) for inst in scene.instances],
                 key=lambda w: tuple(np.round(w.mean(axis=0), 6)))
    for e, g in zip(expected, got, strict=True):
        assert e.shape == g.shape
        # Vertex order may change in the file; compare as sorted point sets (float32 data).
        np.testing.assert_allclose(np.array(sorted(map(tuple, g))),
                                   np.array(sorted(map(tuple, e))), atol=1e-5)
