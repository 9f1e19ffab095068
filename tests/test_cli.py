"""The `clraster` command line: argument errors (exit 2), input errors (exit 1), renders."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest

from clraster.cli import main

SIZE = (96, 64)  # small, not a multiple of the tile size
WHITE = np.array([255, 255, 255], dtype=np.uint8)


def _render(tmp_path, *extra: str) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    out, depth, ids = tmp_path / "img.png", tmp_path / "depth.npy", tmp_path / "ids.npy"
    code = main(["render", "example", "--size", f"{SIZE[0]}x{SIZE[1]}", "--out", str(out),
                 "--depth", str(depth), "--ids", str(ids), *extra])
    assert code == 0
    return code, iio.imread(out), np.load(depth), np.load(ids)


@pytest.mark.parametrize("extra", [(), ("--reference",)], ids=["opencl", "reference"])
def test_render_example(tmp_path, capsys, extra):
    _, img, depth, ids = _render(tmp_path, *extra)
    w, h = SIZE
    assert img.shape == (h, w, 3) and img.dtype == np.uint8
    assert depth.shape == (h, w) and depth.dtype == np.float32
    assert ids.shape == (h, w) and ids.dtype == np.int32
    background = ids == -1
    assert 0 < background.sum() < 0.9 * background.size  # the framed scene fills the view
    assert np.all(img[background] == WHITE)
    assert np.any(img[~background] != WHITE)
    assert np.all(depth[background] == 1.0)
    assert np.all((depth[~background] >= 0) & (depth[~background] < 1))
    out = capsys.readouterr().out
    assert "frame time" in out and "sent to setup" in out


def test_tile_size_does_not_change_output(tmp_path):
    _, img, depth, ids = _render(tmp_path, "--tile-log2", "4")
    for log2 in ("3", "5", "6"):
        _, img2, depth2, ids2 = _render(tmp_path, "--tile-log2", log2)
        np.testing.assert_array_equal(ids2, ids)
        np.testing.assert_array_equal(depth2, depth)
        np.testing.assert_array_equal(img2, img)


def test_explicit_camera(tmp_path):
    _, img, _, ids = _render(tmp_path, "--eye=-6,3,6", "--target", "0,1,0", "--up", "0,1,0",
                             "--fov", "50", "--near", "0.5", "--far", "40")
    assert (ids >= 0).any()


@pytest.mark.parametrize("args", [
    ["render", "example", "--size", "0x10"],
    ["render", "example", "--size", "100"],
    ["render", "example", "--size", "axb"],
    ["render", "example", "--size", "100x-5"],
    ["render", "example", "--size", "99999x10"],
    ["render", "example"],  # --out missing
    ["render", "example", "--cull", "sideways"],
    ["render", "example", "--eye", "1,2"],
    ["render", "example", "--near", "-1"],
    ["render", "example", "--tile-log2", "9"],
    ["render", "example", "--repeat", "0"],
    ["paint", "example"],
    [],
])
def test_bad_arguments_exit_2(tmp_path, capsys, args):
    if "render" in args and "--out" not in args and args != ["render", "example"]:
        args = [*args, "--out", str(tmp_path / "x.png")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "usage:" in err and "Traceback" not in err
    assert not (tmp_path / "x.png").exists()


def test_bad_size_message(capsys, tmp_path):
    assert main(["render", "example", "--size", "12by7", "--out", str(tmp_path / "a.png")]) == 2
    assert "expected WIDTHxHEIGHT" in capsys.readouterr().err


def test_missing_mesh_exit_1(tmp_path, capsys):
    missing = tmp_path / "missing.ply"
    assert main(["render", str(missing), "--size", "32x32", "--out", str(tmp_path / "a.png")]) == 1
    err = capsys.readouterr().err
    assert "missing.ply" in err and "Traceback" not in err


def test_unreadable_mesh_exit_1(tmp_path, capsys):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a mesh")
    assert main(["render", str(bad), "--size", "32x32", "--out", str(tmp_path / "a.png")]) == 1
    assert "bad.ply" in capsys.readouterr().err


def test_bad_camera_exit_1(tmp_path, capsys):
    code = main(["render", "example", "--size", "32x32", "--out", str(tmp_path / "a.png"),
                 "--eye", "1,1,1", "--target", "1,1,1"])
    assert code == 1
    err = capsys.readouterr().err
    assert "eye and target must differ" in err and "Traceback" not in err


def test_help_exit_0(capsys):
    assert main(["render", "--help"]) == 0
    assert "--size" in capsys.readouterr().out


def test_wireframe_overlay(tmp_path, capsys):
    """--wireframe paints depth-tested mesh edges: only over drawn pixels (edges behind the
    surface or off the mesh never show on the background), the same pixels for OpenCL and
    the NumPy twin, and nothing changes in depth or ids."""
    _, plain, depth, ids = _render(tmp_path)
    _, wire, depth_w, ids_w = _render(tmp_path, "--wireframe")
    _, wire_ref, _, _ = _render(tmp_path, "--wireframe", "--reference")
    assert np.array_equal(depth, depth_w) and np.array_equal(ids, ids_w)
    painted = np.any(wire != plain, axis=2)
    assert painted.sum() > 0.05 * (ids >= 0).sum()
    assert np.all(wire[painted] == 20)   # the overlay colour
    # edges lie on the surface or its silhouette: a painted background pixel can only be
    # one next to a drawn pixel (a silhouette edge lights pixel centres the faces miss)
    assert np.all(_near_drawn(ids)[painted])
    assert np.array_equal(wire, wire_ref)
    assert "wireframe:" in capsys.readouterr().out


def test_vectors_as_three_numbers(tmp_path):
    """--eye X Y Z with negative numbers (and exponents) reads like the one-word forms."""
    _, img, depth, ids = _render(tmp_path, "--eye=-6,3,6", "--target", "0,1,0")
    for words in (["--eye", "-6", "3", "6", "--target", "0", "1", "0"],
                  ["--eye", "-6,3,6", "--target", "0", "1.0", "0e0", "--up", "0", "1", "0"],
                  ["--eye", "-0.6e1", "3", "6", "--target=0,1,0"]):
        _, img2, depth2, ids2 = _render(tmp_path, *words)
        np.testing.assert_array_equal(ids2, ids, err_msg=str(words))
        np.testing.assert_array_equal(depth2, depth)
        np.testing.assert_array_equal(img2, img)
    # --eye 1 -2 3: the camera below the scene sees something else, but parses
    _, _, _, below = _render(tmp_path, "--eye", "1", "-2", "3")
    assert (below >= 0).any() and not np.array_equal(below, ids)


@pytest.mark.parametrize("words", [["--eye", "1", "2"], ["--eye", "1", "x", "3"],
                                   ["--up", "0", "nan", "1"], ["--target"]])
def test_bad_vectors_exit_2(tmp_path, capsys, words):
    assert main(["render", "example", "--out", str(tmp_path / "x.png"), *words]) == 2
    assert "usage:" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_quiet_prints_nothing(tmp_path, capsys):
    _render(tmp_path, "--quiet")
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
    assert (tmp_path / "img.png").is_file()


def test_version(capsys):
    import clraster

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"clraster {clraster.__version__}"


def test_nothing_visible_exit_1_unless_allow_empty(tmp_path, capsys):
    away = ["--eye", "0", "0", "-100", "--target", "0", "0", "-200"]
    out = tmp_path / "img.png"
    args = ["render", "example", "--size", "48x32", "--out", str(out), "--ids",
            str(tmp_path / "ids.npy"), *away]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "nothing is visible" in err and "--allow-empty" in err and "outside the view" in err
    assert not out.exists() and not (tmp_path / "ids.npy").exists()
    assert main([*args, "--allow-empty", "--quiet"]) == 0
    assert out.is_file() and np.all(np.load(tmp_path / "ids.npy") == -1)


@pytest.mark.parametrize("name", ["image.ply", "image", "missing/image.png"])
def test_output_checked_before_rendering(tmp_path, capsys, name):
    assert main(["render", "example", "--size", "32x32", "--out", str(tmp_path / name)]) == 1
    out = capsys.readouterr()
    assert "--out" in out.err and "mesh:" not in out.out   # refused before loading


def test_depth_and_ids_files_follow_the_extension(tmp_path, capsys):
    """--depth/--ids write the file named, in the format its extension names
    (clraster.outputs); an extension that cannot hold them is refused before rendering."""
    _, _, depth, ids = _render(tmp_path)
    d_png, i_png = tmp_path / "d.png", tmp_path / "i.png"
    assert main(["render", "example", "--size", f"{SIZE[0]}x{SIZE[1]}", "--quiet", "--out",
                 str(tmp_path / "x.png"), "--depth", str(d_png), "--ids", str(i_png)]) == 0
    d16, i16 = iio.imread(d_png), iio.imread(i_png)
    assert d16.dtype == np.uint16 and i16.dtype == np.uint16
    np.testing.assert_array_equal(i16.astype(np.int64) - 1, ids)
    np.testing.assert_array_equal(d16, np.round(depth.astype(np.float64) * 65535))
    assert not (tmp_path / "d.png.npy").exists()
    capsys.readouterr()
    assert main(["render", "example", "--size", "32x32", "--out", str(tmp_path / "y.png"),
                 "--depth", str(tmp_path / "d.txt")]) == 1
    out = capsys.readouterr()
    assert "--depth" in out.err and "mesh:" not in out.out


# -- user clip planes ------------------------------------------------------------------------

# keeps x + z <= 1: a vertical plane through the example scene (x, z in [-4, 4]), cutting
# the ground and the objects on it
CUT_PLANE = (-1.0, 0.0, -1.0, 1.0)
CUT = ["--clip-plane", "-1", "0", "-1", "1"]


def _near_drawn(ids: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels drawn or next to a drawn one."""
    drawn = np.pad(ids >= 0, 1)
    h, w = ids.shape
    near = np.zeros_like(ids, dtype=bool)
    for dy in range(3):
        for dx in range(3):
            near |= drawn[dy:dy + h, dx:dx + w]
    return near


def test_clip_plane_cuts_the_image(tmp_path):
    """--clip-plane A B C D removes what lies on the plane's negative side: less coverage,
    the same cut with OpenCL and the NumPy twin, either way of writing the numbers, and a
    plane that keeps everything changes nothing."""
    _, img, depth, ids = _render(tmp_path)
    _, img_c, depth_c, ids_c = _render(tmp_path, *CUT)
    whole, cut = int((ids >= 0).sum()), int((ids_c >= 0).sum())
    assert 0 < cut < 0.9 * whole
    # nothing new appears: a cut pixel shows what the uncut image shows there, or a
    # surface that was hidden behind the removed part (farther away)
    drawn = ids_c >= 0
    assert np.all(depth_c[drawn] >= depth[drawn] - 1e-6)
    assert np.all(img_c[~drawn] == WHITE)
    _, _, depth_r, ids_r = _render(tmp_path, *CUT, "--reference")
    np.testing.assert_array_equal(ids_r, ids_c)
    np.testing.assert_array_equal(depth_r, depth_c)
    _, _, _, ids_w = _render(tmp_path, "--clip-plane=-1,0,-1,1")
    np.testing.assert_array_equal(ids_w, ids_c)
    _, _, _, ids_all = _render(tmp_path, "--clip-plane", "0", "-1", "0", "1e3")
    np.testing.assert_array_equal(ids_all, ids)
    # two planes cut more than one: keep x + z <= 1 and y <= 0.5
    _, _, _, ids_2 = _render(tmp_path, *CUT, "--clip-plane", "0", "-1", "0", "0.5")
    assert 0 < (ids_2 >= 0).sum() < cut
    assert np.all(ids_c[ids_2 >= 0] >= 0)


@pytest.mark.parametrize("extra", [(), ("--reference",)], ids=["opencl", "reference"])
def test_clip_plane_clips_the_wireframe(tmp_path, extra):
    """The wireframe is cut by the same planes: the edges of the removed part would paint
    the background far from any drawn pixel. (With --cull none: the cut opens closed
    objects, and with back-face culling the edges of their inside faces would show through
    the opening over the background.)"""
    _, plain, _, ids = _render(tmp_path, *CUT, "--cull", "none", *extra)
    _, wire, _, _ = _render(tmp_path, *CUT, "--cull", "none", "--wireframe", *extra)
    painted = np.any(wire != plain, axis=2)
    assert painted.sum() > 0.05 * (ids >= 0).sum()
    assert np.all(_near_drawn(ids)[painted])


@pytest.mark.parametrize("words, message", [
    (["--clip-plane", "0", "0", "0", "1"], "normal"),
    (["--clip-plane", "0", "1", "0"], "four finite numbers"),
    (["--clip-plane", "a", "b", "c", "d"], "four finite numbers"),
    (["--clip-plane", "0", "nan", "0", "1"], "four finite numbers"),
    (["--clip-plane=1,2,3"], "four finite numbers"),
    (CUT * 9, "at most 8"),
])
def test_bad_clip_planes_exit_2(tmp_path, capsys, words, message):
    assert main(["render", "example", "--out", str(tmp_path / "x.png"), *words]) == 2
    err = capsys.readouterr().err
    assert "usage:" in err and "Traceback" not in err
    errors = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "--clip-plane" in errors[0] and message in errors[0], err
    assert not (tmp_path / "x.png").exists()


def test_clip_planes_reach_the_views_paths(tmp_path, monkeypatch, capsys):
    """--views renders every view with the planes, on the local and on the Dask path."""
    import json

    from clraster import Camera, Renderer
    from clraster.world.examples import example_mesh

    w, h = SIZE
    cams = [Camera.look_at((6.0, 3.0, 5.0), (0, 0.8, 0), fov_y=50, near=0.5, far=30),
            Camera.look_at((-5.0, 2.0, 6.0), (0, 0.8, 0), fov_y=50, near=0.5, far=30)]
    f = tmp_path / "cams.json"
    f.write_text(json.dumps([{"eye": c.eye.tolist(), "target": [0, 0.8, 0], "up": [0, 1, 0],
                              "fov_y": 50, "near": 0.5, "far": 30} for c in cams]))
    out = tmp_path / "views"
    assert main(["render", "example", "--views", str(f), "--out", str(out), "--size",
                 f"{w}x{h}", "--outputs", "ids", *CUT]) == 0
    from clraster.scale.batch import view_files

    r, mesh = Renderer(w, h), example_mesh()
    for k, cam in enumerate(cams):
        got = np.load(view_files(out, k, ("ids",))["ids"])
        np.testing.assert_array_equal(got, r.render(mesh, cam, clip_planes=[CUT_PLANE])
                                      .triangle_id)
        assert (got >= 0).sum() < (r.render(mesh, cam).triangle_id >= 0).sum()

    # the Dask path: the planes go to clraster.distributed.render_views with the rest
    import types

    import clraster.cli as cli
    import clraster.scale.distributed as dist

    seen = {}

    def fake_render_views(target, cameras, client, out_dir, outputs, **kw):
        seen.update(kw)
        return types.SimpleNamespace(failures=[])

    monkeypatch.setattr(cli, "_dask_client", lambda args, stack: None)
    monkeypatch.setattr(dist, "render_views", fake_render_views)
    assert main(["render", "example", "--views", str(f), "--out", str(tmp_path / "v2"),
                 "--size", f"{w}x{h}", "--workers", "2", *CUT, *CUT[:1], "1", "0", "0",
                 "0"]) == 0
    np.testing.assert_array_equal(seen["clip_planes"], [CUT_PLANE, [1, 0, 0, 0]])
    assert seen["cull"] == "back" and seen["reversed_z"] is False
    capsys.readouterr()
