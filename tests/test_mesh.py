"""Mesh: validation, storage (float32/int32, C-contiguous, read-only), loading, bounds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clraster.world.mesh import Mesh

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"

CUBE_V = np.array([[x, y, z] for x in (-1.0, 2.0) for y in (0.5, 1.5) for z in (-3.0, 4.0)])
# 12 triangles, counter-clockwise seen from outside.
CUBE_F = np.array([
    [0, 1, 3], [0, 3, 2],  # x = -1
    [4, 6, 7], [4, 7, 5],  # x = +2
    [0, 4, 5], [0, 5, 1],  # y = 0.5
    [2, 3, 7], [2, 7, 6],  # y = 1.5
    [0, 2, 6], [0, 6, 4],  # z = -3
    [1, 5, 7], [1, 7, 3],  # z = +4
])


def test_storage_dtypes_and_flags():
    v = np.asfortranarray(CUBE_V)  # float64, not C-contiguous
    f = CUBE_F.astype(np.uint16)
    m = Mesh(v, f)
    assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32
    assert m.vertices.shape == (8, 3) and m.faces.shape == (12, 3)
    assert m.vertices.flags.c_contiguous and m.faces.flags.c_contiguous
    assert not m.vertices.flags.writeable and not m.faces.flags.writeable
    assert (m.n_vertices, m.n_faces) == (8, 12)
    np.testing.assert_array_equal(m.vertices, CUBE_V.astype(np.float32))
    np.testing.assert_array_equal(m.faces, CUBE_F)
    with pytest.raises(ValueError):
        m.vertices[0, 0] = 1.0
    with pytest.raises(ValueError):
        m.faces[0, 0] = 1


def test_inputs_are_copied():
    v = CUBE_V.astype(np.float32)
    f = CUBE_F.astype(np.int32)
    m = Mesh(v, f)
    v[0, 0] = 99.0
    f[0, 0] = 5
    assert m.vertices[0, 0] == -1.0 and m.faces[0, 0] == 0
    assert v.flags.writeable  # the caller's array is not frozen


def test_accepts_lists_and_integer_vertices():
    m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert m.vertices.dtype == np.float32 and m.faces.dtype == np.int32


@pytest.mark.parametrize("v, f", [
    (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)),
    ([], []),
    (np.zeros((5, 3)), np.zeros((0, 3), dtype=np.int32)),
])
def test_empty_mesh(v, f):
    m = Mesh(v, f)
    assert m.faces.shape == (0, 3) and m.faces.dtype == np.int32
    assert m.vertices.shape[1] == 3
    assert m.face_normals().shape == (0, 3)
    with pytest.raises(ValueError, match="no finite vertex"):
        m.bounds()


@pytest.mark.parametrize("v, match", [
    (np.zeros((4, 2)), r"vertices must have shape \(n, 3\)"),
    (np.zeros(12), r"vertices must have shape \(n, 3\)"),
    (np.zeros((2, 4, 3)), r"vertices must have shape \(n, 3\)"),
    (np.zeros((4, 3), dtype=complex), "vertices must have a real numeric dtype"),
    (np.zeros((4, 3), dtype=bool), "vertices must have a real numeric dtype"),
    (np.zeros((4, 3), dtype=object), "vertices must have a real numeric dtype"),
    ([["a", "b", "c"]], "vertices must have a real numeric dtype"),
])
def test_bad_vertices(v, match):
    with pytest.raises(ValueError, match=match):
        Mesh(v, np.zeros((0, 3), dtype=np.int32))


@pytest.mark.parametrize("f, match", [
    (np.zeros((2, 3)), "faces must have an integer dtype"),
    (np.zeros((2, 3), dtype=bool), "faces must have an integer dtype"),
    (np.zeros((2, 3), dtype=complex), "faces must have an integer dtype"),
    (np.zeros((2, 3), dtype=object), "faces must have an integer dtype"),
    (np.zeros((2, 4), dtype=np.int32), r"faces must have shape \(n, 3\)"),
    (np.zeros(3, dtype=np.int32), r"faces must have shape \(n, 3\)"),
    (np.zeros((1, 2, 3), dtype=np.int32), r"faces must have shape \(n, 3\)"),
    (np.array([[0, 1, 2**31]], dtype=np.int64), "too large for int32"),
    (np.array([[0, 1, 2**63]], dtype=np.uint64), "too large for int32"),
])
def test_bad_faces(f, match):
    with pytest.raises(ValueError, match=match):
        Mesh(CUBE_V, f)


def test_out_of_range_indices_reported():
    f = CUBE_F.copy()
    f[3, 1] = 8
    f[5, 0] = -1
    f[7, 2] = 100
    with pytest.raises(ValueError, match=r"3 index\(es\) outside \[0, 8\).*faces\[3, 1\] = 8"):
        Mesh(CUBE_V, f)
    with pytest.raises(ValueError, match=r"faces\[0, 0\] = -4294967296"):
        Mesh(CUBE_V, np.array([[-(2**32), 0, 1]]))  # must not wrap to 0 in int32
    with pytest.raises(ValueError, match="outside"):
        Mesh(np.zeros((0, 3)), [[0, 0, 0]])


def test_non_finite_vertices_allowed():
    v = np.vstack([CUBE_V, [[np.nan, 0, 0], [np.inf, 1e40, -np.inf]]])
    f = np.vstack([CUBE_F, [[0, 1, 8], [9, 1, 2]]])
    m = Mesh(v, f)
    assert np.isnan(m.vertices[8, 0]) and np.isinf(m.vertices[9]).all()
    lo, hi = m.bounds()  # non-finite vertices ignored
    np.testing.assert_array_equal(lo, [-1.0, 0.5, -3.0])
    np.testing.assert_array_equal(hi, [2.0, 1.5, 4.0])
    n = m.face_normals()
    np.testing.assert_array_equal(n[12:], 0.0)


def test_bounds_of_cube():
    lo, hi = Mesh(CUBE_V, CUBE_F).bounds()
    assert lo.dtype == np.float64 and lo.shape == (3,)
    np.testing.assert_array_equal(lo, [-1.0, 0.5, -3.0])
    np.testing.assert_array_equal(hi, [2.0, 1.5, 4.0])


def test_bounds_ignore_unreferenced_vertices():
    v = np.vstack([CUBE_V, [[100.0, 100.0, 100.0]]])
    lo, hi = Mesh(v, CUBE_F).bounds()
    np.testing.assert_array_equal(hi, [2.0, 1.5, 4.0])


def test_face_normals_point_outward():
    m = Mesh(CUBE_V, CUBE_F)
    n = m.face_normals()
    assert n.dtype == np.float32 and n.shape == (12, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-6)
    centroids = m.vertices[m.faces].mean(axis=1) - CUBE_V.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", n, centroids) > 0)
    expected = np.repeat([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]],
                         2, axis=0)
    np.testing.assert_allclose(n, expected, atol=1e-7)


def test_face_normals_degenerate_zero():
    m = Mesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2], [0, 0, 1]])
    np.testing.assert_array_equal(m.face_normals(), 0.0)


def test_load_spot():
    path = MESHES / "spot.ply"
    if not path.is_file():
        pytest.skip(f"test meshes not found at {MESHES} (shared/ must sit beside the repo)")
    m = Mesh.load(path)
    assert (m.n_vertices, m.n_faces) == (2930, 5856)  # shared/meshes/SOURCES.md
    lo, hi = m.bounds()
    np.testing.assert_allclose(lo, [-0.471552, -0.736784, -0.668909], atol=1e-6)
    np.testing.assert_allclose(hi, [0.471552, 0.953646, 1.049], atol=1e-6)
    # Face order is the file's (process=False): compare with trimesh's raw read.
    import trimesh

    tm = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_array_equal(m.faces, tm.faces)
    assert Mesh.from_trimesh(tm).n_faces == 5856


def test_load_quads_triangulated(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    m = Mesh.load(p)
    assert (m.n_vertices, m.n_faces) == (4, 2)


def test_load_errors(tmp_path):
    missing = tmp_path / "nope.ply"
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        Mesh.load(missing)
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"this is not a ply file\n")
    with pytest.raises(ValueError, match="bad.ply"):
        Mesh.load(bad)
    with pytest.raises(TypeError, match="trimesh.Trimesh"):
        Mesh.from_trimesh("not a mesh")  # type: ignore[arg-type]
