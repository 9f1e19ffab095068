"""Dataset outputs on the batch paths: metric depth PNGs in millimetres, normals, masks and
point clouds with normals from `clraster.scale.batch.render_views` (one machine), the Dask
path and ``clraster render --views --outputs NAME:FORMAT``; `iter_views` (arrays, no files);
`Frame.save` of points with normals, in camera space, and refusing options it would ignore."""

from __future__ import annotations

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest

from clraster import Camera, Renderer
from clraster.cli import main
from clraster.scale.batch import (
    OutDirMismatchError,
    iter_views,
    render_views,
    view_files,
)
from clraster.world.examples import example_mesh

W, H = 97, 61   # small, not a multiple of the tile size


@pytest.fixture(scope="module")
def mesh():
    return example_mesh()


@pytest.fixture(scope="module")
def renderer():
    return Renderer(W, H)


def cameras(n: int = 3) -> list[Camera]:
    """An orbit around the example scene (it spans x, z in [-4, 4], y in [0, 2.9]: a few
    units away, so at 1000 PNG units per unit every depth fits 16 bits)."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n + 0.3
        eye = (5.0 * math.sin(a), 2.5 + 0.4 * k, 5.0 * math.cos(a))
        out.append(Camera.look_at(eye, (0, 0.8, 0), fov_y=55, near=0.5, far=30))
    return out


def face_normals(mesh) -> np.ndarray:
    """Unit face normals normalize((b - a) x (c - a)) in float64, from the mesh itself."""
    v = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def read_ply(path) -> tuple[list[str], np.ndarray]:
    """(header lines, (N, 6) float32 x y z nx ny nz) of a binary little-endian PLY cloud."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    props = [line.split()[-1] for line in header if line.startswith("property")]
    assert props == ["x", "y", "z", "nx", "ny", "nz"]
    assert all(line.split()[1] == "float" for line in header if line.startswith("property"))
    n = int(next(line for line in header if line.startswith("element vertex")).split()[-1])
    rows = np.frombuffer(data[end:], "<f4")
    assert rows.size == 6 * n
    return header, rows.reshape(n, 6)


def folder_bytes(path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(path.iterdir())}


# -- one machine ---------------------------------------------------------------------------------

def test_metric_png_normals_mask_points(mesh, renderer, tmp_path):
    cams = cameras()
    outs = ("linear_depth", "distance:png", "normals", "camera_normals", "mask", "ids",
            "points", "depth")
    s = render_views(mesh, cams, tmp_path, outs, renderer=renderer)
    assert (s.rendered, len(s.failures)) == (3, 0)
    fn = face_normals(mesh)
    for k, cam in enumerate(cams):
        frame = renderer.render(mesh, cam)
        files = view_files(tmp_path, k, outs)
        assert files["linear_depth"].name == f"view_{k:05d}_linear_depth.png"
        assert files["points"].name == f"view_{k:05d}_points.ply"
        ids = np.load(files["ids"])
        np.testing.assert_array_equal(ids, frame.triangle_id)
        hit = ids >= 0
        assert hit.sum() > 500, "the view should show the scene"
        # 16-bit PNG in millimetres: round(depth * 1000), 0 where nothing was hit
        for name, exact in (("linear_depth", frame.linear_depth(cam, mesh)),
                            ("distance", frame.distance(cam, mesh))):
            png = iio.imread(files[name])
            assert png.dtype == np.uint16 and png.shape == (H, W)
            assert (png[~hit] == 0).all() and (png[hit] > 0).all()
            err = np.abs(png[hit].astype(np.float64) - exact[hit].astype(np.float64) * 1000.0)
            assert err.max() <= 0.5 + 1e-3, name
        # linear depth is -z in eye space of the surface point: check one pixel by hand
        y, x = np.argwhere(hit)[len(np.argwhere(hit)) // 2]
        p = frame.points(mesh).points[np.flatnonzero(hit.ravel()) == y * W + x][0]
        z_eye = (np.asarray(cam.view) @ np.append(p, 1.0))[2]
        assert abs(iio.imread(files["linear_depth"])[y, x] - round(-z_eye * 1000)) <= 1
        # face normals, world and camera frame, against the mesh's own
        n = np.load(files["normals"])
        assert n.dtype == np.float32 and n.shape == (H, W, 3)
        np.testing.assert_allclose(n[hit], fn[ids[hit]], atol=1e-5)
        assert not n[~hit].any()
        r = np.asarray(cam.view, np.float64)[:3, :3]
        np.testing.assert_allclose(np.load(files["camera_normals"])[hit],
                                   fn[ids[hit]] @ r.T, atol=1e-5)
        # mask: 255 where ids >= 0
        m = iio.imread(files["mask"])
        assert m.dtype == np.uint8 and set(np.unique(m).tolist()) <= {0, 255}
        np.testing.assert_array_equal(m == 255, hit)
        # points with normals, in row-major pixel order
        _, rows = read_ply(files["points"])
        pts = frame.points(mesh)
        assert rows.shape == (int(hit.sum()), 6)
        np.testing.assert_allclose(rows[:, :3], pts.points, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(rows[:, 3:], fn[pts.ids], atol=1e-5)


def test_depth_scale_record_and_overflow(mesh, renderer, tmp_path):
    cams = cameras(2)
    out = tmp_path / "v"
    render_views(mesh, cams, out, ("linear_depth",), renderer=renderer, depth_scale=5000)
    frame = renderer.render(mesh, cams[0])
    png = iio.imread(view_files(out, 0, ("linear_depth",))["linear_depth"])
    hit = frame.mask
    exact = frame.linear_depth(cams[0], mesh)
    assert np.abs(png[hit] - exact[hit].astype(np.float64) * 5000).max() <= 0.5 + 1e-3
    record = json.loads((out / "render_views.json").read_text())
    assert record["outputs"] == {"linear_depth.png": {"depth_scale": 5000.0}}
    # another depth_scale for the same files: refused like other settings
    with pytest.raises(OutDirMismatchError, match="linear_depth.png.*5000.*1000"):
        render_views(mesh, cams, out, ("linear_depth",), renderer=renderer)
    # another output joins the folder; the rerun skips what is there
    s = render_views(mesh, cams, out, ("linear_depth", "mask"), renderer=renderer,
                     depth_scale=5000)
    assert (s.rendered, s.skipped) == (2, 0)
    s = render_views(mesh, cams, out, ("linear_depth",), renderer=renderer, depth_scale=5000)
    assert (s.rendered, s.skipped) == (0, 2)
    assert set(json.loads((out / "render_views.json").read_text())["outputs"]) == {
        "linear_depth.png", "mask.png"}
    # overwrite: the new scale replaces the old, every view rendered again
    s = render_views(mesh, cams, out, ("linear_depth",), renderer=renderer, overwrite=True)
    assert s.rendered == 2
    png = iio.imread(view_files(out, 0, ("linear_depth",))["linear_depth"])
    assert np.abs(png[hit] - exact[hit].astype(np.float64) * 1000).max() <= 0.5 + 1e-3
    # depths beyond 16 bits: the view fails, naming itself and its depth range; no file
    far = tmp_path / "far"
    s = render_views(mesh, cams[:1], far, ("ids", "linear_depth"), renderer=renderer,
                     depth_scale=1e5)
    assert s.rendered == 0 and len(s.failures) == 1
    msg = s.failures[0].message
    assert msg.startswith("camera 0:") and "linear_depth" in msg
    assert f"{float(exact[hit].max()):.6g}" in msg and "65535" in msg
    assert not any(p.exists() for p in view_files(far, 0, ("ids", "linear_depth")).values())


def test_formats_and_refusals(mesh, renderer, tmp_path):
    cams = cameras(1)
    outs = ("linear_depth:npy", "normals:png", "mask:npy", "points:npz", "smooth_normals",
            "ids:tif")
    render_views(mesh, cams, tmp_path / "f", outs, renderer=renderer)
    frame = renderer.render(mesh, cams[0])
    files = view_files(tmp_path / "f", 0, outs)
    assert [p.name for p in files.values()] == [
        "view_00000_linear_depth.npy", "view_00000_normals.png", "view_00000_mask.npy",
        "view_00000_points.npz", "view_00000_smooth_normals.npy", "view_00000_ids.tif"]
    np.testing.assert_array_equal(np.load(files["linear_depth"]),
                                  frame.linear_depth(cams[0], mesh))
    np.testing.assert_array_equal(np.load(files["mask"]), frame.triangle_id >= 0)
    np.testing.assert_array_equal(np.load(files["smooth_normals"]),
                                  frame.normals(mesh, smooth=True))
    np.testing.assert_array_equal(iio.imread(files["ids"], plugin="pillow"),
                                  frame.triangle_id)
    rgb = iio.imread(files["normals"])
    n = frame.normals(mesh)
    np.testing.assert_array_equal(rgb[frame.mask], np.round((n[frame.mask] + 1) * 127.5))
    with np.load(files["points"]) as z:
        np.testing.assert_array_equal(z["points"], frame.points(mesh).points)
        np.testing.assert_array_equal(z["normals"], frame.point_normals(mesh))
    # refused before anything is written
    bad = tmp_path / "bad"
    for outputs, kw, match in [
            (("ids",), {"depth_scale": 1000}, "depth_scale"),
            (("linear_depth:npy",), {"depth_scale": 1000}, "depth_scale"),
            (("linear_depth",), {"depth_scale": 0}, "depth_scale"),
            (("ids:ply",), {}, "ids cannot be written as ply"),
            (("normals:jpg",), {}, "normals cannot be written as jpg"),
            (("colour",), {}, "distinct names"),
            (("ids", "ids:png"), {}, "distinct names")]:
        with pytest.raises(ValueError, match=match):
            render_views(mesh, cams, bad, outputs, renderer=renderer, **kw)
        assert not bad.exists()
    # formats this installation may lack: written, or refused up front with what to install
    try:
        import tifffile  # noqa: F401
    except ImportError:
        with pytest.raises(ValueError, match="tifffile"):
            render_views(mesh, cams, bad, ("normals:tiff",), renderer=renderer)
        assert not bad.exists()
    try:
        render_views(mesh, cams, bad, ("distance:exr",), renderer=renderer)
    except ValueError as exc:
        assert "EXR" in str(exc) and not bad.exists()
    else:
        np.testing.assert_array_equal(
            iio.imread(view_files(bad, 0, ("distance:exr",))["distance"]),
            frame.distance(cams[0], mesh))


# -- Frame.save ------------------------------------------------------------------------------

def test_save_points_with_normals_world_and_camera(mesh, renderer, tmp_path):
    import trimesh

    cam = cameras(1)[0]
    frame = renderer.render(mesh, cam)
    fn = face_normals(mesh)
    pts = frame.points(mesh)
    view = np.asarray(cam.view, np.float64)
    # world: PLY with normals (our parser and trimesh), NPY (N, 6)
    p = frame.save(tmp_path / "w.ply", "points", target=mesh)
    _, rows = read_ply(p)
    np.testing.assert_allclose(rows[:, :3], pts.points, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(rows[:, 3:], fn[pts.ids], atol=1e-5)
    cloud = trimesh.load(p)
    np.testing.assert_allclose(cloud.vertices, pts.points, rtol=1e-6, atol=1e-6)
    a = np.load(frame.save(tmp_path / "w.npy", "points", target=mesh))
    assert a.shape == (len(pts.ids), 6) and a.dtype == np.float64
    np.testing.assert_array_equal(a[:, :3], pts.points)
    np.testing.assert_allclose(a[:, 3:], fn[pts.ids], atol=1e-5)
    # camera space: the world points through the view matrix, the normals rotated
    c = np.load(frame.save(tmp_path / "c.npy", "points", target=mesh, space="camera",
                           camera=cam))
    np.testing.assert_allclose(c[:, :3], pts.points @ view[:3, :3].T + view[:3, 3],
                               rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(c[:, 3:], fn[pts.ids] @ view[:3, :3].T, atol=1e-5)
    assert (c[:, 2] < 0).all()   # in front of the camera, which looks down -z
    _, crows = read_ply(frame.save(tmp_path / "c.ply", "points", target=mesh,
                                   space="camera", camera=cam))
    np.testing.assert_allclose(crows, c, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(frame.points(mesh, space="camera", camera=cam).points,
                                  c[:, :3])


@pytest.mark.parametrize("name, what, kw, match", [
    ("i.npy", "ids", {"depth_scale": 1000}, "depth_scale"),
    ("d.npy", "linear_depth", {"camera": "cam", "depth_scale": 1000}, "depth_scale"),
    ("d.npy", "depth", {"target": "mesh"}, "target"),
    ("m.png", "mask", {"camera": "cam"}, "camera"),
    ("n.npy", "normals", {"target": "mesh", "camera": "cam"}, "camera"),
    ("p.ply", "points", {"target": "mesh", "camera": "cam"}, "camera"),
    ("p.ply", "points", {"target": "mesh", "space": "camera"}, "camera"),
    ("i.png", "ids", {"smooth": True}, "smooth"),
    ("d.png", "linear_depth", {"camera": "cam", "space": "camera"}, "space"),
    ("n.npy", "normals", {"target": "mesh", "light_dir": (0, 1, 0)}, "light_dir"),
])
def test_save_refuses_options_it_would_ignore(mesh, renderer, tmp_path, name, what, kw, match):
    cam = cameras(1)[0]
    frame = renderer.render(mesh, cam)
    given = {k: {"mesh": mesh, "cam": cam}.get(v, v) if isinstance(v, str) else v
             for k, v in kw.items()}
    with pytest.raises(ValueError, match=match):
        frame.save(tmp_path / name, what, **given)
    assert not list(tmp_path.iterdir())


# -- arrays for training loops ----------------------------------------------------------------

def test_iter_views_equals_frame_methods(mesh, renderer):
    from clraster.output.shade import shade

    cams = cameras(2)
    outs = ("depth", "ids", "bary", "mask", "linear_depth", "distance", "normals",
            "smooth_normals", "camera_normals", "points", "shaded")
    got = list(iter_views(mesh, cams, outs, renderer=renderer))
    assert [v["index"] for v in got] == [0, 1]
    for v, cam in zip(got, cams, strict=True):
        assert v["camera"] is cam
        f = renderer.render(mesh, cam)
        np.testing.assert_array_equal(v["depth"], f.depth)
        np.testing.assert_array_equal(v["ids"], f.triangle_id)
        np.testing.assert_array_equal(v["bary"], f.barycentrics)
        np.testing.assert_array_equal(v["mask"], f.triangle_id >= 0)
        np.testing.assert_array_equal(v["linear_depth"], f.linear_depth(cam, mesh))
        np.testing.assert_array_equal(v["distance"], f.distance(cam, mesh))
        np.testing.assert_array_equal(v["normals"], f.normals(mesh))
        np.testing.assert_array_equal(v["smooth_normals"], f.normals(mesh, smooth=True))
        np.testing.assert_array_equal(v["camera_normals"],
                                      f.normals(mesh, space="camera", camera=cam))
        np.testing.assert_array_equal(v["points"][:, :3], f.points(mesh).points)
        np.testing.assert_array_equal(v["points"][:, 3:], f.point_normals(mesh))
        np.testing.assert_array_equal(v["shaded"], shade(f, mesh))
    # a broken camera raises its ViewError, or is skipped
    broken = [cams[0], {"eye": [0, 0, 1], "target": [0, 0, 0], "near": -1.0}, cams[1]]
    with pytest.raises(ValueError, match="camera 1: field 'near'"):
        list(iter_views(mesh, broken, ("ids",), renderer=renderer))
    kept = list(iter_views(mesh, broken, ("ids",), renderer=renderer, errors="skip"))
    assert [v["index"] for v in kept] == [0, 2]
    with pytest.raises(ValueError, match="name a format"):
        iter_views(mesh, cams, ("ids:png",), renderer=renderer)


# -- command line ----------------------------------------------------------------------------

def camera_file(tmp_path, cams) -> str:
    ent = []
    for c in cams:
        inv = np.linalg.inv(c.view)
        ent.append({"eye": c.eye.tolist(), "target": (c.eye - inv[:3, 2]).tolist(),
                    "up": inv[:3, 1].tolist(), "fov_y": c.fov_y, "near": c.near,
                    "far": c.far})
    f = tmp_path / "cams.json"
    f.write_text(json.dumps(ent))
    return str(f)


def test_cli_outputs_with_formats(mesh, renderer, tmp_path, capsys):
    cams = cameras(2)
    f = camera_file(tmp_path, cams)
    out = tmp_path / "views"
    spec = "linear_depth:png,normals:npy,mask:png,ids:npy,points:ply"
    assert main(["render", "example", "--views", f, "--out", str(out), "--size", f"{W}x{H}",
                 "--outputs", spec, "--depth-scale", "2000"]) == 0
    capsys.readouterr()
    for k, cam in enumerate(cams):
        frame = renderer.render(mesh, cam)
        hit = frame.mask
        d = iio.imread(out / f"view_{k:05d}_linear_depth.png")
        exact = frame.linear_depth(cam, mesh)
        assert np.abs(d[hit] - exact[hit].astype(np.float64) * 2000).max() <= 0.5 + 1e-3
        assert (d[~hit] == 0).all()
        np.testing.assert_array_equal(np.load(out / f"view_{k:05d}_ids.npy"),
                                      frame.triangle_id)
        np.testing.assert_array_equal(np.load(out / f"view_{k:05d}_normals.npy"),
                                      frame.normals(mesh))
        np.testing.assert_array_equal(iio.imread(out / f"view_{k:05d}_mask.png") > 0, hit)
        _, rows = read_ply(out / f"view_{k:05d}_points.ply")
        assert rows.shape == (int(hit.sum()), 6)
    rec = json.loads((out / "render_views.json").read_text())["outputs"]
    assert rec["linear_depth.png"] == {"depth_scale": 2000.0} and rec["points.ply"] == {}
    # another scale into the same folder: refused (exit 1) with what differs
    assert main(["render", "example", "--views", f, "--out", str(out), "--size", f"{W}x{H}",
                 "--outputs", spec]) == 1
    assert "depth_scale" in capsys.readouterr().err
    # --depth-scale with no depth PNG: refused before anything is rendered
    assert main(["render", "example", "--views", f, "--out", str(tmp_path / "o2"),
                 "--outputs", "ids,linear_depth:npy", "--depth-scale", "1000"]) == 1
    assert "depth_scale" in capsys.readouterr().err and not (tmp_path / "o2").exists()
    # a format an output cannot have: a usage error
    assert main(["render", "example", "--views", f, "--out", str(tmp_path / "o3"),
                 "--outputs", "ids:ply"]) == 2
    assert main(["render", "example", "--out", str(tmp_path / "a.png"),
                 "--depth-scale", "1000"]) == 2


# -- Dask --------------------------------------------------------------------------------------


def test_dask_writes_the_same_bytes(client, mesh, renderer, tmp_path):
    from clraster.scale.distributed import render_views as dask_views

    cams: list = cameras(3)
    outs = ("linear_depth", "distance:tiff", "normals", "smooth_camera_normals:npz", "mask",
            "points", "ids:png")
    one = render_views(mesh, cams, tmp_path / "one", outs, renderer=renderer,
                       depth_scale=4000)
    dask = dask_views(mesh, cams, client, tmp_path / "dask", outs, size=(W, H), chunk=1,
                      depth_scale=4000)
    assert one.rendered == dask.rendered == 3 and not dask.failures
    assert folder_bytes(tmp_path / "dask") == folder_bytes(tmp_path / "one")
    assert len(folder_bytes(tmp_path / "one")) == 3 * len(outs) + 3 + 1
    with pytest.raises(ValueError, match="depth_scale"):
        dask_views(mesh, cams, client, tmp_path / "x", ("ids",), size=(W, H),
                   depth_scale=1000)
