"""Frame outputs: metric depth and distance, normals, point clouds, and the files they are
saved to (`clraster.outputs`, `Frame.save`)."""

from __future__ import annotations

import os

import imageio.v3 as iio
import numpy as np
import pytest
import trimesh
from conftest import get_renderer, load_shared_mesh

from clraster import Camera, Mesh
from clraster.output.frame import Frame, FrameStats
from clraster.output.outputs import FramePoints, write_output
from clraster.world.scene import Scene

W, H = 96, 72


def pixel_rays(camera, width, height):
    """(H, W, 3) float64 unit world directions through the pixel centres."""
    inv = np.linalg.inv(camera.view_projection(width, height))
    yc, xc = np.mgrid[0:height, 0:width] + 0.5
    ndc = np.stack([xc / width * 2 - 1, 1 - yc / height * 2, np.zeros_like(xc),
                    np.ones_like(xc)], -1)
    p = ndc @ inv.T
    d = p[..., :3] / p[..., 3:] - camera.eye
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def grid(p0, u, v, n) -> Mesh:
    """The parallelogram p0 + s·u + t·v, s, t ∈ [0, 1], as n × n cells of two triangles,
    normal u × v. (Small triangles: a surface point's error is its barycentrics' float32
    error times the triangle's size.)"""
    p0, u, v = (np.asarray(a, np.float64) for a in (p0, u, v))
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    verts = p0 + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + (n + 1), a + (n + 1) + 1, a + 1
    return Mesh(verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))


def quad(p0, u, v) -> Mesh:
    """A parallelogram p0 + s·u + t·v, s, t ∈ [0, 1], two triangles, normal u × v."""
    p0, u, v = (np.asarray(a, np.float64) for a in (p0, u, v))
    verts = np.array([p0, p0 + u, p0 + u + v, p0 + v])
    return Mesh(verts, [[0, 1, 2], [0, 2, 3]])


#: How far from the pixel centre the renderer's interpolated values (depth, barycentrics)
#: may sit, in pixels: measured ~2e-3 (about the 1/256-pixel vertex snap), here with margin.
POSITION_ERROR = 4e-3


def position_tolerance(field):
    """Change of an (H, W) analytic field over `POSITION_ERROR` pixels in x and in y."""
    gy, gx = np.gradient(field)
    return (np.abs(gx) + np.abs(gy)) * POSITION_ERROR


@pytest.mark.parametrize("tilted", [False, True])
@pytest.mark.parametrize("head_on", [False, True])
def test_linear_depth_and_distance_of_a_plane(tilted, head_on):
    """A plane in front of a camera: analytic depth along the view axis and distance along
    each pixel's ray (float64 ray–plane intersection through the pixel centre).

    Facing the camera head-on, the depth is one number, and both ways of computing it give
    it to float32 precision, as does the window-depth distance along the rays. Otherwise
    the error is what the renderer's values allow: the depth buffer's float32 resolution
    and values interpolated within `POSITION_ERROR` pixels of the pixel centre."""
    eye = np.array([0.5, 0.25, 3.0])
    look = [0.0, 0.0, -1.0] if head_on else [0.1, -0.05, -1.0]
    cam = Camera.look_at(eye, eye + look, fov_y=50.0, near=0.5, far=20.0)
    normal = np.array([0.3, 0.2, 1.0]) if tilted else np.array([0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal)
    centre = np.array([0.5, 0.25, -2.0])
    a = np.cross(normal, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    plane = grid(centre - 20 * a - 20 * b, 40 * a, 40 * b, 64)
    # the plane as the renderer sees it: its float32 vertices (a best-fit plane of them)
    v = plane.vertices.astype(np.float64)
    n32 = np.linalg.svd(v - v.mean(0))[2][2]
    frame = get_renderer(W, H).render(plane, cam, cull="none")
    assert frame.mask.all()
    rays = pixel_rays(cam, W, H)
    t = ((v.mean(0) - eye) @ n32) / (rays @ n32)                 # distance along the ray
    fwd = -cam.view[2, :3]
    want_depth = t * (rays @ fwd)
    f32 = 2.4e-7      # two float32 ulps, relative
    lin, dist = frame.linear_depth(cam), frame.distance(cam)
    lin_t, dist_t = frame.linear_depth(cam, plane), frame.distance(cam, plane)
    for out in (lin, dist, lin_t, dist_t):
        assert out.dtype == np.float32 and out.shape == (H, W)
    if head_on and not tilted:
        d = float((centre - eye) @ fwd)
        np.testing.assert_allclose(lin, d, rtol=f32)
        np.testing.assert_allclose(lin_t, d, rtol=f32)
        np.testing.assert_allclose(dist, t, rtol=f32)
    # window path: the window depth is off by its float32 resolution plus its change over
    # the interpolation offset; the point then moves along the pixel's own ray
    p22, p23 = cam.projection(W, H)[2, 2:]
    window = (-p22 + p23 / want_depth + 1.0) / 2.0
    slope = -p23 / (2.0 * want_depth ** 2)                    # dw / d(depth)
    win_tol = (4e-7 + position_tolerance(window)) / slope + f32 * want_depth
    assert np.all(np.abs(lin - want_depth) <= win_tol)
    assert np.all(np.abs(dist - t) <= win_tol * t / want_depth)
    # target path: the surface point moves on the plane by the interpolation offset
    assert np.all(np.abs(lin_t - want_depth) <= position_tolerance(want_depth) + f32 * want_depth)
    assert np.all(np.abs(dist_t - t) <= position_tolerance(t) + f32 * t)


def test_far_surface_depth_from_target_beats_the_depth_buffer():
    """Far away with a large far/near ratio the float32 window depth resolves metres only;
    the surface points (target=) still give the depth to a small fraction of a unit."""
    eye = np.array([0.0, 0.0, 0.0])
    cam = Camera.look_at(eye, (0, 0, -1), fov_y=50.0, near=0.01, far=1000.0)
    plane = grid((-400, -400, -500), (800, 0, 0), (0, 800, 0), 64)
    frame = get_renderer(W, H).render(plane, cam)
    assert frame.mask.all()
    np.testing.assert_allclose(frame.linear_depth(cam, plane), 500.0, rtol=2.4e-7)
    coarse = np.abs(frame.linear_depth(cam) - 500.0).max()
    assert coarse > 0.01      # the buffer's resolution there (documented, not a bug)


def test_background_depth_is_inf():
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), near=1.0, far=10.0)
    small = quad((-0.1, -0.1, 0), (0.2, 0, 0), (0, 0.2, 0))
    frame = get_renderer(W, H).render(small, cam)
    lin = frame.linear_depth(cam)
    assert np.isinf(lin[~frame.mask]).all() and np.isfinite(lin[frame.mask]).all()
    np.testing.assert_allclose(lin[frame.mask], 5.0, rtol=1e-5)
    with pytest.raises(ValueError, match="camera"):
        frame.linear_depth(object())


def test_orthographic_distance_is_depth():
    from conftest import ortho

    view = Camera.look_at((0, 0, 5), (0, 0, 0)).view
    cam = Camera.from_matrices(view, ortho(-2, 2, -1.5, 1.5, 1.0, 10.0))
    plane = quad((-5, -5, -1), (10, 0, 0), (0, 10, 0))
    frame = get_renderer(W, H).render(plane, cam)
    np.testing.assert_allclose(frame.linear_depth(cam), 6.0, rtol=1e-6)
    np.testing.assert_allclose(frame.distance(cam), 6.0, rtol=1e-6)


def cube() -> Mesh:
    return Mesh.from_trimesh(trimesh.creation.box(extents=(2.0, 2.0, 2.0)))


def test_normals_of_a_cube():
    mesh = cube()
    cam = Camera.look_at((3.0, 2.5, 4.0), (0, 0, 0), fov_y=40.0, near=1.0, far=20.0)
    frame = get_renderer(W, H).render(mesh, cam)
    n = frame.normals(mesh)
    assert n.dtype == np.float32 and n.shape == (H, W, 3)
    m = frame.mask
    assert not n[~m].any()
    # each covered pixel: its face's axis-aligned outward normal
    want = mesh.face_normals()[frame.triangle_id[m]]
    np.testing.assert_allclose(n[m], want, atol=1e-6)
    seen = {tuple(np.round(x).astype(int)) for x in n[m]}
    assert seen == {(1, 0, 0), (0, 1, 0), (0, 0, 1)}     # the three faces seen from +x+y+z
    # camera space: rotated by the view, facing the viewer (+z)
    nc = frame.normals(mesh, space="camera", camera=cam)
    np.testing.assert_allclose(nc[m], n[m] @ cam.view[:3, :3].T, atol=1e-6)
    assert (nc[m][:, 2] > 0).all()
    with pytest.raises(ValueError, match="camera"):
        frame.normals(mesh, space="camera")
    with pytest.raises(ValueError, match="space"):
        frame.normals(mesh, space="object")


def test_smooth_normals_of_a_sphere():
    tm = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mesh = Mesh.from_trimesh(tm)
    cam = Camera.look_at((0.5, 0.4, 3.0), (0, 0, 0), fov_y=45.0, near=0.5, far=10.0)
    frame = get_renderer(W, H).render(mesh, cam)
    radial = frame.points(mesh).points
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    m = frame.mask
    err_smooth = np.linalg.norm(frame.normals(mesh, smooth=True)[m] - radial, axis=1)
    err_flat = np.linalg.norm(frame.normals(mesh)[m] - radial, axis=1)
    assert err_smooth.max() < 0.02 and err_smooth.mean() < 0.5 * err_flat.mean()


def test_scene_normals_mirror_rule_and_points():
    """Two instances of a cube, one mirrored: normals point out of both (glTF's rule), and
    the points lie on each instance's transformed faces."""
    mesh = cube()
    left = np.eye(4)
    left[:3, 3] = (-1.6, 0.0, 0.0)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = (1.6, 0.2, 0.0)
    scene = Scene([(mesh, left), (mesh, mirror)])
    cam = Camera.look_at((1.0, 2.5, 6.0), (0, 0, 0), fov_y=50.0, near=1.0, far=20.0)
    frame = get_renderer(W, H).render(scene, cam, cull="none")
    pts = frame.points(scene)
    assert isinstance(pts, FramePoints)
    inst, _ = scene.split_ids(pts.ids)
    assert set(inst.tolist()) == {0, 1}
    centres = np.array([left[:3, 3], mirror[:3, 3]])[inst]
    n = frame.normals(scene)[pts.pixels[:, 1], pts.pixels[:, 0]]
    assert (np.einsum("ij,ij->i", n, pts.points - centres) > 0.5).all()
    # points on the transformed cube surfaces: max |coordinate − centre| is the half size 1
    np.testing.assert_allclose(np.abs(pts.points - centres).max(axis=1), 1.0, atol=1e-5)


def test_points_lie_on_the_mesh_and_on_their_pixels():
    spot = load_shared_mesh("spot.ply")
    cam = Camera.look_at((1.6, 0.9, 2.2), (0.0, 0.1, 0.2), fov_y=40.0, near=0.3, far=10.0)
    frame = get_renderer(W, H).render(spot, cam)
    pts, ids, pix = frame.points(spot)
    assert pts.dtype == np.float64 and pts.shape == (int(frame.mask.sum()), 3)
    assert ids.dtype == np.int32 and pix.dtype == np.int32
    np.testing.assert_array_equal(ids, frame.triangle_id[pix[:, 1], pix[:, 0]])
    tri = spot.vertices.astype(np.float64)[spot.faces[ids]]
    # on the triangle's plane...
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert np.abs(np.einsum("ij,ij->i", pts - tri[:, 0], n)).max() < 1e-6
    # ...and on the triangle, except at edge pixels whose centre the snapped coverage takes
    # in just outside the unsnapped triangle (<= sqrt(2)/512 px, where the values
    # extrapolate): no farther than 1/128 px of world size at the point's distance
    closest = trimesh.triangles.closest_point(tri, pts)
    off = np.linalg.norm(pts - closest, axis=1)
    px = 2.0 * np.linalg.norm(pts - cam.eye, axis=1) * np.tan(np.radians(20.0)) / H
    assert (off <= px / 128).all(), (off / px).max()
    assert (off < 1e-6).mean() > 0.97
    # and they project back onto their pixel centres
    clip = np.c_[pts, np.ones(len(pts))] @ cam.view_projection(W, H).T
    ndc = clip[:, :2] / clip[:, 3:]
    win = np.stack([(ndc[:, 0] + 1) / 2 * W, (1 - ndc[:, 1]) / 2 * H], 1)
    np.testing.assert_allclose(win, pix + 0.5, atol=2e-3)
    # trimesh input: the same points
    tm = trimesh.load(str(load_shared_mesh.__globals__["MESH_DIR"] / "spot.ply"),
                      process=False)
    np.testing.assert_array_equal(frame.points(tm).points, pts)


# -- files ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def spot_frame():
    spot = load_shared_mesh("spot.ply")
    cam = Camera.look_at((1.6, 0.9, 2.2), (0.0, 0.1, 0.2), fov_y=40.0, near=0.3, far=10.0)
    return get_renderer(W, H).render(spot, cam), spot, cam


def only_file(folder, name):
    assert sorted(os.listdir(folder)) == [name], "the file written is exactly the file named"


def test_png_16_bit_depth_round_trip(tmp_path, spot_frame):
    frame, spot, cam = spot_frame
    p = frame.save(tmp_path / "d.png", "linear_depth", camera=cam)
    only_file(tmp_path, "d.png")
    back = iio.imread(p)
    assert back.dtype == np.uint16 and back.shape == (H, W)
    lin = frame.linear_depth(cam)[frame.mask].astype(np.float64)
    assert (back[~frame.mask] == 0).all()
    np.testing.assert_array_equal(back[frame.mask], np.round(lin * 1000.0))
    # another scale (TUM RGB-D: 5000 per metre), and the window depth as unorm16
    back5 = iio.imread(frame.save(tmp_path / "d5.png", "linear_depth", camera=cam,
                                  depth_scale=5000.0))
    np.testing.assert_array_equal(back5[frame.mask], np.round(lin * 5000.0))
    win = iio.imread(frame.save(tmp_path / "w.png", "depth"))
    np.testing.assert_array_equal(win, np.round(frame.depth.astype(np.float64) * 65535))
    # ids + 1, 0 on the background
    ids = iio.imread(frame.save(tmp_path / "ids.png", "ids"))
    assert ids.dtype == np.uint16
    np.testing.assert_array_equal(ids.astype(np.int64) - 1, frame.triangle_id)
    # normals as RGB8
    nrm = iio.imread(frame.save(tmp_path / "n.png", "normals", target=spot))
    assert nrm.dtype == np.uint8 and nrm.shape == (H, W, 3)
    want = frame.normals(spot)[frame.mask]
    np.testing.assert_allclose(nrm[frame.mask] / 255.0 * 2 - 1, want, atol=1 / 255 + 1e-6)


def test_png_refuses_what_it_cannot_hold(tmp_path, spot_frame):
    frame, _, cam = spot_frame
    with pytest.raises(ValueError, match="depth_scale"):
        frame.save(tmp_path / "far.png", "linear_depth", camera=cam, depth_scale=1e5)
    big = Frame.empty(4, 4)
    big.triangle_id[0, 0] = 70000
    with pytest.raises(ValueError, match=r"\.npy"):
        big.save(tmp_path / "ids.png", "ids")
    assert os.listdir(tmp_path) == []
    big.save(tmp_path / "ids.npy", "ids")
    assert np.load(tmp_path / "ids.npy")[0, 0] == 70000


def read_tiff(path):
    """Read back with tifffile where installed, else Pillow (imageio's own vendored TIFF
    reader is deprecated)."""
    try:
        import tifffile  # noqa: F401
    except ImportError:
        return iio.imread(path, plugin="pillow")
    return iio.imread(path, plugin="tifffile")


def test_tiff_round_trip(tmp_path, spot_frame):
    frame, spot, cam = spot_frame
    d = read_tiff(frame.save(tmp_path / "d.tiff", "linear_depth", camera=cam))
    assert d.dtype == np.float32
    np.testing.assert_array_equal(d, frame.linear_depth(cam))
    w = read_tiff(frame.save(tmp_path / "w.tif", "depth"))
    np.testing.assert_array_equal(w, frame.depth)
    ids = read_tiff(frame.save(tmp_path / "ids.tif", "ids"))
    assert ids.dtype == np.int32
    np.testing.assert_array_equal(ids, frame.triangle_id)
    try:
        import tifffile  # noqa: F401
    except ImportError:
        with pytest.raises(ValueError, match="tifffile"):
            frame.save(tmp_path / "n.tiff", "normals", target=spot)
        assert not (tmp_path / "n.tiff").exists()
    else:
        n = read_tiff(frame.save(tmp_path / "n.tiff", "normals", target=spot))
        np.testing.assert_array_equal(n, frame.normals(spot))


def test_exr_round_trip_or_clear_error(tmp_path, spot_frame):
    frame, _, cam = spot_frame
    try:
        p = frame.save(tmp_path / "d.exr", "linear_depth", camera=cam)
    except ValueError as exc:
        assert "EXR" in str(exc)
        assert os.listdir(tmp_path) == []
    else:
        only_file(tmp_path, "d.exr")
        np.testing.assert_array_equal(iio.imread(p), frame.linear_depth(cam))


def test_npy_npz_ply(tmp_path, spot_frame):
    frame, spot, cam = spot_frame
    frame.save(tmp_path / "d.npy", "distance", camera=cam, target=spot)
    only_file(tmp_path, "d.npy")
    np.testing.assert_array_equal(np.load(tmp_path / "d.npy"), frame.distance(cam, spot))
    frame.save(tmp_path / "ids.npz", "ids")
    with np.load(tmp_path / "ids.npz") as z:
        np.testing.assert_array_equal(z["ids"], frame.triangle_id)
    frame.save(tmp_path / "p.npz", "points", target=spot)
    pts = frame.points(spot)
    with np.load(tmp_path / "p.npz") as z:
        for name in ("points", "ids", "pixels"):
            np.testing.assert_array_equal(z[name], getattr(pts, name))
    frame.save(tmp_path / "p.ply", "points", target=spot)
    cloud = trimesh.load(tmp_path / "p.ply")
    np.testing.assert_allclose(cloud.vertices, pts.points, rtol=1e-6)


def test_shaded_delegates_to_shade(tmp_path, spot_frame):
    from clraster.output.shade import shade

    frame, spot, _ = spot_frame
    img = iio.imread(frame.save(tmp_path / "s.png", "shaded", target=spot))
    np.testing.assert_array_equal(img, shade(frame, spot))


@pytest.mark.parametrize("name, what, match", [
    ("x.jpg", "depth", "extension"),
    ("noext", "depth", "extension"),
    ("x.png", "points", "cannot hold"),
    ("x.ply", "depth", "cannot hold"),
    ("x.png", "colour", "unknown output"),
    ("x.png", "linear_depth", "camera"),
    ("x.png", "normals", "target"),
])
def test_save_refuses_before_writing(tmp_path, spot_frame, name, what, match):
    frame, _, _ = spot_frame
    with pytest.raises(ValueError, match=match):
        write_output(tmp_path / name, frame, what)
    assert os.listdir(tmp_path) == []


def test_empty_frame_files(tmp_path):
    """Nothing drawn: a depth PNG of zeros ("no depth"), not an error."""
    empty = Frame.empty(8, 6, FrameStats())
    cam = Camera.look_at((0, 0, 5), (0, 0, 0))
    d = iio.imread(empty.save(tmp_path / "d.png", "linear_depth", camera=cam))
    assert d.dtype == np.uint16 and not d.any()
