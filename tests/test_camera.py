"""Camera: OpenGL conventions (right-handed, looks down −Z, gluPerspective clip space)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clraster.world.camera import Camera, look_at_matrix, perspective_matrix


def project(m: np.ndarray, p) -> np.ndarray:
    """World point → NDC (x, y, z) through a 4×4 view-projection."""
    clip = m @ np.append(np.asarray(p, dtype=np.float64), 1.0)
    return clip[:3] / clip[3]


def to_window(ndc: np.ndarray, width: int, height: int) -> tuple[float, float]:
    """NDC → window pixels, row 0 at the top (the renderer's convention)."""
    return (ndc[0] + 1) / 2 * width, (1 - ndc[1]) / 2 * height


# A camera off the axes, so a swapped or flipped axis changes the numbers.
EYE = np.array([1.0, 2.0, 5.0])
TARGET = np.array([0.5, -0.25, 0.0])
UP = np.array([0.0, 1.0, 0.0])


@pytest.fixture
def cam() -> Camera:
    return Camera.look_at(EYE, TARGET, UP, fov_y=60.0, near=0.5, far=50.0)


def test_near_far_map_to_ndc_minus_one_plus_one(cam):
    vp = cam.view_projection(640, 480)
    fwd = (TARGET - EYE) / np.linalg.norm(TARGET - EYE)
    assert project(vp, EYE + 0.5 * fwd)[2] == pytest.approx(-1.0, abs=1e-12)
    assert project(vp, EYE + 50.0 * fwd)[2] == pytest.approx(1.0, abs=1e-9)
    # Window depth (z/w + 1) / 2 grows with distance.
    z = [project(vp, EYE + d * fwd)[2] for d in (0.5, 1, 2, 10, 50)]
    assert np.all(np.diff(z) > 0)


def test_eye_space_near_far():
    p = perspective_matrix(45.0, 1.5, 0.1, 100.0)
    for z_eye, ndc in ((-0.1, -1.0), (-100.0, 1.0)):
        clip = p @ np.array([0.0, 0.0, z_eye, 1.0])
        assert clip[3] == pytest.approx(-z_eye)  # w = distance in front of the eye
        assert clip[2] / clip[3] == pytest.approx(ndc, abs=1e-9)


@pytest.mark.parametrize("size", [(640, 480), (101, 333)])
def test_view_axis_projects_to_window_centre(cam, size):
    w, h = size
    vp = cam.view_projection(w, h)
    for d in (0.7, 3.0, 20.0):
        p = EYE + d * (TARGET - EYE) / np.linalg.norm(TARGET - EYE)
        x, y = to_window(project(vp, p), w, h)
        assert (x, y) == (pytest.approx(w / 2), pytest.approx(h / 2))


def test_look_at_axes():
    # Looking down −Z from +Z with +Y up: world axes are the eye axes.
    v = look_at_matrix((0, 0, 3), (0, 0, 0), (0, 1, 0))
    np.testing.assert_allclose(v[:3, :3], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(v[:3, 3], [0, 0, -3])
    # Looking down −X: world −Z is the camera's right, world +Y its up.
    cam = Camera.look_at((5, 0, 0), (0, 0, 0), (0, 1, 0))
    v = cam.view
    np.testing.assert_allclose(v[0, :3], [0, 0, -1], atol=1e-15)  # right
    np.testing.assert_allclose(v[1, :3], [0, 1, 0], atol=1e-15)  # up
    np.testing.assert_allclose(v[2, :3], [1, 0, 0], atol=1e-15)  # backward (+Z eye)
    # A point right of and above the target lands right of and above the window centre.
    x, y = to_window(project(cam.view_projection(200, 100), (0, 0.5, -0.5)), 200, 100)
    assert x > 100 and y < 50


def test_look_at_view_is_rigid(cam):
    r = cam.view[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)  # right-handed: no mirror
    np.testing.assert_allclose(cam.eye, EYE)
    np.testing.assert_allclose(cam.view @ np.append(EYE, 1), [0, 0, 0, 1], atol=1e-12)


def test_up_need_not_be_orthogonal():
    a = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0)).view
    b = Camera.look_at((0, 0, 3), (0, 0, 0), (0, 7, -2)).view
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_aspect_from_image(cam):
    # Vertical field of view is fixed; horizontal scale follows width / height.
    p1 = cam.projection(100, 100)
    p2 = cam.projection(200, 100)
    assert p1[1, 1] == pytest.approx(1 / math.tan(math.radians(30)))
    assert p2[1, 1] == p1[1, 1]
    assert p2[0, 0] == pytest.approx(p1[0, 0] / 2)


def test_matches_glu_formula():
    f = 1 / math.tan(math.radians(45) / 2)
    n, fa, a = 0.1, 100.0, 16 / 9
    expected = np.array([[f / a, 0, 0, 0], [0, f, 0, 0],
                         [0, 0, (fa + n) / (n - fa), 2 * fa * n / (n - fa)], [0, 0, -1, 0]])
    np.testing.assert_allclose(perspective_matrix(45, a, n, fa), expected)


def test_from_matrices_round_trip(cam):
    proj = cam.projection(320, 240)
    c2 = Camera.from_matrices(cam.view, proj)
    np.testing.assert_allclose(c2.view_projection(320, 240), cam.view_projection(320, 240))
    # The projection is used unchanged whatever the image size.
    np.testing.assert_array_equal(c2.view_projection(999, 17), proj @ cam.view)
    np.testing.assert_allclose(c2.eye, EYE, atol=1e-12)
    assert c2.fov_y is None and c2.near is None and c2.far is None


def test_matrices_are_read_only_copies(cam):
    view = np.array(cam.view)
    c2 = Camera.from_matrices(view, np.eye(4))
    view[0, 0] = 42.0
    assert c2.view[0, 0] != 42.0
    with pytest.raises(ValueError):
        c2.view[0, 0] = 1.0
    with pytest.raises(ValueError):
        cam.eye[0] = 1.0
    eye = np.array(EYE)
    Camera.look_at(eye, TARGET, UP)
    np.testing.assert_array_equal(eye, EYE)  # caller's array untouched


@pytest.mark.parametrize("size", [(1, 1), (1920, 1080), (7, 300)])
def test_framing_contains_box(size):
    lo, hi = np.array([-1.0, 2.0, 10.0]), np.array([3.0, 2.5, 14.0])
    w, h = size
    cam = Camera.framing(lo, hi, aspect=w / h)
    vp = cam.view_projection(w, h)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    for c in corners:
        ndc = project(vp, c)
        assert np.all(np.abs(ndc) < 1.0), (c, ndc)
    centre = to_window(project(vp, (lo + hi) / 2), w, h)
    assert centre == (pytest.approx(w / 2), pytest.approx(h / 2))


@pytest.mark.parametrize("direction", [(0, 1, 0), (0, -2, 0), (1, 0, 0)])
def test_framing_any_direction(direction):
    cam = Camera.framing((0, 0, 0), (1, 1, 1), direction=direction)
    d = np.asarray(direction, dtype=float)
    np.testing.assert_allclose(np.cross(cam.eye - 0.5, d), 0, atol=1e-9)


def test_framing_point_box():
    cam = Camera.framing((1, 1, 1), (1, 1, 1))
    ndc = project(cam.view_projection(10, 10), (1, 1, 1))
    np.testing.assert_allclose(ndc[:2], 0, atol=1e-9)
    assert -1 < ndc[2] < 1


NAN3 = (0.0, math.nan, 0.0)
INF3 = (math.inf, 0.0, 0.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(eye=NAN3), "eye must be finite"),
    (dict(target=INF3), "target must be finite"),
    (dict(up=(0, math.nan, 1)), "up must be finite"),
    (dict(eye=(0, 0)), r"eye must have shape \(3,\)"),
    (dict(target=[[0, 0, 0]]), r"target must have shape \(3,\)"),
    (dict(up="abc"), "up must be"),
    (dict(eye=(1j, 0, 0)), "eye must be"),
    (dict(eye=(0, 0, 0)), "eye and target must differ"),
    (dict(up=(0, 0, 0)), "up must be a non-zero"),
    (dict(up=(0, 0, -5)), "parallel to the view direction"),
    (dict(near=0.0), "near must be > 0"),
    (dict(near=-1.0), "near must be > 0"),
    (dict(near=2.0, far=2.0), "far must be > near"),
    (dict(near=2.0, far=1.0), "far must be > near"),
    (dict(fov_y=0.0), r"fov_y .* \(0, 180\)"),
    (dict(fov_y=180.0), r"fov_y .* \(0, 180\)"),
    (dict(fov_y=-10.0), r"fov_y .* \(0, 180\)"),
    (dict(fov_y=math.nan), "fov_y must be finite"),
    (dict(far=math.inf), "far must be finite"),
])
def test_look_at_validation(kwargs, match):
    args = dict(eye=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Camera.look_at(**args)


def test_from_matrices_validation():
    good = np.eye(4)
    with pytest.raises(ValueError, match=r"view must have shape \(4, 4\)"):
        Camera.from_matrices(np.eye(3), good)
    with pytest.raises(ValueError, match=r"projection must have shape \(4, 4\)"):
        Camera.from_matrices(good, np.eye(4)[:3])
    bad = np.eye(4)
    bad[1, 2] = math.nan
    with pytest.raises(ValueError, match="view must be finite"):
        Camera.from_matrices(bad, good)
    with pytest.raises(ValueError, match="projection must be finite"):
        Camera.from_matrices(good, bad)
    singular = np.eye(4)
    singular[2] = singular[1]
    with pytest.raises(ValueError, match="not invertible"):
        Camera.from_matrices(singular, good)
    with pytest.raises(ValueError, match="not invertible"):
        Camera.from_matrices(np.zeros((4, 4)), good)


@pytest.mark.parametrize("size", [(0, 10), (10, -1), (10.0, 10), (True, 5)])
def test_view_projection_size_validation(size):
    with pytest.raises(ValueError, match="(width|height) must be (an integer|in 1..16384)"):
        Camera.look_at((0, 0, 3), (0, 0, 0), (0, 1, 0)).view_projection(*size)


def test_framing_validation():
    with pytest.raises(ValueError, match="bounds_min"):
        Camera.framing((1, 0, 0), (0, 1, 1))
    with pytest.raises(ValueError, match="direction must be a non-zero"):
        Camera.framing((0, 0, 0), (1, 1, 1), direction=(0, 0, 0))
    with pytest.raises(ValueError, match="aspect"):
        Camera.framing((0, 0, 0), (1, 1, 1), aspect=0.0)
    with pytest.raises(ValueError, match="bounds_max must be finite"):
        Camera.framing((0, 0, 0), (1, math.inf, 1))
