"""Batch views (`clraster.batch.render_views`, `clraster.distributed.render_views`) and the
atomic writers (`clraster.atomic`) under the faults a long batch meets:

* a re-run into a folder rendered with another size or other image options is refused
  before anything is rendered (saying what differs and what to do), or renders everything
  again with ``overwrite=True``; a view whose camera changed is rendered again, and one
  that now fails leaves none of its old files; options that never change an image
  (occlusion, frustum) still skip; a folder of view files with no record is refused;
* a file name as long as the file system allows is written (the temporary name fits), and
  one longer is refused naming the file asked for, not a temporary;
* bad render keyword values (cull, clip planes, reversed_z) raise once, before any view,
  on one machine and on Dask;
* a writer killed (SIGKILL) mid-file leaves a temporary that the next run deletes, and no
  other file (a live writer's temporary, another file ending in .tmp) is touched.

The Dask cases run on one small LocalCluster (one worker process, one thread), started
once for the module.
"""

from __future__ import annotations

import errno
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from clraster import Camera, Renderer
from clraster.scale.batch import render_views, view_files
from clraster.world.examples import example_mesh

W, H = 40, 30


@pytest.fixture(scope="module")
def mesh():
    return example_mesh()


@pytest.fixture(scope="module")
def renderer():
    return Renderer(W, H)


def orbit(n: int, shift: float = 0.0) -> list[Camera]:
    return [Camera.look_at((6.0 * math.sin(a + shift), 2.5, 6.0 * math.cos(a + shift)),
                           (0, 0.8, 0), fov_y=50, near=0.5, far=30)
            for a in np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)]


def stamps(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in folder.glob("view_*")}


# -- item 6: what made the files is recorded, and a mismatch is never reported as done -------

@pytest.mark.parametrize("change", [
    {"size": (W + 8, H)},
    {"cull": "none"},
    {"reversed_z": True},
    {"clip_planes": [[0.0, 1.0, 0.0, -0.5]]},
    {"window": [[0.0, 0.0], [W, 0.0], [0.0, H]]},
])
def test_rerun_with_other_settings_is_refused(mesh, tmp_path, change):
    out = tmp_path / "views"
    cams = orbit(3)
    first = render_views(mesh, cams, out, size=(W, H), progress=False)
    assert first.rendered == 3
    before = stamps(out)
    kw = {"size": (W, H), **change}
    with pytest.raises(ValueError) as info:
        render_views(mesh, cams, out, progress=False, **kw)
    assert type(info.value).__name__ == "OutDirMismatchError"
    msg = str(info.value)
    name = next(iter(change))
    assert f"{name}:" in msg and "there" in msg, msg     # what differs
    assert "another out_dir" in msg and "overwrite=True" in msg, msg   # what to do
    assert stamps(out) == before   # nothing rendered over the old files
    # overwrite: every view rendered again with the new settings
    again = render_views(mesh, cams, out, progress=False, overwrite=True, **kw)
    assert (again.rendered, again.skipped) == (3, 0)
    size = kw["size"]
    r = Renderer(*size)
    opts = {k: v for k, v in kw.items() if k != "size"}
    for k, cam in enumerate(cams):
        depth = np.load(view_files(out, k, ("depth",))["depth"])
        np.testing.assert_array_equal(depth, r.render(mesh, cam, **opts).depth)
    # and from now on the new settings are the folder's: a plain re-run skips
    assert render_views(mesh, cams, out, progress=False, **kw).skipped == 3


def test_image_neutral_options_and_outputs_still_skip(mesh, tmp_path):
    """Culling switches documented never to change an image are not a mismatch; an output
    added later renders only what is missing, and an output never written is not skipped."""
    out = tmp_path / "views"
    cams = orbit(3)
    render_views(mesh, cams, out, ("depth",), size=(W, H), progress=False)
    s = render_views(mesh, cams, out, ("depth",), size=(W, H), progress=False,
                     occlusion=True, frustum=False, cones=False)
    assert (s.rendered, s.skipped) == (0, 3)
    s = render_views(mesh, cams, out, ("depth", "ids"), size=(W, H), progress=False)
    assert (s.rendered, s.skipped) == (3, 0)
    # equal options given in another form are the same options
    other = tmp_path / "windowed"
    ring = [[0.0, 0.0], [W, 0.0], [0.0, H]]
    render_views(mesh, cams, other, size=(W, H), progress=False, window=ring,
                 clip_planes=[0.0, 1.0, 0.0, 0.5])
    s = render_views(mesh, cams, other, size=(W, H), progress=False,
                     window=np.array(ring[::-1]), clip_planes=np.array([[0.0, 1.0, 0.0, 0.5]]))
    assert (s.rendered, s.skipped) == (0, 3)
    # a size change is refused even for an output the folder never held
    with pytest.raises(ValueError, match="size"):
        render_views(mesh, cams, out, ("bary",), size=(W, H + 1), progress=False)


def test_changed_camera_is_rendered_again(mesh, renderer, tmp_path):
    out = tmp_path / "views"
    cams = orbit(4)
    render_views(mesh, cams, out, ("depth", "ids"), renderer=renderer, progress=False)
    new = list(cams)
    new[2] = Camera.look_at((1.0, 3.0, 5.0), (0, 0.8, 0), fov_y=60, near=0.5, far=30)
    s = render_views(mesh, new, out, ("depth", "ids"), renderer=renderer, progress=False)
    assert (s.rendered, s.skipped) == (1, 3)
    ids = np.load(view_files(out, 2, ("ids",))["ids"])
    np.testing.assert_array_equal(ids, renderer.render(mesh, new[2]).triangle_id)
    assert not np.array_equal(ids, renderer.render(mesh, cams[2]).triangle_id)

    # a camera that now fails: its view's old files go (they are another camera's)
    broken = list(new)
    broken[1] = {"eye": [0, 1, 5], "target": [0, 0, 0], "near": -1.0}
    s = render_views(mesh, broken, out, ("depth", "ids"), renderer=renderer, progress=False)
    assert [f.index for f in s.failures] == [1] and s.skipped == 3
    assert not any(p.exists() for p in view_files(out, 1, ("depth", "ids")).values())
    # and it stays failed, never skipped, on the next run
    s = render_views(mesh, broken, out, ("depth", "ids"), renderer=renderer, progress=False)
    assert [f.index for f in s.failures] == [1] and s.skipped == 3


def test_view_files_without_a_record_are_refused(mesh, renderer, tmp_path):
    out = tmp_path / "views"
    out.mkdir()
    stale = view_files(out, 0, ("depth",))["depth"]
    np.save(stale, np.zeros((7, 5), np.float32))   # someone else's file under our name
    with pytest.raises(ValueError, match="render_views.json") as info:
        render_views(mesh, orbit(2), out, ("depth",), renderer=renderer, progress=False)
    assert "overwrite=True" in str(info.value)
    assert np.load(stale).shape == (7, 5)
    s = render_views(mesh, orbit(2), out, ("depth",), renderer=renderer, progress=False,
                     overwrite=True)
    assert s.rendered == 2 and np.load(stale).shape == (H, W)


# -- item 9: temporary names fit wherever the final name does ---------------------------------

def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (AttributeError, OSError, ValueError):
        return 255


def test_longest_legal_name_is_written(renderer, mesh, tmp_path):
    from clraster.output.outputs import write_output

    frame = renderer.render(mesh, orbit(1)[0])
    limit = _name_max(tmp_path)
    path = tmp_path / ("d" * (limit - 4) + ".npy")
    assert len(os.fsencode(path.name)) == limit
    write_output(path, frame, "depth")
    np.testing.assert_array_equal(np.load(path), frame.depth)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]   # no temporary left
    # a name longer than the file system allows: refused naming it, not a temporary
    too_long = tmp_path / ("e" * (limit - 3) + ".npy")
    with pytest.raises(OSError) as info:
        write_output(too_long, frame, "depth")
    assert info.value.errno == errno.ENAMETOOLONG
    assert info.value.filename == str(too_long)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_temporary_names_fit_and_stay_distinct():
    from clraster.output.atomic import TEMPORARY_RE, temporary_name

    for limit in (255, 143, 64):
        names = ["a" * (limit - 4) + ".npy", "a" * (limit - 4) + ".png", "é" * 200 + ".npy",
                 "short.npy"]
        tmps = [temporary_name(n, limit) for n in names]
        assert all(len(os.fsencode(t)) <= limit for t in tmps), tmps
        assert len(set(tmps)) == len(tmps), tmps   # names sharing their start stay apart
        for t in tmps:
            m = TEMPORARY_RE.match(t)
            assert m is not None and int(m["pid"]) == os.getpid(), t
    assert temporary_name("short.npy").startswith(".short.npy.")


# -- item 11: bad render keyword values raise once, before any view ---------------------------

BAD_VALUES = [({"cull": "sideways"}, "cull"),
              ({"clip_planes": [[0.0, 0.0, 0.0, 1.0]]}, "zero normal"),
              ({"reversed_z": "yes"}, "reversed_z"),
              ({"occlusion": 1}, "occlusion")]


@pytest.mark.parametrize(("kw", "match"), BAD_VALUES)
def test_bad_render_values_raise_before_any_view(mesh, renderer, tmp_path, kw, match, caplog):
    out = tmp_path / "views"
    with pytest.raises(ValueError, match=match):
        render_views(mesh, orbit(3), out, renderer=renderer, progress=False, **kw)
    assert not out.exists()   # refused before the folder was made
    assert not [r for r in caplog.records if r.levelname == "WARNING"]


# -- item 12: a killed writer's temporary is deleted by the next run, and nothing else --------

WRITER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from clraster.scale.batch import _write_atomic

    def write(fh):
        fh.write(b"x" * (1 << 20))
        fh.flush()
        print("writing", flush=True)
        time.sleep(600)   # killed here, mid-file

    _write_atomic(Path(sys.argv[1]), write)
""")


def start_writer(path: Path) -> subprocess.Popen:
    """A process writing ``path`` through `clraster.batch`'s writer, stopped mid-file (1 MiB
    of it written) until it is killed."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "writing":
        proc.kill()
        proc.wait()
        pytest.fail("the writer process did not start writing")
    return proc


def test_killed_writers_temporary_is_removed_by_the_next_run(mesh, renderer, tmp_path):
    out = tmp_path / "views"
    out.mkdir()
    target = view_files(out, 0, ("depth",))["depth"]
    dead = start_writer(target)
    os.kill(dead.pid, signal.SIGKILL)
    dead.wait()
    left = [p for p in out.iterdir() if p.name.endswith(".tmp")]
    assert len(left) == 1 and left[0].stat().st_size == 1 << 20, left
    assert not target.exists()
    # files the clean-up must leave alone: a live writer's temporary (a view this run does
    # not write), and files that merely end in .tmp
    live = start_writer(view_files(out, 99, ("depth",))["depth"])
    try:
        live_tmp = [p for p in out.iterdir() if p.name.endswith(".tmp") and p != left[0]]
        assert len(live_tmp) == 1
        keep = [out / ".notes.tmp", out / "view_00000_depth.npy.tmp",
                out / f".unrelated.{dead.pid}.tmp"]
        for p in keep:
            p.write_bytes(b"keep")
        s = render_views(mesh, orbit(2), out, ("depth",), renderer=renderer, progress=False)
        assert s.rendered == 2
        assert not left[0].exists()
        assert live_tmp[0].exists() and live_tmp[0].stat().st_size == 1 << 20
        assert all(p.read_bytes() == b"keep" for p in keep)
    finally:
        live.kill()
        live.wait()


# -- the same on Dask --------------------------------------------------------------------------


def test_dask_rerun_with_other_settings_is_refused(client, mesh, renderer, tmp_path):
    from clraster.scale.distributed import render_views as dask_views

    out = tmp_path / "views"
    cams = orbit(4)
    first = dask_views(mesh, cams, client, out, size=(W, H), chunk=2)
    assert first.rendered == 4
    before = stamps(out)
    with pytest.raises(ValueError, match=r"size: \[40, 30\] there, \[48, 30\] now") as info:
        dask_views(mesh, cams, client, out, size=(W + 8, H))
    assert type(info.value).__name__ == "OutDirMismatchError"
    with pytest.raises(ValueError, match="cull"):
        dask_views(mesh, cams, client, out, size=(W, H), cull="front")
    assert stamps(out) == before
    # a folder rendered on one machine is checked the same way on the workers
    render_views(mesh, cams, tmp_path / "one", renderer=renderer, progress=False)
    with pytest.raises(ValueError, match="reversed_z"):
        dask_views(mesh, cams, client, tmp_path / "one", size=(W, H), reversed_z=True)
    # a changed camera is rendered again, the others skipped
    new = list(cams)
    new[3] = Camera.look_at((1.0, 3.0, 5.0), (0, 0.8, 0), fov_y=60, near=0.5, far=30)
    s = dask_views(mesh, new, client, out, size=(W, H), chunk=2)
    assert (s.rendered, s.skipped) == (1, 3)
    np.testing.assert_array_equal(np.load(view_files(out, 3, ("ids",))["ids"]),
                                  renderer.render(mesh, new[3]).triangle_id)
    s = dask_views(mesh, new, client, out, size=(W + 8, H), overwrite=True)
    assert (s.rendered, s.skipped) == (4, 0)
    assert np.load(view_files(out, 0, ("depth",))["depth"]).shape == (H, W + 8)
    record = json.loads((out / "render_views.json").read_text())
    assert record["settings"]["size"] == [W + 8, H]


@pytest.mark.parametrize(("kw", "match"), BAD_VALUES)
def test_dask_bad_render_values_raise_before_any_work(client, mesh, tmp_path, kw, match):
    from clraster.scale.distributed import render_views as dask_views

    out = tmp_path / "views"
    with pytest.raises(ValueError, match=match):
        dask_views(mesh, orbit(3), client, out, size=(W, H), **kw)
    assert not out.exists()


def test_atomic_writer_never_follows_a_link_at_its_temporary_name(tmp_path):
    """A link planted at the (predictable) temporary name neither redirects the write nor
    ends up as the output."""
    import os

    from clraster.output.atomic import name_max, temporary_name, write_atomic

    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    out = tmp_path / "view_00000_depth.npy"
    tmp = tmp_path / temporary_name(out.name, name_max(tmp_path))
    os.symlink(victim, tmp)
    write_atomic(out, b"NEW")
    assert victim.read_text() == "keep me"
    assert not out.is_symlink() and out.read_bytes() == b"NEW"
    assert not tmp.exists() and not tmp.is_symlink()


def test_rerun_with_another_mesh_is_refused(mesh, tmp_path):
    """The record holds the scene: views of an edited mesh are not taken for done."""
    from clraster import Mesh

    out = tmp_path / "views"
    cams = orbit(2)
    assert render_views(mesh, cams, out, size=(W, H), progress=False).rendered == 2
    moved = Mesh(np.asarray(mesh.vertices) + np.float32(0.01), mesh.faces)
    with pytest.raises(ValueError, match="scene:") as info:
        render_views(moved, cams, out, size=(W, H), progress=False)
    assert type(info.value).__name__ == "OutDirMismatchError"
    again = render_views(moved, cams, out, size=(W, H), progress=False, overwrite=True)
    assert again.rendered == 2
    assert render_views(moved, cams, out, size=(W, H), progress=False).skipped == 2


def test_overwrite_with_other_settings_leaves_no_views_of_the_old_ones(mesh, tmp_path):
    out = tmp_path / "views"
    assert render_views(mesh, orbit(4), out, size=(W, H), progress=False).rendered == 4
    again = render_views(mesh, orbit(4)[:2], out, size=(W, H), progress=False,
                         overwrite=True, cull="none")
    assert again.rendered == 2
    left = sorted(p.name for p in out.iterdir() if "view_" in p.name)
    assert left == sorted([f"view_0000{k}_{o}.npy" for k in range(2) for o in ("depth", "ids")]
                          + [f".view_0000{k}.key" for k in range(2)])
