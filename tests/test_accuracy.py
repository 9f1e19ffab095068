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

Edge pixels whose centre the snapped coverage takes in but which lie outside the unsnapped
triangle (the oracle's barycentrics have a negative weight; at most 1/512 px outside) are
where the ray caster extrapolates the plane beyond the triangle. clraster raises depth there
to the piece's nearest vertex depth (layout.py PIECE_DTYPE zlo) so culling stays
conservative, which moves such pixels AWAY from the oracle, by up to the extrapolation
(|grad z|/362). The depth bars apply to the pixels whose centre lies in the triangle; at the
others the depth must not be nearer than the oracle's (the clamp only raises) and, at every
pixel, not nearer than the triangle's nearest vertex.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import get_renderer, load_shared_mesh

from clraster import Camera
from clraster.bench.accuracy import ray_oracle

W, H = 320, 240

#: The oracle takes the camera's float64 view-projection, as issue 14 states the bar. The
#: value planes are set up in double from the float64 VP · model (FrameDraws.mvps64), so
#: they do not inherit the float32 rounding of the matrix the vertex stage (coverage) and
#: llvmpipe draw with. Measured at 320x240 over the cameras below
#: (`python -m clraster.bench.accuracy`): depth <= 8.5e-8 (llvmpipe on the same pixels
#: 4.4e-7..1.6e-6 ordinary, <= 1.5e-5 near cut), barycentric p99.9 <= 2.8e-7 (triangles
#: >= 1 px²). From the float32 matrix: depth up to 5.8e-6 and barycentrics 2.6e-5 near cut;
#: from the snapped vertices (before issue 14): depth 5.7e-5..9.7e-4, barycentric p99.9
#: 3.9e-3..3.2e-2.
DEPTH_BOUND = 2e-7
BARY_P999 = 1e-5


class Measured:
    """One render compared with the oracle: frame, mask, oracle depth dz, |depth error|
    derr, signed error dsigned (clraster − oracle), max |barycentric error| berr per pixel,
    triangle area in px², whether the centre lies in the triangle (inside), the oracle's
    nearest vertex depth zmin (arrays over the K covered pixels)."""

    def __init__(self, mesh, cam, cull="back"):
        f = get_renderer(W, H).render(mesh, cam, cull=cull)
        vp = np.asarray(cam.view_projection(W, H), np.float64)
        self.frame = f
        self.mask, self.dz, b, self.area, self.zmin = ray_oracle(mesh, vp, f.triangle_id)
        self.dsigned = f.depth[self.mask].astype(np.float64) - self.dz
        self.derr = np.abs(self.dsigned)
        self.berr = np.abs(f.barycentrics[self.mask].astype(np.float64) - b).max(axis=1)
        self.inside = b.min(axis=1) >= 0.0


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


def _check(mesh, cam, cull, clipped=False):
    m = Measured(mesh, cam, cull)
    assert m.mask.sum() > 1000
    big = m.area >= 1.0
    assert big.sum() > 50
    assert m.inside.mean() > 0.97
    assert m.derr[m.inside].max() <= DEPTH_BOUND, m.derr[m.inside].max()
    # outside the unsnapped triangle the depth is the plane's or raised towards zlo
    assert m.dsigned[~m.inside].min() >= -DEPTH_BOUND, m.dsigned[~m.inside].min()
    if not clipped:
        # no fragment nearer than its triangle's nearest vertex (culling relies on it)
        f = m.frame.depth[m.mask].astype(np.float64)
        assert (f >= m.zmin - DEPTH_BOUND).all(), (m.zmin - f).max()
    assert np.quantile(m.berr[big], 0.999) <= BARY_P999, np.quantile(m.berr[big], 0.999)


@pytest.mark.parametrize("name", MESHES)
def test_depth_and_barycentrics_ordinary_cameras(name):
    mesh = load_shared_mesh(name)
    for cam in _cameras(mesh):
        _check(mesh, cam, "back")


@pytest.mark.parametrize("name", MESHES)
def test_depth_and_barycentrics_near_plane_cut(name):
    """The near plane cuts the mesh: clipped pieces (values from the clipper's double
    vertices, barycentrics relative to the parent triangle)."""
    mesh = load_shared_mesh(name)
    cam = _near_cut(mesh)
    f = get_renderer(W, H).render(mesh, cam, cull="none")
    assert f.stats.clipped > 0
    _check(mesh, cam, "none", clipped=True)


def _peer():
    from clraster.bench.peer_llvmpipe import LlvmpipePeer, probe

    ok, why = probe()
    if not ok:
        pytest.skip(f"peer unavailable: {why}")
    return LlvmpipePeer(W, H)


@pytest.mark.parametrize("name", MESHES)
def test_depth_no_worse_than_llvmpipe(name):
    """On pixels where clraster and llvmpipe show the same triangle (centres inside it),
    clraster's max window depth error against the oracle is no worse than llvmpipe's
    (ordinary cameras and a near-plane cut)."""
    mesh = load_shared_mesh(name)
    peer = _peer()
    try:
        peer.upload(mesh)
        for cam, cull in [*((c, "back") for c in _cameras(mesh)), (_near_cut(mesh), "none")]:
            m = Measured(mesh, cam, cull)
            pf = peer.render(cam.view_projection(W, H), cull=cull, repeat=1, ids=True)
            if pf.depth_format != "depth32f":
                pytest.skip("llvmpipe fell back to a 24-bit depth buffer")
            same = (pf.triangle_id[m.mask] == m.frame.triangle_id[m.mask]) & m.inside
            assert same.mean() > 0.95
            perr = np.abs(pf.depth[m.mask].astype(np.float64) - m.dz)
            ours, theirs = m.derr[same].max(), perr[same].max()
            assert ours <= max(theirs, 1.5e-7), (ours, theirs)
    finally:
        peer.release()


def test_steep_edge_pixels_never_nearer_than_their_vertices():
    """Slivers whose depth changes steeply across their width: where a pixel centre is
    covered by the snapped triangle but lies just outside the unsnapped one, the depth plane
    extrapolates nearer than every vertex. Culling's error model (pyramid.cl) needs no
    fragment nearer than its triangle's nearest vertex, so depth is raised to it there."""
    from conftest import MatrixCamera, window_to_ndc

    from clraster import Mesh

    rng = np.random.default_rng(14)
    n = 4000
    # long thin triangles (0.05–0.6 px high, 4–30 px long) at positions off the 1/256 grid,
    # vertex depths anywhere in the view volume
    x0 = rng.uniform(2, W - 40, n)
    y0 = rng.uniform(2, H - 4, n)
    length = rng.uniform(4, 30, n)
    thick = rng.uniform(0.05, 0.6, n)
    xw = np.stack([x0, x0 + length, x0 + rng.uniform(0, 1, n) * length], axis=1)
    yw = np.stack([y0, y0 + rng.uniform(-0.3, 0.3, n), y0 + thick], axis=1)
    zn = rng.uniform(-0.95, 0.95, (n, 3))
    xn, yn = window_to_ndc(xw, yw, W, H)
    v = np.stack([xn, yn, zn], axis=-1).reshape(-1, 3)
    mesh = Mesh(v.astype(np.float32), np.arange(3 * n).reshape(-1, 3))
    f = get_renderer(W, H).render(mesh, MatrixCamera(np.eye(4)), cull="none")
    mask = f.triangle_id >= 0
    assert mask.sum() > 2000
    zv = (mesh.vertices.astype(np.float64)[:, 2].reshape(-1, 3) * 0.5 + 0.5).min(axis=1)
    below = zv[f.triangle_id[mask]] - f.depth[mask].astype(np.float64)
    assert below.max() <= 1e-7, below.max()
