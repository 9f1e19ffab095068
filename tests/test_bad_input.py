"""Bad input, the whole catalogue in one place, with the outcome each case must have.

| input | outcome |
|---|---|
| NaN/Inf vertices, clip positions beyond float32 | dropped, counted in stats.invalid |
| empty meshes | an empty frame |
| malformed meshes, sizes, lenses, cameras, cull, tile sizes | ValueError, twin too |
| non-bool flags (occlusion="no", frustum=1), cull=[] | ValueError naming the option |
| a file with no triangle (points, lines, DXF, GLB of points) | ValueError: no triangles |
| a glTF node scaled to zero | skipped with a SceneWarning; the rest renders |
| a camera ~1e6–1e7 from the origin (georeferenced) | accepted and rendered |
| a mesh scaled by 1e-15 / 1e15, a projection scaled by 1e±13 | the same image as unscaled |
| near so small that float32 depth collapses (1e-30, 1e-7/1e7) | PrecisionWarning naming near |
| PYOPENCL_CTX: the Oclgrind simulator / nothing | SimulatorWarning / NoDeviceError |
| CLI: --ids/--depth not .npy, a folder, no extension | exit 1 before rendering |
| CLI: out of memory, Ctrl-C | one line, exit 1 / exit 130 (tests/test_processes.py) |
| CLI: a later output fails while writing | exit 1; every output as it was (all-or-none) |
| output names of 250 bytes (any writer) | written; temporary names fit NAME_MAX |
| `local_cluster(0)`, `(-1)`, `(1.5)`, `(True)` | ValueError: a positive integer |
| Dask calls on a client with no workers | NoWorkersError (a ValueError) within WORKER_WAIT_S |
| `render_views` re-run with one camera changed | that view re-rendered; the others skipped |
| a batch writer SIGKILLed mid-file | the next run removes its temporary (dead pid, same host) |

More cases, input → outcome:

* CLI: two outputs naming one file (`--out a.png --depth a.png`, `./`, `..`, links) → exit 1
  before loading, naming both options; nothing written
* CLI: an output or folder name over NAME_MAX, a parent that is a file → exit 1 before
  rendering; nothing written
* CLI / load_cameras: a camera file nested 100,000 levels, not UTF-8, a 5000-digit integer →
  CameraFileError naming the file; CLI exit 1, one line
* `render_sort_last` with more parts than clusters, an empty mesh or scene → empty parts
  render as background; the frame equals one machine's bit for bit
* `render_views` into a folder made with another size or options → OutDirMismatchError
  listing the differences, before any view (or `overwrite=True`)
* `render_views(cull="sideways")`, a zero-normal plane, `reversed_z="yes"` → one ValueError
  before any view (one machine and Dask)
* `render_shaded(ssaa=k, render_kwargs={"window": w})` → the window scaled by k: the same
  region as ssaa=1
* `depth_image` / `depth_picture` of a reversed-Z frame; a contradicting flag → read by the
  frame's own convention; ValueError
* `Camera.from_pyrender`: orthographic xmag at another aspect; yfov/aspect/xmag/fx ≤ 0, yfov
  ≥ π → pyrender's aspect-corrected xmag; CameraArgumentError naming the attribute
* `Camera.look_at` with an eye 1e300 away; in a camera file → CameraArgumentError /
  ViewError naming eye (overflow), not "must differ" / up
* `from_intrinsics(fx=5e-324)`, projections singular in float32 → CameraArgumentError naming
  the parameter
* a polygon window of 10⁵–10⁶ vertices → validated in O(n log n)
  (tests/test_reliability_clip2d.py)

The cases added with the reliability issue live in tests/test_reliability_*.py (one file per
area: cli, views, dask, shade, camera, clip2d, device) and tests/test_camera_files.py.

A renderer that refused an input still renders correctly afterwards. Threads, fork and leaks:
tests/test_processes.py.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import (
    NDC_CAMERA,
    MatrixCamera,
    assert_frames_equal,
    get_renderer,
    load_shared_mesh,
    perspective,
    render_both,
    render_ref,
)

from clraster import Camera, Mesh, RasterConfig, Renderer
from clraster.pipeline import reference

W, H = 24, 16
GOOD = Mesh([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]], [[0, 1, 2]])


def both_raise(mesh=GOOD, camera=NDC_CAMERA, cull="none", match=None):
    with pytest.raises(ValueError, match=match):
        get_renderer(W, H).render(mesh, camera, cull=cull)
    with pytest.raises(ValueError, match=match):
        reference.render(mesh, camera, W, H, cull=cull)


# --- non-finite vertices: dropped and counted --------------------------------------------

@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("coord", [0, 1, 2])
def test_non_finite_vertices_dropped(bad, coord):
    v = np.array([[-0.9, -0.9, 0], [0.9, -0.9, 0], [0.0, 0.9, 0], [0.2, 0.2, 0.1]])
    v[3, coord] = bad
    mesh = Mesh(v, [[0, 1, 3], [0, 1, 2], [3, 2, 1], [3, 3, 3]])
    a, b = render_both(mesh, NDC_CAMERA, W, H)
    assert_frames_equal(a, b, f"bad={bad} coord={coord}")
    assert a.stats.invalid == 3 and a.stats.rasterized == 1
    assert set(a.visible_faces().tolist()) == {1}
    assert np.isfinite(a.depth).all() and np.isfinite(a.barycentrics).all()


def test_all_vertices_non_finite():
    v = np.full((6, 3), np.nan)
    v[3:] = np.inf
    mesh = Mesh(v, [[0, 1, 2], [3, 4, 5], [0, 4, 2]])
    a, b = render_both(mesh, NDC_CAMERA, W, H)
    assert_frames_equal(a, b, "all NaN")
    assert a.stats.invalid == 3 and not a.mask.any()
    assert (a.depth == 1.0).all()


def test_float32_overflow_is_invalid():
    """Coordinates beyond float32 become ±Inf in the Mesh; finite ones whose clip position
    overflows (1e38 × a projection scale > 1) are invalid too."""
    cam = MatrixCamera(perspective(30.0, W / H, 0.1, 10.0))  # x scale ≈ 2.5
    v = np.array([[0, 0, -1], [1e39, 0, -1], [0, 1, -1], [3e38, 0.5, -1], [0.5, 0, -1]])
    mesh = Mesh(v, [[0, 1, 2], [0, 3, 2], [0, 4, 2]])
    assert np.isinf(mesh.vertices[1, 0]) and np.isfinite(mesh.vertices[3, 0])
    a, b = render_both(mesh, cam, W, H)
    assert_frames_equal(a, b, "overflow")
    assert a.stats.invalid == 2


def test_huge_finite_coordinates_stay_finite():
    """Large but representable clip coordinates go through the guard-band clipper (larger
    ones: see test_clipping.test_huge_finite_triangle_covers_window)."""
    v = np.array([[-1e10, -1e10, 0], [1e10, -1e10, 0], [0, 1e10, 0]])
    a, b = render_both(Mesh(v, [[0, 1, 2]]), NDC_CAMERA, W, H)
    assert_frames_equal(a, b, "huge")
    assert a.stats.invalid == 0 and a.stats.clipped == 1
    assert a.mask.all()
    assert np.isfinite(a.depth).all() and np.isfinite(a.barycentrics).all()


# --- empty input -------------------------------------------------------------------------

@pytest.mark.parametrize("v, f", [([], []), ([[0, 0, 0], [1, 0, 0]], []),
                                  (np.zeros((0, 3)), np.zeros((0, 3), np.int32))])
@pytest.mark.parametrize("cull", ["back", "none"])
def test_empty_mesh_gives_empty_frame(v, f, cull):
    mesh = Mesh(v, f)
    for fr in render_both(mesh, NDC_CAMERA, W, H, cull=cull):
        assert fr.depth.shape == (H, W) and fr.depth.dtype == np.float32
        assert fr.triangle_id.shape == (H, W) and fr.triangle_id.dtype == np.int32
        assert fr.barycentrics.shape == (H, W, 3) and fr.barycentrics.dtype == np.float32
        assert (fr.depth == 1.0).all() and (fr.triangle_id == -1).all()
        assert (fr.barycentrics == 0).all()
        assert fr.stats.triangles_in == 0 and fr.stats.fragments_tested == 0


def test_empty_then_full_then_empty():
    """Device buffers survive an empty frame in between."""
    r = get_renderer(W, H)
    first = r.render(GOOD, NDC_CAMERA, cull="none")
    r.render(Mesh([], []), NDC_CAMERA)
    again = r.render(GOOD, NDC_CAMERA, cull="none")
    assert_frames_equal(first, again, "after empty", bary_atol=0.0, check_counts=True)
    assert first.mask.sum() > 20


def test_frames_are_independent():
    """A returned frame is not changed by later renders with the same renderer."""
    r = get_renderer(W, H)
    a = r.render(GOOD, NDC_CAMERA, cull="none")
    keep = (a.depth.copy(), a.triangle_id.copy(), a.barycentrics.copy())
    other = Mesh([[-1, -1, 0.5], [1, -1, 0.5], [1, 1, 0.5], [-1, 1, 0.5]],
                 [[0, 1, 2], [0, 2, 3]])
    b = r.render(other, NDC_CAMERA, cull="none")
    assert b.mask.all()
    np.testing.assert_array_equal(a.depth, keep[0])
    np.testing.assert_array_equal(a.triangle_id, keep[1])
    np.testing.assert_array_equal(a.barycentrics, keep[2])


# --- malformed meshes --------------------------------------------------------------------

@pytest.mark.parametrize("v, f", [
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]]),  # index == N
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, -1, 2]]),  # negative
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2**40]]),  # beyond int32
    ([[0, 0, 0], [1, 0, 0]], [[0, 1]]),  # faces not (M, 3)
    ([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]]),  # vertices not (N, 3)
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0.0, 1.0, 2.0]]),  # float faces
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[True, False, True]]),  # bool faces
    ([["a", "b", "c"]] * 3, [[0, 1, 2]]),  # string vertices
    (np.zeros((3, 3), complex), [[0, 1, 2]]),  # complex vertices
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [0, 1, 2]),  # 1-D faces
])
def test_mesh_rejects(v, f):
    with pytest.raises(ValueError):
        Mesh(v, f)


@pytest.mark.parametrize("obj", [
    SimpleNamespace(vertices=np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 3]], np.int32)),
    SimpleNamespace(vertices=np.zeros((3, 3), np.float32), faces=np.array([[0, -2, 1]], np.int32)),
    SimpleNamespace(vertices=np.zeros((3, 3), np.float64), faces=np.array([[0, 1, 2]], np.int32)),
    SimpleNamespace(vertices=np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 2]], np.int64)),
    SimpleNamespace(vertices=np.zeros((3, 4), np.float32), faces=np.array([[0, 1, 2]], np.int32)),
    SimpleNamespace(vertices=np.zeros(9, np.float32), faces=np.array([[0, 1, 2]], np.int32)),
    "not a mesh",
    None,
])
def test_renderers_reject_non_meshes(obj):
    """Mesh-like objects are checked before anything reaches the kernels (an index out of
    range would be an out-of-bounds device read)."""
    both_raise(mesh=obj)


# --- sizes, cameras, cull modes, config --------------------------------------------------

@pytest.mark.parametrize("w, h", [(0, 10), (10, 0), (-5, 10), (16385, 8), (8, 16385),
                                  (10.0, 10), (10, 10.5), ("10", 10), (True, 10), (None, 10)])
def test_bad_sizes(w, h):
    with pytest.raises(ValueError):
        Renderer(w, h)
    with pytest.raises(ValueError):
        reference.render(GOOD, NDC_CAMERA, w, h)


def test_size_limits_accepted():
    for w, h in ((1, 1), (1, 7), (np.int64(5), np.int32(3))):
        a, b = render_both(GOOD, NDC_CAMERA, int(w), int(h))
        assert_frames_equal(a, b, f"{w}x{h}")
        assert a.depth.shape == (int(h), int(w))
    r = Renderer(np.int64(5), np.int32(3))
    assert r.render(GOOD, NDC_CAMERA, cull="none").depth.shape == (3, 5)


@pytest.mark.parametrize("kw", [dict(near=0.0), dict(near=-1.0), dict(near=2.0, far=2.0),
                                dict(near=2.0, far=1.0), dict(fov_y=0.0), dict(fov_y=180.0),
                                dict(fov_y=-10.0), dict(fov_y=200.0), dict(near=math.nan),
                                dict(far=math.inf), dict(fov_y="wide")])
def test_bad_lens(kw):
    with pytest.raises(ValueError):
        Camera.look_at((0, 0, 3), (0, 0, 0), **kw)


@pytest.mark.parametrize("cam", [
    MatrixCamera(np.full((4, 4), np.nan)),
    MatrixCamera(np.eye(3)),
    MatrixCamera(np.diag([1e39, 1.0, 1.0, 1.0])),  # finite in float64, not in float32
    SimpleNamespace(),  # no view_projection
    "camera",
])
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_bad_cameras(cam):
    both_raise(camera=cam)


@pytest.mark.parametrize("cull", ["BACK", "Back", "cw", "", None, 1, "both"])
def test_bad_cull(cull):
    both_raise(cull=cull)


@pytest.mark.parametrize("t", [2, 7, -1])
def test_bad_tile_size(t):
    with pytest.raises(ValueError):
        RasterConfig(tile_log2=t)


def test_renderer_still_good_after_errors():
    r = get_renderer(W, H)
    for bad in (dict(cull="sideways"), dict(camera="x"), dict(mesh=None)):
        args = dict(mesh=GOOD, camera=NDC_CAMERA, cull="none") | bad
        with pytest.raises(ValueError):
            r.render(args["mesh"], args["camera"], cull=args["cull"])
    a = r.render(GOOD, NDC_CAMERA, cull="none")
    assert_frames_equal(a, render_ref(GOOD, NDC_CAMERA, W, H), "after errors")
    assert a.mask.sum() > 20


# --- options that must be booleans ---------------------------------------------------------

@pytest.mark.parametrize("kw", [dict(occlusion="no"), dict(frustum=1), dict(cones=None),
                                dict(overdraw="yes"), dict(fates=[])])
def test_flags_must_be_bool(kw):
    (name,) = kw
    with pytest.raises(ValueError, match=f"{name} must be True or False"):
        get_renderer(W, H).render(GOOD, NDC_CAMERA, cull="none", **kw)


@pytest.mark.parametrize("cull", [[], {}, ("back",)])
def test_unhashable_cull(cull):
    both_raise(cull=cull, match="cull must be one of")


# --- files with no triangle ----------------------------------------------------------------

def _no_triangle_files(tmp_path):
    import trimesh

    pts = np.random.default_rng(0).random((10, 3))
    files = {}
    files["points.ply"] = tmp_path / "points.ply"
    trimesh.PointCloud(pts).export(files["points.ply"])
    files["lines.obj"] = tmp_path / "lines.obj"
    files["lines.obj"].write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2\nl 2 3\n")
    files["line.dxf"] = tmp_path / "line.dxf"
    files["line.dxf"].write_text("0\nSECTION\n2\nENTITIES\n0\nLINE\n8\n0\n10\n0.0\n20\n0.0\n"
                                 "30\n0.0\n11\n1.0\n21\n1.0\n31\n0.0\n0\nENDSEC\n0\nEOF\n")
    files["points.glb"] = tmp_path / "points.glb"
    trimesh.Scene([trimesh.PointCloud(pts)]).export(files["points.glb"])
    return files


@pytest.mark.parametrize("name", ["points.ply", "lines.obj", "line.dxf", "points.glb"])
def test_load_file_without_triangles(tmp_path, name):
    from clraster.world.scene import Scene

    path = _no_triangle_files(tmp_path)[name]
    with pytest.raises(ValueError, match="holds no triangle"):
        Mesh.load(path)
    with pytest.raises(ValueError, match="holds no triangle"):
        Scene.load(path)


def test_cli_file_without_triangles_writes_nothing(tmp_path, capsys):
    from clraster.cli import main

    path = _no_triangle_files(tmp_path)["points.ply"]
    out = tmp_path / "x.png"
    rc = main(["render", str(path), "--size", "32x24", "--out", str(out),
               "--eye", "0,0,3", "--target", "0,0,0"])
    assert rc == 1 and not out.exists()
    err = capsys.readouterr().err
    assert "holds no triangles" in err and "camera" not in err


def test_gltf_node_scaled_to_zero_is_skipped(tmp_path):
    import trimesh

    from clraster.world.scene import Scene, SceneWarning

    box = trimesh.creation.box()
    tms = trimesh.Scene()
    tms.add_geometry(box, node_name="shown", geom_name="box")
    hide = np.diag([0.0, 0.0, 0.0, 1.0])
    hide[:3, 3] = (5.0, 0.0, 0.0)
    tms.add_geometry(box, node_name="hidden", geom_name="box", transform=hide)
    path = tmp_path / "hidden.glb"
    tms.export(path)
    with pytest.warns(SceneWarning, match="scaled to zero.*hidden"):
        scene = Scene.load(path)
    assert scene.n_instances == 1
    cam = Camera.look_at((3, 2, 4), (0, 0, 0), near=0.1, far=20)
    a = get_renderer(W, H).render(scene, cam)
    b = get_renderer(W, H).render(Mesh.from_trimesh(box), cam)
    np.testing.assert_array_equal(a.triangle_id, b.triangle_id)
    assert a.mask.sum() > 10


# --- far from the origin -------------------------------------------------------------------

PYRAMID_V = np.array([[-10, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10], [0, 8, 0]],
                     np.float64)
PYRAMID_F = [[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]


@pytest.mark.parametrize("offset", [(4.5e5, 12.0, 5.3e6), (-2e7, 0.0, 3e6), (1e6, 1e6, 1e6)])
def test_camera_far_from_origin(offset):
    """Georeferenced coordinates (UTM: ~1e6 m) used to be refused as "not invertible"; the
    image must match the same scene centred at the origin: the same ids, depth within 1e-6
    (the far-off vertices here are exact in float32)."""
    o = np.array(offset)
    cam = Camera.look_at(o + (30, 20, 30), o + (0, 2, 0), near=0.5, far=500)
    np.testing.assert_allclose(cam.eye, o + (30, 20, 30), rtol=0, atol=1e-6)
    view = cam.view.copy()
    same = Camera.from_matrices(view, cam.projection(W, H))   # a rigid view, raw matrices
    np.testing.assert_allclose(same.eye, cam.eye, rtol=0, atol=1e-6)
    r = get_renderer(64, 48)
    far = r.render(Mesh(PYRAMID_V + o, PYRAMID_F), cam)
    near = r.render(Mesh(PYRAMID_V, PYRAMID_F),
                    Camera.look_at((30, 20, 30), (0, 2, 0), near=0.5, far=500))
    assert near.mask.sum() > 200
    # exact since the pool stores a far-off mesh relative to its centre (camera-relative
    # rendering: the 1e6 offsets cancel in float64); it was > 97% of pixels before
    np.testing.assert_array_equal(far.triangle_id, near.triangle_id)
    np.testing.assert_allclose(far.depth, near.depth, rtol=0, atol=1e-6)


def test_singular_view_still_refused():
    with pytest.raises(ValueError, match="not invertible"):
        Camera.from_matrices(np.diag([1.0, 1.0, 0.0, 1.0]), np.eye(4))


# --- float32 limits: scale-invariant where possible, a warning where not -----------------

def test_extreme_scales_render_like_unit_scale():
    """The facing determinant is homogeneous: scaling the scene (or the projection) must not
    change the image; in float32 the raw triple product underflowed at 1e-15 (5,711 of 5,856
    faces "degenerate") and overflowed for a projection × 1e13."""
    spot = load_shared_mesh("spot.ply")
    w, h = 96, 72
    lo, hi = spot.bounds()
    base_cam = Camera.framing(lo, hi, aspect=w / h)
    base = render_both(spot, base_cam, w, h, cull="back")
    assert base[0].mask.sum() > 500
    small = Mesh(spot.vertices.astype(np.float64) * 1e-15, spot.faces)
    cam = Camera.framing(lo * 1e-15, hi * 1e-15, aspect=w / h)
    for fr in render_both(small, cam, w, h, cull="back"):
        assert fr.stats.degenerate == base[0].stats.degenerate
        np.testing.assert_array_equal(fr.triangle_id, base[0].triangle_id)
    vp = base_cam.view_projection(w, h)
    for k in (1e13, 1e-13, 1e30):
        for fr in render_both(spot, MatrixCamera(vp * k), w, h, cull="back"):
            np.testing.assert_array_equal(fr.triangle_id, base[0].triangle_id)


@pytest.mark.parametrize("near, far", [(1e-30, 100.0), (1e-7, 1e7)])
def test_depth_collapse_warns(near, far):
    from clraster.world.precision import PrecisionWarning

    spot = load_shared_mesh("spot.ply")
    cam = Camera.look_at((1.5, 1.0, 2.5), (0, 0.1, 0), near=near, far=far)
    with pytest.warns(PrecisionWarning, match="larger near plane"):
        get_renderer(W, H).render(spot, cam)
    with pytest.warns(PrecisionWarning, match="larger near plane"):
        reference.render(spot, cam, W, H)


@pytest.mark.filterwarnings("error::UserWarning")
@pytest.mark.parametrize("near, far", [(0.1, 100.0), (1e-3, 1e5), (1e-5, 10.0)])
def test_ordinary_depth_range_does_not_warn(near, far):
    spot = load_shared_mesh("spot.ply")
    cam = Camera.look_at((1.5, 1.0, 2.5), (0, 0.1, 0), near=near, far=far)
    assert get_renderer(W, H).render(spot, cam).mask.any()


# --- device selection ----------------------------------------------------------------------

def _device_probe(env_value: str) -> subprocess.CompletedProcess:
    code = ("import warnings, sys\n"
            "warnings.simplefilter('always')\n"
            "from clraster.pipeline.device import default_context\n"
            "try:\n"
            "    print(default_context().devices[0].platform.name)\n"
            "except Exception as e:\n"
            "    print(type(e).__name__, e); sys.exit(3)\n")
    env = dict(os.environ, PYOPENCL_CTX=env_value)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=120, cwd=Path(__file__).resolve().parents[1])


def test_pyopencl_ctx_selecting_simulator_warns():
    import pyopencl as cl

    names = [p.name for p in cl.get_platforms()]
    idx = [i for i, n in enumerate(names) if "oclgrind" in n.lower()]
    if not idx:
        pytest.skip("Oclgrind is not installed")
    res = _device_probe(str(idx[0]))
    assert res.returncode == 0, res.stderr
    assert "SimulatorWarning" in res.stderr and "1000x slower" in res.stderr


def test_pyopencl_ctx_garbage_names_the_platforms():
    res = _device_probe("no-such-platform:7")
    assert res.returncode == 3
    assert "NoDeviceError" in res.stdout and "platforms here are" in res.stdout
    assert "Zen" not in res.stdout   # the unrelated LLVM hint is gone


# --- command line: output paths and errors ----------------------------------------------------

@pytest.mark.parametrize("extra, what", [
    # the extension names the format (clraster.outputs): none, or one that names no format
    (["--ids", "{d}/ids"], "missing file extension"),
    (["--depth", "{d}/depth.txt"], "unknown or missing file extension"),
    (["--ids", "{d}"], "is a folder"),
    (["--depth", "{d}/missing/depth.npy"], "does not exist"),
])
def test_cli_output_paths_checked_before_rendering(tmp_path, capsys, extra, what):
    from clraster.cli import main

    out = tmp_path / "x.png"
    args = ["render", "example", "--size", "32x24", "--out", str(out)]
    rc = main(args + [e.format(d=tmp_path) for e in extra])
    err = capsys.readouterr().err
    assert rc == 1 and what in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_cli_out_without_extension(tmp_path, capsys):
    from clraster.cli import main

    rc = main(["render", "example", "--size", "32x24", "--out", str(tmp_path / "image")])
    assert rc == 1 and "no file extension" in capsys.readouterr().err


def test_cli_npy_written_where_told(tmp_path):
    from clraster.cli import main

    ids, depth = tmp_path / "ids.npy", tmp_path / "d.NPY"
    assert main(["render", "example", "--size", "32x24", "--out", str(tmp_path / "x.png"),
                 "--ids", str(ids), "--depth", str(depth)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.NPY", "ids.npy", "x.png"]
    assert np.load(ids).shape == (24, 32) and np.load(depth).dtype == np.float32


def test_cli_memory_error_is_one_line(monkeypatch, capsys):
    """Out of memory (host or a device buffer past its limit) is a message, not a
    traceback; MemoryError is what GrowBuffer raises for an oversized device buffer."""
    from clraster import cli
    from clraster.pipeline.renderer import Renderer

    def oom(*_a, **_k):
        raise MemoryError("this frame needs a 5,063 MiB bin list")

    monkeypatch.setattr(Renderer, "render", oom)
    rc = cli.main(["render", "example", "--size", "32x24", "--out", "/tmp/unused.png"])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1 and "5,063 MiB" in err and "--size" in err
