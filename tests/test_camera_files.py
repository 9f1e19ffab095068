"""Users' camera files (clraster.camera_files): COLMAP text models, NeRF transforms.json and
NPZ arrays. Each format is checked on a rendered image against its *own documented*
projection, computed here independently in float64: which pixels a triangle covers is
predicted by projecting its corners with the format's equations and testing each pixel
centre where the format puts it (COLMAP and NeRF: pixel (i, j)'s centre at (i + ½, j + ½);
OpenCV/NPZ: at (i, j)). A flipped axis, a transposed rotation or a half-pixel slip fails.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import get_renderer

from clraster import Camera, Mesh
from clraster.world.camera_files import (
    CameraFileError,
    common_size,
    read_colmap,
    read_nerf,
    read_npz,
)

W, H = 61, 47           # odd sizes: a half-pixel slip of the principal point shows
NEAR, FAR = 0.1, 50.0


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def _quat(r):
    """(w, x, y, z) of a rotation matrix (Shepperd), as COLMAP writes them."""
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return np.array([w, x, y, z])


# a scene of three asymmetric triangles in front of a camera looking roughly down +x
TRIS = np.array([
    [[5.0, -0.9, -1.1], [5.5, 0.7, -0.6], [5.2, -0.2, 0.9]],
    [[8.0, 1.5, 0.8], [8.0, 2.6, 1.9], [7.5, 0.9, 2.4]],
    [[4.0, -1.3, 0.2], [4.2, -0.6, 0.3], [4.1, -1.0, 1.2]],
])
MESH = Mesh(TRIS.reshape(-1, 3), np.arange(9).reshape(3, 3))


def _cv_pose():
    """A camera → world pose in OpenCV axes (+z forward, +y down), looking along +x."""
    base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: x, y, z
    r = _rot([0.3, 1.0, 0.2], 7.0) @ base
    pose = np.eye(4)
    pose[:3, :3] = r
    pose[:3, 3] = [0.2, 0.15, 0.1]
    return pose


def _expected_ids(project, centre_offset, margin=0.02):
    """Per pixel: the id of the nearest triangle whose projection holds the pixel centre,
    −1 for none, and a mask of pixels too close (< margin px) to an edge to judge.
    ``project(points (n, 3)) -> (u, v, depth)`` in the format's pixel units."""
    ys, xs = np.mgrid[0:H, 0:W]
    px = xs + centre_offset
    py = ys + centre_offset
    best = np.full((H, W), np.inf)
    ids = np.full((H, W), -1)
    unsure = np.zeros((H, W), bool)
    for t, tri in enumerate(TRIS):
        u, v, z = project(tri)
        assert np.all(z > 0)
        e = []
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ex, ey = u[b] - u[a], v[b] - v[a]
            e.append(((px - u[a]) * ey - (py - v[a]) * ex) / math.hypot(ex, ey))
        e = np.array(e)
        inside = np.all(e > margin, axis=0) | np.all(e < -margin, axis=0)
        near_edge = ~inside & (np.all(e > -margin, axis=0) | np.all(e < margin, axis=0))
        unsure |= near_edge
        zc = z.mean()       # the triangles do not overlap in depth order ambiguously here
        take = inside & (zc < best)
        ids[take] = t
        best[take] = zc
    return ids, unsure


def _check(camera, project, centre_offset):
    frame = get_renderer(W, H).render(MESH, camera, cull="none")
    want, unsure = _expected_ids(project, centre_offset)
    assert (want >= 0).sum() > 40          # the test sees the triangles at all
    got = np.asarray(frame.triangle_id)
    bad = (got != want) & ~unsure
    assert not bad.any(), f"{bad.sum()} pixels differ, first at {np.argwhere(bad)[0]}"


def _project_cv(k, pose_cv):
    w2c = np.linalg.inv(pose_cv)

    def project(p):
        c = (w2c[:3, :3] @ p.T).T + w2c[:3, 3]
        uvw = (k @ c.T).T
        return uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], c[:, 2]
    return project


# --- COLMAP --------------------------------------------------------------------------------

def _write_colmap(folder, model="PINHOLE", params=None, extra_images=0):
    folder.mkdir(parents=True, exist_ok=True)
    params = params or [52.0, 49.0, 29.3, 24.1]
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"7 {model} {W} {H} {' '.join(repr(float(p)) for p in params)}\n")
    pose = _cv_pose()
    r = pose[:3, :3].T                      # world → camera
    t = -r @ pose[:3, 3]
    q = _quat(r)
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i in range(1 + extra_images):
        lines.append(f"{i + 3} {' '.join(map(repr, q.tolist()))} "
                     f"{' '.join(map(repr, t.tolist()))} 7 view {i}.jpg")
        lines.append("" if i % 2 == 0 else "12.5 3.5 -1 1.0 2.0 17")
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    return pose


def test_colmap_pinhole_renders_where_colmap_projects(tmp_path):
    pose = _write_colmap(tmp_path / "sparse" / "0", extra_images=2)
    cams, names = read_colmap(tmp_path, near=NEAR, far=FAR)
    assert names == ["view 0.jpg", "view 1.jpg", "view 2.jpg"]   # names with spaces kept
    assert common_size(cams) == (W, H)
    # COLMAP's own projection: x = K (R X + t), pixel centres at (i + 0.5, j + 0.5)
    k_colmap = np.array([[52.0, 0, 29.3], [0, 49.0, 24.1], [0, 0, 1]])
    _check(cams[0], _project_cv(k_colmap, pose), 0.5)


def test_colmap_simple_pinhole_and_hand_built_camera_agree(tmp_path):
    pose = _write_colmap(tmp_path, "SIMPLE_PINHOLE", [50.0, 30.0, 23.5])
    cams, _ = read_colmap(tmp_path, near=NEAR, far=FAR)
    hand = Camera.from_intrinsics([[50.0, 0, 29.5], [0, 50.0, 23.0], [0, 0, 1]], W, H,
                                  pose=pose, near=NEAR, far=FAR)
    a = get_renderer(W, H).render(MESH, cams[0], cull="none")
    ids_a = np.asarray(a.triangle_id).copy()
    b = get_renderer(W, H).render(MESH, hand, cull="none")
    np.testing.assert_array_equal(ids_a, np.asarray(b.triangle_id))
    assert (ids_a >= 0).sum() > 40


def test_colmap_distortion_refused_unless_dropped(tmp_path):
    _write_colmap(tmp_path, "OPENCV", [52.0, 49.0, 29.3, 24.1, 0.01, 0.0, 0.0, 0.0])
    with pytest.raises(CameraFileError, match=r"OPENCV has lens distortion \(k1=0.01\)"):
        read_colmap(tmp_path, near=NEAR, far=FAR)
    pose = _cv_pose()
    cams, _ = read_colmap(tmp_path, near=NEAR, far=FAR, drop_distortion=True)
    _check(cams[0], _project_cv(np.array([[52.0, 0, 29.3], [0, 49.0, 24.1], [0, 0, 1]]),
                                pose), 0.5)
    # zero coefficients are a pinhole: no flag needed
    _write_colmap(tmp_path, "SIMPLE_RADIAL", [50.0, 30.0, 23.5, 0.0])
    assert len(read_colmap(tmp_path, near=NEAR, far=FAR)[0]) == 1
    _write_colmap(tmp_path, "OPENCV_FISHEYE", [52.0, 49.0, 29.3, 24.1, 0, 0, 0, 0])
    with pytest.raises(CameraFileError, match="fisheye"):
        read_colmap(tmp_path, near=NEAR, far=FAR, drop_distortion=True)


@pytest.mark.parametrize("cameras, images, match", [
    ("7 PINHOLE 61 47 52 49 29\n", None, "has 4 parameters"),
    ("7 WEIRD 61 47 52\n", None, "unknown camera model 'WEIRD'"),
    ("7 PINHOLE 61 47 52 49 nan 24\n", None, "finite"),
    ("7 PINHOLE 61 47 52 -49 29 24\n", None, "fy"),
    ("7 PINHOLE 61 47 52 49 29 24\n", "1 1 0 0 0 0 0 0 9 a.jpg\n\n", "CAMERA_ID 9"),
    ("7 PINHOLE 61 47 52 49 29 24\n", "1 0 0 0 0 0 0 0 7 a.jpg\n\n", "quaternion"),
    ("7 PINHOLE 61 47 52 49 29 24\n", "1 1 0 0 0 0 0 7 a.jpg\n", "expected IMAGE_ID"),
    ("7 PINHOLE 61 47 52 49 29 24\n", "", "no images"),
])
def test_colmap_malformed_files_name_the_line(tmp_path, cameras, images, match):
    (tmp_path / "cameras.txt").write_text("# header\n" + cameras)
    (tmp_path / "images.txt").write_text(images if images is not None else
                                         "1 1 0 0 0 0 0 0 7 a.jpg\n\n")
    with pytest.raises(CameraFileError, match=match) as info:
        read_colmap(tmp_path, near=NEAR, far=FAR)
    assert str(tmp_path) in str(info.value)


def test_colmap_needs_clip_planes_and_a_text_model(tmp_path):
    _write_colmap(tmp_path)
    with pytest.raises(CameraFileError, match="near= and far="):
        read_colmap(tmp_path)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "cameras.bin").write_bytes(b"\0" * 8)
    with pytest.raises(CameraFileError, match="model_converter"):
        read_colmap(tmp_path / "b", near=NEAR, far=FAR)


# --- NeRF transforms.json -------------------------------------------------------------------

def _gl_pose():
    pose = _cv_pose()
    return pose @ np.diag([1.0, -1.0, -1.0, 1.0])     # OpenCV axes → OpenGL axes


def _project_gl(fx, fy, cx, cy, pose_gl):
    w2c = np.linalg.inv(pose_gl)

    def project(p):
        c = (w2c[:3, :3] @ p.T).T + w2c[:3, 3]       # OpenGL camera: looks down −z, y up
        z = -c[:, 2]
        return fx * c[:, 0] / z + cx, -fy * c[:, 1] / z + cy, z
    return project


def test_nerf_fl_and_principal_point(tmp_path):
    pose = _gl_pose()
    doc = {"fl_x": 51.0, "fl_y": 48.5, "cx": 31.2, "cy": 22.9, "w": W, "h": H,
           "frames": [{"file_path": "images/0001.png", "transform_matrix": pose.tolist()},
                      {"file_path": "images/0002.png",
                       "transform_matrix": pose[:3].tolist(), "cx": 20.0}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    cams, names = read_nerf(tmp_path / "transforms.json", near=NEAR, far=FAR)
    assert names == ["images/0001.png", "images/0002.png"]
    _check(cams[0], _project_gl(51.0, 48.5, 31.2, 22.9, pose), 0.5)
    _check(cams[1], _project_gl(51.0, 48.5, 20.0, 22.9, pose), 0.5)   # per-frame value wins


def test_nerf_camera_angle_x_blender_scene(tmp_path):
    """The original Blender scenes: camera_angle_x only, no size in the file."""
    pose = _gl_pose()
    ax = 1.1
    doc = {"camera_angle_x": ax, "frames": [{"transform_matrix": pose.tolist()}]}
    f = tmp_path / "transforms_train.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(CameraFileError, match="no image size"):
        read_nerf(f, near=NEAR, far=FAR)
    cams, _ = read_nerf(f, width=W, height=H, near=NEAR, far=FAR)
    fx = 0.5 * W / math.tan(ax / 2)
    _check(cams[0], _project_gl(fx, fx, W / 2, H / 2, pose), 0.5)
    with pytest.raises(CameraFileError, match="differs from the size"):
        doc["w"] = W + 1
        f.write_text(json.dumps(doc))
        read_nerf(f, width=W, height=H, near=NEAR, far=FAR)


@pytest.mark.parametrize("doc, match", [
    ({"frames": [{"transform_matrix": np.eye(4).tolist()}], "w": 4, "h": 4}, "focal length"),
    ({"fl_x": 5, "w": 4, "h": 4, "frames": [{"transform_matrix": [[1, 2], [3, 4]]}]}, "4x4"),
    ({"fl_x": 5, "w": 4, "h": 4, "k1": 0.1, "frames": [{"transform_matrix": np.eye(4).tolist()}]},
     "lens distortion"),
    ({"camera_angle_x": 4.0, "w": 4, "h": 4,
      "frames": [{"transform_matrix": np.eye(4).tolist()}]}, "radians"),
    ({"fl_x": "5", "w": 4, "h": 4, "frames": [{"transform_matrix": np.eye(4).tolist()}]},
     "finite number"),
    ({"camera_angle_x": 1.0}, "frames"),
])
def test_nerf_malformed(tmp_path, doc, match):
    f = tmp_path / "t.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(CameraFileError, match=match):
        read_nerf(f, near=NEAR, far=FAR)


# --- NPZ ------------------------------------------------------------------------------------

def test_npz_opencv_and_opengl(tmp_path):
    k = np.array([[50.0, 0, 30.4], [0, 52.0, 22.6], [0, 0, 1]])
    pose = _cv_pose()
    np.savez(tmp_path / "c.npz", K=k, poses=np.stack([pose, pose]), width=W, height=H,
             near=NEAR, far=FAR)
    cams = read_npz(tmp_path / "c.npz")
    assert len(cams) == 2 and common_size(cams) == (W, H)
    _check(cams[1], _project_cv(k, pose), 0.0)      # OpenCV: centres at integers
    np.savez(tmp_path / "g.npz", K=k[None], poses=(pose @ np.diag([1, -1, -1, 1.0]))[None],
             convention="opengl")
    cams = read_npz(tmp_path / "g.npz", width=W, height=H, near=NEAR, far=FAR)
    _check(cams[0], _project_cv(k, pose), 0.0)


@pytest.mark.parametrize("arrays, match", [
    ({"K": np.eye(3)}, "needs arrays 'K' and 'poses'"),
    ({"K": np.eye(3), "poses": np.eye(4)}, r"\(N, 4, 4\)"),
    ({"K": np.ones((2, 3, 3)), "poses": np.ones((3, 4, 4))}, r"\(3, 3, 3\)"),
    ({"K": np.eye(3), "poses": np.eye(4)[None], "convention": "weird"}, "convention"),
    ({"K": np.eye(3), "poses": np.eye(4)[None], "width": 8}, "no image size"),
])
def test_npz_malformed(tmp_path, arrays, match):
    np.savez(tmp_path / "c.npz", **arrays)
    with pytest.raises(CameraFileError, match=match):
        read_npz(tmp_path / "c.npz", near=NEAR, far=FAR)


def test_common_size_refuses_mixed_sizes():
    k = np.array([[10.0, 0, 4], [0, 10, 3], [0, 0, 1]])
    a = Camera.from_intrinsics(k, 8, 6, near=1, far=2)
    b = Camera.from_intrinsics(k, 9, 6, near=1, far=2)
    assert common_size([a, Camera.look_at([0, 0, 1], [0, 0, 0])]) == (8, 6)
    assert common_size([Camera.look_at([0, 0, 1], [0, 0, 0])]) is None
    with pytest.raises(ValueError, match="8x6, 9x6"):
        common_size([a, b])


# --- through load_cameras, render_views and the CLI -----------------------------------------

def test_load_cameras_reads_every_format(tmp_path):
    from clraster.world.views import load_cameras

    _write_colmap(tmp_path / "colmap", extra_images=1)
    assert len(load_cameras(tmp_path / "colmap", near=NEAR, far=FAR)) == 2
    pose = _gl_pose()
    (tmp_path / "transforms.json").write_text(json.dumps(
        {"camera_angle_x": 1.0, "frames": [{"transform_matrix": pose.tolist()}]}))
    cams = load_cameras(tmp_path / "transforms.json", size=(W, H), near=NEAR, far=FAR)
    assert cams[0].image_size == (W, H)
    np.savez(tmp_path / "c.npz", K=np.array([[50.0, 0, 30], [0, 50, 23], [0, 0, 1]]),
             poses=_cv_pose()[None], near=NEAR, far=FAR)
    assert load_cameras(tmp_path / "c.npz", size=(W, H))[0].image_size == (W, H)
    # a camera list carries its own clip planes: near/far for it are refused, not ignored
    (tmp_path / "list.json").write_text(json.dumps([{"eye": [0, 0, 5], "target": [0, 0, 0]}]))
    with pytest.raises(CameraFileError, match="near, far cannot be given"):
        load_cameras(tmp_path / "list.json", near=NEAR, far=FAR)


def test_camera_list_intrinsics_entries(tmp_path):
    """{"K", "pose", "near", "far"} entries, with and without their own size, OpenCV and
    OpenGL poses, against the OpenCV projection on the image."""
    from clraster.world.views import ViewError, load_cameras

    k = np.array([[50.0, 0, 30.4], [0, 52.0, 22.6], [0, 0, 1]])
    pose = _cv_pose()
    entries = [{"K": k.tolist(), "pose": pose.tolist(), "near": NEAR, "far": FAR},
               {"K": k.tolist(), "pose": (pose @ np.diag([1, -1, -1, 1.0])).tolist(),
                "convention": "opengl", "near": NEAR, "far": FAR, "width": W, "height": H,
                "name": "gl"}]
    f = tmp_path / "cams.json"
    f.write_text(json.dumps(entries))
    for cam in load_cameras(f, size=(W, H)):
        _check(cam, _project_cv(k, pose), 0.0)
    with pytest.raises(ViewError, match="camera 0: field 'K'.*image size"):
        load_cameras(f)
    bad = [{"K": k.tolist(), "near": NEAR},
           {"K": k.tolist(), "near": 1, "far": 2, "eye": [0, 0, 1]},
           {"K": k.tolist(), "near": 1, "far": 2, "width": 4},
           {"K": k.tolist(), "near": 1, "far": 2, "convention": "dx"},
           {"K": [[1, 2], [3, 4]], "near": 1, "far": 2, "width": 4, "height": 4}]
    fields = ["far", "eye", "height", "convention", "K"]
    f.write_text(json.dumps(bad))
    broken = load_cameras(f, strict=False, size=(W, H))
    assert [b.error.field for b in broken] == fields


def test_cli_views_from_a_colmap_model(tmp_path):
    """`clraster render MESH --views COLMAP_DIR --near --far`: the size comes from the model;
    the ids written equal the ones COLMAP's projection predicts."""
    from clraster.cli import main

    pose = _write_colmap(tmp_path / "model")
    import trimesh

    trimesh.Trimesh(TRIS.reshape(-1, 3), np.arange(9).reshape(3, 3), process=False).export(
        tmp_path / "tris.ply")
    out = tmp_path / "out"
    code = main(["render", str(tmp_path / "tris.ply"), "--views", str(tmp_path / "model"),
                 "--near", str(NEAR), "--far", str(FAR), "--cull", "none", "--out", str(out),
                 "--outputs", "ids"])
    assert code == 0
    ids = np.load(out / "view_00000_ids.npy")
    assert ids.shape == (H, W)
    want, unsure = _expected_ids(_project_cv(
        np.array([[52.0, 0, 29.3], [0, 49.0, 24.1], [0, 0, 1]]), pose), 0.5)
    assert not ((ids != want) & ~unsure).any()
    # --size may repeat the model's size, not contradict it; near/far are needed
    assert main(["render", str(tmp_path / "tris.ply"), "--views", str(tmp_path / "model"),
                 "--near", str(NEAR), "--far", str(FAR), "--size", f"{W + 1}x{H}",
                 "--out", str(tmp_path / "o2")]) == 1
    assert main(["render", str(tmp_path / "tris.ply"), "--views", str(tmp_path / "model"),
                 "--out", str(tmp_path / "o3")]) == 1
    assert not (tmp_path / "o2").exists() or not any((tmp_path / "o2").iterdir())
    # options of the many-view path alone
    assert main(["render", "example", "--drop-distortion", "--out", str(tmp_path / "a.png")]) == 2


# --- hostile and odd files: one clear CameraFileError, never a traceback or a silent loss ---

def test_colmap_images_without_points_lines_are_refused_not_halved(tmp_path):
    (tmp_path / "cameras.txt").write_text(f"7 PINHOLE {W} {H} 52 49 29 24\n")
    (tmp_path / "images.txt").write_text("".join(
        f"{i} 1 0 0 0 0 0 0 7 {c}.png\n" for i, c in enumerate("abcd", 1)))
    with pytest.raises(CameraFileError, match=r"images.txt:2: expected the POINTS2D line"):
        read_colmap(tmp_path, near=NEAR, far=FAR)


@pytest.mark.parametrize("doc, match", [
    ({"w": W, "h": H, "fl_x": 10 ** 400, "frames": [{"transform_matrix": np.eye(4).tolist()}]},
     "finite number"),
    ({"w": W, "h": H, "fl_x": 50, "is_fisheye": True, "k1": 0.1,
      "frames": [{"transform_matrix": np.eye(4).tolist()}]}, "fisheye"),
    ({"w": W, "h": H, "fl_x": 50, "camera_model": "EQUIRECTANGULAR",
      "frames": [{"transform_matrix": np.eye(4).tolist()}]}, "'EQUIRECTANGULAR' is not a pinhole"),
    ({"w": 640.5, "h": H, "fl_x": 50, "frames": [{"transform_matrix": np.eye(4).tolist()}]},
     "positive whole number"),
])
def test_nerf_lenses_and_numbers_it_cannot_render(tmp_path, doc, match):
    f = tmp_path / "t.json"
    f.write_text(json.dumps(doc))
    for drop in (False, True):      # dropping distortion never makes a fisheye a pinhole
        with pytest.raises(CameraFileError, match=match):
            read_nerf(f, near=NEAR, far=FAR, drop_distortion=drop)


def test_npz_broken_files(tmp_path):
    k, pose = np.eye(3), np.eye(4)[None]
    np.savez(tmp_path / "good.npz", K=k, poses=pose, width=8, height=6, near=1, far=2)
    data = (tmp_path / "good.npz").read_bytes()
    (tmp_path / "trunc.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(CameraFileError, match="trunc.npz"):
        read_npz(tmp_path / "trunc.npz")
    np.savez(tmp_path / "obj.npz", K=np.array([k], dtype=object), poses=pose)
    with pytest.raises(CameraFileError, match="array 'K' cannot be read"):
        read_npz(tmp_path / "obj.npz", width=8, height=6, near=1, far=2)
    np.savez(tmp_path / "frac.npz", K=k, poses=pose, width=640.9, height=6, near=1, far=2)
    with pytest.raises(CameraFileError, match="whole number"):
        read_npz(tmp_path / "frac.npz")
    np.savez(tmp_path / "none.npz", K=k, poses=np.zeros((0, 4, 4)), width=8, height=6,
             near=1, far=2)
    with pytest.raises(CameraFileError, match="no pose"):
        read_npz(tmp_path / "none.npz")


def test_cli_broken_npz_is_one_line(tmp_path, capsys):
    from clraster.cli import main

    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 not really a zip")
    assert main(["render", "example", "--views", str(tmp_path / "bad.npz"), "--near", "0.1",
                 "--far", "10", "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "bad.npz" in err


def test_render_views_refuses_cameras_of_another_size_once(tmp_path):
    from clraster.batch import render_views

    _write_colmap(tmp_path / "m")
    cams, _ = read_colmap(tmp_path / "m", near=NEAR, far=FAR)
    with pytest.raises(ValueError, match=rf"{W}x{H} images.*pass size=\({W}, {H}\)"):
        render_views(MESH, cams, tmp_path / "out", size=(640, 480), progress=False)
    ok = render_views(MESH, cams, tmp_path / "out", size=(W, H), progress=False,
                      cull="none")
    assert ok.rendered == 1 and not ok.failures
