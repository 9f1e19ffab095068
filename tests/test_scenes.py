"""Scene generators: sizes, determinism, closed outward meshes, cameras in the right place."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from clraster import Camera, Mesh
from clraster.world import generators as scenes
from clraster.world.generators.primitives import boxes

MESH_DIR = Path(__file__).resolve().parents[2] / "shared" / "meshes"


# -- helpers -------------------------------------------------------------------------------

def _world_box(inst) -> tuple[np.ndarray, np.ndarray] | None:
    """World-space AABB of an instance (of its mesh's finite bounds' 8 corners)."""
    try:
        lo, hi = inst.mesh.bounds()
    except ValueError:
        return None
    corners = np.stack(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij"), -1).reshape(-1, 3)
    t = np.asarray(inst.transform, dtype=np.float64)
    pts = corners @ t[:3, :3].T + t[:3, 3]
    return pts.min(axis=0), pts.max(axis=0)


def _unique_meshes(scene) -> list[Mesh]:
    seen: dict[int, Mesh] = {}
    for inst in scene.instances:
        seen.setdefault(id(inst.mesh), inst.mesh)
    return list(seen.values())


def _component_labels(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Connected-component label per face (union-find with pointer jumping, vectorized)."""
    parent = np.arange(n_vertices)
    edges = faces[:, [0, 1, 1, 2]].reshape(-1, 2).astype(np.int64)
    while True:
        ra, rb = parent[edges[:, 0]], parent[edges[:, 1]]
        if np.array_equal(ra, rb):
            break
        np.minimum.at(parent, np.maximum(ra, rb), np.minimum(ra, rb))
        while True:
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
    return parent[faces[:, 0]]


def _assert_closed_outward(mesh: Mesh, what: str, allow_degenerate: bool = False) -> None:
    """Watertight, consistently wound, and every connected part has positive volume
    (counter-clockwise seen from outside)."""
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    tm = trimesh.Trimesh(v, f, process=False)
    assert tm.is_watertight, f"{what}: not watertight"
    assert tm.is_winding_consistent, f"{what}: winding inconsistent"
    tri = v[f]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    labels = _component_labels(f, v.shape[0])
    _, inv = np.unique(labels, return_inverse=True)
    per_part = np.bincount(inv, weights=vol)
    assert per_part.min() > 0.0, f"{what}: a part has volume {per_part.min()} (inside out)"
    if not allow_degenerate:  # generators make no zero-area (wasted) faces
        zero = int((np.abs(mesh.face_normals()).sum(axis=1) == 0).sum())
        assert zero == 0, f"{what}: {zero} zero-area faces"


def _winding_numbers(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """Generalized winding number of `points` (P, 3) w.r.t. a closed mesh (van Oosterom &
    Strackee solid angles): ≈1 inside a part, ≈0 outside."""
    tri = mesh.vertices.astype(np.float64)[mesh.faces]
    out = np.empty(points.shape[0])
    for k, p in enumerate(points):
        a, b, c = (tri[:, i] - p for i in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb)
        out[k] = np.sum(2.0 * np.arctan2(num, den)) / (4.0 * np.pi)
    return out


def _inside_any_solid(scene, points: np.ndarray) -> np.ndarray:
    """Per point: inside some instance's closed mesh (checked where its AABB holds it)."""
    inside = np.zeros(points.shape[0], dtype=bool)
    for inst in scene.instances:
        box = _world_box(inst)
        if box is None:
            continue
        near = np.all((points >= box[0] - 1e-6) & (points <= box[1] + 1e-6), axis=1)
        if not near.any():
            continue
        t = np.asarray(inst.transform, dtype=np.float64)
        local = (points[near] - t[:3, 3]) @ np.linalg.inv(t[:3, :3]).T
        w = _winding_numbers(inst.mesh, local)
        inside[np.flatnonzero(near)[w > 0.5]] = True
    return inside


def _clip_of(camera: Camera, w: int, h: int, pts: np.ndarray) -> np.ndarray:
    vp = camera.view_projection(w, h)
    return np.c_[pts, np.ones(len(pts))] @ vp.T


def _arrays(scene) -> list[np.ndarray]:
    out = []
    for inst in scene.instances:
        out += [inst.mesh.vertices, inst.mesh.faces, np.asarray(inst.transform)]
    return out


def test_helpers_detect_inside_points_and_inside_out_parts():
    mesh = _box_mesh((1.0, 1.0, 1.0))
    s = scenes.instance_grid(mesh, 2, spacing=2.0)  # boxes centred at x = ±1
    pts = np.array([[1.0, 0.0, 0.0], [-1.2, 0.3, -0.2], [0.0, 0.0, 0.0], [1.0, 0.6, 0.0]])
    np.testing.assert_array_equal(_inside_any_solid(s, pts), [True, True, False, False])
    _assert_closed_outward(mesh, "box")
    with pytest.raises(AssertionError, match="inside out"):
        v, f = boxes([[0, 0, 0], [2, 0, 0]], [[1, 1, 1], [3, 1, 1]])
        f[12:] = f[12:, ::-1]  # the second box inside out
        _assert_closed_outward(Mesh(v, f), "two boxes")


# -- plant ----------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [2_000, 5_000, 20_000, 100_000, 1_000_000])
def test_plant_triangle_count(n):
    s = scenes.plant(n)
    assert abs(s.n_faces - n) <= 0.1 * n, (n, s.n_faces)
    assert abs(s.n_faces - n) <= 0.01 * n  # in practice: within one pipe section


@pytest.mark.slow
def test_plant_10m_triangles():
    s = scenes.plant(10_000_000)
    assert abs(s.n_faces - 10_000_000) <= 1_000_000
    assert 1_000 <= s.n_instances <= 20_000
    assert max(m.n_faces for m in _unique_meshes(s)) >= 300_000


def test_plant_deterministic():
    a, b = scenes.plant(60_000, seed=3), scenes.plant(60_000, seed=3)
    assert a.n_instances == b.n_instances
    for x, y in zip(_arrays(a), _arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    c = scenes.plant(60_000, seed=4)
    assert c.n_instances != a.n_instances or any(
        x.shape != y.shape or not np.array_equal(x, y)
        for x, y in zip(_arrays(a), _arrays(c), strict=True))


def test_plant_structure_mixes_instances_and_big_meshes():
    s = scenes.plant(1_000_000)
    meshes = _unique_meshes(s)
    uses: dict[int, int] = {}
    for inst in s.instances:
        uses[id(inst.mesh)] = uses.get(id(inst.mesh), 0) + 1
    assert 300 <= s.n_instances <= 5_000
    assert 20 <= len(meshes) <= 80
    assert max(uses.values()) >= 50  # a mesh instanced many times
    assert max(m.n_faces for m in meshes) >= 50_000  # and big meshes
    nonuniform = 0
    for inst in s.instances:
        t = np.asarray(inst.transform)
        assert t.shape == (4, 4) and t.dtype == np.float64
        np.testing.assert_array_equal(t[3], [0, 0, 0, 1])
        assert np.linalg.det(t[:3, :3]) > 0  # no mirrors: winding stays outward
        col = np.linalg.norm(t[:3, :3], axis=0)
        nonuniform += int(np.ptp(col) > 1e-6 * col.max())
    assert nonuniform >= 10


def test_plant_bounds_follow_the_layout():
    s = scenes.plant(300_000)
    lo, hi = (np.asarray(a, dtype=np.float64) for a in s.bounds())
    np.testing.assert_allclose(lo, [0.0, -scenes.SLAB, 0.0], atol=1e-5)
    storeys = hi[1] / scenes.STOREY
    assert abs(storeys - round(storeys)) < 1e-5 and round(storeys) >= 2
    bands = hi[2] / scenes.BAND
    assert abs(bands - round(bands)) < 1e-5
    rooms = hi[0] / scenes.ROOM_X
    assert abs(rooms - round(rooms)) < 1e-5


@pytest.mark.parametrize("n", [5_000, 100_000])
def test_plant_meshes_closed_and_outward(n):
    for k, mesh in enumerate(_unique_meshes(scenes.plant(n))):
        _assert_closed_outward(mesh, f"plant({n}) mesh {k} ({mesh})")


@pytest.mark.parametrize("tessellation", [3, 8, 24, 48])
def test_catalog_closed_and_outward(tessellation):
    for name, mesh in scenes.plant_catalog(tessellation).items():
        _assert_closed_outward(mesh, f"{name} at tessellation {tessellation}")


def test_plant_inside_camera_in_a_corridor():
    s = scenes.plant(1_000_000)
    lo, hi = (np.asarray(a, dtype=np.float64) for a in s.bounds())
    storeys = round((hi[1] - lo[1] - scenes.SLAB) / scenes.STOREY)
    assert storeys >= 3
    offsets = np.stack(np.meshgrid(*[[-0.3, 0.0, 0.3]] * 3, indexing="ij"), -1).reshape(-1, 3)
    for storey in range(storeys):
        cam = scenes.plant_inside_camera(s, 640, 360, storey=storey)
        eye = np.asarray(cam.eye)
        assert np.all(eye > lo) and np.all(eye < hi)
        np.testing.assert_allclose(eye[1], storey * scenes.STOREY + scenes.EYE_HEIGHT)
        assert cam.near <= 0.1 and cam.far >= hi[0] - lo[0]
        assert 50 <= cam.fov_y <= 70
        # Looking along +x (down the corridor).
        fwd = -np.asarray(cam.view)[2, :3]
        np.testing.assert_allclose(fwd, [1.0, 0.0, 0.0], atol=1e-9)
        # Neither the eye nor a 0.3 m cube around it is inside any solid object.
        assert not _inside_any_solid(s, eye + offsets).any()
    with pytest.raises(ValueError, match="storey"):
        scenes.plant_inside_camera(s, 640, 360, storey=storeys)


def test_plant_inside_camera_rejects_other_scenes():
    with pytest.raises(ValueError, match="plant"):
        scenes.plant_inside_camera(scenes.random_scene(0, 5), 64, 64)


def test_plant_overview_camera_sees_the_whole_building():
    s = scenes.plant(20_000)
    lo, hi = (np.asarray(a, dtype=np.float64) for a in s.bounds())
    cam = scenes.plant_overview_camera(s, 800, 450)
    assert np.any((cam.eye < lo) | (cam.eye > hi))  # outside
    corners = np.stack(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij"), -1).reshape(-1, 3)
    clip = _clip_of(cam, 800, 450, corners)
    assert np.all(np.abs(clip[:, :3]) <= clip[:, 3:4])


@pytest.mark.parametrize("bad", [1_999, 0, -5, 2.5e6, True, "1000"])
def test_plant_rejects_bad_sizes(bad):
    with pytest.raises(ValueError, match="n_triangles"):
        scenes.plant(bad)


# -- instance grid ----------------------------------------------------------------------------

def _box_mesh(ex=(1.0, 2.0, 0.5)) -> Mesh:
    v, f = boxes(np.zeros(3), np.asarray(ex))
    return Mesh(v, f)


def test_instance_grid_layout():
    mesh = _box_mesh()
    s = scenes.instance_grid(mesh, 3, 2, 4, spacing=1.5)
    assert s.n_instances == 24 and s.n_faces == 24 * mesh.n_faces
    assert all(inst.mesh is mesh for inst in s.instances)
    centres = np.array([np.asarray(i.transform)[:3, 3] for i in s.instances])
    base = centres - centres[0]
    pitch = 1.5 * np.array([1.0, 2.0, 0.5])
    idx = base / pitch
    np.testing.assert_allclose(idx, np.rint(idx), atol=1e-9)
    # x varies fastest; the grid is centred on the origin
    np.testing.assert_allclose(idx[:4], [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    lo, hi = (np.asarray(a, dtype=np.float64) for a in s.bounds())
    np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
    for inst in s.instances:
        t = np.asarray(inst.transform)
        np.testing.assert_array_equal(t[:3, :3], np.eye(3))


def test_instance_grid_flat_mesh_uses_largest_extent():
    flat = Mesh([[0, 0, 0], [2, 0, 0], [0, 0, 1]], [[0, 2, 1]])
    s = scenes.instance_grid(flat, 1, 3, 1, spacing=2.0)
    ys = sorted(np.asarray(i.transform)[1, 3] for i in s.instances)
    np.testing.assert_allclose(np.diff(ys), 4.0)


@pytest.mark.parametrize("args, kw", [((0,), {}), ((2, -1), {}), ((1.5,), {}),
                                      ((2,), {"spacing": 0.0}),
                                      ((2,), {"spacing": math.inf})])
def test_instance_grid_rejects_bad_arguments(args, kw):
    with pytest.raises(ValueError):
        scenes.instance_grid(_box_mesh(), *args, **kw)


def test_grid_camera_frames_the_grid():
    s = scenes.instance_grid(_box_mesh(), 5, 1, 3)
    cam = scenes.grid_camera(s, 320, 200)
    lo, hi = (np.asarray(a, dtype=np.float64) for a in s.bounds())
    corners = np.stack(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij"), -1).reshape(-1, 3)
    clip = _clip_of(cam, 320, 200, corners)
    assert np.all(np.abs(clip[:, :3]) <= clip[:, 3:4])


@pytest.mark.skipif(not (MESH_DIR / "stanford_dragon_vrip.ply").is_file(),
                    reason="shared dragon mesh not present")
def test_dragon_grid():
    dragon = Mesh.load(MESH_DIR / "stanford_dragon_vrip.ply")
    s = scenes.instance_grid(dragon, 4, 1, 3)
    assert s.n_faces == 12 * dragon.n_faces
    cam = scenes.grid_camera(s, 640, 480)
    assert np.isfinite(cam.view).all()


# -- random scenes ------------------------------------------------------------------------------

def test_random_scene_deterministic_and_shared():
    a, b = scenes.random_scene(7, 30), scenes.random_scene(7, 30)
    for x, y in zip(_arrays(a), _arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.n_instances == 30
    assert len(_unique_meshes(a)) < 30  # instances share meshes
    c = scenes.random_scene(8, 30)
    assert not all(x.shape == y.shape and np.array_equal(x, y)
                   for x, y in zip(_arrays(a), _arrays(c), strict=True))


@pytest.mark.parametrize("seed", range(5))
def test_random_scene_contents(seed):
    s = scenes.random_scene(seed, 12, extent=3.0)
    nan_meshes = flat_meshes = 0
    nonuniform = False
    for inst in s.instances:
        t = np.asarray(inst.transform)
        assert np.linalg.det(t[:3, :3]) > 0
        assert np.all(np.abs(t[:3, 3]) <= 3.0)
        col = np.linalg.norm(t[:3, :3], axis=0)
        nonuniform |= np.ptp(col) > 1e-6 * col.max()
    for k, mesh in enumerate(_unique_meshes(s)):
        v = mesh.vertices
        if np.isnan(v).any():
            nan_meshes += 1
            continue
        lo, hi = mesh.bounds()
        if np.any(hi - lo == 0):
            flat_meshes += 1
            continue
        _assert_closed_outward(mesh, f"random_scene({seed}) mesh {k}")
    assert (nan_meshes, flat_meshes) == (1, 1)
    no_degenerate = scenes.random_scene(seed, 12, degenerate=False)
    assert not any(np.isnan(m.vertices).any() for m in _unique_meshes(no_degenerate))


def test_random_scene_has_nonuniform_scales():
    found = 0
    for inst in scenes.random_scene(1, 40).instances:
        col = np.linalg.norm(np.asarray(inst.transform)[:3, :3], axis=0)
        found += int(np.ptp(col) > 1e-3 * col.max())
    assert found >= 5


def test_random_scene_mirrors_only_flip_signs():
    plain, mirrored = scenes.random_scene(2, 40), scenes.random_scene(2, 40, mirrors=True)
    dets = []
    for a, b in zip(plain.instances, mirrored.instances, strict=True):
        assert a.mesh.n_faces == b.mesh.n_faces
        ta, tb = np.asarray(a.transform), np.asarray(b.transform)
        np.testing.assert_allclose(np.abs(np.linalg.det(ta)), np.abs(np.linalg.det(tb)))
        np.testing.assert_array_equal(ta[:3, 3], tb[:3, 3])
        dets.append(np.linalg.det(tb[:3, :3]))
    assert 1 <= sum(d < 0 for d in dets) < 40


def test_random_scene_rejects_bad_arguments():
    with pytest.raises(ValueError, match="n_instances"):
        scenes.random_scene(0, 0)
    with pytest.raises(ValueError, match="extent"):
        scenes.random_scene(0, 3, extent=-1.0)
