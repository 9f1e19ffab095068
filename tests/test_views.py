"""Many views per call: `Renderer.render_many`, `clraster.batch.render_views`, camera list
files (`clraster.views`) and ``clraster render MESH --views cameras.json --out DIR``."""

from __future__ import annotations

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
from conftest import assert_frames_equal

from clraster import Camera, Renderer
from clraster.cli import main
from clraster.output.shade import shade
from clraster.scale.batch import render_views, view_files
from clraster.world.examples import example_mesh
from clraster.world.views import CameraFileError, ViewError, load_cameras

W, H = 97, 61   # small, not a multiple of the tile size


@pytest.fixture(scope="module")
def mesh():
    return example_mesh()


def path_cameras(n: int = 6) -> list[Camera]:
    """An orbit around the example scene, plus a low close-up whose near plane cuts the
    ground (clipped triangles) and a camera looking away (nothing drawn)."""
    cams = []
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = (6.0 * math.sin(a), 2.5 + 0.5 * k, 6.0 * math.cos(a))
        cams.append(Camera.look_at(eye, (0, 0.8, 0), fov_y=50, near=0.5, far=30))
    cams.append(Camera.look_at((0.3, 0.15, 2.0), (0, 0.4, 0), fov_y=70, near=0.3, far=20))
    cams.append(Camera.look_at((0, 1, 5), (0, 1, 20), near=0.5, far=10))
    return cams


def entries(cams: list[Camera]) -> list[dict]:
    """The cameras as camera-file entries: look-at ones by their fields, alternating with
    matrices entries, so both kinds are read."""
    out = []
    for k, c in enumerate(cams):
        if k % 2:
            out.append({"view": np.asarray(c.view).tolist(),
                        "projection": np.asarray(c.projection(W, H)).tolist()})
        else:
            inv = np.linalg.inv(c.view)
            out.append({"eye": c.eye.tolist(), "target": (c.eye - inv[:3, 2]).tolist(),
                        "up": inv[:3, 1].tolist(), "fov_y": c.fov_y, "near": c.near,
                        "far": c.far, "name": f"cam{k}"})
    return out


def assert_same(a, b, context: str) -> None:
    assert_frames_equal(a, b, context)
    np.testing.assert_array_equal(a.barycentrics, b.barycentrics, err_msg=context)


@pytest.mark.parametrize("occlusion", [False, True], ids=["plain", "occlusion"])
def test_render_many_equals_render(mesh, occlusion):
    cams = path_cameras()
    loop = Renderer(W, H)   # fresh renderers: with occlusion, the history is part of a frame
    expected = [loop.render(mesh, c, occlusion=occlusion) for c in cams]
    many = Renderer(W, H)
    got = list(many.render_many(mesh, cams, occlusion=occlusion))
    assert len(got) == len(cams)
    for k, (a, b) in enumerate(zip(got, expected, strict=True)):
        assert_same(a, b, f"view {k}")
    assert (expected[-2].triangle_id >= 0).any() and expected[-2].stats.clipped > 0
    assert (expected[-1].triangle_id < 0).all()
    if occlusion:   # the history was used: later views culled something by occlusion
        assert sum(f.stats.clusters_occlusion_culled for f in got[1:]) > 0
    # each frame owns its arrays: earlier frames are not overwritten by later views
    assert not np.shares_memory(got[0].depth, got[1].depth)


def test_render_many_from_file_and_dicts(mesh, tmp_path):
    cams = path_cameras(3)
    f = tmp_path / "cams.json"
    f.write_text(json.dumps({"cameras": entries(cams)}))
    r = Renderer(W, H)
    expected = [r.render(mesh, c) for c in cams]
    for source in (f, str(f), entries(cams), load_cameras(f)):
        for k, (a, b) in enumerate(zip(r.render_many(mesh, source), expected, strict=True)):
            assert_frames_equal(a, b, f"{type(source).__name__} view {k}", bary_atol=1e-6)


def test_render_many_checks_eagerly(mesh):
    r = Renderer(W, H)
    with pytest.raises(TypeError, match="colour"):
        r.render_many(mesh, path_cameras(2), colour=True)
    with pytest.raises(ValueError, match="Mesh or clraster.Scene"):
        r.render_many("mesh.ply", path_cameras(2))
    with pytest.raises(ValueError, match="wrap it in a list"):
        r.render_many(mesh, path_cameras(1)[0])


def test_render_many_names_broken_entry(mesh):
    cams: list = path_cameras(3)
    cams[1] = {"eye": [0, 1, 5], "target": [0, 0, 0], "near": 2.0, "far": 1.0}
    gen = Renderer(W, H).render_many(mesh, cams)
    next(gen)
    with pytest.raises(ViewError, match=r"camera 1: field 'far'") as info:
        next(gen)
    assert info.value.index == 1 and info.value.field == "far"


@pytest.mark.parametrize("entry, field", [
    ({"eye": [0, 1, float("nan")], "target": [0, 0, 0]}, "eye"),
    ({"eye": [0, 1, 5], "target": [0, 0]}, "target"),
    ({"eye": [0, 1, 5], "target": [0, 0, 0], "near": 3, "far": 3}, "far"),
    ({"eye": [0, 1, 5], "target": [0, 0, 0], "near": -1}, "near"),
    ({"eye": [0, 1, 5], "target": [0, 0, 0], "fov_y": 180}, "fov_y"),
    ({"eye": [0, 5, 0], "target": [0, 0, 0], "up": [0, 1, 0]}, "up"),
    ({"eye": [0, 1, 5], "target": [0, 0, 0], "fovy": 30}, "fovy"),
    ({"eye": [0, 1, 5]}, "target"),
    ({"view": np.eye(4).tolist()}, "projection"),
    ({"view": np.zeros((4, 4)).tolist(),
      "projection": Camera.look_at((0, 0, 1), (0, 0, 0)).projection(W, H).tolist()}, "view"),
    ({"view": np.eye(4).tolist(), "projection": [[1, 0, 0], [0, 1, 0]]}, "projection"),
    ({"view": np.eye(4).tolist(), "projection": np.zeros((4, 4)).tolist()}, "projection"),
    # gluPerspective written with near and far swapped: near >= far
    ({"view": np.eye(4).tolist(),
      "projection": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, (1 + 10) / (10 - 1),
                                                  2 * 10 * 1 / (10 - 1)], [0, 0, -1, 0]]},
     "projection"),
    ({"eye": [0, 1, 5], "target": [0, 0, 0], "view": np.eye(4).tolist()}, "view"),
])
def test_broken_entry_named(tmp_path, entry, field):
    good = {"eye": [0, 1, 5], "target": [0, 0, 0]}
    f = tmp_path / "cams.json"
    # json writes NaN as the literal NaN, which Python's reader accepts
    f.write_text(json.dumps([good, good, entry, good]))
    with pytest.raises(ViewError, match=rf"camera 2: field '{field}'"):
        load_cameras(f)
    kept = load_cameras(f, strict=False)
    assert [type(c).__name__ for c in kept] == ["Camera", "Camera", "BrokenCamera", "Camera"]
    assert kept[2].error.field == field


@pytest.mark.parametrize("text", ["{not json", '{"views": []}', '"camera"', "3"])
def test_structurally_broken_file(tmp_path, text):
    f = tmp_path / "cams.json"
    f.write_text(text)
    with pytest.raises(CameraFileError, match="cams.json"):
        load_cameras(f)


def test_render_views_files(mesh, tmp_path):
    cams = path_cameras(3)
    outs = ("depth", "ids", "bary", "shaded")
    summary = render_views(mesh, cams, tmp_path / "out", outs, size=(W, H), progress=False)
    assert (summary.views, summary.rendered, summary.skipped) == (5, 5, 0)
    assert summary.ok and summary.failures_file is None and summary.views_per_s > 0
    r = Renderer(W, H)
    expected = {f"view_{k:05d}_{o}{'.png' if o == 'shaded' else '.npy'}"
                for k in range(5) for o in outs}
    # plus what made them: the run's record and each view's key (clraster.batch)
    expected |= {"render_views.json"} | {f".view_{k:05d}.key" for k in range(5)}
    assert {p.name for p in (tmp_path / "out").iterdir()} == expected   # no temp files left
    for k, cam in enumerate(cams):
        fr = r.render(mesh, cam)
        files = view_files(tmp_path / "out", k, outs)
        depth, ids, bary = (np.load(files[o]) for o in ("depth", "ids", "bary"))
        assert depth.dtype == np.float32 and ids.dtype == np.int32 and bary.dtype == np.float32
        np.testing.assert_array_equal(depth, fr.depth)
        np.testing.assert_array_equal(ids, fr.triangle_id)
        np.testing.assert_array_equal(bary, fr.barycentrics)
        np.testing.assert_array_equal(iio.imread(files["shaded"]), shade(fr, mesh))


def test_render_views_broken_entry_fails_one_view(mesh, tmp_path):
    cams: list = path_cameras(3)
    cams[1] = {"eye": [0, 1, 5], "target": [0, 0, 0], "near": 1.0, "far": float("nan")}
    cams[3] = "not a camera"
    # a matrices camera made in Python with near >= far
    bad = np.asarray(cams[0].projection(W, H)).copy()
    bad[2, 2], bad[2, 3] = -bad[2, 2], -bad[2, 3]
    cams[4] = Camera.from_matrices(cams[0].view, bad)
    out = tmp_path / "out"
    s = render_views(mesh, cams, out, size=(W, H), progress=False)
    assert s.rendered == 2 and [f.index for f in s.failures] == [1, 3, 4]
    assert "camera 1: field 'far'" in s.failures[0].message
    assert s.failures[1].message.startswith("camera 3:")
    assert "camera 4: field 'projection'" in s.failures[2].message
    assert "near" in s.failures[2].message
    assert json.loads(s.failures_file.read_text())[0]["index"] == 1
    for k in range(5):
        have = all(p.exists() for p in view_files(out, k, ("depth", "ids")).values())
        assert have == (k in (0, 2)), k

    # the same in a file: the broken entry fails only its view
    f = tmp_path / "cams.json"
    ent = entries(path_cameras(3))
    ent[2]["near"] = "far away"
    f.write_text(json.dumps(ent))
    s2 = render_views(mesh, f, tmp_path / "out2", size=(W, H), progress=False)
    assert s2.rendered == 4 and [x.index for x in s2.failures] == [2]
    assert "camera 2: field 'near'" in s2.failures[0].message


def test_render_views_rerun_skips(mesh, tmp_path, monkeypatch):
    cams = path_cameras(2)
    out = tmp_path / "out"
    first = render_views(mesh, cams, out, size=(W, H), progress=False)
    assert first.rendered == 4
    ids1 = view_files(out, 1, ("ids",))["ids"]
    ids1.unlink()   # as if the batch had been killed while writing view 1
    stamp = view_files(out, 0, ("depth",))["depth"].stat().st_mtime_ns
    second = render_views(mesh, cams, out, size=(W, H), progress=False)
    assert (second.rendered, second.skipped, second.views) == (1, 3, 4)
    assert ids1.exists()
    assert view_files(out, 0, ("depth",))["depth"].stat().st_mtime_ns == stamp
    # chunks of one list: start numbers the files by the whole list
    third = render_views(mesh, cams[2:], out, size=(W, H), progress=False, start=2)
    assert third.skipped == 2 and third.rendered == 0


def test_cli_views(tmp_path, capsys):
    cams = path_cameras(2)
    f = tmp_path / "cams.json"
    ent = entries(cams)
    f.write_text(json.dumps(ent))
    out = tmp_path / "views"
    args = ["render", "example", "--views", str(f), "--out", str(out), "--size", f"{W}x{H}",
            "--outputs", "ids,shaded", "--cull", "none"]
    assert main(args) == 0
    r = Renderer(W, H)
    mesh = example_mesh()
    for k, cam in enumerate(cams):
        files = view_files(out, k, ("ids", "shaded"))
        fr = r.render(mesh, cam, cull="none")
        np.testing.assert_array_equal(np.load(files["ids"]), fr.triangle_id)
        assert iio.imread(files["shaded"]).shape == (H, W, 3)
    assert not view_files(out, 0, ("depth",))["depth"].exists()
    assert "4 rendered" in capsys.readouterr().out

    ent[1]["view"][0][0] = float("nan")
    f.write_text(json.dumps(ent))
    out2 = tmp_path / "views2"
    assert main(["render", "example", "--views", str(f), "--out", str(out2), "--size",
                 f"{W}x{H}"]) == 1
    err = capsys.readouterr().err
    assert "camera 1: field 'view'" in err
    assert "1 of 4 views failed" in err and "failures.json" in err
    # rerun: the good views are skipped, the broken one fails again
    assert main(["render", "example", "--views", str(f), "--out", str(out2), "--size",
                 f"{W}x{H}"]) == 1
    assert "0 rendered, 3 skipped, 1 failed" in capsys.readouterr().out


@pytest.mark.parametrize("extra", [["--eye", "0,1,2"], ["--depth", "d.npy"], ["--repeat", "2"],
                                   ["--outputs", "depth,colour"]])
def test_cli_views_bad_arguments(tmp_path, extra):
    f = tmp_path / "cams.json"
    f.write_text("[]")
    assert main(["render", "example", "--views", str(f), "--out", str(tmp_path / "o"),
                 *extra]) == 2


def test_cli_outputs_need_views(tmp_path):
    assert main(["render", "example", "--out", str(tmp_path / "a.png"), "--outputs",
                 "ids"]) == 2


def test_cli_views_broken_file(tmp_path, capsys):
    f = tmp_path / "cams.json"
    f.write_text("[{")
    assert main(["render", "example", "--views", str(f), "--out", str(tmp_path / "o")]) == 1
    assert "not valid JSON" in capsys.readouterr().err
