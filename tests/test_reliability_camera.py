"""Camera reliability: pyrender's projections and their parameters, projections that are not
invertible (in float64 or in the renderer's float32), overflow in look_at named as overflow
of the right argument, and camera files JSON cannot read (deep nesting, not UTF-8)."""

from __future__ import annotations

import json
import math
import pickle
from types import SimpleNamespace

import numpy as np
import pytest

from clraster import Camera
from clraster.cli import main
from clraster.world.camera import CameraArgumentError, intrinsics_projection, look_at_matrix
from clraster.world.views import (
    BrokenCamera,
    CameraFileError,
    ViewError,
    iter_cameras,
    load_cameras,
)


def perspective(fov_y=None, znear=0.1, zfar=10.0, aspect_ratio=None, **kw):
    """pyrender.PerspectiveCamera's attributes (pyrender is not installed)."""
    return SimpleNamespace(yfov=1.0 if fov_y is None else fov_y, znear=znear, zfar=zfar,
                           aspectRatio=aspect_ratio, **kw)


def orthographic(xmag=1.0, ymag=1.0, znear=0.1, zfar=10.0):
    """pyrender.OrthographicCamera's attributes."""
    return SimpleNamespace(xmag=xmag, ymag=ymag, znear=znear, zfar=zfar)


def intrinsics(fx=60.0, fy=55.0, cx=32.0, cy=24.0, znear=0.1, zfar=10.0):
    """pyrender.IntrinsicsCamera's attributes."""
    return SimpleNamespace(fx=fx, fy=fy, cx=cx, cy=cy, znear=znear, zfar=zfar)


def k_matrix(fx=100.0, fy=100.0):
    return np.array([[fx, 0.0, 31.5], [0.0, fy, 23.5], [0.0, 0.0, 1.0]])


# --- item 5: pyrender adapter ----------------------------------------------------------------

def test_pyrender_orthographic_xmag_follows_the_viewport():
    """pyrender's renderer calls get_projection_matrix(width, height), which replaces xmag by
    width / height · ymag (pyrender/camera.py, OrthographicCamera): xmag = ymag = 1 at
    640×480 renders with P[0, 0] = 1 / (640/480) = 0.75, not 1 / xmag."""
    w, h = 640, 480
    cam = Camera.from_pyrender(orthographic(1.0, 1.0), np.eye(4), w, h)
    p = cam.projection(w, h)
    assert p[0, 0] == pytest.approx(h / w)
    assert p[1, 1] == pytest.approx(1.0)
    # xmag does not matter, as in pyrender's renderer
    other = Camera.from_pyrender(orthographic(7.0, 1.0), np.eye(4), w, h)
    np.testing.assert_array_equal(other.projection(w, h), p)
    # the view is ymag high and square pixels make it ymag · W/H wide: its corner (eye
    # space) lands on clip (1, 1)
    ymag = 1.5
    cam = Camera.from_pyrender(orthographic(1.0, ymag, 0.1, 10.0), np.eye(4), w, h)
    clip = cam.projection(w, h) @ [ymag * w / h, ymag, -10.0, 1.0]
    np.testing.assert_allclose(clip, [1.0, 1.0, 1.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("camera, name, match", [
    (perspective(0.0), "yfov", r"yfov .*radians.*\(0, π\), got 0\.0"),
    (perspective(-0.5), "yfov", r"\(0, π\), got -0\.5"),
    (perspective(4.0), "yfov", r"\(0, π\), got 4\.0.*radians"),
    (perspective(60.0), "yfov", r"degrees\? pyrender's yfov is in radians"),
    (perspective(1.0, aspect_ratio=0.0), "aspectRatio", r"aspectRatio .*> 0, got 0\.0"),
    (perspective(1.0, aspect_ratio=-1.5), "aspectRatio", r"> 0, got -1\.5"),
    (perspective(1.0, aspect_ratio=math.nan), "aspectRatio", "aspectRatio must be finite"),
    (orthographic(xmag=0.0), "xmag", r"xmag .*> 0, got 0\.0"),
    (orthographic(xmag=-1.0), "xmag", r"> 0, got -1\.0"),
    (orthographic(ymag=0.0), "ymag", r"ymag .*> 0, got 0\.0"),
    (orthographic(ymag=-2.0), "ymag", r"> 0, got -2\.0"),
    (intrinsics(fx=0.0), "fx", r"fx .*focal length.*> 0, got 0\.0"),
    (intrinsics(fx=-60.0), "fx", r"> 0, got -60\.0"),
    (intrinsics(fy=-1.0), "fy", r"fy .*> 0, got -1\.0"),
    (intrinsics(cx=math.inf), "cx", r"cx must be finite, got inf"),
    (intrinsics(cy="middle"), "cy", r"cy must be a real number, got 'middle'"),
    (intrinsics(zfar=0.05), "zfar", r"zfar must be > znear .*znear=0\.1, zfar=0\.05"),
], ids=lambda v: v if isinstance(v, str) and len(v) < 12 else None)
def test_pyrender_parameters_are_validated_by_name(camera, name, match):
    """Each of these raised ZeroDivisionError or made a mirrored / collapsed projection."""
    with pytest.raises(CameraArgumentError, match=match) as info:
        Camera.from_pyrender(camera, np.eye(4), 64, 48)
    assert info.value.argument == name
    assert name in str(info.value)


@pytest.mark.parametrize("camera, name", [
    (intrinsics(fx=5e-324), "fx"),           # P[0, 0] = 0: a blank frame
    (intrinsics(fy=1e300), "fy"),            # beyond float32
    (perspective(5e-324), "yfov"),           # tan(yfov/2) = 0: was ZeroDivisionError
    (perspective(1e-30), "yfov"),            # scale 2e30: rounding decides the image
    (orthographic(ymag=1e300), "ymag"),      # 1e-300: flushes to zero in float32
    (perspective(1.0, aspect_ratio=1e-320), "aspectRatio"),
], ids=["fx-tiny", "fy-huge", "yfov-denormal", "yfov-tiny", "ymag-huge", "aspect-tiny"])
def test_pyrender_degenerate_projection_refused(camera, name):
    with pytest.raises(CameraArgumentError, match=rf"projection .* set by {name}") as info:
        Camera.from_pyrender(camera, np.eye(4), 64, 48)
    assert info.value.argument == name


# --- item 14: projections that are not invertible ---------------------------------------------

@pytest.mark.parametrize("kwargs, name", [
    (dict(K=k_matrix(fx=5e-324)), "fx"),     # 2·fx/W underflows to 0: singular
    (dict(K=k_matrix(fx=1e-40)), "fx"),      # a float32 denormal: flushed on the device
    (dict(K=k_matrix(fy=1e-300)), "fy"),
    (dict(K=k_matrix(fx=1e308)), "fx"),      # 2·fx overflows float64
    (dict(K=k_matrix(fy=1e40)), "fy"),       # beyond float32
    (dict(near=1e-300, far=10.0), "near"),   # the depth entry flushes to zero in float32
    (dict(near=1.0, far=1.0 + 2.0 ** -52), "far"),   # near == far but for one ulp
], ids=["fx-5e-324", "fx-1e-40", "fy-1e-300", "fx-1e308", "fy-1e40", "near", "far"])
def test_from_intrinsics_refuses_a_singular_projection(kwargs, name):
    args = dict(K=k_matrix(), width=64, height=48, near=0.1, far=10.0)
    args.update(kwargs)
    with pytest.raises(CameraArgumentError, match=rf"set by {name}") as info:
        Camera.from_intrinsics(**args)
    assert info.value.argument == name
    with pytest.raises(CameraArgumentError):
        intrinsics_projection(args["K"], 64, 48, args["near"], args["far"])


def test_from_trimesh_refuses_a_singular_projection():
    stand_in = SimpleNamespace(fov=(1e-20, 45.0), resolution=(64, 48), z_near=0.1, z_far=10.0)
    with pytest.raises(CameraArgumentError, match="fov_x") as info:
        Camera.from_trimesh(stand_in)
    assert info.value.argument == "fov_x"


@pytest.mark.parametrize("kwargs, name", [
    (dict(fov_y=1e-20), "fov_y"),            # scale 1e22: rounding decides the image
    (dict(fov_y=5e-324), "fov_y"),           # tan(fov_y/2) = 0: was ZeroDivisionError later
    (dict(near=1e200, far=1e201), "near"),   # 2·far·near overflows float64
    (dict(near=1e-300, far=1.0), "near"),    # flushes to zero in float32
])
def test_look_at_refuses_a_lens_it_cannot_render(kwargs, name):
    with pytest.raises(CameraArgumentError) as info:
        Camera.look_at((0, 0, 3), (0, 0, 0), **kwargs)
    assert info.value.argument == name


def test_invertibility_does_not_depend_on_units():
    """The same camera in units 1e17 times smaller or larger (near 1e-18 or 1e16) is as
    invertible: only P's translation column changes. A camera file's matrices (and a
    from_intrinsics camera in a camera list) were refused as singular for it."""
    for near, far in ((1e16, 1e20), (1e-18, 1e-14)):
        cam = Camera.from_intrinsics(k_matrix(), 64, 48, near=near, far=far)
        (_, got), = iter_cameras([cam], 64, 48)
        assert got is cam
        entry = {"view": np.eye(4).tolist(), "projection": cam.projection(64, 48).tolist()}
        (_, got), = iter_cameras([entry], 64, 48)
        assert isinstance(got, Camera)
    # framing a box of size 1e-15 (near ~1e-16) still makes a camera
    assert Camera.framing((0, 0, 0), (1e-15, 1e-15, 1e-15)).near < 1e-14


def test_camera_file_projection_singular_in_float32(tmp_path):
    """A projection scaled by 1e-40 is invertible in float64 but every entry is a float32
    denormal: refused with the field named, not a blank frame."""
    proj = Camera.from_intrinsics(k_matrix(), 64, 48, near=0.1, far=10.0).projection(64, 48)
    f = tmp_path / "cams.json"
    f.write_text(json.dumps([{"view": np.eye(4).tolist(), "projection": (proj * 1e-40).tolist()}]))
    with pytest.raises(ViewError, match="float32") as info:
        load_cameras(f)
    assert (info.value.index, info.value.field) == (0, "projection")


# --- item 13: overflow named as overflow, of the right argument --------------------------------

def test_look_at_far_eye_is_an_overflow_of_eye():
    with pytest.raises(CameraArgumentError) as info:
        Camera.look_at((1e300, 1e300, 1e300), (0, 0, 0))
    msg = str(info.value)
    assert info.value.argument == "eye"
    assert "overflows" in msg and "must differ" not in msg
    assert pickle.loads(pickle.dumps(info.value)).argument == "eye"


@pytest.mark.parametrize("eye, target, name", [
    ((-1e308, 0, 0), (1e308, 0, 0), "eye"),                # target − eye is inf
    ((-1e308, 0, 0), (1.5e308, 0, 0), "target"),           # the farther one is named
    ((1.7e308,) * 3, (1.6e308,) * 3, "eye"),               # −R·eye is inf
])
def test_look_at_matrix_overflow_names_the_argument(eye, target, name):
    with pytest.raises(CameraArgumentError, match=rf"{name} .*overflows") as info:
        look_at_matrix(eye, target, (0, 1, 0))
    assert info.value.argument == name
    assert "must differ" not in str(info.value)


def test_look_at_lengths_do_not_matter():
    """Only directions matter: a target 1e-320 or 1e300 (or 1.7e308 per axis) away, an up
    of 1e200 or 1e-320, were "eye and target must differ", "up ... parallel" or "up must be
    non-zero"."""
    ref = look_at_matrix((0, 0, 0), (1, 1, 1), (0, 1, 0))
    for far in (1e300, 1.7e308):
        np.testing.assert_allclose(look_at_matrix((0, 0, 0), (far, far, far), (0, 1, 0)),
                                   ref, atol=1e-15)
    np.testing.assert_allclose(look_at_matrix((0, 0, 0), (1e-320, 1e-320, 1e-320), (0, 1, 0)),
                               ref, atol=1e-15)
    ref = look_at_matrix((0, 0, 3), (0, 0, 0), (0, 1, 0))
    for up in ((0, 1e200, 0), (0, 1e-320, 0)):
        np.testing.assert_allclose(look_at_matrix((0, 0, 3), (0, 0, 0), up), ref, atol=1e-15)
    cam = Camera.look_at((0, 0, 0), (1e300, 1e300, 1e300))
    np.testing.assert_allclose(cam.view[:3, :3], look_at_matrix((0, 0, 0), (1, 1, 1),
                                                                (0, 1, 0))[:3, :3], atol=1e-15)


@pytest.mark.parametrize("entry, field", [
    ({"eye": [1e300, 1e300, 1e300], "target": [0, 0, 0]}, "eye"),
    ({"eye": [-1e308, 0, 0], "target": [1.5e308, 0, 0]}, "target"),
    ({"eye": [0, 0, 3], "target": [0, 0, 0], "fov_y": 1e-20}, "fov_y"),
    ({"eye": [0, 0, 3], "target": [0, 0, 0], "near": 1e200, "far": 1e201}, "near"),
])
def test_camera_file_blames_the_field_that_overflowed(tmp_path, entry, field):
    f = tmp_path / "cams.json"
    f.write_text(json.dumps([entry]))
    with pytest.raises(ViewError) as info:
        load_cameras(f)
    assert (info.value.index, info.value.field) == (0, field)
    assert str(f) in str(info.value)
    (broken,) = load_cameras(f, strict=False)
    assert isinstance(broken, BrokenCamera) and broken.error.field == field


# --- item 10: camera files JSON cannot read ---------------------------------------------------

@pytest.mark.parametrize("content, match", [
    (b"[" * 100_000, "nested too deeply"),
    (b'{"cameras": ' + b'{"a": ' * 100_000, "nested too deeply"),
    (b"\xff\xfe[\x00]\x00", "not a UTF-8"),                  # UTF-16
    (b"[" + b"7" * 5000 + b"]", "not valid JSON"),           # int beyond 4300 digits
], ids=["lists", "objects", "utf16", "long-int"])
def test_unreadable_camera_file_is_a_camera_file_error(tmp_path, content, match):
    f = tmp_path / "cams.json"
    f.write_bytes(content)
    with pytest.raises(CameraFileError, match=match) as info:
        load_cameras(f)
    assert str(f) in str(info.value)


def test_deeply_nested_camera_file_through_the_cli(tmp_path, capsys):
    """`clraster render --views FILE` with 100,000 levels of '[' was a RecursionError
    traceback: exit 1 and one error line naming the file."""
    f = tmp_path / "deep.json"
    f.write_text("[" * 100_000)
    code = main(["render", "example", "--views", str(f), "--out", str(tmp_path / "views"),
                 "--size", "32x32"])
    err = capsys.readouterr().err
    assert code == 1
    assert "Traceback" not in err and "RecursionError" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("clraster: error:") and str(f) in lines[0]
