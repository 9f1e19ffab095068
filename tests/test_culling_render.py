"""Object culling is conservative: culling never changes the image.

Instances and clusters removed by the frustum test of their bounding volumes, and clusters
removed by their normal cones, must be exactly those that would not have written a single
pixel: the OpenCL frame rendered with ``frustum=True, cones=True`` has the same triangle ids
and depths (bit for bit) as the frame rendered with both off, and the same barycentrics
wherever the ids agree. Checked here on

* random scenes (`random_scene`, several seeds, with and without mirroring transforms, with
  its degenerate instances: a zero-thickness box and a sphere with a NaN vertex), plus finely
  tessellated spheres, tori, subdivided boxes and flat grids so that clusters have narrow
  normal cones; optionally with every instance axis-aligned, so that bounding boxes are
  tight and a culling error shows in the image. Seen by random cameras of many kinds
  (`CAMERA_KINDS`): outside looking in, inside an object, inside the scene; a frustum side
  plane through an instance's centre, one of its vertices or a corner of its or one of its
  clusters' boxes; the near or far plane through a box corner, cutting an object, or
  leaving only a sliver of an object (or cluster) inside; an object just touching a plane
  from inside (the culler's INSIDE margin: INSIDE clusters skip per-triangle clipping);
  a tiny near distance with the eye a hair above a surface; faces seen nearly edge-on
  (normal cones); wide and narrow fields of view; orthographic and mirroring projections.
  Non-square sizes including 2^k ± 1, tile sizes 8..64, cull "back", "none" and "front";
* the NumPy twin on scenes (ids, depth, every stat count equal to the OpenCL frame);
* constructed scenes whose culling counts are computed by hand;
* triangle ids of scenes (`Scene.split_ids` against rendering one instance alone);
* a grid of Stanford dragons seen from inside the grid, and a small power plant seen from
  one of its corridors (`-s` prints the culling funnel).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    MatrixCamera,
    assert_frames_equal,
    assert_same_image,
    get_renderer,
    ortho,
    perspective,
)
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from clraster import Camera, Mesh, RasterConfig
from clraster.culling.clusters import clusters_of
from clraster.pipeline import reference
from clraster.world.generators import instance_grid, plant, plant_inside_camera, random_scene
from clraster.world.scene import Scene

MESH_DIR = Path(__file__).resolve().parents[2] / "shared" / "meshes"

CULLS = ("back", "none", "front")
#: Image sizes: non-square, on both sides of powers of two.
SIZES = ((64, 48), (33, 17), (31, 65), (65, 33), (17, 63), (128, 72))
CAMERA_KINDS = ("outside", "inside_object", "inside_scene", "graze_centre", "graze_vertex",
                "graze_box", "graze_cluster", "near_box", "far_box", "near_cut", "tiny_near",
                "far_cut", "near_sliver", "far_sliver", "side_sliver", "near_touch",
                "far_touch", "side_touch", "edge_on", "wide", "narrow", "ortho", "mirrored")
SLIVERS = ("near_sliver", "far_sliver", "side_sliver", "near_touch", "far_touch", "side_touch")


# -- helpers ------------------------------------------------------------------------------

def render(scene, camera, size, cull, culling=True, tile_log2=4):
    return get_renderer(*size, tile_log2).render(scene, camera, cull=cull, frustum=culling,
                                                 cones=culling)


def check_partition(s) -> None:
    """Object-culling counts partition the scene."""
    assert s.triangles_total == (s.triangles_frustum_culled + s.triangles_cone_culled
                                 + s.triangles_in), s.counts()
    assert s.clusters_total == (s.clusters_frustum_culled + s.clusters_cone_culled
                                + s.clusters_drawn), s.counts()
    assert 0 <= s.instances_frustum_culled + s.instances_empty <= s.instances_total


def compare_culling(scene, camera, size, cull, context: str, tile_log2: int = 4):
    on = render(scene, camera, size, cull, True, tile_log2)
    off = render(scene, camera, size, cull, False, tile_log2)
    ctx = f"{context} cull={cull} size={size}"
    assert_same_image(on, off, ctx)
    check_partition(on.stats)
    check_partition(off.stats)
    # Culling off culls nothing at the object level.
    so = off.stats
    assert so.instances_frustum_culled == 0 and so.clusters_frustum_culled == 0, ctx
    assert so.clusters_cone_culled == 0 and so.triangles_in == so.triangles_total, ctx
    if cull == "none":
        assert on.stats.clusters_cone_culled == 0, ctx
    return on, off


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _rotation_taking(a: np.ndarray, b: np.ndarray, roll: float) -> np.ndarray:
    """A rotation R with R @ a = b (unit vectors), then rolled by `roll` about b."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            r = np.eye(3)
        else:  # half turn about any axis perpendicular to a
            p = _unit(np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0]))
            r = 2.0 * np.outer(p, p) - np.eye(3)
    else:
        k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        r = np.eye(3) + k + k @ k / (1.0 + c)
    kb = np.array([[0, -b[2], b[1]], [b[2], 0, -b[0]], [-b[1], b[0], 0]])
    roll_m = np.eye(3) + math.sin(roll) * kb + (1.0 - math.cos(roll)) * kb @ kb
    return roll_m @ r


def view_towards(eye, point, ndc=(0.0, 0.0), *, fov_y: float, aspect: float,
                 roll: float = 0.0) -> np.ndarray:
    """World → eye matrix of a camera at `eye` that sees `point` at NDC (x, y) (with
    `perspective(fov_y, aspect, ...)`): (±1, y) puts `point` on the left/right plane,
    (x, ±1) on the bottom/top plane. `roll` turns the camera about that line of sight."""
    ty = math.tan(math.radians(fov_y) / 2.0)
    a = _unit([ndc[0] * ty * aspect, ndc[1] * ty, -1.0])  # eye-space direction
    b = _unit(np.asarray(point, np.float64) - eye)  # world direction
    r = _rotation_taking(a, b, roll)  # eye → world rotation
    view = np.eye(4)
    view[:3, :3] = r.T
    view[:3, 3] = -r.T @ np.asarray(eye, np.float64)
    return view


def _instance_centre_radius(scene: Scene, i: int) -> tuple[np.ndarray, float]:
    lo, hi = scene.world_aabbs()
    return (lo[i] + hi[i]) / 2.0, float(np.linalg.norm(hi[i] - lo[i])) / 2.0


def _finite_vertex(scene: Scene, i: int, rng) -> np.ndarray:
    inst = scene.instances[i]
    v = inst.mesh.vertices[np.isfinite(inst.mesh.vertices).all(axis=1)]
    p = v[int(rng.integers(0, v.shape[0]))]
    return inst.transform[:3, :3] @ p + inst.transform[:3, 3]


def _box_corner(scene: Scene, i: int, rng, cluster: bool) -> np.ndarray:
    """World position of a random corner of instance i's object AABB, or of one of its
    clusters' AABBs: where the culler's box tests meet their boundary."""
    inst = scene.instances[i]
    if cluster:
        cm = clusters_of(inst.mesh)
        c = int(rng.integers(0, cm.n_clusters))
        lo, hi = cm.aabb_min[c].astype(np.float64), cm.aabb_max[c].astype(np.float64)
    else:
        lo, hi = inst.mesh.bounds()
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return _finite_vertex(scene, i, rng)
    p = np.where(rng.random(3) < 0.5, lo, hi)
    return inst.transform[:3, :3] @ p + inst.transform[:3, 3]


def _part(scene: Scene, i: int, rng, cluster: bool) -> tuple[np.ndarray, np.ndarray]:
    """World positions of the finite vertices of instance i, or of one of its clusters, and
    one of its faces with finite vertices ((3, 3) world positions)."""
    inst = scene.instances[i]
    mesh = inst.mesh
    faces = np.arange(mesh.n_faces)
    if cluster:
        cm = clusters_of(mesh)
        c = int(rng.integers(0, cm.n_clusters))
        faces = cm.face_ids[cm.tri_offset[c]:cm.tri_offset[c + 1]]
    tris = mesh.vertices[mesh.faces[faces]] @ inst.transform[:3, :3].T + inst.transform[:3, 3]
    ok = np.isfinite(tris).all(axis=(1, 2))
    if not ok.any():  # a cluster made only of NaN faces: take the whole instance
        return _part(scene, i, rng, False)
    tris = tris[ok]
    return tris.reshape(-1, 3), tris[int(rng.integers(0, tris.shape[0]))]


def _is_boxy(mesh: Mesh) -> bool:
    """Every face normal is along a coordinate axis (boxes, subdivided boxes)."""
    n = mesh.face_normals()
    n = n[np.isfinite(n).all(axis=1) & (np.abs(n).sum(axis=1) > 0)]
    return bool(n.size) and bool(((np.abs(n) > 1e-9).sum(axis=1) == 1).all())


def _turn(view: np.ndarray, axis: int, alpha: float) -> np.ndarray:
    """`view` followed by a turn of the camera that lowers every point's angle
    atan2(eye coordinate `axis`, −z) by `alpha` (about the eye's y axis for axis 0, its x
    axis for axis 1)."""
    r = np.eye(4)
    c, s = math.cos(alpha), math.sin(alpha)
    # (u, v) = (x or y, −z) → (u cos α − v sin α, u sin α + v cos α)
    r[axis, axis], r[axis, 2] = c, s
    r[2, axis], r[2, 2] = -s, c
    return r @ view


def random_camera(scene: Scene, kind: str, seed: int, size) -> tuple[MatrixCamera, str]:
    """A camera of the given kind for `scene` (deterministic in `seed`); returns it with a
    description for failure messages."""
    rng = np.random.default_rng(seed)
    w, h = size
    aspect = w / h
    lo, hi = scene.bounds()
    centre = (lo + hi) / 2.0
    span = float(np.linalg.norm(hi - lo))
    bounded = np.flatnonzero(scene.has_bounds & ~scene.empty)
    inst = int(rng.choice(bounded))
    c_i, r_i = _instance_centre_radius(scene, inst)
    fov = float(rng.uniform(30.0, 100.0))
    near, far = 0.05, 4.0 * span
    roll = float(rng.uniform(-math.pi, math.pi))
    ndc = tuple(rng.uniform(-0.5, 0.5, 2))
    direction = _unit(rng.normal(size=3))
    if kind in SLIVERS or kind == "edge_on":
        # Prefer meshes with flat sides: the sliver can then be a whole face (a whole
        # cluster of a subdivided box), and a flat cluster has an exact normal cone.
        boxy = [i for i in bounded if _is_boxy(scene.instances[i].mesh)]
        if boxy and rng.random() < 0.7:
            inst = int(rng.choice(boxy))
            c_i, r_i = _instance_centre_radius(scene, inst)
    if kind == "outside":
        eye = centre + direction * span * rng.uniform(0.35, 0.9)
        target = centre + rng.normal(size=3) * span * 0.1
    elif kind == "inside_object":
        t = scene.instances[inst].transform
        eye = t[:3, :3] @ rng.uniform(-0.05, 0.05, 3) + t[:3, 3]
        target = eye + direction
    elif kind == "inside_scene":
        eye = rng.uniform(lo, hi)
        target = eye + direction
    elif kind in ("graze_centre", "graze_vertex", "graze_box", "graze_cluster"):
        # A frustum plane (left/right/bottom/top, or a corner: two of them) passes exactly
        # through the instance's centre, one of its vertices, or a corner of its (or one of
        # its clusters') object bounding box.
        if kind == "graze_centre":
            target = c_i
        elif kind == "graze_vertex":
            target = _finite_vertex(scene, inst, rng)
        else:
            target = _box_corner(scene, inst, rng, kind == "graze_cluster")
        eye = target + direction * rng.uniform(1.5 * r_i, 0.7 * span + 2 * r_i)
        side = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, 1), (-1, 1), (1, -1)]
        ndc = side[int(rng.integers(0, len(side)))]
        ndc = (ndc[0] if ndc[0] else rng.uniform(-0.9, 0.9),
               ndc[1] if ndc[1] else rng.uniform(-0.9, 0.9))
    elif kind in ("near_box", "far_box"):
        # The near (far) plane passes through a corner of a bounding box of the instance or
        # of one of its clusters (set below, once the view is known).
        target = _box_corner(scene, inst, rng, bool(rng.random() < 0.5))
        eye = target + direction * rng.uniform(0.2 * r_i, 0.5 * span + 2 * r_i)
    elif kind == "near_cut":
        # Eye just outside the instance's bounding sphere, near plane through the instance.
        eye = c_i + direction * r_i * rng.uniform(1.0, 1.3)
        target = c_i
        near = float(np.linalg.norm(eye - c_i)) * rng.uniform(0.3, 1.2)
    elif kind == "tiny_near":
        # Eye a hair above a vertex, near distance 1e-4: the near plane cuts faces there.
        p = _finite_vertex(scene, inst, rng)
        eye = p + _unit(p - c_i) * 10.0 ** rng.uniform(-4, -2)
        target = p if rng.random() < 0.5 else c_i
        near = 1e-4
    elif kind == "far_cut":
        eye = c_i + direction * r_i * rng.uniform(1.5, 4.0)
        target = c_i
        far = float(np.linalg.norm(eye - c_i)) * rng.uniform(0.8, 1.2)
        near = min(0.05, far / 10)
    elif kind in SLIVERS:
        # Slivers: only a sliver of the instance (or of one of its clusters) is inside the
        # frustum: the near (far) plane just short of its farthest (nearest) vertex, or a
        # side plane a fraction of a pixel to a few pixels inside its outermost vertex.
        # Touches: the part is just inside (or just outside) one plane, its nearest
        # (farthest, outermost) vertex within a relative 1e-8..1e-3 of the near (far)
        # plane, or within 0.01 pixel of a side: the case of the culler's INSIDE margin
        # (INSIDE clusters skip the per-triangle clip tests). Planes set below. Near/far:
        # seen head-on along the normal of one of its faces, from either side, so that a
        # flat part (a box side, a cluster of a subdivided box) lies whole against the plane
        # and covers many pixels.
        part, face = _part(scene, inst, rng, bool(rng.random() < 0.5))
        if kind in ("side_sliver", "side_touch"):
            eye = c_i + direction * r_i * rng.uniform(2.0, 6.0)
            target = c_i
        else:
            n = np.cross(face[1] - face[0], face[2] - face[0])
            n = _unit(n) if np.linalg.norm(n) > 0 else direction
            target = face.mean(axis=0)
            eye = target + n * float(rng.choice([-1.0, 1.0])) * r_i * rng.uniform(2.5, 6.0)
        ndc = (0.0, 0.0)
        fov = float(rng.uniform(40.0, 100.0))
    elif kind == "edge_on":
        # Eye (almost) in the plane of one face, looking at it: the face and its cluster
        # are seen (nearly) edge-on, the hard case for normal cones.
        t = scene.instances[inst].transform
        mesh = scene.instances[inst].mesh
        ok = np.flatnonzero(np.isfinite(mesh.vertices[mesh.faces]).all(axis=(1, 2)))
        tri = mesh.vertices[mesh.faces[int(rng.choice(ok))]] @ t[:3, :3].T + t[:3, 3]
        target = tri.mean(axis=0)
        n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        n = _unit(n) if np.linalg.norm(n) > 0 else _unit(rng.normal(size=3))
        along = _unit(np.cross(n, rng.normal(size=3)))
        # eps: the tangent of the angle between the face's plane and the line of sight.
        eps = float(rng.choice([1e-7, 1e-5, 1e-3, 0.02, 0.05, 0.1])) * rng.choice([-1, 0, 1])
        d = r_i * rng.uniform(0.5, 4.0)
        eye = target + along * d + n * eps * d
    elif kind == "wide":
        eye = rng.uniform(lo, hi)
        target = eye + direction
        fov = float(rng.uniform(150.0, 178.0))
        near = 10.0 ** rng.uniform(-3, -1)
    elif kind == "narrow":
        eye = centre + direction * span * rng.uniform(0.8, 2.0)
        target = c_i
        fov = float(rng.uniform(0.5, 5.0))
        near = span * 0.05
    elif kind in ("ortho", "mirrored"):
        eye = centre + direction * span * rng.uniform(0.6, 1.2)
        target = centre + rng.normal(size=3) * span * 0.1
    else:
        raise ValueError(kind)
    view = view_towards(eye, target, ndc, fov_y=fov, aspect=aspect, roll=roll)
    if kind in ("near_box", "far_box"):
        depth = -float((view @ np.append(target, 1.0))[2])
        if kind == "near_box":
            near = depth
        else:
            far, near = depth, min(near, depth * 0.1)
    if kind in SLIVERS:
        pe = part @ view[:3, :3].T + view[:3, 3]  # eye space, all in front (z < 0)
        depth = -pe[:, 2]
        if kind.endswith("sliver"):
            frac = 10.0 ** rng.uniform(-5.0, -1.5)
        else:
            frac = 10.0 ** rng.uniform(-8.0, -3.0) * rng.choice([-1.0, 1.0])
        if kind == "near_sliver":
            near = float(depth.max()) * (1.0 - frac)
        elif kind == "near_touch":
            near = float(depth.min()) * (1.0 - frac)
        elif kind == "far_sliver":
            far = float(depth.min()) * (1.0 + frac)
        elif kind == "far_touch":
            far = float(depth.max()) * (1.0 + frac)
        else:
            axis, sign = int(rng.integers(0, 2)), float(rng.choice([-1.0, 1.0]))
            half_tan = math.tan(math.radians(fov) / 2.0) * (aspect if axis == 0 else 1.0)
            pixels = rng.uniform(0.3, 4.0) if kind == "side_sliver" else rng.uniform(-0.01, 0.01)
            theta_t = math.atan(sign * (1.0 - 2.0 * pixels / size[axis]) * half_tan)
            theta = np.arctan2(pe[:, axis], -pe[:, 2])
            # sliver: the part beyond the plane but for its innermost vertex; touch: the
            # part inside but for (maybe) its outermost one.
            extreme = (theta.min() if sign > 0 else theta.max()) if kind == "side_sliver" \
                else (theta.max() if sign > 0 else theta.min())
            view = _turn(view, axis, float(extreme) - theta_t)
        if kind.startswith("far"):
            near = min(near, far * 0.1)
    if kind == "ortho":
        half = span * rng.uniform(0.1, 0.6)
        proj = ortho(-half * aspect + ndc[0], half * aspect + ndc[0], -half, half,
                     -span * rng.uniform(0.0, 0.5), 2.5 * span)
    else:
        proj = perspective(fov, aspect, near, far)
    if kind == "mirrored":
        proj = np.diag([-1.0, 1.0, 1.0, 1.0]) @ proj
    desc = (f"camera kind={kind} seed={seed} inst={inst} eye={eye.tolist()} "
            f"target={np.asarray(target).tolist()} ndc={ndc} fov={fov:.3f} near={near:g} "
            f"far={far:g} roll={roll:.3f}")
    return MatrixCamera(proj @ view), desc


_FINE: list[Mesh] = []


def fine_meshes() -> list[Mesh]:
    """Meshes with several clusters each: a UV sphere, a torus and a box subdivided into
    small quads (closed), and a flat square grid (one-sided: its clusters are flat, their
    normal cones as narrow as they get). Built once, shared by all scenes."""
    from clraster.world.generators.primitives import torus, uv_sphere  # procedural mesh primitives

    if not _FINE:
        _FINE.extend([Mesh(*uv_sphere(0.5, 24, 48)), Mesh(*torus(0.4, 0.15, 64, 16)),
                      subdivided_box(12), flat_grid(32)])
    return _FINE


def flat_grid(n: int) -> Mesh:
    """The square [−0.5, 0.5]² in the plane y = 0 as an n×n grid of quads, facing +y."""
    g = np.linspace(-0.5, 0.5, n + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q0, q1, q2, q3 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    # (z, x) is counter-clockwise seen from +y: q0 → q3 (+z) → q2 → q1 (+x).
    f = np.concatenate([np.stack([q0, q3, q2], -1).reshape(-1, 3),
                        np.stack([q0, q2, q1], -1).reshape(-1, 3)])
    return Mesh(v, f)


def subdivided_box(n: int, half: float = 0.5) -> Mesh:
    """A closed cube [−half, half]³, each face an n×n grid of quads, wound outward."""
    verts, faces = [], []
    g = np.linspace(-half, half, n + 1)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    for axis in range(3):
        for sign in (-1.0, 1.0):
            p = np.zeros((n + 1, n + 1, 3))
            a, b = (axis + 1) % 3, (axis + 2) % 3
            p[..., axis] = sign * half
            p[..., a] = uu
            p[..., b] = vv
            base = sum(len(x) for x in verts)
            verts.append(p.reshape(-1, 3))
            idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1) + base
            q0, q1, q2, q3 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
            # (a, b, axis) is right-handed: counter-clockwise in (a, b) faces +axis.
            t = np.stack([np.stack([q0, q1, q2], -1), np.stack([q0, q2, q3], -1)], 2)
            t = t.reshape(-1, 3)
            if sign < 0:
                t = t[:, [0, 2, 1]]
            faces.append(t)
    # Weld: the grid points on shared edges are the same floats on both faces.
    v, inv = np.unique(np.concatenate(verts), axis=0, return_inverse=True)
    return Mesh(v, inv.reshape(-1)[np.concatenate(faces)])


def test_flat_grid_faces_up():
    m = flat_grid(4)
    assert m.n_faces == 32
    assert np.allclose(m.face_normals(), [0.0, 1.0, 0.0])


def test_subdivided_box_is_closed_and_outward():
    m = subdivided_box(3)
    assert m.n_faces == 6 * 9 * 2
    centroids = m.vertices[m.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", m.face_normals(), centroids) > 0).all()
    # closed: every undirected edge used exactly twice, once in each direction
    e = np.concatenate([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, counts = np.unique(key, axis=0, return_counts=True)
    assert (counts == 2).all()


def make_scene(seed: int, mirrors: bool, n_instances: int = 12, fine: int = 2,
               extent: float = 5.0, aligned: bool = False) -> Scene:
    """`random_scene` plus `fine` instances of finely tessellated meshes (random rotation,
    scale, sometimes mirrored when `mirrors`).

    With `aligned`, every rotation is replaced by a random rotation that maps axes to axes
    (mirrors kept): box meshes then have exact world bounding boxes and faces parallel to
    the frustum planes of axis-aligned views, so the culler's box tests are tight and a
    culling error shows in the image (with free rotations the boxes are loose)."""
    base = random_scene(seed, n_instances, extent=extent, mirrors=mirrors)
    scene = Scene(base.instances)
    rng = np.random.default_rng(10_000 + seed)
    meshes = fine_meshes()
    for _ in range(fine):
        mesh = meshes[int(rng.integers(0, len(meshes)))]
        q = _unit(rng.normal(size=4))
        a, b, c, d = q
        rot = np.array([
            [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
            [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
            [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d]])
        sc = np.exp(rng.uniform(math.log(0.5), math.log(4.0), 3))
        if rng.random() < 0.5:
            sc[:] = sc[0]
        if mirrors and rng.random() < 0.5:
            sc[int(rng.integers(0, 3))] *= -1.0
        m = np.eye(4)
        m[:3, :3] = rot * sc[None, :]
        m[:3, 3] = rng.uniform(-extent, extent, 3)
        scene.add(mesh, m)
    if not aligned:
        return scene
    out = Scene()
    for inst in scene.instances:
        lin = inst.transform[:3, :3]
        p = np.eye(3)[rng.permutation(3)] * rng.choice([-1.0, 1.0], 3)[:, None]
        if np.linalg.det(p) < 0:
            p[0] *= -1.0
        d = np.linalg.norm(lin, axis=0)  # the scales (lin = rotation · diag(scales))
        if np.linalg.det(lin) < 0:
            d[0] = -d[0]
        m = inst.transform.copy()
        m[:3, :3] = p @ np.diag(d)
        out.add(inst.mesh, m)
    return out


# -- 1. culling on == culling off, random scenes and cameras -------------------------------

_SCENES: dict[tuple, Scene] = {}


def scene_for(seed: int, mirrors: bool, extent: float = 5.0, aligned: bool = False) -> Scene:
    """Cached `make_scene` (the renderer caches its plans per scene object)."""
    key = (seed, mirrors, extent, aligned)
    if key not in _SCENES:
        _SCENES[key] = make_scene(seed, mirrors, extent=extent, aligned=aligned)
    return _SCENES[key]


@pytest.mark.parametrize("kind", CAMERA_KINDS)
def test_culling_never_changes_the_image(kind):
    """Every camera kind, on 4 scenes (2 with axis-aligned instances) × with/without
    mirrors, × the 3 cull modes."""
    k = CAMERA_KINDS.index(kind)
    covered = culled = 0
    for seed in (1, 2, 3, 4):
        aligned = seed >= 3
        for mirrors in (False, True):
            scene = scene_for(seed, mirrors, 5.0 if seed % 2 else 2.0, aligned)
            size = SIZES[(seed + k) % len(SIZES)]
            cam, desc = random_camera(scene, kind, 1000 * seed + 37 * k + mirrors, size)
            for cull in CULLS:
                on, _ = compare_culling(scene, cam, size, cull,
                                        f"seed={seed} mirrors={mirrors} aligned={aligned} "
                                        f"{desc}")
                covered += int(on.mask.sum())
                culled += on.stats.clusters_frustum_culled + on.stats.clusters_cone_culled
    assert covered > 0 and culled > 0  # the kind is not vacuous


def _property(seed, mirrors, extent, aligned, kind, size, tile_log2, cam_seed):
    scene = scene_for(seed, mirrors, extent, aligned)
    cam, desc = random_camera(scene, kind, cam_seed, size)
    for cull in CULLS:
        compare_culling(scene, cam, size, cull,
                        f"seed={seed} mirrors={mirrors} extent={extent} aligned={aligned} "
                        f"tile_log2={tile_log2} {desc}", tile_log2=tile_log2)


_PROPERTY_ARGS = dict(
    seed=st.integers(0, 40), mirrors=st.booleans(), extent=st.sampled_from([2.0, 5.0]),
    aligned=st.booleans(),
    kind=st.sampled_from(CAMERA_KINDS), size=st.sampled_from(SIZES),
    tile_log2=st.sampled_from([3, 4, 5, 6]), cam_seed=st.integers(0, 2**31 - 1))


@settings(deadline=None, max_examples=150, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(**_PROPERTY_ARGS)
def test_culling_never_changes_the_image_property(seed, mirrors, extent, aligned, kind, size,
                                                  tile_log2, cam_seed):
    _property(seed, mirrors, extent, aligned, kind, size, tile_log2, cam_seed)


@pytest.mark.slow
@settings(deadline=None, max_examples=3000, derandomize=True, database=None,
          phases=(Phase.explicit, Phase.generate), suppress_health_check=[HealthCheck.too_slow])
@given(**_PROPERTY_ARGS)
def test_culling_never_changes_the_image_property_slow(seed, mirrors, extent, aligned, kind,
                                                       size, tile_log2, cam_seed):
    _property(seed, mirrors, extent, aligned, kind, size, tile_log2, cam_seed)


# -- 2. the NumPy twin on scenes, culling on -------------------------------------------------

# Chosen (by a scan over seeds) so that each frame covers >= 15% of the image with culling
# on and something frustum-culled; most also cone-cull clusters or clip triangles.
@pytest.mark.parametrize("seed, mirrors, kind, size, tile_log2", [
    (9, True, "outside", (64, 48), 4),
    (21, True, "graze_centre", (33, 17), 3),
    (6, False, "near_cut", (31, 65), 5),
    (5, True, "tiny_near", (65, 33), 6),
    (21, True, "inside_scene", (17, 63), 4),
    (7, True, "graze_cluster", (64, 48), 3),
    (6, False, "edge_on", (33, 17), 4),
    (6, False, "ortho", (31, 65), 4),
    (7, True, "wide", (65, 33), 5),
    (5, True, "far_box", (64, 48), 4),
])
def test_twin_equals_opencl_on_scenes(seed, mirrors, kind, size, tile_log2):
    scene = scene_for(seed, mirrors, 2.0)
    cam, desc = random_camera(scene, kind, 77 * seed, size)
    for cull in CULLS:
        a = render(scene, cam, size, cull, True, tile_log2)
        b = reference.render(scene, cam, *size, cull=cull, frustum=True, cones=True,
                             config=RasterConfig(tile_log2=tile_log2))
        assert_frames_equal(a, b, f"OpenCL vs twin, seed={seed} mirrors={mirrors} "
                                  f"cull={cull} {desc}")
        check_partition(b.stats)
        if cull == "back":  # the case is not trivial (see above)
            assert a.mask.mean() > 0.1 and a.stats.instances_frustum_culled > 0, desc


# -- 3. counts on constructed scenes ---------------------------------------------------------

def translation(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def unit_cube() -> Mesh:
    """Cube [−0.5, 0.5]³: 8 vertices, 12 faces wound outward; 12 <= 128 triangles, so it is
    one cluster."""
    return subdivided_box(1)


@pytest.mark.parametrize("k", [1, 4, 7, 10])
def test_row_of_cubes_frustum_counts(k):
    # Ten unit cubes centred at (3i, 0, 0), i = 0..9. The eye is at (c, 0, 50), c = 1.5(k−1),
    # looking down −z; tan(half fov_x) = 3k/100, so at distance t the frustum's half-width
    # is t·3k/100. Cubes span distances 49.5..50.5. Cubes 0..k−1 reach at most 1.5k − 1
    # from the axis, inside (half-width >= 49.5·3k/100 = 1.485k >= 1.5k − 1 for k <= 66,
    # margin >= 0.85 for k <= 10); cubes i >= k start at 1.5k + 1 from it, outside
    # (half-width <= 50.5·3k/100 = 1.515k < 1.5k + 1, margin >= 0.89). Vertically the
    # half-height is >= 49.5·(3k/100)/(4/3) >= 1.1 > 0.5: all inside.
    w, h = 64, 48
    cube = unit_cube()
    scene = Scene()
    for i in range(10):
        scene.add(cube, translation(3.0 * i, 0.0, 0.0))
    tan_x = 3.0 * k / 100.0
    fov_y = math.degrees(2.0 * math.atan(tan_x / (w / h)))
    cam = MatrixCamera(perspective(fov_y, w / h, 1.0, 100.0)
                       @ translation(-1.5 * (k - 1), 0.0, -50.0))
    for cull in CULLS:
        on, off = compare_culling(scene, cam, (w, h), cull, f"row of cubes k={k}")
        s = on.stats
        assert s.instances_total == 10 and s.clusters_total == 10 and s.triangles_total == 120
        assert s.instances_frustum_culled == 10 - k
        assert s.clusters_frustum_culled == 10 - k
        assert s.triangles_frustum_culled == (10 - k) * 12
        assert s.clusters_cone_culled == 0  # a closed cube faces every way: no cone culls it
        assert s.triangles_in == 12 * k and s.clusters_drawn == k
        inst, _ = scene.split_ids(off.triangle_id)
        # With cull "none" every kept cube shows (about two pixels wide at k = 10), and no
        # culled one: with culling off, the image holds exactly instances 0..k−1.
        if cull == "none":
            assert set(np.unique(inst[inst >= 0]).tolist()) == set(range(k))


def test_instances_behind_the_camera_are_culled():
    # Eye at the origin looking down −z (identity view). Cube 0 is in front (z = −5); cube 1
    # is right behind the eye on the axis (z = +5: it would project into the image if w < 0
    # were ignored); cube 2 is behind and off to the side.
    cube = unit_cube()
    scene = Scene([(cube, translation(0, 0, -5)), (cube, translation(0, 0, 5)),
                   (cube, translation(2, 1, 8))])
    cam = MatrixCamera(perspective(60.0, 64 / 48, 0.1, 100.0))
    for cull in CULLS:
        on, off = compare_culling(scene, cam, (64, 48), cull, "behind the camera")
        s = on.stats
        assert s.instances_frustum_culled == 2 and s.triangles_frustum_culled == 24
        assert s.triangles_in == 12
        inst, _ = scene.split_ids(off.triangle_id)
        assert set(np.unique(inst).tolist()) == {-1, 0}


def _back_facing(mesh: Mesh, transform: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """bool (F,): the face, placed in world space, is seen from behind from `eye`:
    dot(n, p − eye) > 0 at its centroid p (the same sign everywhere on its plane), with n
    the outward normal: from the world-space vertex order, reversed for a mirroring
    transform (faces keep their outward side, the Scene rule as glTF's; it used to be the
    world-space order alone, which turned an outward-wound mirrored mesh inward)."""
    v = mesh.vertices[mesh.faces] @ transform[:3, :3].T + transform[:3, 3]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]) * np.sign(np.linalg.det(transform[:3, :3]))
    return np.einsum("ij,ij->i", n, v.mean(axis=1) - eye) > 0


@pytest.mark.parametrize("transform", [np.eye(4), np.diag([1.5, 0.7, 1.0, 1.0]),
                                       np.diag([-1.0, 1.0, 1.0, 1.0])],
                         ids=["identity", "stretched", "mirrored"])
def test_sphere_normal_cones(transform):
    """A fine closed sphere seen from outside: cone culling removes some clusters with cull
    "back" (only clusters whose every face is seen from behind) and none with "none"."""
    from clraster.culling.cull import build_draw_list

    sphere = fine_meshes()[0]  # UV sphere, 2208 faces
    cm = clusters_of(sphere)
    assert cm.n_clusters >= 8
    scene = Scene.from_mesh(sphere, transform)
    eye = np.array([0.3, 0.4, 4.0])
    size = (64, 48)
    cam = Camera.look_at(eye, (0.0, 0.0, 0.0), fov_y=45.0, near=0.5, far=10.0)
    vp = cam.view_projection(*size)
    back = _back_facing(sphere, transform, eye)
    for cull in CULLS:
        on, off = compare_culling(scene, cam, size, cull, "sphere")
        s = on.stats
        assert s.instances_frustum_culled == 0 and s.clusters_frustum_culled == 0
        assert s.clusters_total == cm.n_clusters
        dl = build_draw_list(scene, vp, cull=cull)
        culled = sorted(set(range(cm.n_clusters)) - set(dl.cluster.tolist()))
        assert len(culled) == s.clusters_cone_culled
        tris = [cm.face_ids[cm.tri_offset[c]:cm.tri_offset[c + 1]] for c in culled]
        assert s.triangles_cone_culled == sum(t.size for t in tris)
        if cull == "none":
            assert s.clusters_cone_culled == 0
            continue
        # From 4 units away, the far side of a unit sphere holds whole clusters that face
        # away; cones remove some but never all, and only clusters culled faces make up.
        assert 0 < s.clusters_cone_culled < cm.n_clusters
        for t in tris:
            facing_away = back[t] if cull == "back" else ~back[t]
            assert facing_away.all(), cull
        # Cones off: nothing cone-culled, same image.
        plain = get_renderer(*size).render(scene, cam, cull=cull, frustum=True, cones=False)
        assert plain.stats.clusters_cone_culled == 0
        assert_same_image(on, plain, f"cones on/off cull={cull}")


@pytest.mark.parametrize("look", [(0, 0, -1), (0, 0, 1), (1, 0, 0), (0, -1, 0),
                                  (0.3, 0.5, -0.8)])
def test_camera_inside_a_large_box(look):
    """Eye inside a closed box of side 20 (each face a 16×16 grid of quads, 3072 faces in
    several clusters): from inside, every face is seen from behind."""
    box = subdivided_box(16, half=10.0)
    scene = Scene.from_mesh(box)
    eye = np.array([1.0, -2.0, 3.0])
    size = (64, 48)
    cam = Camera.look_at(eye, eye + np.asarray(look, float),
                         up=(0.0, 1.0, 0.0) if abs(look[1]) < 0.9 else (0.0, 0.0, 1.0),
                         fov_y=90.0, near=0.1, far=100.0)
    frames = {}
    for cull in CULLS:
        on, off = compare_culling(scene, cam, size, cull, f"inside box look={look}")
        frames[cull] = on
        s = on.stats
        # The eye is inside the instance's bounds: the instance is never culled.
        assert s.instances_frustum_culled == 0
        # Some clusters lie behind the eye (on the wall it turns its back to).
        assert s.clusters_frustum_culled > 0
        assert s.triangles_in + s.triangles_frustum_culled + s.triangles_cone_culled == 3072
    # cull "none": the walls surround the eye, every pixel is covered (farthest corner
    # sqrt(11² + 12² + 13²) < 21 < far).
    assert frames["none"].mask.all()
    # No face is front-facing from inside: "front" drops nothing (same frame as "none",
    # no cluster cone-culled) and "back" drops everything.
    assert frames["front"].stats.clusters_cone_culled == 0
    assert_same_image(frames["front"], frames["none"], "front vs none inside the box")
    assert not frames["back"].mask.any()
    assert frames["back"].stats.clusters_cone_culled > 0


def test_empty_and_unbounded_instances():
    """An instance with no faces is counted empty and skipped; an instance whose vertices
    are all NaN has no bounds and must not be culled as a whole (its triangles are dropped
    by setup); neither changes the image."""
    cube = unit_cube()
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    nan = Mesh(np.full((3, 3), np.nan), [[0, 1, 2]])
    scene = Scene([(cube, translation(0, 0, -5)), (empty, None), (nan, None),
                   (cube, translation(0, 0, 5))])
    cam = MatrixCamera(perspective(60.0, 64 / 48, 0.1, 100.0))
    for cull in CULLS:
        on, off = compare_culling(scene, cam, (64, 48), cull, "empty and NaN instances")
        s = on.stats
        assert s.instances_total == 4 and s.instances_empty == 1
        assert s.instances_frustum_culled == 1  # the cube behind the eye
        assert s.triangles_total == 25 and s.triangles_frustum_culled == 12
        assert s.triangles_in == 13 and s.invalid == 1
        assert off.stats.instances_empty == 1 and off.stats.triangles_in == 25


def test_partition_invariants_on_random_scenes():
    for seed in range(6):
        scene = scene_for(seed, bool(seed % 2))
        for k, kind in enumerate(CAMERA_KINDS):
            cam, _ = random_camera(scene, kind, seed * 31 + k, (33, 17))
            for cull in CULLS:
                s = render(scene, cam, (33, 17), cull).stats
                check_partition(s)
                assert s.instances_total == scene.n_instances
                assert s.triangles_total == scene.n_faces
                assert s.instances_empty == 0


# -- 4. triangle ids of scenes ---------------------------------------------------------------

def _solo_checks(scene: Scene, frame, camera, size, cull, context: str) -> None:
    """Every instance rendered alone (a one-instance scene with its mesh and transform)
    agrees with the scene frame: where the scene shows instance j, the solo frame shows the
    same face at the same depth; elsewhere the solo frame is never nearer."""
    inst, face = scene.split_ids(frame.triangle_id)
    assert ((inst >= 0) == (frame.triangle_id >= 0)).all()
    hit = inst >= 0
    assert (scene.face_base[inst[hit]] + face[hit] == frame.triangle_id[hit]).all()
    for j, instance in enumerate(scene.instances):
        solo = render(Scene.from_mesh(instance.mesh, instance.transform), camera, size, cull)
        mine = inst == j
        ctx = f"{context} instance {j}"
        assert (solo.triangle_id[mine] == face[mine]).all(), ctx
        assert (solo.depth[mine] == frame.depth[mine]).all(), ctx
        assert (face[mine] < instance.mesh.n_faces).all(), ctx
        assert (frame.depth <= solo.depth).all(), ctx
        # A pixel the solo frame covers is covered in the scene too (by j or a nearer one).
        assert (frame.triangle_id[solo.triangle_id >= 0] >= 0).all(), ctx


def test_split_ids_two_separate_instances():
    """A sphere (2208 faces) on the left and a torus (2048 faces) on the right, apart on
    screen: each one's pixels in the scene frame are exactly its solo frame."""
    sphere, torus = fine_meshes()[:2]
    rot = np.eye(4)
    rot[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # torus ring facing the camera
    scene = Scene([(sphere, translation(-1.2, 0.0, 0.0)),
                   (torus, translation(1.2, 0.1, 0.0) @ rot)])
    cam = Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov_y=50.0, near=1.0, far=20.0)
    size = (64, 48)
    for cull in CULLS:
        frame, _ = compare_culling(scene, cam, size, cull, "two instances")
        inst, face = scene.split_ids(frame.triangle_id)
        assert set(np.unique(inst).tolist()) == {-1, 0, 1}
        assert (frame.triangle_id[inst == 1] >= sphere.n_faces).all()  # face_base[1] = 2208
        assert (frame.triangle_id[inst == 1] == 2208 + face[inst == 1]).all()
        for j, instance in enumerate(scene.instances):
            solo = render(Scene.from_mesh(instance.mesh, instance.transform), cam, size, cull)
            mine = inst == j
            # Apart on screen: the solo frame covers exactly the instance's pixels.
            assert ((solo.triangle_id >= 0) == mine).all(), (cull, j)
            assert (solo.triangle_id[mine] == face[mine]).all(), (cull, j)
            assert (solo.depth[mine] == frame.depth[mine]).all(), (cull, j)
            np.testing.assert_array_equal(solo.barycentrics[mine], frame.barycentrics[mine])
            # ... and a one-instance scene's ids are the mesh's face indices: the bare mesh
            # gives the same frame.
            bare = get_renderer(*size).render(
                Mesh(instance.mesh.vertices @ instance.transform[:3, :3].T
                     + instance.transform[:3, 3], instance.mesh.faces), cam, cull=cull)
            assert ((bare.triangle_id >= 0) == mine).all(), (cull, j)


@pytest.mark.parametrize("seed", [3, 4])
def test_split_ids_match_solo_renders_on_random_scenes(seed):
    scene = scene_for(seed, True, 2.0)
    for k, kind in enumerate(("outside", "near_cut", "graze_vertex")):
        size = SIZES[k]
        cam, desc = random_camera(scene, kind, 500 + seed * 7 + k, size)
        for cull in CULLS:
            frame = render(scene, cam, size, cull)
            _solo_checks(scene, frame, cam, size, cull, f"seed={seed} cull={cull} {desc}")


# -- 5. a grid of dragons, camera inside the grid ----------------------------------------------

def test_dragon_grid_inside_view():
    path = MESH_DIR / "stanford_dragon_res4.ply"
    if not path.is_file():
        pytest.skip(f"{path} not found (the shared mesh folder is absent)")
    dragon = Mesh.load(path)
    nx, ny, nz = 8, 2, 8
    scene = instance_grid(dragon, nx, ny, nz)
    t = scene.transforms()[:, :3, 3]
    # Eye in the middle of the grid (x between columns 3 and 4), at the height of row
    # j = 0, in the corridor between rows k = 3 and k = 4, looking down +x along it
    # (slightly towards row 3): the half of the grid behind the eye is outside the frustum.
    y0 = t[:, 1].min() + (dragon.bounds()[0][1] + dragon.bounds()[1][1]) / 2
    z_mid = (np.unique(t[:, 2])[3] + np.unique(t[:, 2])[4]) / 2 + (dragon.bounds()[0][2]
                                                                 + dragon.bounds()[1][2]) / 2
    x_mid = (np.unique(t[:, 0])[3] + np.unique(t[:, 0])[4]) / 2 + (dragon.bounds()[0][0]
                                                                 + dragon.bounds()[1][0]) / 2
    eye = np.array([x_mid, y0, z_mid])
    cam = Camera.look_at(eye, eye + [1.0, 0.0, -0.05], fov_y=50.0, near=0.01, far=10.0)
    size = (96, 64)
    for cull in CULLS:
        on, off = compare_culling(scene, cam, size, cull, "dragon grid")
        s = on.stats
        assert on.mask.mean() > 0.05
        assert s.instances_frustum_culled > 0.3 * s.instances_total, s.counts()
        assert s.triangles_frustum_culled > 0.3 * s.triangles_total
        if cull == "back":
            print(f"\ndragon grid {nx}x{ny}x{nz} ({s.triangles_total:,} triangles), "
                  f"culling on:\n{s}")


# -- 6. a small power plant, first-person camera in a corridor ---------------------------------

def test_plant_inside_view():
    scene = plant(20_000)
    size = (160, 90)
    cam = plant_inside_camera(scene, *size)
    for cull in CULLS:
        on, off = compare_culling(scene, cam, size, cull, "plant(20_000) corridor")
        assert on.mask.mean() > 0.5
        if cull == "back":
            s = on.stats
            print(f"\nplant(20_000) corridor view, cull=back, {size[0]}x{size[1]}: "
                  f"instances {s.instances_total} → frustum-culled "
                  f"{s.instances_frustum_culled}; clusters {s.clusters_total} → frustum "
                  f"{s.clusters_frustum_culled}, cones {s.clusters_cone_culled}, drawn "
                  f"{s.clusters_drawn}; triangles {s.triangles_total:,} → frustum "
                  f"{s.triangles_frustum_culled:,}, cones {s.triangles_cone_culled:,}, to "
                  f"setup {s.triangles_in:,} ({s.triangles_in / s.triangles_total:.0%}); "
                  f"culling off sends {off.stats.triangles_in:,}\n{s}")
    # The twin agrees on this scene too.
    b = reference.render(scene, cam, *size, cull="back", config=RasterConfig(tile_log2=4))
    assert_frames_equal(render(scene, cam, size, "back"), b, "plant: OpenCL vs twin")
