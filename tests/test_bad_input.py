"""Bad input: non-finite geometry is dropped and counted (never an exception), malformed
arguments raise ValueError with the same behaviour in the OpenCL renderer and the twin, and
a renderer that refused an input still renders correctly afterwards.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import (
    NDC_CAMERA,
    MatrixCamera,
    assert_frames_equal,
    get_renderer,
    perspective,
    render_both,
    render_ref,
)

from clraster import Camera, Mesh, RasterConfig, Renderer, reference

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
