"""Vision cameras: `Camera.from_intrinsics` / `to_intrinsics` (OpenCV pixel convention) and
the trimesh / pyrender adapters.

The oracle is a float64 ray cast through each pixel centre, built from K alone (OpenCV's
meaning: pixel (i, j) is image point (u, v) = (i, j), its ray is ``R · K⁻¹ [u, v, 1]``), so
it is independent of the projection-matrix derivation it checks. Its narrow phase is
trimesh's ray–triangle test (`trimesh.intersections.planes_lines` +
`trimesh.triangles.points_to_barycentric`, as `trimesh.ray.ray_triangle.ray_triangle_id` runs
them); its broad phase is a float64 screen-space bounding box per triangle, because
`RayMeshIntersector`'s own broad phase needs rtree (not installed here) and its ray boxes
are too coarse to run over a whole image on this machine. `test_oracle_matches_trimesh`
checks the oracle against `ray_triangle_id` itself (all triangles as candidates) on a
sample of rays.
"""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import trimesh
from conftest import get_renderer, load_shared_mesh

from clraster import Camera
from clraster.world.camera import intrinsics_projection

#: Image sizes of the random cameras (few sizes: one cached Renderer each).
SIZES = ((512, 384), (384, 512))


def random_intrinsics(rng, width, height) -> np.ndarray:
    """fx ≠ fy, skew, principal point off centre."""
    fx = rng.uniform(0.7, 1.4) * width
    fy = fx * rng.uniform(0.8, 1.25)
    k = np.eye(3)
    k[0, 0], k[1, 1] = fx, fy
    k[0, 1] = rng.uniform(-0.05, 0.05) * fx
    k[0, 2] = (width - 1) / 2 + rng.uniform(-0.08, 0.08) * width
    k[1, 2] = (height - 1) / 2 + rng.uniform(-0.08, 0.08) * height
    return k


def random_pose_cv(rng, centre, distance) -> np.ndarray:
    """OpenCV camera → world (+z forward, y down) looking at `centre`, random roll."""
    fwd = rng.normal(size=3)
    fwd /= np.linalg.norm(fwd)
    a = np.cross(fwd, rng.normal(size=3))
    x = a / np.linalg.norm(a)
    y = np.cross(fwd, x)       # x × y = z: right-handed
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = x, y, fwd
    pose[:3, 3] = centre - distance * fwd
    return pose


def ray_cast_ids(vertices, faces, k, pose_cv, width, height) -> np.ndarray:
    """(H, W) int64 face hit first by the float64 ray through each pixel centre, −1 if none.

    Needs every vertex in front of the camera (z > 0), so that a triangle's projection
    is bounded by its projected vertices (the broad phase)."""
    v = np.asarray(vertices, np.float64)
    rot, eye = pose_cv[:3, :3], pose_cv[:3, 3]
    cam = (v - eye) @ rot               # OpenCV camera coordinates
    assert np.all(cam[:, 2] > 0), "the oracle's broad phase needs the mesh in front"
    uvw = cam @ k.T
    uv = uvw[:, :2] / uvw[:, 2:]        # image coordinates: pixel (i, j) centre = (i, j)
    tri_uv = uv[faces]                  # (M, 3, 2)
    margin = 1e-3
    lo = np.ceil(tri_uv.min(axis=1) - margin).astype(np.int64)
    hi = np.floor(tri_uv.max(axis=1) + margin).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = nx * ny
    tri = np.repeat(np.arange(len(faces)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    px = lo[tri, 0] + local % nx[tri]
    py = lo[tri, 1] + local // nx[tri]
    # pixel rays in world space, float64
    dirs = np.stack([px, py, np.ones_like(px)], axis=1).astype(np.float64)
    dirs = np.linalg.solve(k, dirs.T).T @ rot.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    triangles = v[faces[tri]]
    normals, ok = trimesh.triangles.normals(triangles)
    assert ok.all()
    loc, valid = trimesh.intersections.planes_lines(
        plane_origins=triangles[:, 0], plane_normals=normals,
        line_origins=np.broadcast_to(eye, dirs.shape), line_directions=dirs)
    keep = np.nonzero(valid)[0]
    bary = trimesh.triangles.points_to_barycentric(triangles[keep], loc)
    tz = trimesh.constants.tol.zero
    hit = ((bary > -tz) & (bary < 1 + tz)).all(axis=1)
    t = np.einsum("ij,ij->i", loc - eye, dirs[keep])
    hit &= t > 0
    keep, t = keep[hit], t[hit]
    ids = np.full((height, width), -1, np.int64)
    best = np.full((height, width), np.inf)
    order = np.argsort(-t)              # farthest first: the nearest hit is written last
    ids[py[keep[order]], px[keep[order]]] = tri[keep[order]]
    best[py[keep[order]], px[keep[order]]] = t[order]
    return ids


@pytest.fixture(scope="module")
def spot():
    return load_shared_mesh("spot.ply")


def _scene(spot, seed, size):
    rng = np.random.default_rng(seed)
    width, height = size
    lo, hi = spot.bounds()
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    k = random_intrinsics(rng, width, height)
    pose = random_pose_cv(rng, centre + rng.uniform(-0.2, 0.2, 3) * radius,
                          rng.uniform(1.6, 2.6) * radius)
    return k, pose, 0.05 * radius, 10.0 * radius


def edge_distance(uv, faces, ids, px, py) -> np.ndarray:
    """Distance in pixels from image point (px, py) to the nearest edge of face ``ids``
    (inf where ids == −1); ``uv`` are the vertices' float64 image coordinates."""
    out = np.full(len(ids), np.inf)
    ok = ids >= 0
    tri = uv[faces[ids[ok]]]                     # (n, 3, 2)
    p = np.stack([px[ok], py[ok]], 1).astype(np.float64)
    d = []
    for i in range(3):
        a, b = tri[:, i], tri[:, (i + 1) % 3]
        e = b - a
        cross = e[:, 0] * (p[:, 1] - a[:, 1]) - e[:, 1] * (p[:, 0] - a[:, 0])
        d.append(np.abs(cross) / np.maximum(np.linalg.norm(e, axis=1), 1e-300))
    out[ok] = np.min(d, axis=0)
    return out


def test_triangle_ids_match_float64_ray_cast(spot):
    """Random intrinsics (skew, off-centre, non-square pixels) and poses: the visible face at
    each pixel is the face the float64 ray through the pixel centre hits first.

    The renderer snaps vertices to 1/256 pixel (D3D11's 8 sub-pixel bits, DESIGN.md), so a
    pixel centre within that snap of an edge may go to the face on the other side: on
    spot at 512×384 that is ~0.03% of the covered pixels (measured: every disagreement was
    within 1/512 pixel of an edge of both faces). Those pixels are set aside; of the rest,
    >= 99.99% must agree (measured: all of them), and at least 99.9% of all covered pixels;
    the set-aside pixels (~0.35%) are bounded at 1%."""
    covered = agree = decided = decided_agree = 0
    for seed in range(6):
        size = SIZES[seed % len(SIZES)]
        k, pose, near, far = _scene(spot, seed, size)
        cam = Camera.from_intrinsics(k, *size, pose=pose, near=near, far=far)
        frame = get_renderer(*size).render(spot, cam, cull="none")
        want = ray_cast_ids(spot.vertices, spot.faces, k, pose, *size)
        got = frame.triangle_id
        union = (want >= 0) | (got >= 0)
        assert union.sum() > 0.05 * size[0] * size[1], f"seed {seed}: mesh barely visible"
        py, px = np.nonzero(union)
        same = want[py, px] == got[py, px]
        v = spot.vertices.astype(np.float64)
        uvw = ((v - pose[:3, 3]) @ pose[:3, :3]) @ k.T
        uv = uvw[:, :2] / uvw[:, 2:]
        near_edge = np.minimum(edge_distance(uv, spot.faces, want[py, px], px, py),
                               edge_distance(uv, spot.faces, got[py, px], px, py)) < 1 / 256
        covered += len(px)
        agree += int(same.sum())
        decided += int((~near_edge).sum())
        decided_agree += int((same & ~near_edge).sum())
    assert decided >= 0.99 * covered, f"{covered - decided} of {covered} pixels near edges"
    assert decided_agree >= 0.9999 * decided, (
        f"{decided - decided_agree} of {decided} covered pixels farther than 1/256 pixel from "
        f"any edge disagree with the ray cast")
    assert agree >= 0.999 * covered, (
        f"{covered - agree} of {covered} covered pixels disagree with the ray cast")


def test_oracle_matches_trimesh(spot):
    """The oracle (own broad phase) against trimesh's `ray_triangle_id` with every triangle
    as a candidate, on a sample of pixels."""
    from trimesh.ray.ray_triangle import ray_triangle_id

    size = SIZES[0]
    k, pose, _, _ = _scene(spot, 0, size)
    want = ray_cast_ids(spot.vertices, spot.faces, k, pose, *size)
    rng = np.random.default_rng(1)
    ys, xs = np.nonzero(want >= 0)
    pick = rng.choice(len(xs), 60, replace=False)
    px = np.concatenate([xs[pick], rng.integers(0, size[0], 20)])
    py = np.concatenate([ys[pick], rng.integers(0, size[1], 20)])
    dirs = np.stack([px, py, np.ones_like(px)], 1).astype(np.float64)
    dirs = np.linalg.solve(k, dirs.T).T @ pose[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    triangles = spot.vertices.astype(np.float64)[spot.faces]

    class AllTriangles:
        """rtree stand-in: every triangle is a candidate for every ray."""
        bounds = np.concatenate([triangles.reshape(-1, 3).min(0),
                                 triangles.reshape(-1, 3).max(0)])

        def intersection(self, _bounds):
            return range(len(triangles))

    origins = np.broadcast_to(pose[:3, 3], dirs.shape)
    tri, ray, loc = ray_triangle_id(triangles, origins, dirs, tree=AllTriangles())
    first = np.full(len(px), -1)
    dist = np.full(len(px), np.inf)
    t = np.einsum("ij,ij->i", loc - origins[ray], dirs[ray])
    for f, r, d in zip(tri, ray, t, strict=True):
        if 0 < d < dist[r]:
            first[r], dist[r] = f, d
    np.testing.assert_array_equal(want[py, px], first)


def test_projection_derivation_centres_pixels():
    """A point on pixel (i, j)'s ray (OpenCV: image point (i, j)) lands on window
    (i + 0.5, j + 0.5), row 0 at the top; skew and off-centre principal point included."""
    width, height = 64, 48
    k = np.array([[70.0, 3.0, 30.2], [0.0, 55.0, 20.7], [0.0, 0.0, 1.0]])
    proj = intrinsics_projection(k, width, height, 0.1, 10.0)
    for i, j, z in ((0, 0, 1.0), (63, 47, 2.5), (12, 30, 7.0)):
        cv = z * np.linalg.solve(k, [i, j, 1.0])                 # OpenCV camera point
        clip = proj @ np.array([cv[0], -cv[1], -cv[2], 1.0])     # OpenGL eye: y, z negated
        ndc = clip[:3] / clip[3]
        xw, yw = (ndc[0] + 1) / 2 * width, (1 - ndc[1]) / 2 * height
        assert (xw, yw) == pytest.approx((i + 0.5, j + 0.5), abs=1e-9)
    # centred principal point: a symmetric frustum
    kc = np.array([[50.0, 0, (width - 1) / 2], [0, 50.0, (height - 1) / 2], [0, 0, 1]])
    pc = intrinsics_projection(kc, width, height, 0.1, 10.0)
    assert pc[0, 2] == 0.0 and pc[1, 2] == 0.0


def test_to_intrinsics_round_trips():
    rng = np.random.default_rng(7)
    for _ in range(20):
        width, height = int(rng.integers(16, 2000)), int(rng.integers(16, 2000))
        k = random_intrinsics(rng, width, height)
        pose = random_pose_cv(rng, rng.normal(size=3) * 100, rng.uniform(0.5, 50))
        for conv in ("opencv", "opengl"):
            cam = Camera.from_intrinsics(k, width, height, pose=pose, near=0.1, far=100.0,
                                         convention=conv)
            k2, pose2 = cam.to_intrinsics(width, height, convention=conv)
            np.testing.assert_allclose(k2, k, rtol=1e-12, atol=1e-9 * width)
            np.testing.assert_allclose(pose2, pose, rtol=0, atol=1e-9 * 100, err_msg=conv)
            assert k2[1, 0] == k2[2, 0] == k2[2, 1] == 0.0 and k2[2, 2] == 1.0


def test_opencv_and_opengl_poses_agree():
    """The same camera given as an OpenCV pose and as an OpenGL pose (y, z axes negated)."""
    k = np.array([[300.0, 1.0, 150.0], [0.0, 320.0, 110.0], [0.0, 0.0, 1.0]])
    pose_cv = random_pose_cv(np.random.default_rng(3), np.zeros(3), 4.0)
    pose_gl = pose_cv @ np.diag([1.0, -1.0, -1.0, 1.0])
    a = Camera.from_intrinsics(k, 320, 240, pose=pose_cv, near=0.5, far=9.0)
    b = Camera.from_intrinsics(k, 320, 240, pose=pose_gl, near=0.5, far=9.0,
                               convention="opengl")
    np.testing.assert_allclose(a.view, b.view, atol=1e-12)
    np.testing.assert_allclose(a.eye, pose_cv[:3, 3], atol=1e-12)
    # look_at cameras convert too: a symmetric K, the look_at pose
    la = Camera.look_at((1, 2, 3), (0, 0, 0), fov_y=50.0, near=0.1, far=10.0)
    k3, pose3 = la.to_intrinsics(640, 480, convention="opengl")
    assert k3[0, 2] == pytest.approx(319.5) and k3[1, 2] == pytest.approx(239.5)
    assert k3[1, 1] == pytest.approx(240 / math.tan(math.radians(25.0)))
    back = Camera.from_intrinsics(k3, 640, 480, pose=pose3, near=0.1, far=10.0,
                                  convention="opengl")
    np.testing.assert_allclose(back.view_projection(640, 480), la.view_projection(640, 480),
                               atol=1e-9)


def test_intrinsics_camera_is_tied_to_its_size():
    k = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    cam = Camera.from_intrinsics(k, 64, 48, near=0.1, far=10.0)
    assert cam.image_size == (64, 48)
    cam.view_projection(64, 48)
    with pytest.raises(ValueError, match="64×48"):
        cam.view_projection(128, 96)
    with pytest.raises(ValueError, match="64×48"):
        get_renderer(32, 32).render(load_shared_mesh("spot.ply"), cam)
    assert "from_intrinsics" in repr(cam)
    again = pickle.loads(pickle.dumps(cam))   # Dask workers receive cameras pickled
    np.testing.assert_array_equal(again.view_projection(64, 48), cam.view_projection(64, 48))
    assert again.image_size == (64, 48)


@pytest.mark.parametrize("bad, match", [
    (np.eye(4), "shape \\(3, 3\\)"),
    ([[1.0, 0, 0], [0.1, 1.0, 0], [0, 0, 1]], "upper triangular"),
    ([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 2]], "upper triangular"),
    ([[-1.0, 0, 0], [0, 1.0, 0], [0, 0, 1]], "fx"),
    ([[np.nan, 0, 0], [0, 1.0, 0], [0, 0, 1]], "finite"),
])
def test_bad_intrinsics(bad, match):
    with pytest.raises(ValueError, match=match):
        Camera.from_intrinsics(bad, 64, 48, near=0.1, far=1.0)


def test_bad_pose_and_convention():
    k = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    with pytest.raises(ValueError, match="convention"):
        Camera.from_intrinsics(k, 64, 48, near=0.1, far=1.0, convention="blender")
    proj_pose = np.eye(4)
    proj_pose[3, 2] = 1.0
    with pytest.raises(ValueError, match="affine"):
        Camera.from_intrinsics(k, 64, 48, pose=proj_pose, near=0.1, far=1.0)
    with pytest.raises(ValueError, match="singular"):
        Camera.from_intrinsics(k, 64, 48, pose=np.diag([1.0, 0.0, 1.0, 1.0]), near=0.1,
                               far=1.0)
    with pytest.raises(ValueError, match="near"):
        Camera.from_intrinsics(k, 64, 48, near=0.0, far=1.0)


def test_to_intrinsics_refuses_non_pinhole():
    from conftest import ortho

    view = np.eye(4)
    with pytest.raises(ValueError, match="orthographic"):
        Camera.from_matrices(view, ortho(-1, 1, -1, 1, 0.1, 10)).to_intrinsics(64, 64)
    oblique = Camera.look_at((0, 0, 5), (0, 0, 0)).projection(64, 64).copy()
    oblique[2, 0] = 0.3
    with pytest.raises(ValueError, match="oblique"):
        Camera.from_matrices(view, oblique).to_intrinsics(64, 64)


def test_trimesh_adapter_matches_camera_rays():
    """Every pixel centre's ray of the adapted camera is trimesh's `scene.camera_rays()`
    direction for that pixel (trimesh numbers pixel rows bottom-up)."""
    rng = np.random.default_rng(5)
    scene = trimesh.Scene(trimesh.creation.box())
    scene.camera.resolution = (37, 23)
    scene.camera.fov = (63.0, 41.0)
    pose = random_pose_cv(rng, np.zeros(3), 3.0) @ np.diag([1.0, -1.0, -1.0, 1.0])
    scene.camera_transform = pose
    origins, dirs, pixels = scene.camera_rays()
    cam = Camera.from_trimesh(scene)
    w, h = 37, 23
    assert cam.image_size == (w, h)
    inv = np.linalg.inv(cam.view_projection(w, h))
    xw = pixels[:, 0] + 0.5
    yw = (h - 1 - pixels[:, 1]) + 0.5           # trimesh's row index counts from the bottom
    ndc = np.stack([xw / w * 2 - 1, 1 - yw / h * 2, np.zeros_like(xw), np.ones_like(xw)], 1)
    p = ndc @ inv.T
    p = p[:, :3] / p[:, 3:]
    ours = p - cam.eye
    ours /= np.linalg.norm(ours, axis=1, keepdims=True)
    np.testing.assert_allclose(ours, dirs, atol=1e-12)
    np.testing.assert_allclose(origins, np.broadcast_to(cam.eye, origins.shape), atol=1e-12)
    # a bare trimesh camera with an explicit pose is the same camera
    bare = Camera.from_trimesh(scene.camera, pose=pose)
    np.testing.assert_allclose(bare.view_projection(w, h), cam.view_projection(w, h),
                               atol=1e-12)
    with pytest.raises(ValueError, match="trimesh"):
        Camera.from_trimesh(object(), 4, 4)


class StandInPerspective:
    """pyrender.PerspectiveCamera's documented attributes (pyrender is not installed)."""

    def __init__(self, yfov, znear=0.05, zfar=None, aspectRatio=None):  # noqa: N803
        self.yfov, self.znear, self.zfar, self.aspectRatio = yfov, znear, zfar, aspectRatio


class StandInIntrinsics:
    """pyrender.IntrinsicsCamera's documented attributes."""

    def __init__(self, fx, fy, cx, cy, znear=0.05, zfar=100.0):
        self.fx, self.fy, self.cx, self.cy, self.znear, self.zfar = fx, fy, cx, cy, znear, zfar


class StandInOrthographic:
    """pyrender.OrthographicCamera's documented attributes."""

    def __init__(self, xmag, ymag, znear=0.05, zfar=100.0):
        self.xmag, self.ymag, self.znear, self.zfar = xmag, ymag, znear, zfar


def test_pyrender_adapter_stand_ins():
    """pyrender is not installed (and not a dependency): small stand-ins carrying the
    attributes pyrender documents; the matrices are pyrender's get_projection_matrix."""
    pose = random_pose_cv(np.random.default_rng(2), np.zeros(3), 3.0) @ np.diag(
        [1.0, -1.0, -1.0, 1.0])
    w, h = 64, 48
    persp = Camera.from_pyrender(StandInPerspective(math.radians(50.0), 0.1, 20.0), pose, w, h)
    ref = Camera.look_at(pose[:3, 3], pose[:3, 3] - pose[:3, 2], pose[:3, 1], fov_y=50.0,
                         near=0.1, far=20.0)
    np.testing.assert_allclose(persp.view_projection(w, h), ref.view_projection(w, h),
                               atol=1e-12)
    # infinite far plane: pyrender's (−1, −2·znear) depth row; far points stay inside
    inf = Camera.from_pyrender(StandInPerspective(1.0, 0.1, None, 2.0), np.eye(4), w, h)
    p = inf.projection(w, h)
    assert p[0, 0] == pytest.approx(1 / (2.0 * math.tan(0.5)))
    assert (p[2, 2], p[2, 3]) == (-1.0, -0.2)
    clip = p @ [0, 0, -1e9, 1]
    assert -clip[3] <= clip[2] <= clip[3]
    # intrinsics: pyrender's cx, cy are measured from the corner (no half-pixel shift)
    intr = Camera.from_pyrender(StandInIntrinsics(60.0, 55.0, 32.0, 24.0), np.eye(4), w, h)
    k, _ = intr.to_intrinsics(w, h)
    np.testing.assert_allclose(k, [[60.0, 0, 31.5], [0, 55.0, 23.5], [0, 0, 1]], atol=1e-12)
    ortho_cam = Camera.from_pyrender(StandInOrthographic(2.0, 1.5, 0.1, 10.0), np.eye(4), w, h)
    clip = ortho_cam.projection(w, h) @ [2.0, 1.5, -10.0, 1]
    np.testing.assert_allclose(clip, [1, 1, 1, 1], atol=1e-12)
    with pytest.raises(ValueError, match="pyrender"):
        Camera.from_pyrender(object(), np.eye(4), w, h)
