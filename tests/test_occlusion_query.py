"""Exact occlusion queries and the conservative Hi-Z verdict.

* The key property: the Hi-Z test never says OCCLUDED (or VIEW_CULLED) for a box of which
  at least one sample passes the exact query — on depth buffers rendered from random
  occluders and synthetic ones, with query boxes placed at random and at near-ties with the
  depth buffer (a hair in front of / behind the visible surface), cameras far from the
  world origin (large float32 rounding), sizes 2^k ± 1.
* The exact query follows the renderer's rules: against a cleared depth buffer a box's count
  is the coverage of rendering that box alone; against an occluder scene's depth it is the
  number of pixels where the box wins when rendered together with the occluders.
* Device == NumPy twin, tile-size invariance, hand-counted cases, 100K boxes in one call,
  the public API and its errors.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MatrixCamera, get_renderer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clraster import Camera, Mesh, RasterConfig
from clraster.pipeline.occlusion import Occlusion, OcclusionQuery, QueryResult, query, sphere_boxes
from clraster.pipeline.reference import pyramid as ref_pyr
from clraster.pipeline.reference import query as ref_q

_QUERIES: dict[int, OcclusionQuery] = {}


def oq(tile_log2: int = 4) -> OcclusionQuery:
    """One OcclusionQuery per tile size for the whole session."""
    if tile_log2 not in _QUERIES:
        _QUERIES[tile_log2] = OcclusionQuery(config=RasterConfig(tile_log2=tile_log2))
    return _QUERIES[tile_log2]


def _vp(camera, w, h) -> np.ndarray:
    return np.asarray(camera.view_projection(w, h), np.float64).astype(np.float32)


def _render_depth(w, h, mins, maxs, camera) -> np.ndarray:
    v, f = ref_q.box_mesh(mins, maxs)
    return get_renderer(w, h).render(Mesh(v, f), camera, cull="none").depth


# ---- hand-made cases ----------------------------------------------------------------------

HEAD_ON = Camera.look_at((0, 0, 5), (0, 0, 0), (0, 1, 0), fov_y=90.0, near=0.1, far=100.0)


def _wall(x0=-10.0, x1=10.0, z=0.0):
    return np.float32([[x0, -10, z - 0.01]]), np.float32([[x1, 10, z]])


def test_head_on_box_counts_by_hand():
    """64×64, fov 90°, eye at z = 5: a face at z = 2 (distance 3) maps x → (x/3 + 1)·32.
    Box x ∈ [−0.75, 0.375] → window [24, 36]: 12 columns; y ∈ [−0.1875, 0.75] → window
    [24, 34]: 10 rows; its back face (z = 1) projects inside: 120 samples, in front of a wall
    or on a cleared buffer. The same box at z ∈ [−3, −2] (front face at distance 7: window
    x ∈ [28.57, 33.71], y ∈ [28.57, 32.86]: 5 × 4) has 0 samples behind the wall (OCCLUDED)
    and 20 on a cleared buffer."""
    w = h = 64
    lo = np.float32([[-0.75, -0.1875, 1.0], [-0.75, -0.1875, -3.0]])
    hi = np.float32([[0.375, 0.75, 2.0], [0.375, 0.75, -2.0]])
    wall_lo, wall_hi = _wall()
    depth = _render_depth(w, h, wall_lo, wall_hi, HEAD_ON)
    assert np.all(depth < 1)
    r = oq()(depth, lo, hi, HEAD_ON)
    assert r.samples.tolist() == [120, 0]
    assert r.samples.dtype == np.int64 and r.hiz.dtype == np.uint8
    assert r.hiz.tolist() == [Occlusion.VISIBLE, Occlusion.OCCLUDED]
    clear = oq()(np.ones((h, w), np.float32), lo, hi, HEAD_ON)
    assert clear.samples.tolist() == [120, 20]
    assert clear.hiz.tolist() == [Occlusion.VISIBLE, Occlusion.VISIBLE]


def test_half_wall_counts_by_hand():
    """A wall covering x < 0 (window columns < 32) at z = 0. A box x ∈ [−1, 1],
    y ∈ [−0.7, 0.7], z ∈ [−3, −2] (front face at distance 7: window x ∈ 32 ± 4.571,
    y ∈ 32 ± 3.2) shows columns 32..36 and rows 29..34 beside the wall: 30 samples."""
    w = h = 64
    depth = _render_depth(w, h, *_wall(x1=0.0), HEAD_ON)
    lo, hi = np.float32([[-1, -0.7, -3]]), np.float32([[1, 0.7, -2]])
    r = oq()(depth, lo, hi, HEAD_ON)
    assert r.samples.tolist() == [30]
    assert r.hiz.tolist() == [Occlusion.VISIBLE]


def test_boxes_crossing_near():
    """A box around the eye covers every pixel of a cleared buffer with its inner faces
    (each ray leaves it once, at distance >= 1 > near); one that only pokes through the
    near plane counts what lies beyond near. Both are VISIBLE whatever the depth buffer."""
    w, h = 33, 31
    lo = np.float32([[-1, -1, 4], [-0.05, -0.05, 4.8]])
    hi = np.float32([[1, 1, 6], [0.05, 0.05, 5.2]])   # second: from 0.2 in front to behind
    r = oq()(np.ones((h, w), np.float32), lo, hi, HEAD_ON)
    assert r.samples[0] == w * h
    assert r.samples[1] > 0
    assert r.hiz.tolist() == [Occlusion.VISIBLE, Occlusion.VISIBLE]
    near_wall = np.zeros((h, w), np.float32)   # nothing can pass against depth 0
    r = oq()(near_wall, lo, hi, HEAD_ON)
    assert r.samples.tolist() == [0, 0]
    assert r.hiz.tolist() == [Occlusion.VISIBLE, Occlusion.VISIBLE]


def test_outside_the_frustum():
    w = h = 32
    lo = np.float32([[-1, -1, 6], [-1, -1, -300], [-100, -1, -3], [-1, 50, -3]])
    hi = np.float32([[1, 1, 7], [1, 1, -200], [-50, 1, -2], [1, 60, -2]])
    r = oq()(np.ones((h, w), np.float32), lo, hi, HEAD_ON)
    assert r.samples.tolist() == [0, 0, 0, 0]
    assert r.hiz.tolist() == [Occlusion.VIEW_CULLED] * 4


# ---- the exact query follows the renderer -------------------------------------------------

def _scene_boxes(rng, n, spread=3.0, z=-2.0, size=(0.1, 1.2)):
    c = rng.uniform(-spread, spread, (n, 3))
    c[:, 2] += z
    e = rng.uniform(*size, (n, 3))
    return (c - e).astype(np.float32), (c + e).astype(np.float32)


def test_cleared_buffer_count_is_rendered_coverage():
    """On a cleared buffer a box's samples are the pixels that rendering the box alone
    (cull "none") covers."""
    w, h = 47, 33
    rng = np.random.default_rng(7)
    lo, hi = _scene_boxes(rng, 25, spread=4.0, size=(0.05, 2.0))
    r = oq()(np.ones((h, w), np.float32), lo, hi, HEAD_ON, pyramid=False)
    assert r.hiz is None
    for b in range(lo.shape[0]):
        v, f = ref_q.box_mesh(lo[b:b + 1], hi[b:b + 1])
        frame = get_renderer(w, h).render(Mesh(v, f), HEAD_ON, cull="none")
        assert r.samples[b] == int((frame.triangle_id >= 0).sum()), b


def test_count_is_what_rendering_with_the_occluders_shows():
    """Render occluders + box b together (box faces after the occluders', so ties go to
    the occluders, which is LESS against their depth): the pixels showing box b are its
    samples against the occluders' depth buffer."""
    w, h = 61, 45
    rng = np.random.default_rng(8)
    occ_lo, occ_hi = _scene_boxes(rng, 12, spread=3.0, z=-1.0, size=(0.3, 1.5))
    depth = _render_depth(w, h, occ_lo, occ_hi, HEAD_ON)
    lo, hi = _scene_boxes(rng, 20, spread=3.0, z=-1.0, size=(0.05, 1.0))
    r = oq()(depth, lo, hi, HEAD_ON)
    assert (r.samples > 0).sum() >= 5 and (r.samples == 0).sum() >= 1
    for b in range(lo.shape[0]):
        v, f = ref_q.box_mesh(np.concatenate([occ_lo, lo[b:b + 1]]),
                              np.concatenate([occ_hi, hi[b:b + 1]]))
        frame = get_renderer(w, h).render(Mesh(v, f), HEAD_ON, cull="none")
        shows = int((frame.triangle_id >= 12 * occ_lo.shape[0]).sum())
        assert r.samples[b] == shows, b
        if r.hiz[b] == Occlusion.OCCLUDED:
            assert shows == 0


@pytest.mark.parametrize("tile_log2", [3, 4, 5, 6])
@pytest.mark.parametrize("size", [(31, 17), (64, 64), (65, 33)])
def test_query_matches_twin(tile_log2, size):
    """Counts and Hi-Z codes equal to the twin's; counts do not depend on the tile size."""
    w, h = size
    rng = np.random.default_rng(w * 7 + h + tile_log2)
    depth = _render_depth(w, h, *_scene_boxes(rng, 10, z=-1.0), HEAD_ON)
    depth[rng.random((h, w)) < 0.05] = np.float32(0.5)   # some speckle
    lo, hi = _scene_boxes(rng, 60, spread=4.0, z=-1.0, size=(0.01, 1.0))
    lo[:5], hi[:5] = np.float32([-0.3, -0.3, 4.7]), np.float32([0.3, 0.3, 5.3])  # near
    r = oq(tile_log2)(depth, lo, hi, HEAD_ON)
    vp = _vp(HEAD_ON, w, h)
    cfg = RasterConfig(tile_log2=tile_log2)
    assert np.array_equal(r.samples, ref_q.samples_passed(depth, lo, hi, vp, cfg))
    assert np.array_equal(r.hiz, ref_pyr.test_boxes(ref_pyr.build(depth), lo, hi, vp, w, h))
    assert np.array_equal(r.samples, oq(4)(depth, lo, hi, HEAD_ON, pyramid=False).samples)


# ---- the conservative property ------------------------------------------------------------

def _unproject(vp64_inv, x, y, d, w, h):
    ndc = np.stack([2 * x / w - 1, 1 - 2 * y / h, 2 * d - 1, np.ones_like(x)], axis=-1)
    p = ndc @ vp64_inv.T
    return p[:, :3] / p[:, 3:]


def _random_case(seed: int, w: int, h: int, offset: float, synthetic: bool):
    """Camera, depth buffer, query boxes (mins, maxs) and the occluder boxes (None for a
    synthetic depth buffer) for one example (see the module docstring)."""
    rng = np.random.default_rng(seed)
    eye = offset + rng.uniform(-1, 1, 3)
    fwd = np.array([0, 0, -1.0]) + rng.normal(0, 0.3, 3)
    fwd /= np.linalg.norm(fwd)
    near = float(rng.choice([0.05, 0.5]))
    far = float(rng.choice([30.0, 300.0]))
    cam = Camera.look_at(eye, eye + fwd, (0, 1, 0), fov_y=float(rng.choice([30, 60, 100])),
                         near=near, far=far)
    vp64 = np.asarray(cam.view_projection(w, h), np.float64)

    def along(n, dmin, dmax):   # points in front of the eye, log-uniform distance
        d = np.exp(rng.uniform(np.log(dmin), np.log(dmax), n))
        side = rng.normal(0, 0.5, (n, 3))
        return eye + (fwd + side) * d[:, None]

    occ = None
    if synthetic:
        # blocks of constant depth: window depths of random distances
        zs = np.exp(rng.uniform(np.log(near * 1.5), np.log(far * 0.9), 6))
        dvals = far / (far - near) * (1 - near / zs)   # window depth at eye distance zs
        depth = np.ones((h, w), np.float32)
        for d in dvals:
            y0, x0 = rng.integers(0, h), rng.integers(0, w)
            depth[y0:y0 + rng.integers(1, h + 1), x0:x0 + rng.integers(1, w + 1)] = d
    else:
        n_occ = int(rng.integers(3, 12))
        c = along(n_occ, near * 3, far * 0.3)
        dist = np.linalg.norm(c - eye, axis=1, keepdims=True)
        e = dist * rng.uniform(0.05, 0.5, (n_occ, 3))
        e[rng.random(n_occ) < 0.3, rng.integers(0, 3)] *= 0.01   # walls
        occ = (c - e).astype(np.float32), (c + e).astype(np.float32)
        depth = _render_depth(w, h, *occ, cam)

    boxes = []
    n = 300
    c = along(n, near * 0.5, far * 1.2)                 # anywhere, incl. crossing near / far
    dist = np.linalg.norm(c - eye, axis=1, keepdims=True)
    e = dist * np.exp(rng.uniform(np.log(1e-4), np.log(0.5), (n, 1))) * rng.uniform(0.2, 1, (n, 3))
    boxes.append((c - e, c + e))
    # near-ties: a small box just in front of / behind the visible surface at a pixel
    covered = np.argwhere(depth < 1)
    if covered.size:
        m = 300
        pick = covered[rng.integers(0, covered.shape[0], m)]
        py, px = pick[:, 0], pick[:, 1]
        d0 = depth[py, px].astype(np.float64)
        delta = rng.choice([-1, 1], m) * 10.0 ** rng.uniform(-8, -3, m)
        p = _unproject(np.linalg.inv(vp64), px + rng.uniform(0, 1, m), py + rng.uniform(0, 1, m),
                       np.clip(d0 + delta, 0, 1), w, h)
        dist = np.linalg.norm(p - eye, axis=1, keepdims=True)
        e = dist * 10.0 ** rng.uniform(-6, -1, (m, 1)) * rng.uniform(0, 1, (m, 3))
        front = rng.random(m) < 0.5   # the point is the box's nearest corner-ish, or centre
        lo, hi = p - e, p + e
        lo[front] = p[front] - e[front] * (fwd[None] < 0)
        hi[front] = p[front] + e[front] * (fwd[None] > 0)
        boxes.append((lo, hi))
    lo = np.concatenate([b[0] for b in boxes]).astype(np.float32)
    hi = np.concatenate([b[1] for b in boxes]).astype(np.float32)
    return cam, depth, lo, hi, occ


CASES = st.tuples(
    st.builds(lambda kw, dw, kh, dh: ((1 << kw) + dw, (1 << kh) + dh),
              st.integers(3, 7), st.sampled_from([-1, 0, 1]),
              st.integers(3, 7), st.sampled_from([-1, 0, 1])),
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 0.0, 100.0, 1000.0, 30000.0]),
    st.booleans(),
)


@settings(max_examples=150, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=CASES)
def test_hiz_never_occludes_a_box_with_passing_samples(case):
    (w, h), seed, offset, synthetic = case
    cam, depth, lo, hi, _ = _random_case(seed, w, h, offset, synthetic)
    r = oq()(depth, lo, hi, cam)
    bad = (r.hiz != Occlusion.VISIBLE) & (r.samples > 0)
    if bad.any():
        b = int(np.nonzero(bad)[0][0])
        raise AssertionError(
            f"box {b} ({lo[b].tolist()} .. {hi[b].tolist()}) is "
            f"{Occlusion(r.hiz[b]).name} but {r.samples[b]} samples pass")


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(case=CASES)
def test_occluded_content_changes_no_pixel(case):
    """What the renderer relies on: content inside an OCCLUDED box, drawn through its own
    instance transform (rounded float32 VP · model, not the box's VP), changes no pixel of
    the frame. Occluders are instance 0; each content mesh (random triangles with vertices
    in model space) is one more instance, its box the outward-rounded world bounds."""
    from clraster.world.scene import Scene

    (w, h), seed, offset, _ = case
    cam, depth, _lo, _hi, occ = _random_case(seed, w, h, offset, synthetic=False)
    rng = np.random.default_rng(seed + 1)
    vp64 = np.asarray(cam.view_projection(w, h), np.float64)
    inv = np.linalg.inv(vp64)
    v, f = ref_q.box_mesh(*occ)
    items = [(Mesh(v, f), np.eye(4))]
    boxes_lo, boxes_hi = [], []
    for _ in range(12):
        # a world point seen at a random pixel, at a depth near the depth buffer's there
        py, px = rng.integers(0, h), rng.integers(0, w)
        d = float(np.clip(depth[py, px] + rng.choice([-1, 1]) * 10.0 ** rng.uniform(-7, -2),
                          0.0, 0.999999))
        centre = _unproject(inv, np.array([px + 0.5]), np.array([py + 0.5]), np.array([d]),
                            w, h)[0]
        size = np.linalg.norm(centre - cam.eye) * 10.0 ** rng.uniform(-3, -1)
        rot = _rotation(rng)
        t = np.eye(4)
        t[:3, :3] = rot
        t[:3, 3] = centre + rng.normal(0, 1, 3) * float(rng.choice([0.0, 10.0, 1000.0]))
        world = centre + rng.normal(0, size, (8, 3))
        model = ((world - t[:3, 3]) @ rot).astype(np.float32)          # t⁻¹ · world
        exact = model.astype(np.float64) @ rot.T + t[:3, 3]             # what it really is
        boxes_lo.append(np.nextafter(exact.min(0).astype(np.float32), np.float32(-np.inf)))
        boxes_hi.append(np.nextafter(exact.max(0).astype(np.float32), np.float32(np.inf)))
        items.append((Mesh(model, rng.integers(0, 8, (10, 3)).astype(np.int32)), t))
    lo, hi = np.array(boxes_lo, np.float32), np.array(boxes_hi, np.float32)
    r = oq()(depth, lo, hi, cam)
    scene = Scene(items)
    frame = get_renderer(w, h).render(scene, cam, cull="none")
    inst, _face = scene.split_ids(frame.triangle_id[frame.triangle_id >= 0])
    shown = np.bincount(inst, minlength=len(items))[1:]
    culled = r.hiz != Occlusion.VISIBLE
    assert not np.any(culled & (shown > 0)), np.nonzero(culled & (shown > 0))[0]


@pytest.mark.parametrize("side", ["left", "right", "top", "bottom"])
def test_hiz_edge_ties_with_the_snap(side):
    """Box edges a hair off a pixel centre. Vertices snap to 1/256 px, so a box whose exact
    left (or top) edge misses a centre by less than 1/512 px covers it (edges through a
    centre belong to left/top edges). Only that pixel column (row) has a far depth (1.0;
    elsewhere 0.0, where nothing passes), and the boxes are about a pixel wide, so the Hi-Z
    verdict hinges on whether its rectangle includes that pixel: without the pixel slack
    the snapped cases come out OCCLUDED with samples passing."""
    w = h = 64
    c = 21 if side in ("left", "top") else 20   # its level-1 texel ends (starts) with it
    depth = np.zeros((h, w), np.float32)
    if side in ("left", "right"):
        depth[:, c] = 1.0
    else:
        depth[c, :] = 1.0
    offsets = [s * t for s in (-1, 1) for t in (0.0, 1e-5, 1e-4, 1 / 1024, 1 / 600, 1 / 512,
                                                  1 / 400, 1 / 256, 1 / 100, 0.1)]
    lo, hi = [], []
    for t in offsets:
        e = c + 0.5 + t                                     # the edge, window coordinates
        a, b = (e, e + 1.2) if side in ("left", "top") else (e - 1.2, e)
        # a flat box (a quad) at z = 2, distance 3: window x = (x/3 + 1)·32,
        # window y = (1 − y/3)·32; across the edge it spans 0.4 px around a pixel centre
        if side in ("left", "right"):
            x0, x1 = (a / 32 - 1) * 3, (b / 32 - 1) * 3
            y1, y0 = (1 - 30.3 / 32) * 3, (1 - 30.7 / 32) * 3
        else:
            y1, y0 = (1 - a / 32) * 3, (1 - b / 32) * 3
            x0, x1 = (30.3 / 32 - 1) * 3, (30.7 / 32 - 1) * 3
        lo.append([x0, y0, 2.0])
        hi.append([x1, y1, 2.0])
    r = oq()(depth, np.float32(lo), np.float32(hi), HEAD_ON)
    bad = (r.hiz != Occlusion.VISIBLE) & (r.samples > 0)
    assert not bad.any(), [offsets[i] for i in np.nonzero(bad)[0]]
    covered = dict(zip(offsets, (r.samples > 0).tolist(), strict=True))
    occluded = dict(zip(offsets, (r.hiz == Occlusion.OCCLUDED).tolist(), strict=True))
    if side in ("left", "top"):   # edge at the centre + t: covered iff snapped t <= 0
        assert covered[1 / 1024] and covered[0.0] and covered[-1 / 100]
        assert not covered[1 / 400] and not covered[1 / 100]
    else:                         # edge at the centre + t: covered iff snapped t > 0
        assert not covered[0.0] and not covered[1 / 1024] and not covered[-1 / 100]
        assert covered[1 / 400] and covered[1 / 100]
    # culled when clearly off the centre (by more than the 1/16 px slack)
    assert occluded[0.1 if side in ("left", "top") else -0.1]


def test_hiz_culls_a_useful_share():
    """Not vacuous: boxes well behind a wall are OCCLUDED; near-ties may stay VISIBLE but
    most boxes with no passing sample in a dense scene are culled by the pyramid."""
    w, h = 129, 65
    cam, depth, lo, hi, _ = _random_case(12345, w, h, 0.0, synthetic=False)
    r = oq()(depth, lo, hi, cam)
    zero = r.samples == 0
    assert zero.sum() > 50
    culled = r.hiz != Occlusion.VISIBLE
    assert not np.any(culled & ~zero)
    assert culled[zero].mean() > 0.5, culled[zero].mean()


# ---- scale, API, errors -------------------------------------------------------------------

def test_100k_boxes_in_one_query():
    w, h = 64, 48
    rng = np.random.default_rng(4)
    depth = _render_depth(w, h, *_scene_boxes(rng, 30, z=-1.0), HEAD_ON)
    lo, hi = _scene_boxes(rng, 100_000, spread=6.0, z=-1.0, size=(0.001, 0.05))
    r = oq()(depth, lo, hi, HEAD_ON)
    assert r.samples.shape == r.hiz.shape == (100_000,)
    assert not np.any((r.hiz != Occlusion.VISIBLE) & (r.samples > 0))
    vp = _vp(HEAD_ON, w, h)
    assert np.array_equal(r.hiz, ref_pyr.test_boxes(ref_pyr.build(depth), lo, hi, vp, w, h))
    assert (r.samples > 0).sum() > 1000 and (r.hiz == Occlusion.OCCLUDED).sum() > 1000
    sub = slice(0, 100_000, 50)   # the twin on every 50th box
    assert np.array_equal(r.samples[sub], ref_q.samples_passed(depth, lo[sub], hi[sub], vp))


def test_query_api_entry_points():
    w, h = 20, 12
    depth = np.ones((h, w), np.float32)
    lo, hi = np.float32([[-1, -1, -1]]), np.float32([[1, 1, 1]])
    want = oq()(depth, lo, hi, HEAD_ON)
    renderer = get_renderer(w, h)
    for target in (renderer, renderer.context, None):
        r = query(target, depth, lo, hi, HEAD_ON)
        assert isinstance(r, QueryResult)
        assert np.array_equal(r.samples, want.samples) and np.array_equal(r.hiz, want.hiz)
    assert query(None, depth, lo, hi, HEAD_ON, pyramid=False).hiz is None
    empty = query(None, depth, np.zeros((0, 3)), np.zeros((0, 3)), HEAD_ON)
    assert empty.samples.shape == (0,) and empty.hiz.shape == (0,)
    # a raw matrix camera and non-finite boxes (0 samples, VISIBLE)
    cam = MatrixCamera(np.eye(4))
    r = query(None, depth, np.float32([[np.nan, 0, 0], [-0.5, -0.5, 0]]),
              np.float32([[1, 1, 1], [0.5, 0.5, 0.5]]), cam)
    assert r.samples[0] == 0 and r.hiz[0] == Occlusion.VISIBLE
    assert r.samples[1] == (w // 2) * (h // 2)   # NDC [−0.5, 0.5]²: the centre half


def test_query_input_errors():
    depth = np.ones((8, 8), np.float32)
    lo, hi = np.zeros((1, 3)), np.ones((1, 3))
    with pytest.raises(ValueError, match="float32"):
        query(None, depth.astype(np.float64), lo, hi, HEAD_ON)
    with pytest.raises(ValueError, match="float32"):
        query(None, np.ones(8, np.float32), lo, hi, HEAD_ON)
    with pytest.raises(ValueError, match=r"\(K, 3\)"):
        query(None, depth, np.zeros((2, 3)), np.ones((1, 3)), HEAD_ON)
    with pytest.raises(ValueError, match="Camera"):
        query(None, depth, lo, hi, object())
    with pytest.raises(ValueError, match="Renderer"):
        query("gpu", depth, lo, hi, HEAD_ON)


def test_sphere_boxes_contain_spheres():
    rng = np.random.default_rng(1)
    c = rng.normal(0, 1000, (500, 3))
    r = rng.uniform(0, 10, 500)
    lo, hi = sphere_boxes(c, r)
    assert lo.dtype == hi.dtype == np.float32 and lo.shape == (500, 3)
    assert np.all(lo.astype(np.float64) <= c - r[:, None])
    assert np.all(hi.astype(np.float64) >= c + r[:, None])
    with pytest.raises(ValueError):
        sphere_boxes(c, r[:3])


# ---- memory checking on the Oclgrind simulator ---------------------------------------------

_OCLGRIND_SCRIPT = r"""
import json, sys
import numpy as np
import pyopencl as cl
plats = [p for p in cl.get_platforms() if "oclgrind" in p.name.lower()]
if not plats:
    print(json.dumps({"unavailable": True}))
    sys.exit(0)
ctx = cl.Context(plats[0].get_devices())
from clraster import Camera, RasterConfig
from clraster.base.checks import mvp_matrix
from clraster.pipeline.occlusion import OcclusionQuery
from clraster.pipeline.reference import pyramid as rp, query as rq
rng = np.random.default_rng(0)
same = []
for (w, h), tl in (((33, 17), 3), ((17, 9), 4), ((1, 5), 3), ((70, 3), 6)):
    cam = Camera.look_at((0, 0, 5), (0, 0, 0), fov_y=70, near=0.5, far=50)
    depth = rng.choice(np.float32([0.9, 0.95, 1.0]), size=(h, w)).astype(np.float32)
    c = rng.uniform(-3, 3, (30, 3))
    e = rng.uniform(0.01, 1.5, (30, 3))
    lo, hi = (c - e).astype(np.float32), (c + e).astype(np.float32)
    lo[0], hi[0] = [-1, -1, 4], [1, 1, 6]      # around the eye
    lo[1, 0] = np.nan                          # non-finite
    lo[2], hi[2] = [-1, -1, 6], [1, 1, 7]      # behind the eye
    r = OcclusionQuery(ctx, RasterConfig(tile_log2=tl, bin_chunks=5))(depth, lo, hi, cam)
    vp = mvp_matrix(cam, w, h)
    same.append(bool(
        np.array_equal(r.samples, rq.samples_passed(depth, lo, hi, vp, RasterConfig(tile_log2=tl)))
        and np.array_equal(r.hiz, rp.test_boxes(rp.build(depth), lo, hi, vp, w, h))))
print(json.dumps({"same": same}))
"""


def test_kernels_on_oclgrind():
    """The pyramid, box-test and query kernels (and the stages they reuse) on Oclgrind with
    data-race checking: no invalid access or race, and the answers equal the twin's."""
    import json
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    import clraster

    env = dict(os.environ)
    env.pop("PYOPENCL_CTX", None)
    env["OCLGRIND_DATA_RACES"] = "1"
    root = str(Path(clraster.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join([root, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    proc = subprocess.run([sys.executable, "-c", _OCLGRIND_SCRIPT], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    if out.get("unavailable"):
        pytest.skip("no Oclgrind OpenCL platform")
    reports = re.findall(r"^(?:Invalid (?:read|write)|.*data race|.*out of bounds|"
                         r"Uninitiali[sz]ed).*$", proc.stderr, re.MULTILINE | re.IGNORECASE)
    assert not reports, proc.stderr[:4000]
    assert out["same"] == [True] * 4
