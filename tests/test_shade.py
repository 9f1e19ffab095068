"""shade() and depth_image(): flat Lambert shading from triangle ids; depth visualization."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from clraster.mesh import Mesh
from clraster.shade import depth_image, shade

# Two faces: one facing +Z, the same triangle wound the other way (facing −Z), one degenerate.
MESH = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], [[0, 1, 2], [0, 2, 1], [0, 1, 3]])


def frame(ids) -> SimpleNamespace:
    return SimpleNamespace(triangle_id=np.asarray(ids, dtype=np.int32))


def test_shape_dtype_background():
    img = shade(frame([[-1, 0, 1], [2, -1, -1]]), MESH, background=(10, 20, 30))
    assert img.shape == (2, 3, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img[0, 0], [10, 20, 30])
    np.testing.assert_array_equal(img[1, 1:], [[10, 20, 30]] * 2)


def test_two_sided_and_light_direction():
    ids = frame([[0, 1, 2]])
    head_on = shade(ids, MESH, light_dir=(0, 0, 5))
    np.testing.assert_array_equal(head_on[0, 0], head_on[0, 1])  # |n·l|: both sides lit
    grazing = shade(ids, MESH, light_dir=(1, 0, 0))
    assert np.all(grazing[0, 0] < head_on[0, 0])  # ambient only at 90°
    np.testing.assert_array_equal(grazing[0, 0], grazing[0, 2])  # degenerate = ambient
    assert np.all(grazing[0, 0] > 0)


def test_default_light_is_deterministic():
    ids = frame(np.array([[0, 1], [2, -1]]))
    np.testing.assert_array_equal(shade(ids, MESH), shade(ids, MESH))
    np.testing.assert_array_equal(shade(ids, MESH)[1, 1], [255, 255, 255])


@pytest.mark.parametrize("ids, match", [
    ([[0, 3]], r"outside \[-1, 3\)"),
    ([[-2, 0]], r"outside \[-1, 3\)"),
    ([0, 1], r"\(H, W\) integer"),
    ([[0.0, 1.0]], r"\(H, W\) integer"),
])
def test_bad_ids(ids, match):
    with pytest.raises(ValueError, match=match):
        shade(SimpleNamespace(triangle_id=np.asarray(ids)), MESH)


@pytest.mark.parametrize("kw, match", [
    (dict(light_dir=(0, 0, 0)), "light_dir"),
    (dict(light_dir=(0, np.nan, 1)), "light_dir"),
    (dict(light_dir=(1, 0)), "light_dir"),
    (dict(background=(0, 0, 256)), "background"),
    (dict(background=(0, 0)), "background"),
])
def test_bad_options(kw, match):
    with pytest.raises(ValueError, match=match):
        shade(frame([[0]]), MESH, **kw)


def test_depth_image():
    d = np.array([[1.0, 0.2, 0.6], [0.4, 1.0, np.nan]], dtype=np.float32)
    img = depth_image(d)
    assert img.dtype == np.uint8 and img.shape == (2, 3)
    assert img[0, 1] == 0  # nearest: black
    assert img[0, 2] == 235  # farthest covered
    assert 0 < img[1, 0] < 235
    assert img[0, 0] == img[1, 1] == img[1, 2] == 255  # background (and NaN)


def test_depth_image_edge_cases():
    np.testing.assert_array_equal(depth_image(np.ones((2, 2))), 255)
    np.testing.assert_array_equal(depth_image(np.full((2, 2), 0.5)), 0)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        depth_image(np.ones(4))
