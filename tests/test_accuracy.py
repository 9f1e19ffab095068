"""Window depth and barycentrics against a float64 ray caster (issue 14, item 1).

Coverage snaps vertices to 1/256 px (24.8 fixed point); the values written at covered pixels
must not move with the snap: setup.cl's value planes come from the unsnapped vertices. The
oracle, per covered pixel: the ray through the pixel centre meets the plane of the triangle
clraster says is visible there; its window depth (z/w + 1)/2 and its barycentrics relative to
the triangle's three vertices are solved in float64 from the float64 view-projection and the
mesh's float32 vertices. Real meshes (spot, bunny, dragon_res2) at ordinary cameras and with
the near plane cutting the mesh (clipped triangles).

Bars: max |window depth − oracle| no worse than Mesa llvmpipe's on the same pixels (where a
headless llvmpipe is available: clraster.bench.peer_llvmpipe), and always an absolute bound
measured here; barycentric error <= 1e-5 at the 99.9th percentile over pixels of triangles
covering >= 1 pixel.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import get_renderer, load_shared_mesh

from clraster import Camera

W, H = 320, 240

#: Two oracles. "f32": the float32 matrix the renderer draws with (VP · model rounded to
#: float32, as llvmpipe gets it too) in float64 from there on: what the rasterizer itself
#: adds. "f64": the float64 view-projection, as issue 14 states the bar (it includes the
#: float32 rounding of the matrix, which is the vertex stage's input, not the rasterizer's).
#: Measured at 320x240 (max over the cameras below), values from the unsnapped double
#: vertices: f32 depth <= 8.6e-8, barycentric p99.9 <= 3e-7 (triangles >= 1 px²);
#: f64 depth 1.2e-7..9.3e-7 ordinary, <= 5.8e-6 near cut (llvmpipe on the same pixels
#: 4.4e-7..1.6e-6 and <= 1.5e-5). Values from the snapped vertices (before): f64 depth
#: 5.7e-5..9.7e-4, barycentric p99.9 3.9e-3..3.2e-2.
DEPTH_BOUND_F32 = 2e-7
BARY_P999 = 1e-5
DEPTH_BOUND_F64 = 2e-6
DEPTH_BOUND_F64_NEAR_CUT = 1.5e-5


def oracle(mesh, vp: np.ndarray, ids: np.ndarray):
    """Float64 ray–plane oracle at the pixel centres of `ids` >= 0, for the float64
    view-projection `vp` (4, 4) (column vectors).

    Returns (mask bool (H, W), depth float64 (K,), barycentrics float64 (K, 3), screen area
    of the pixel's triangle in px² float64 (K,)) for the K pixels of the mask, row-major.
    """
    h, w = ids.shape
    mask = ids >= 0
    ys, xs = np.nonzero(mask)
    tri = mesh.faces[ids[mask]]
    p = mesh.vertices[tri].astype(np.float64)                       # (K, 3, 3)
    c = np.einsum("ij,kvj->kvi", vp[:, :3], p) + vp[:, 3]            # (K, 3, 4)
    xn = 2.0 * (xs + 0.5) / w - 1.0
    yn = 1.0 - 2.0 * (ys + 0.5) / h
    # b with sum 1 whose clip point projects to (xn, yn): a 3x3 solve per pixel
    a = np.empty((xs.size, 3, 3))
    a[:, 0] = c[:, :, 0] - xn[:, None] * c[:, :, 3]
    a[:, 1] = c[:, :, 1] - yn[:, None] * c[:, :, 3]
    a[:, 2] = 1.0
    rhs = np.zeros((xs.size, 3, 1))
    rhs[:, 2] = 1.0
    b = np.linalg.solve(a, rhs)[:, :, 0]
    q = np.einsum("kv,kvi->ki", b, c)
    depth = (q[:, 2] / q[:, 3]) * 0.5 + 0.5
    sx = (c[..., 0] / c[..., 3] + 1.0) * (w / 2)
    sy = (1.0 - c[..., 1] / c[..., 3]) * (h / 2)
    area = 0.5 * np.abs((sx[:, 1] - sx[:, 0]) * (sy[:, 2] - sy[:, 0])
                        - (sy[:, 1] - sy[:, 0]) * (sx[:, 2] - sx[:, 0]))
    return mask, depth, b, area


def _measure(mesh, cam, cull="back", matrix="f32"):
    """Render and compare: (frame, mask, oracle depth, |depth error|, max |barycentric
    error| per pixel, triangle area in px² per pixel) against the `matrix` oracle."""
    f = get_renderer(W, H).render(mesh, cam, cull=cull)
    vp = np.asarray(cam.view_projection(W, H), np.float64)
    if matrix == "f32":
        vp = vp.astype(np.float32).astype(np.float64)
    mask, dz, b, area = oracle(mesh, vp, f.triangle_id)
    derr = np.abs(f.depth[mask].astype(np.float64) - dz)
    berr = np.abs(f.barycentrics[mask].astype(np.float64) - b).max(axis=1)
    return f, mask, dz, derr, berr, area


def _cameras(mesh):
    lo, hi = mesh.bounds()
    return [Camera.framing(lo, hi, direction=d, aspect=W / H)
            for d in ((0.7, 0.4, 1.0), (-1.0, 0.2, -0.3))]


def _near_cut(mesh):
    """A camera whose near plane cuts through the mesh (many clipped triangles)."""
    lo, hi = np.asarray(mesh.bounds()[0], float), np.asarray(mesh.bounds()[1], float)
    centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    eye = centre + size * np.array([0.35, 0.2, 0.6])
    dist = float(np.linalg.norm(eye - centre))
    return Camera.look_at(eye, centre, fov_y=50.0, near=0.8 * dist, far=3.0 * dist)


MESHES = ["spot.ply", "stanford_bunny.ply", "stanford_dragon_res2.ply"]


def _check(mesh, cam, cull, f64_bound):
    _, mask, _, derr, berr, area = _measure(mesh, cam, cull, "f32")
    assert mask.sum() > 1000
    big = area >= 1.0
    assert big.sum() > 50
    assert derr.max() <= DEPTH_BOUND_F32, derr.max()
    assert np.quantile(berr[big], 0.999) <= BARY_P999, np.quantile(berr[big], 0.999)
    _, _, _, derr64, _, _ = _measure(mesh, cam, cull, "f64")
    assert derr64.max() <= f64_bound, derr64.max()


@pytest.mark.parametrize("name", MESHES)
def test_depth_and_barycentrics_ordinary_cameras(name):
    mesh = load_shared_mesh(name)
    for cam in _cameras(mesh):
        _check(mesh, cam, "back", DEPTH_BOUND_F64)


@pytest.mark.parametrize("name", MESHES)
def test_depth_and_barycentrics_near_plane_cut(name):
    """The near plane cuts the mesh: clipped pieces (values from the clipper's double
    vertices, barycentrics relative to the parent triangle)."""
    mesh = load_shared_mesh(name)
    cam = _near_cut(mesh)
    f = get_renderer(W, H).render(mesh, cam, cull="none")
    assert f.stats.clipped > 0
    _check(mesh, cam, "none", DEPTH_BOUND_F64_NEAR_CUT)


def _peer():
    from clraster.bench.peer_llvmpipe import LlvmpipePeer, probe

    ok, why = probe()
    if not ok:
        pytest.skip(f"peer unavailable: {why}")
    return LlvmpipePeer(W, H)


@pytest.mark.parametrize("name", MESHES)
def test_depth_no_worse_than_llvmpipe(name):
    """On pixels where clraster and llvmpipe show the same triangle, clraster's max window
    depth error against the oracle is no worse than llvmpipe's (ordinary cameras and a
    near-plane cut)."""
    mesh = load_shared_mesh(name)
    peer = _peer()
    try:
        peer.upload(mesh)
        for cam, cull in [*((c, "back") for c in _cameras(mesh)), (_near_cut(mesh), "none")]:
            f, mask, dz, derr, _, _ = _measure(mesh, cam, cull, "f64")
            pf = peer.render(cam.view_projection(W, H), cull=cull, repeat=1, ids=True)
            if pf.depth_format != "depth32f":
                pytest.skip("llvmpipe fell back to a 24-bit depth buffer")
            same = (pf.triangle_id[mask] == f.triangle_id[mask])
            assert same.mean() > 0.95
            perr = np.abs(pf.depth[mask].astype(np.float64) - dz)
            ours, theirs = derr[same].max(), perr[same].max()
            assert ours <= max(theirs, 1.5e-7), (ours, theirs)
    finally:
        peer.release()
