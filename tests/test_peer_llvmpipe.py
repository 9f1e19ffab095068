"""The peer renderer (Mesa llvmpipe through moderngl) agrees with clraster.

Same mesh, same view-projection, same size: coverage masks, window depth and triangle ids
compare pixel for pixel, which pins the conventions the peer must translate (row 0 = top,
d = (z/w + 1)/2, column-major matrices, counter-clockwise front faces). Negative controls
show that a transposed matrix, an unflipped image or a reversed cull sense would fail.

Tests that draw skip with probe()'s reason where no headless EGL context with llvmpipe can
be created; coverage_agreement and probe's failure paths are tested everywhere.
"""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
from conftest import MatrixCamera, get_renderer, load_shared_mesh

from clraster import Camera, Mesh
from clraster.bench import peer_llvmpipe as peer_mod
from clraster.bench.peer_llvmpipe import LlvmpipePeer, coverage_agreement, probe
from clraster.world.scene import Scene

OK, WHY = probe()
needs_gl = pytest.mark.skipif(not OK, reason=f"peer unavailable: {WHY}")

W, H = 320, 240


@pytest.fixture(scope="module")
def peer():
    p = LlvmpipePeer(W, H)
    yield p
    p.release()


@pytest.fixture(scope="module")
def small_peer():
    p = LlvmpipePeer(64, 48)
    yield p
    p.release()


def _clraster(target, cam, w, h, cull="back", clip_planes=None):
    kw = {} if clip_planes is None else {"clip_planes": clip_planes}
    return get_renderer(w, h).render(target, cam, cull=cull, **kw)


def _spot_camera(mesh):
    lo, hi = mesh.bounds()
    # off-axis direction: an image that is not symmetric under flips or a transpose
    return Camera.framing(lo, hi, direction=(0.7, 0.4, 1.0), aspect=W / H)


# -- probe ----------------------------------------------------------------------------------

def test_probe_returns_a_reason():
    ok, why = probe()
    assert isinstance(ok, bool) and isinstance(why, str) and why
    if ok:
        assert "llvmpipe" in why and "OpenGL" in why
    else:
        assert "install" in why


def test_probe_without_moderngl_says_what_to_install(monkeypatch):
    monkeypatch.setattr(peer_mod, "_PROBE", None)
    monkeypatch.setitem(sys.modules, "moderngl", None)   # import moderngl → ImportError
    ok, why = probe()
    assert not ok
    assert "moderngl" in why and "clraster[peers]" in why and "libegl-mesa0" in why
    with pytest.raises(RuntimeError, match="clraster\\[peers\\]"):
        LlvmpipePeer(8, 8)


def test_probe_refuses_a_gpu_renderer(monkeypatch):
    released = []

    class FakeContext:
        info = {"GL_RENDERER": "NVIDIA GeForce RTX 4090/PCIe/SSE2",
                "GL_VERSION": "4.6.0 NVIDIA 550.54"}

        def release(self):
            released.append(self)

    def create(backend, require, device_index=0):
        if device_index > 1:
            raise RuntimeError("eglInitialize failed")
        return FakeContext()

    fake = types.SimpleNamespace(create_standalone_context=create)
    monkeypatch.setattr(peer_mod, "_PROBE", None)
    monkeypatch.setitem(sys.modules, "moderngl", fake)
    ok, why = probe()
    assert not ok
    assert "NVIDIA GeForce" in why and "not Mesa's llvmpipe" in why and "install" in why
    assert len(released) == 2   # both GPU contexts given back


def test_probe_never_raises(monkeypatch):
    def create(**kw):
        raise SystemError("driver exploded")

    monkeypatch.setattr(peer_mod, "_PROBE", None)
    monkeypatch.setattr(peer_mod, "_create_context", lambda: create())
    ok, why = probe()
    assert not ok and "driver exploded" in why


# -- coverage_agreement ---------------------------------------------------------------------

def test_coverage_agreement_counts():
    a = np.array([[0.5, 1.0], [0.25, 1.0]], np.float32)
    b = np.array([[0.5, 0.3], [1.0, 1.0]], np.float32)
    r = coverage_agreement(a, b)
    assert r["pixels"] == 4
    assert r["agree"] == 0.5 and r["agree_pixels"] == 2
    assert (r["both"], r["clraster_only"], r["peer_only"]) == (1, 1, 1)
    assert r["depth_diff_median"] == 0.0 and r["depth_diff_max"] == 0.0


def test_coverage_agreement_depth_stats():
    a = np.array([[0.125, 0.25, 0.5, 0.375, 1.0]])
    b = np.array([[0.125, 0.375, 0.25, 1.0, 1.0]])
    r = coverage_agreement(a, b)
    assert r["agree"] == pytest.approx(0.8) and r["agree_pixels"] == 4
    assert (r["both"], r["clraster_only"], r["peer_only"]) == (3, 1, 0)
    # |differences| over the 3 pixels both cover: 0, 0.125, 0.25
    assert r["depth_diff_median"] == 0.125
    assert r["depth_diff_p99"] == pytest.approx(0.125 + 0.98 * 0.125)
    assert r["depth_diff_max"] == 0.25


def test_coverage_agreement_edge_cases():
    bg = np.ones((3, 4), np.float32)
    r = coverage_agreement(bg, bg)
    assert r["agree"] == 1.0 and r["both"] == 0 and r["depth_diff_median"] is None
    nan = bg.copy()
    nan[0, 0] = np.nan   # NaN is background
    assert coverage_agreement(bg, nan)["agree"] == 1.0
    # anything with a .depth (Frame, PeerFrame) is accepted
    assert coverage_agreement(types.SimpleNamespace(depth=bg), bg)["pixels"] == 12
    with pytest.raises(ValueError, match="same shape"):
        coverage_agreement(bg, bg.T)


# -- single triangles ----------------------------------------------------------------------

def _tri_camera():
    """An asymmetric world → clip matrix (x shifted by 0.25, y scaled, a perspective w): a
    transposed upload would move the triangle and change its depth."""
    m = np.array([[1.0, 0.0, 0.0, 0.25],
                  [0.0, 0.8, 0.0, 0.0],
                  [0.0, 0.0, 0.5, 0.1],
                  [0.0, 0.0, -0.1, 1.0]])
    return MatrixCamera(m)


# counter-clockwise in NDC, in the upper-left part of the image
CCW = Mesh([[-0.9, 0.1, 0.2], [-0.2, 0.15, -0.3], [-0.85, 0.95, 0.6]], [[0, 1, 2]])
CW = Mesh(CCW.vertices, [[0, 2, 1]])


@needs_gl
def test_triangle_matches_clraster_pixel_for_pixel(small_peer):
    cam = _tri_camera()
    small_peer.upload(CCW)
    pf = small_peer.render(cam.matrix, repeat=1, ids=True)
    f = _clraster(CCW, cam, 64, 48)
    assert pf.depth.shape == (48, 64) and pf.depth.dtype == np.float32
    assert pf.depth_format == "depth32f"
    assert f.mask.sum() > 150
    np.testing.assert_array_equal(pf.coverage, f.mask)
    np.testing.assert_array_equal(pf.triangle_id, f.triangle_id)
    # row 0 is the top: the triangle is in the upper-left quadrant
    ys, xs = np.nonzero(pf.coverage)
    assert ys.max() < 24 and xs.max() < 40
    m = f.mask
    assert np.all(pf.depth[~m] == 1.0)
    # window depth d = (z/w + 1)/2 at the vertices, interpolated linearly in screen space
    clip = np.c_[CCW.vertices.astype(np.float64), np.ones(3)] @ cam.matrix.T
    ndc = clip[:, :3] / clip[:, 3:]
    win = np.c_[(ndc[:, 0] + 1) / 2 * 64, (1 - ndc[:, 1]) / 2 * 48, np.ones(3)]
    plane = np.linalg.solve(win, (ndc[:, 2] + 1) / 2)
    ys, xs = np.nonzero(m)
    exact = plane[0] * (xs + 0.5) + plane[1] * (ys + 0.5) + plane[2]
    assert np.abs(pf.depth[m] - exact).max() < 1e-6
    # clraster interpolates over the vertices snapped to 1/256 pixel, llvmpipe over the
    # unsnapped ones: they differ by at most the depth gradient times the snap (1/512 px)
    snap = (abs(plane[0]) + abs(plane[1])) / 512
    diff = np.abs(pf.depth[m].astype(np.float64) - f.depth[m])
    assert 1e-6 < snap < 1e-4 and diff.max() <= snap + 1e-6


@needs_gl
def test_wrong_conventions_would_be_caught(small_peer):
    cam = _tri_camera()
    small_peer.upload(CCW)
    f = _clraster(CCW, cam, 64, 48)
    good = small_peer.render(cam.matrix, repeat=1)
    transposed = small_peer.render(cam.matrix.T.copy(), repeat=1)
    assert not np.array_equal(transposed.coverage, f.mask)
    assert not np.array_equal(good.coverage[::-1], f.mask)   # an unflipped read-back


@needs_gl
def test_clockwise_triangle_culled_like_clraster(small_peer):
    cam = _tri_camera()
    small_peer.upload(CW)
    for cull, drawn in (("back", False), ("none", True), ("front", True)):
        pf = small_peer.render(cam.matrix, cull=cull, repeat=1)
        f = _clraster(CW, cam, 64, 48, cull=cull)
        assert bool(pf.coverage.any()) is drawn, cull
        np.testing.assert_array_equal(pf.coverage, f.mask, err_msg=cull)
    small_peer.upload(CCW)
    assert not small_peer.render(cam.matrix, cull="front", repeat=1).coverage.any()


# -- meshes and scenes ----------------------------------------------------------------------

@needs_gl
@pytest.mark.parametrize("cull", ["back", "front"])
def test_spot_agrees_with_clraster(peer, cull):
    mesh = load_shared_mesh("spot.ply")
    cam = _spot_camera(mesh)
    vp = cam.view_projection(W, H)
    f = _clraster(mesh, cam, W, H, cull=cull)
    peer.upload(mesh)
    pf = peer.render(vp, cull=cull, repeat=2, ids=True)
    assert len(pf.times_ms) == 2 and all(t > 0 for t in pf.times_ms)
    assert pf.readback_ms > 0 and "llvmpipe" in pf.renderer
    r = coverage_agreement(f.depth, pf.depth)
    assert r["agree"] >= 0.999, r
    assert r["both"] > 5000
    assert r["depth_diff_median"] < 2e-6 and r["depth_diff_p99"] < 1e-4, r
    both = f.mask & pf.coverage
    # ids pin the cull sense: spot is closed, so front- and back-culled silhouettes match,
    # but the faces drawn do not
    assert np.mean(f.triangle_id[both] == pf.triangle_id[both]) >= 0.999
    if cull == "back":
        # negative controls: a transposed matrix or an unflipped image disagree a lot
        t = peer.render(vp.T.copy(), repeat=1)
        assert coverage_agreement(f.depth, t.depth)["agree"] < 0.95
        assert coverage_agreement(f.depth, pf.depth[::-1])["agree"] < 0.95
        other = peer.render(vp, cull="front", repeat=1, ids=True)
        assert np.mean(f.triangle_id[both] == other.triangle_id[both]) < 0.5


def _instances_scene():
    """Three spots (one mirrored: negative determinant) and a quad behind them."""
    spot = load_shared_mesh("spot.ply")
    quad = Mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])

    def rot_y(a, t, s=1.0):
        c, si = np.cos(a), np.sin(a)
        m = np.eye(4)
        m[:3, :3] = s * np.array([[c, 0, si], [0, 1, 0], [-si, 0, c]])
        m[:3, 3] = t
        return m

    mirror = rot_y(0.0, (0.0, 0.0, -1.2))
    mirror[0, 0] = -1.0    # negative determinant: flips the winding on screen
    return Scene([(spot, rot_y(0.3, (-0.8, 0.0, 0.0))),
                  (quad, rot_y(0.0, (0.0, 0.0, -2.0), 1.5)),
                  (spot, rot_y(-0.9, (0.8, 0.1, 0.2), 0.8)),
                  (spot, mirror)])


@needs_gl
def test_scene_instances_agree_with_clraster(peer):
    scene = _instances_scene()
    lo, hi = scene.bounds()
    cam = Camera.framing(lo, hi, direction=(0.3, 0.5, 1.0), aspect=W / H)
    f = _clraster(scene, cam, W, H)
    peer.upload(scene)
    assert peer.n_draws == 3          # one instanced draw per distinct mesh and mirroring
    pf = peer.render(cam.view_projection(W, H), repeat=1, ids=True)
    r = coverage_agreement(f, pf)
    assert r["agree"] >= 0.999 and r["both"] > 10000, r
    assert r["depth_diff_median"] < 2e-6, r
    both = f.mask & pf.coverage
    assert np.mean(f.triangle_id[both] == pf.triangle_id[both]) >= 0.999
    # every instance shows, with its scene-wide ids (face_base[i] + face)
    inst, _ = scene.split_ids(pf.triangle_id[pf.coverage])
    assert set(np.unique(inst).tolist()) == {0, 1, 2, 3}


# -- user clip planes -----------------------------------------------------------------------

def _plane(normal, point):
    """(a, b, c, d) of the plane through ``point`` keeping the side ``normal`` points to."""
    n = np.asarray(normal, np.float64)
    return [*n, -float(n @ np.asarray(point, np.float64))]


def _spot_cuts(mesh):
    """1, 2 or 3 planes through spot, tilted so the camera of `_spot_camera` looks into the
    opened shell (cull="none" then draws inside faces that cull="back" drops)."""
    lo, hi = mesh.bounds()
    c = (lo + hi) / 2
    return {
        1: [_plane((-0.7, -0.4, -1.0), c)],
        2: [_plane((-0.4, -1.0, -0.5), c + (0.0, 0.2, 0.0)),
            _plane((1.0, 0.0, -0.3), c + (0.15, 0.0, 0.0))],
        3: [_plane((-0.3, -1.0, -0.4), c + (0.0, 0.25, 0.0)),
            _plane((-1.0, 0.0, 0.4), c + (0.3, 0.0, 0.0)),
            _plane((0.2, 0.3, -1.0), c + (0.0, 0.0, 0.4))],
    }


@needs_gl
@pytest.mark.parametrize("k", [1, 2, 3])
@pytest.mark.parametrize("cull", ["none", "back"])
def test_spot_cut_by_clip_planes_agrees_with_clraster(peer, cull, k):
    mesh = load_shared_mesh("spot.ply")
    cam = _spot_camera(mesh)
    vp = cam.view_projection(W, H)
    planes = _spot_cuts(mesh)[k]
    whole = _clraster(mesh, cam, W, H, cull=cull)
    f = _clraster(mesh, cam, W, H, cull=cull, clip_planes=planes)
    peer.upload(mesh)
    pf = peer.render(vp, cull=cull, repeat=1, ids=True, clip_planes=planes)
    r = coverage_agreement(f, pf)
    assert r["agree"] >= 0.999 and r["both"] >= 1000, r
    assert r["depth_diff_median"] < 2e-6, r
    # the cut removes a real share of the uncut coverage, so a renderer that ignored the
    # planes would fail the agreement above
    assert f.mask.sum() < 0.85 * whole.mask.sum()
    assert coverage_agreement(whole, pf)["agree"] < 0.99
    both = f.mask & pf.coverage
    # clipped pieces keep their parent's id
    assert np.mean(f.triangle_id[both] == pf.triangle_id[both]) >= 0.999
    if (cull, k) == ("back", 1):
        # negative control: the planes' other side (a flipped sign convention) disagrees
        flipped = peer.render(vp, cull=cull, repeat=1, clip_planes=-np.asarray(planes))
        assert coverage_agreement(f, flipped)["agree"] < 0.95
        # no planes and an empty (0, 4) list both draw the whole mesh
        assert np.array_equal(peer.render(vp, cull=cull, repeat=1).coverage, whole.mask)
        empty = peer.render(vp, cull=cull, repeat=1, clip_planes=np.zeros((0, 4)))
        assert np.array_equal(empty.coverage, whole.mask)


@needs_gl
def test_scene_instances_cut_by_a_clip_plane_agree_with_clraster(peer):
    scene = _instances_scene()
    lo, hi = scene.bounds()
    cam = Camera.framing(lo, hi, direction=(0.3, 0.5, 1.0), aspect=W / H)
    # an oblique plane through the mirrored spot and the quad: keeps the left side
    planes = [_plane((-1.0, -0.4, 0.1), (-0.1, 0.1, -1.2))]
    whole = _clraster(scene, cam, W, H)
    f = _clraster(scene, cam, W, H, clip_planes=planes)
    peer.upload(scene)
    pf = peer.render(cam.view_projection(W, H), repeat=1, ids=True, clip_planes=planes)
    r = coverage_agreement(f, pf)
    assert r["agree"] >= 0.999 and r["both"] >= 1000, r
    assert r["depth_diff_median"] < 2e-6, r
    assert f.mask.sum() < 0.85 * whole.mask.sum()
    both = f.mask & pf.coverage
    assert np.mean(f.triangle_id[both] == pf.triangle_id[both]) >= 0.999
    # the quad and the mirrored spot are cut, not dropped: each keeps part of its pixels
    inst_whole = np.bincount(scene.split_ids(whole.triangle_id[whole.mask])[0], minlength=4)
    inst_cut = np.bincount(scene.split_ids(f.triangle_id[f.mask])[0], minlength=4)
    for i in (1, 3):
        assert 0.1 * inst_whole[i] < inst_cut[i] < 0.9 * inst_whole[i], (inst_whole, inst_cut)


@needs_gl
def test_render_checks_and_release():
    p = LlvmpipePeer(16, 16)
    with pytest.raises(RuntimeError, match="upload"):
        p.render(np.eye(4))
    p.upload(CCW)
    with pytest.raises(ValueError, match="cull"):
        p.render(np.eye(4), cull="sideways")
    with pytest.raises(ValueError, match="4, 4"):
        p.render(np.eye(3))
    with pytest.raises(TypeError, match="Mesh or Scene"):
        p.upload("dragon.ply")
    with pytest.raises(ValueError):
        p.render(np.eye(4), clip_planes=np.zeros((9, 4)) + [1, 0, 0, 0])   # at most 8
    with pytest.raises(ValueError):
        p.render(np.eye(4), clip_planes=[[0, 0, 0, 1]])   # no normal
    assert p.render(np.eye(4), cull="none", repeat=1).coverage.any()
    # CCW lies at x < 0: kept by x <= 0, gone with x >= 0.5 (and the clip program is freed)
    assert p.render(np.eye(4), repeat=1, clip_planes=[[-1, 0, 0, 0]]).coverage.any()
    assert not p.render(np.eye(4), repeat=1, clip_planes=[[1, 0, 0, -0.5]]).coverage.any()
    p.release()
    p.release()   # idempotent
