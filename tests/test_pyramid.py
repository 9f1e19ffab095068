"""Depth pyramid (Hi-Z) and the conservative box test: OpenCL against the NumPy twin and
against brute force.

* Pyramid levels: sizes ceil(w/2) × ceil(h/2) down to 1 × 1; every texel equals the maximum
  of the level-0 pixels in its footprint [i·2^L, min((i+1)·2^L, W)) × (same in y), computed
  here by brute force; the device is bit-identical to the twin. Sizes on both sides of
  powers of two, 1 × 1, 1 × N, N × 1, and sizes that need 2 and 3 launches.
* Box test: device == twin on random boxes of every kind (behind the eye, crossing near,
  outside each plane, sub-pixel, huge, non-finite, inverted corners); VIEW_CULLED only when
  all 8 corners are outside one plane in float64. The "never OCCLUDED with a sample passing"
  property against the exact query lives in tests/test_occlusion_query.py.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clraster.pipeline.device import default_context
from clraster.pipeline.occlusion import Occlusion
from clraster.pipeline.reference import pyramid as ref
from clraster.pipeline.stages.pyramid import PyramidStage, level_shapes, level_table


@pytest.fixture(scope="module")
def dev():
    ctx = default_context()
    queue = cl.CommandQueue(ctx)
    return ctx, queue, PyramidStage(ctx)


def _pyramid(dev, depth: np.ndarray):
    ctx, queue, stage = dev
    h, w = depth.shape
    # the renderer hands over its depth output as a USE_HOST_PTR buffer; do the same
    buf = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR, hostbuf=depth)
    pyr = stage.build(queue, buf, w, h)
    return pyr, pyr.read(queue)


def _brute_force_level(depth: np.ndarray, level: int) -> np.ndarray:
    """Max over each texel's footprint, by padding to a multiple of 2^L with −inf."""
    s = 1 << level
    h, w = depth.shape
    hh, ww = -(-h // s), -(-w // s)
    pad = np.full((hh * s, ww * s), -np.inf, np.float64)
    pad[:h, :w] = depth
    return pad.reshape(hh, s, ww, s).max(axis=(1, 3))


def _random_depth(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """Depth-like values with ties: random, constant blocks, a far background and a ramp."""
    kind = rng.integers(4)
    if kind == 0:
        d = rng.random((h, w), dtype=np.float32)
    elif kind == 1:
        d = rng.choice(np.float32([0.1, 0.25, 0.5, 1.0]), size=(h, w))
    elif kind == 2:
        d = np.ones((h, w), np.float32)
        y0, x0 = rng.integers(0, h), rng.integers(0, w)
        d[y0:y0 + rng.integers(1, h + 1), x0:x0 + rng.integers(1, w + 1)] = np.float32(0.3)
    else:
        d = (np.add.outer(np.arange(h), 2 * np.arange(w)) / (h + 2 * w)).astype(np.float32)
    return np.ascontiguousarray(d, np.float32)


SIZES = ([(1, 1), (1, 2), (2, 1), (1, 17), (33, 1), (2, 2), (3, 3), (5, 7)]
         + [(h, w) for k in (4, 6, 7) for h in ((1 << k) - 1, 1 << k, (1 << k) + 1)
            for w in ((1 << k) - 1, (1 << k) + 1)]
         + [(1, 4097), (4099, 1), (97, 1000), (1080, 1920)])


def test_level_shapes():
    assert level_shapes(1, 1) == [(1, 1)]
    assert level_shapes(5, 1) == [(1, 5), (1, 3), (1, 2), (1, 1)]
    assert level_shapes(1, 6) == [(6, 1), (3, 1), (2, 1), (1, 1)]
    assert level_shapes(1920, 1080)[-3:] == [(3, 4), (2, 2), (1, 1)]
    assert len(level_shapes(1920, 1080)) == 12
    for w, h in ((7, 9), (64, 64), (65, 3), (16384, 1)):
        shapes = level_shapes(w, h)
        assert shapes[0] == (h, w) and shapes[-1] == (1, 1)
        for (h0, w0), (h1, w1) in zip(shapes, shapes[1:], strict=False):
            assert (h1, w1) == (-(-h0 // 2), -(-w0 // 2))
        t = level_table(w, h)
        assert t[0, 0] == 0 and np.all(np.diff(t[:, 0]) == t[:-1, 1] * t[:-1, 2])


@pytest.mark.parametrize("h,w", SIZES)
def test_pyramid_matches_twin_and_footprint_max(dev, h, w):
    rng = np.random.default_rng(h * 100003 + w)
    depth = _random_depth(rng, h, w)
    pyr, levels = _pyramid(dev, depth)
    twin = ref.build(depth)
    assert [lv.shape for lv in levels] == [lv.shape for lv in twin] == level_shapes(w, h)
    assert pyr.n_levels == len(twin)
    for k, (a, b) in enumerate(zip(levels, twin, strict=True)):
        assert a.dtype == np.float32
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32)), f"level {k} differs"
    stride = 1 if h * w < 200_000 else 3   # brute force on every level, or every third
    for k in range(0, len(levels), stride):
        bf = _brute_force_level(depth, k)
        assert np.array_equal(levels[k], bf), f"level {k} is not the footprint maximum"


def test_pyramid_is_a_copy_and_reusable(dev):
    """Level 0 is copied: changing the depth array after the build changes nothing; the
    stage's buffers are reused for other sizes."""
    rng = np.random.default_rng(5)
    for h, w in ((40, 70), (9, 3), (40, 70)):
        depth = rng.random((h, w), dtype=np.float32)
        keep = depth.copy()
        pyr, _ = _pyramid(dev, depth)
        depth[:] = 2.0
        levels = pyr.read(dev[1])
        assert np.array_equal(levels[0], keep)
        assert levels[-1][0, 0] == keep.max()


def test_pyramid_of_a_rendered_frame(dev, renderer_for):
    from conftest import MatrixCamera, perspective

    from clraster import Mesh
    from clraster.pipeline.reference.query import box_mesh

    rng = np.random.default_rng(2)
    c = rng.uniform(-3, 3, (30, 3))
    c[:, 2] -= 8.0
    e = rng.uniform(0.2, 1.5, (30, 3))
    v, f = box_mesh(c - e, c + e)
    w, h = 95, 63
    frame = renderer_for(w, h).render(Mesh(v, f), MatrixCamera(perspective(60, w / h, 1, 50)))
    assert (frame.depth < 1).any()
    _, levels = _pyramid(dev, frame.depth)
    for k, (a, b) in enumerate(zip(levels, ref.build(frame.depth), strict=True)):
        assert np.array_equal(a, b), k
        assert np.array_equal(a, _brute_force_level(frame.depth, k)), k


# ---- box test: device vs twin, VIEW_CULLED vs brute force ---------------------------------

def _camera(rng: np.random.Generator, w: int, h: int):
    """A float32 view-projection: gluPerspective (random lens) · a random look-at."""
    from clraster.world.camera import look_at_matrix, perspective_matrix

    eye = rng.uniform(-3, 3, 3)
    target = eye + rng.normal(size=3)
    fov = rng.choice([20.0, 60.0, 100.0, 150.0])
    near = rng.choice([0.01, 0.3, 2.0])
    far = near * rng.choice([10.0, 1000.0])
    vp = perspective_matrix(fov, w / h, near, far) @ look_at_matrix(eye, target, (0, 1, 0.1))
    return vp.astype(np.float32), eye


def _random_boxes(rng: np.random.Generator, n: int, eye: np.ndarray) -> tuple:
    """Boxes of every kind around ``eye``: log-uniform sizes and distances, some around the
    eye, some degenerate (zero extent), inverted (min > max) or non-finite."""
    d = np.exp(rng.uniform(np.log(0.01), np.log(3000.0), n))
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    c = eye + dirs * d[:, None]
    size = np.exp(rng.uniform(np.log(1e-4), np.log(50.0), (n, 1))) * rng.uniform(0.1, 1, (n, 3))
    lo, hi = c - size, c + size
    kind = rng.random(n)
    hi[kind < 0.05] = lo[kind < 0.05]                                   # points
    sw = (kind >= 0.05) & (kind < 0.1)
    lo[sw], hi[sw] = hi[sw].copy(), lo[sw].copy()                       # inverted
    around = (kind >= 0.1) & (kind < 0.15)
    lo[around], hi[around] = eye - size[around], eye + size[around]     # contain the eye
    bad = rng.random(n) < 0.01
    lo[bad, rng.integers(0, 3, bad.sum())] = rng.choice([np.nan, np.inf, -np.inf], bad.sum())
    return lo.astype(np.float32), hi.astype(np.float32)


def _corners64(lo, hi):
    k = np.arange(8)
    sel = np.stack([(k & 1) != 0, (k & 2) != 0, (k & 4) != 0], axis=1)
    return np.where(sel[None], hi[:, None, :], lo[:, None, :]).astype(np.float64)


def _outside_one_plane(lo, hi, vp) -> np.ndarray:
    """float64 brute force: all 8 corners strictly outside one clip plane."""
    p = _corners64(lo, hi)
    clip = np.einsum("ij,knj->kni", vp.astype(np.float64),
                     np.concatenate([p, np.ones(p.shape[:2] + (1,))], axis=2))
    x, y, z, w = np.moveaxis(clip, 2, 0)
    with np.errstate(invalid="ignore"):
        planes = (x + w, w - x, y + w, w - y, z + w, w - z)
        return np.any([np.all(d < 0, axis=1) for d in planes], axis=0)


SIZES_T = st.builds(lambda kw, dw, kh, dh: ((1 << kw) + dw, (1 << kh) + dh),
                    st.integers(0, 8), st.sampled_from([-1, 0, 1]),
                    st.integers(0, 8), st.sampled_from([-1, 0, 1])).filter(
                        lambda s: s[0] >= 1 and s[1] >= 1)


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(size=SIZES_T, seed=st.integers(0, 2**32 - 1))
def test_box_test_matches_twin(dev, size, seed):
    w, h = size
    rng = np.random.default_rng(seed)
    depth = _random_depth(rng, h, w)
    # a depth buffer of plausible window depths for the camera: pull values towards 1
    depth = np.ascontiguousarray(1 - (1 - depth) ** 3 * 0.2, np.float32)
    vp, eye = _camera(rng, w, h)
    lo, hi = _random_boxes(rng, 3000, eye)
    pyr, levels = _pyramid(dev, depth)
    got = dev[2].test_boxes(dev[1], pyr, lo, hi, vp, w, h)
    want = ref.test_boxes(levels, lo, hi, vp, w, h)
    assert got.dtype == np.uint8 and got.shape == (lo.shape[0],)
    diff = np.nonzero(got != want)[0]
    assert diff.size == 0, (f"{diff.size} boxes differ, first {diff[0]}: device "
                            f"{got[diff[0]]} twin {want[diff[0]]}")
    culled = got == Occlusion.VIEW_CULLED
    bf = _outside_one_plane(lo, hi, vp)
    assert not np.any(culled & ~bf), "VIEW_CULLED for a box not outside any plane"
    finite = np.all(np.isfinite(lo) & np.isfinite(hi), axis=1)
    assert np.all(got[~finite] == Occlusion.VISIBLE)
    assert set(np.unique(got)) <= {0, 1, 2}


def test_box_test_outcomes_by_construction(dev):
    """Clear-cut cases with a gluPerspective camera at the origin looking down −Z."""
    from clraster.world.camera import perspective_matrix

    w, h = 65, 33
    vp = perspective_matrix(60, w / h, 0.5, 100).astype(np.float32)
    depth = np.full((h, w), 0.9, np.float32)   # a wall at window depth 0.9
    pyr, levels = _pyramid(dev, depth)
    z_wall = None
    for z in np.linspace(-0.6, -99, 20000):  # eye-space z of the wall (monotone depth)
        c = vp.astype(np.float64) @ [0, 0, z, 1]
        if (c[2] / c[3] + 1) / 2 > 0.9:
            z_wall = z
            break
    assert z_wall is not None
    boxes = {
        "behind wall": ([-0.5, -0.5, 2 * z_wall], [0.5, 0.5, 1.5 * z_wall]),
        "in front of wall": ([-0.5, -0.5, 0.5 * z_wall], [0.5, 0.5, 0.4 * z_wall]),
        "around the eye": ([-1, -1, -1], [1, 1, 1]),
        "crossing near": ([-0.1, -0.1, -0.7], [0.1, 0.1, -0.3]),
        "behind the eye": ([-1, -1, 1], [1, 1, 2]),
        "beyond far": ([-1, -1, -300], [1, 1, -200]),
        "left of view": ([-500, -1, -20], [-400, 1, -10]),
        "above view": ([-1, 400, -20], [1, 500, -10]),
    }
    want = {"behind wall": Occlusion.OCCLUDED, "in front of wall": Occlusion.VISIBLE,
            "around the eye": Occlusion.VISIBLE, "crossing near": Occlusion.VISIBLE,
            "behind the eye": Occlusion.VIEW_CULLED, "beyond far": Occlusion.VIEW_CULLED,
            "left of view": Occlusion.VIEW_CULLED, "above view": Occlusion.VIEW_CULLED}
    lo = np.array([b[0] for b in boxes.values()], np.float32)
    hi = np.array([b[1] for b in boxes.values()], np.float32)
    got = dev[2].test_boxes(dev[1], pyr, lo, hi, vp, w, h)
    assert np.array_equal(got, ref.test_boxes(levels, lo, hi, vp, w, h))
    for name, g in zip(boxes, got, strict=True):
        assert Occlusion(g) == want[name], name


def test_box_test_level_choice(dev):
    """A single far texel anywhere under a box's pixel range keeps it VISIBLE, at every
    level: the ≤ 2×2 texels read always cover the whole range (pixel-exact rectangles with
    an orthographic camera; the far texel sits on each rectangle corner and edge)."""
    w, h = 200, 131
    # world (x, y) = window pixels (y down), NDC z = world z: depth (z + 1) / 2
    ortho = np.float32([[2.0 / w, 0, 0, -1], [0, -2.0 / h, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]])
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(300):
        x0, y0 = rng.integers(0, w), rng.integers(0, h)
        x1 = min(w - 1, x0 + int(np.exp(rng.uniform(0, np.log(w)))))
        y1 = min(h - 1, y0 + int(np.exp(rng.uniform(0, np.log(h)))))
        # pixel centres x0..x1 lie in [x0 + 0.3, x1 + 0.7] and no others, even with the
        # 1/16 px slack; depth 0.25..0.3
        lo = np.float32([[x0 + 0.3, y0 + 0.3, -0.5]])
        hi = np.float32([[x1 + 0.7, y1 + 0.7, -0.4]])
        for px, py in ((x0, y0), (x1, y1), (x0, y1), (x1, y0), ((x0 + x1) // 2, y0)):
            depth = np.zeros((h, w), np.float32)
            depth[py, px] = 1.0
            pyr, levels = _pyramid(dev, depth)
            got = dev[2].test_boxes(dev[1], pyr, lo, hi, ortho, w, h)
            assert got[0] == Occlusion.VISIBLE, (x0, x1, y0, y1, px, py)
            checked += 1
        depth = np.zeros((h, w), np.float32)
        depth[y0:y1 + 1, x0:x1 + 1] = 0.1   # everything under it nearer: occluded
        pyr, levels = _pyramid(dev, depth)
        got = dev[2].test_boxes(dev[1], pyr, lo, hi, ortho, w, h)
        assert got[0] == Occlusion.OCCLUDED, (x0, x1, y0, y1)
        assert np.array_equal(got, ref.test_boxes(levels, lo, hi, ortho, w, h))
    assert checked == 1500


def test_box_test_100k_boxes(dev):
    """100K boxes in one call; same answers as the twin; all three outcomes occur."""
    w, h = 257, 129
    rng = np.random.default_rng(3)
    depth = np.ascontiguousarray(1 - (1 - _random_depth(rng, h, w)) * 0.05, np.float32)
    vp, eye = _camera(rng, w, h)
    lo, hi = _random_boxes(rng, 100_000, eye)
    pyr, levels = _pyramid(dev, depth)
    got = dev[2].test_boxes(dev[1], pyr, lo, hi, vp, w, h)
    assert got.shape == (100_000,)
    assert np.array_equal(got, ref.test_boxes(levels, lo, hi, vp, w, h))
    assert set(np.unique(got)) == {0, 1, 2}


def test_box_test_input_errors(dev):
    depth = np.ones((8, 8), np.float32)
    pyr, _ = _pyramid(dev, depth)
    stage, q = dev[2], dev[1]
    eye = np.eye(4, dtype=np.float32)
    with pytest.raises(ValueError, match="pyramid is 8x8"):
        stage.test_boxes(q, pyr, np.zeros((1, 3)), np.ones((1, 3)), eye, 9, 8)
    with pytest.raises(ValueError, match=r"\(K, 3\)"):
        stage.test_boxes(q, pyr, np.zeros((2, 3)), np.ones((3, 3)), eye, 8, 8)
    with pytest.raises(ValueError, match="4, 4"):
        stage.test_boxes(q, pyr, np.zeros((2, 3)), np.ones((2, 3)), np.eye(3), 8, 8)
    assert stage.test_boxes(q, pyr, np.zeros((0, 3)), np.zeros((0, 3)), eye, 8, 8).shape == (0,)
