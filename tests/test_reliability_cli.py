"""The `clraster` command line's output paths: two options naming one file are refused, and
every output path is checked before anything is rendered or written (a name longer than
the file system allows, a missing or non-folder parent, a folder where a file is expected,
no write permission); the files are written all or none; a name as long as the file
system allows (250 bytes) works end to end."""

from __future__ import annotations

import os
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from clraster.cli import main

SIZE = "32x24"
RENDER = ["render", "example", "--size", SIZE, "--reference", "-q"]


def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        pytest.skip("the file system does not say how long a name may be")


def _error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip()]


# --- two outputs naming one file ------------------------------------------------------------

def _same_file_cases(d: Path) -> dict[str, list[str]]:
    """Name → the render options naming one file twice (relative to `d`, the current
    folder, where a case needs it)."""
    (d / "sub").mkdir()
    (d / "real").mkdir()
    (d / "linkdir").symlink_to(d / "real")
    (d / "link.npy").symlink_to(d / "target.npy")   # dangling: target.npy is not there yet
    return {
        "png-twice": ["--out", "same.png", "--depth", "same.png"],
        "npy-twice": ["--out", "a.png", "--depth", "x.npy", "--ids", "x.npy"],
        "dot-slash": ["--out", "a.png", "--depth", "x.npy", "--ids", "./x.npy"],
        "relative-absolute": ["--out", "a.png", "--depth", "x.npy", "--ids", str(d / "x.npy")],
        "dot-dot": ["--out", "a.png", "--depth", "x.npy", "--ids", "sub/../x.npy"],
        "symlinked-file": ["--out", "a.png", "--depth", "link.npy", "--ids", "target.npy"],
        "symlinked-folder": ["--out", "real/a.png", "--depth", "linkdir/a.png"],
    }


@pytest.mark.parametrize("case", ["png-twice", "npy-twice", "dot-slash", "relative-absolute",
                                  "dot-dot", "symlinked-file", "symlinked-folder"])
def test_two_outputs_naming_one_file_are_refused(tmp_path, monkeypatch, capsys, case):
    monkeypatch.chdir(tmp_path)
    args = _same_file_cases(tmp_path)[case]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert main([*RENDER[:-1], *args]) == 1   # not quiet: nothing may print "mesh: ..."
    out, err = capsys.readouterr()
    lines = _error_lines(err)
    assert len(lines) == 1 and "same file" in lines[0], err
    options = [a for a in args if a.startswith("--")]
    dup = [o for o in options if o != "--out"] if len(options) == 3 else options
    assert all(o in lines[0] for o in dup)   # names both options
    assert out == ""   # refused before the mesh was loaded or anything rendered
    assert sorted(p.name for p in tmp_path.rglob("*")) == before   # nothing written


def test_hard_links_to_one_file_are_refused(tmp_path, capsys):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, np.arange(3))
    os.link(a, b)
    assert main([*RENDER, "--out", str(tmp_path / "x.png"), "--depth", str(a), "--ids",
                 str(b)]) == 1
    err = capsys.readouterr().err
    assert "--depth" in err and "--ids" in err and "same file" in err
    np.testing.assert_array_equal(np.load(b), np.arange(3))   # untouched
    assert not (tmp_path / "x.png").exists()


# --- every path checked up front ------------------------------------------------------------

@pytest.mark.parametrize("option", ["--out", "--depth", "--ids"])
def test_name_too_long_is_refused_before_rendering(tmp_path, capsys, option):
    limit = _name_max(tmp_path)
    suffix = ".png" if option == "--out" else ".npy"
    long_name = "n" * (limit + 1 - len(suffix)) + suffix
    paths = {"--out": tmp_path / "x.png", "--depth": tmp_path / "d.npy",
             "--ids": tmp_path / "i.npy"}
    paths[option] = tmp_path / long_name
    args = [a for opt, p in paths.items() for a in (opt, str(p))]
    assert main([*RENDER[:-1], *args]) == 1
    out, err = capsys.readouterr()
    lines = _error_lines(err)
    assert len(lines) == 1 and option in lines[0], err
    assert f"{limit + 1} bytes" in lines[0] and f"{limit} bytes" in lines[0]
    assert out == ""
    assert list(tmp_path.iterdir()) == []   # in particular no --out written first


def test_folder_name_too_long_is_refused(tmp_path, capsys):
    limit = _name_max(tmp_path)
    path = tmp_path / ("f" * (limit + 1)) / "ids.npy"
    assert main([*RENDER, "--out", str(tmp_path / "x.png"), "--ids", str(path)]) == 1
    err = capsys.readouterr().err
    assert "--ids" in err and f"{limit + 1} bytes" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_file_used_as_folder_is_refused_before_anything_is_written(tmp_path, capsys):
    # (a folder where a file is expected, a missing folder: tests/test_bad_input.py)
    (tmp_path / "file.txt").write_text("keep")
    out = tmp_path / "x.png"
    assert main([*RENDER, "--out", str(out), "--ids", str(tmp_path / "file.txt" / "i.npy")]) == 1
    lines = _error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and "--ids" in lines[0] and "is a file, not a folder" in lines[0]
    assert not out.exists() and (tmp_path / "file.txt").read_text() == "keep"


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root may write in any folder")
def test_read_only_folder_is_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        assert main([*RENDER, "--out", str(tmp_path / "x.png"), "--depth",
                     str(ro / "d.npy")]) == 1
    finally:
        ro.chmod(0o700)
    assert "permission denied" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


# --- all or nothing, long names -------------------------------------------------------------

def test_a_failing_output_leaves_every_output_as_it_was(tmp_path, monkeypatch, capsys):
    """--ids failing at write time (here a full disk) must not leave --out written and
    --depth replaced: the files are written all or none, and no temporary file stays."""
    import clraster.output.outputs as outputs

    real = outputs.write_output

    def failing(path, frame, what, **kw):
        if what == "ids":
            raise OSError(28, "No space left on device")
        return real(path, frame, what, **kw)

    monkeypatch.setattr(outputs, "write_output", failing)
    out, depth, ids = tmp_path / "x.png", tmp_path / "d.npy", tmp_path / "i.npy"
    np.save(depth, np.arange(4))   # an older depth file: must stay as it was
    assert main([*RENDER, "--out", str(out), "--depth", str(depth), "--ids", str(ids)]) == 1
    assert "No space left" in capsys.readouterr().err
    assert not out.exists() and not ids.exists()
    np.testing.assert_array_equal(np.load(depth), np.arange(4))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy"]


def test_symlinked_output_is_written_where_it_points(tmp_path):
    """A link stays a link and the file it names gets the data; outputs that share a stem
    (x.png, x.npy, x.npz) are not one file."""
    real = tmp_path / "data" / "depth.npy"
    real.parent.mkdir()
    link = tmp_path / "x.npy"
    link.symlink_to(real)
    out, ids = tmp_path / "x.png", tmp_path / "x.npz"
    assert main([*RENDER, "--out", str(out), "--depth", str(link), "--ids", str(ids)]) == 0
    assert link.is_symlink() and np.load(real).shape == (24, 32)
    assert iio.imread(out).shape == (24, 32, 3) and np.load(ids)["ids"].dtype == np.int32
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "x.npy", "x.npz", "x.png"]


def test_names_of_250_bytes_work_end_to_end(tmp_path):
    """A legal name of 250 bytes (under 255) for every output: the temporary files must
    not make it longer than the file system allows."""
    if _name_max(tmp_path) < 250:
        pytest.skip("the file system allows names shorter than 250 bytes")
    out, depth, ids = (tmp_path / (c * 246 + ext)
                       for c, ext in (("o", ".png"), ("d", ".npy"), ("i", ".npy")))
    assert all(len(os.fsencode(p.name)) == 250 for p in (out, depth, ids))
    assert main([*RENDER, "--out", str(out), "--depth", str(depth), "--ids", str(ids)]) == 0
    assert iio.imread(out).shape == (24, 32, 3)
    assert np.load(depth).shape == (24, 32) and np.load(ids).dtype == np.int32
    assert sorted(tmp_path.iterdir()) == sorted([out, depth, ids])


# --- the other subcommands' output folders --------------------------------------------------

def test_demo_output_folder_checked_before_the_plant_is_built(tmp_path, monkeypatch,
                                                              capsys):
    import clraster.world.generators as generators

    def no_plant(*_a, **_k):
        raise AssertionError("the plant was built before --out was checked")

    monkeypatch.setattr(generators, "plant", no_plant)
    file = tmp_path / "file"
    file.write_text("keep")
    limit = _name_max(tmp_path)
    for out, what in ((file, "is a file"), (file / "sub", "is a file, not a folder"),
                      (tmp_path / "new" / ("f" * (limit + 1)), f"{limit + 1} bytes")):
        assert main(["demo", "--out", str(out), "--size", SIZE, "--triangles", "2000"]) == 1
        lines = _error_lines(capsys.readouterr().err)
        assert len(lines) == 1 and "--out" in lines[0] and what in lines[0], lines
    assert file.read_text() == "keep" and not (tmp_path / "new").exists()


def test_views_output_folder_checked_before_the_mesh_is_loaded(tmp_path, capsys):
    cams = tmp_path / "cams.json"
    cams.write_text('[{"eye": [0, 1, 5], "target": [0, 0, 0]}]')
    limit = _name_max(tmp_path)
    out = tmp_path / ("v" * (limit + 1))
    assert main(["render", "example", "--size", SIZE, "--views", str(cams), "--out",
                 str(out)]) == 1
    stdout, err = capsys.readouterr()
    assert f"{limit + 1} bytes" in err and "--out" in err
    assert "mesh:" not in stdout
