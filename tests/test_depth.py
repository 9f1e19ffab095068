"""Depth and barycentrics against closed-form values.

Eye space, camera at the origin looking down −Z, gluPerspective(fov_y, W/H, n, f); a point
at eye depth d (z_eye = −d) has window depth

    depth(d) = ((f + n)/(f − n) − 2·f·n / ((f − n)·d)) · 0.5 + 0.5,

and the ray through pixel centre (x + 0.5, y + 0.5) has direction
(x_ndc·tan(fov_y/2)·W/H, y_ndc·tan(fov_y/2), −1). Expected values are computed in float64
from these formulas, never from the renderer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import (
    MatrixCamera,
    assert_frames_equal,
    perspective,
    pixel_centres,
    render_both,
    render_cl,
)

from clraster import Camera, Mesh


def window_depth(d, near, far):
    d = np.asarray(d, dtype=np.float64)
    return ((far + near) / (far - near) - 2 * far * near / ((far - near) * d)) * 0.5 + 0.5


def pixel_rays(w, h, fov_y):
    """(H, W, 3) eye-space ray directions with z = −1 through the pixel centres."""
    xc, yc = pixel_centres(w, h)
    ty = math.tan(math.radians(fov_y) / 2)
    return np.stack([(xc / w * 2 - 1) * ty * w / h, (1 - yc / h * 2) * ty,
                     -np.ones_like(xc)], axis=-1)


def plane_depth(p0, nrm, w, h, fov, near, far):
    """Analytic window depth of the plane through p0 with normal nrm at every pixel centre,
    and the error the 1/256-px vertex snap may add: vertices move by ≤ √2/512 px and depth
    is affine in screen space, so the interpolated depth may be off by |∇depth|·√2/512.
    (Grazing planes are ill-conditioned: there the bound is large, and honest.)"""
    xc, yc = pixel_centres(w, h)
    ty = math.tan(math.radians(fov) / 2)

    def at(dx, dy):
        rays = np.stack([((xc + dx) / w * 2 - 1) * ty * w / h, (1 - (yc + dy) / h * 2) * ty,
                         -np.ones_like(xc)], axis=-1)
        return window_depth((p0 @ nrm) / (rays @ nrm), near, far)

    e = 1e-3
    grad = np.hypot(at(e, 0) - at(-e, 0), at(0, e) - at(0, -e)) / (2 * e)
    return at(0, 0), grad * math.sqrt(2) / 512 + 2e-6


def plane_quad(p0, u, v, half: float) -> Mesh:
    """A square (two triangles, counter-clockwise seen from +normal = u × v)."""
    p0, u, v = (np.asarray(a, dtype=np.float64) for a in (p0, u, v))
    c = [p0 + half * (-u - v), p0 + half * (u - v), p0 + half * (u + v), p0 + half * (-u + v)]
    return Mesh(np.array(c), [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("d", [0.5001, 0.75, 2.0, 13.7, 99.0])
@pytest.mark.parametrize("near, far", [(0.5, 100.0), (0.1, 1000.0)])
def test_frontal_plane_depth(d, near, far):
    if d <= near:
        pytest.skip("plane in front of the near plane")
    w, h = 33, 17
    fov = 60.0
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    # a quad at z = −d covering the whole view
    half = 3 * d * math.tan(math.radians(fov)) * w / h
    mesh = plane_quad([0, 0, -d], [1, 0, 0], [0, 1, 0], half)
    fr = render_cl(mesh, cam, w, h, cull="back")
    assert fr.mask.all()
    expected = window_depth(d, near, far)
    np.testing.assert_allclose(fr.depth, expected, rtol=0, atol=1e-6)
    assert 0.0 <= expected < 1.0


def test_near_and_far_planes_map_to_0_and_1():
    w, h = 16, 16
    near, far = 1.0, 10.0
    cam = MatrixCamera(perspective(90.0, 1.0, near, far))
    # (exactly on the near plane is a float32 coin toss: z/w = −1 ± 1 ulp)
    d_near = near * (1 + 1e-5)
    at_near = render_cl(plane_quad([0, 0, -d_near], [1, 0, 0], [0, 1, 0], 5.0), cam, w, h)
    assert at_near.mask.all()
    np.testing.assert_allclose(at_near.depth, window_depth(d_near, near, far), atol=1e-6)
    assert (at_near.depth >= 0).all() and (at_near.depth < 1e-4).all()
    just_inside_far = render_cl(plane_quad([0, 0, -far * 0.999], [1, 0, 0], [0, 1, 0], 50.0),
                                cam, w, h)
    assert just_inside_far.mask.all()
    np.testing.assert_allclose(just_inside_far.depth, window_depth(far * 0.999, near, far),
                               atol=1e-6)
    assert (just_inside_far.depth < 1.0).all()
    beyond_far = render_cl(plane_quad([0, 0, -far * 1.01], [1, 0, 0], [0, 1, 0], 50.0),
                           cam, w, h)
    assert not beyond_far.mask.any()
    assert beyond_far.stats.trivially_rejected == 2
    behind_near = render_cl(plane_quad([0, 0, -near * 0.99], [1, 0, 0], [0, 1, 0], 5.0),
                            cam, w, h)
    assert not behind_near.mask.any()


@pytest.mark.parametrize("normal", [(0.0, 0.5, 1.0), (0.8, -0.3, 1.0), (-2.0, 1.0, 1.0)])
@pytest.mark.parametrize("size", [(64, 48), (31, 65)])
def test_tilted_plane_depth_and_perspective_barycentrics(normal, size):
    w, h = size
    near, far, fov = 0.5, 50.0, 70.0
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    nrm = np.asarray(normal) / np.linalg.norm(normal)
    p0 = np.array([0.05, -0.02, -4.0])
    u = np.cross(nrm, [0.0, 1.0, 0.3])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    mesh = plane_quad(p0, u, v, 3.0)
    fr = render_cl(mesh, cam, w, h, cull="none")
    m = fr.mask
    assert m.sum() > w * h // 3
    rays = pixel_rays(w, h, fov)
    s = (p0 @ nrm) / (rays @ nrm)  # eye depth of the plane along each pixel ray
    exp, tol = plane_depth(p0, nrm, w, h, fov, near, far)
    assert np.median(tol[m]) < 1e-4  # well-conditioned: the check below is tight
    err = np.abs(fr.depth[m] - exp[m])
    assert (err <= tol[m]).all(), f"depth off by {err.max()}"
    # barycentrics: perspective-correct, relative to the visible face's own vertices
    b = fr.barycentrics[m].astype(np.float64)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, atol=1e-5)
    # values come from the unsnapped triangle, coverage from the snapped one: a covered pixel
    # centre can lie up to sqrt(2)/512 px outside the unsnapped triangle, where a weight is
    # that distance over the triangle's altitude (>= ~15 px here) below 0
    assert b.min() > -2e-4
    verts = mesh.vertices.astype(np.float64)[mesh.faces[fr.triangle_id[m]]]  # (K, 3, 3)
    pt = np.einsum("ki,kij->kj", b, verts)  # reconstructed eye-space point
    # it lies on the pixel's ray: compare its projection with the pixel centre, in pixels
    ty = math.tan(math.radians(fov) / 2)
    px = (pt[:, 0] / -pt[:, 2] / (ty * w / h) + 1) * 0.5 * w
    py = (1 - pt[:, 1] / -pt[:, 2] / ty) * 0.5 * h
    xc, yc = pixel_centres(w, h)
    err = np.hypot(px - xc[m], py - yc[m])
    assert err.max() < 0.01, f"reconstructed point off its pixel centre by {err.max()} px"
    # its eye depth is the plane's along that ray (screen-space affine weights would be off
    # by percents on these tilted planes; 1e-3 leaves room for the snap on grazing ones)
    np.testing.assert_allclose(-pt[:, 2], s[m], rtol=1e-3)


def test_clipped_triangle_barycentrics_refer_to_parent():
    """A triangle with one vertex behind the eye: the clipper cuts it, but the barycentrics
    must still be weights of the ORIGINAL three vertices, so that b · V lies on the pixel's
    ray and on the triangle's plane; depth matches the plane too."""
    w, h = 48, 40
    near, far, fov = 0.4, 30.0, 80.0
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    verts = np.array([[-3.0, -1.5, -6.0], [3.5, -1.0, -5.0], [0.3, 0.8, 2.0]])  # v2: behind
    mesh = Mesh(verts, [[0, 1, 2]])
    a, b = render_both(mesh, cam, w, h, cull="none")
    assert_frames_equal(a, b, "clipped triangle")
    assert a.stats.clipped == 1 and a.stats.clip_pieces >= 1
    m = a.mask
    assert m.sum() > 200
    bc = a.barycentrics[m].astype(np.float64)
    np.testing.assert_allclose(bc.sum(axis=1), 1.0, atol=1e-5)
    assert bc.min() > -1e-5 and bc[:, 2].max() > 0.05  # the vertex behind the eye has weight
    pt = bc @ verts
    nrm = np.cross(verts[1] - verts[0], verts[2] - verts[0])
    rays = pixel_rays(w, h, fov)[m]
    s = (verts[0] @ nrm) / (rays @ nrm)
    ray_pts = rays * s[:, None]
    np.testing.assert_allclose(pt, ray_pts, atol=2e-3 * np.abs(ray_pts).max())
    # the plane nearly grazes the eye (one vertex is behind it), so depth is sensitive to
    # the snap: compare within the snap bound
    exp, tol = plane_depth(verts[0], nrm, w, h, fov, near, far)
    err = np.abs(a.depth[m] - exp[m])
    assert (err <= tol[m]).all(), f"depth off by {err.max()}"


def test_depth_test_less_first_drawn_wins_ties():
    w, h = 16, 16
    cam = MatrixCamera(perspective(90.0, 1.0, 0.5, 10.0))
    tri = np.array([[-5.0, -5.0, -2.0], [5.0, -5.0, -2.0], [0.0, 6.0, -2.0]])
    nearer = tri + [0.0, 0.0, 0.5]
    # faces: 0 = tri, 1 = the same tri again, 2 = nearer (drawn last), 3 = tri again
    mesh = Mesh(np.concatenate([tri, tri, nearer, tri]), np.arange(12).reshape(4, 3))
    a, b = render_both(mesh, cam, w, h, cull="back")
    assert_frames_equal(a, b, "ties")
    covered = a.mask
    assert covered.sum() > 100
    assert set(np.unique(a.triangle_id[covered])) == {2}
    # only faces 0 and 1 alone: ties → face 0 everywhere, face 1 never passes
    mesh01 = Mesh(np.concatenate([tri, tri]), np.arange(6).reshape(2, 3))
    f01 = render_cl(mesh01, cam, w, h)
    assert set(np.unique(f01.triangle_id[f01.mask])) == {0}
    assert f01.stats.fragments_tested == 2 * f01.mask.sum()
    assert f01.stats.fragments_passed == f01.mask.sum()
    # nearer drawn first: later, farther faces never pass
    mesh_rev = Mesh(np.concatenate([nearer, tri]), np.arange(6).reshape(2, 3))
    frev = render_cl(mesh_rev, cam, w, h)
    assert set(np.unique(frev.triangle_id[frev.mask])) == {0}
    assert frev.stats.fragments_passed == frev.mask.sum()
    assert (frev.depth[frev.mask] < f01.depth[frev.mask]).all()


def test_lower_id_wins_ties_when_drawn_later():
    """Two coplanar triangles facing the camera (equal depth wherever both cover a pixel),
    drawn in the opposite order of their ids: clusters take faces in the Morton order of
    their centroids, 128 at a time, so face 1 (left, with 127 small faces far to the left,
    outside the view) fills the first cluster and face 0 (right) the second, drawn after
    it. The depth test breaks exact ties by the lower id, not by drawing order: face 0 must
    win every pixel the two share (the tile keeps no per-pixel ids: a tie reads the
    winner's id from its entry)."""
    w, h = 64, 48
    cam = MatrixCamera(perspective(60.0, w / h, 0.5, 10.0))
    z = -3.0
    right = np.array([[-0.6, -1.2, z], [1.6, -1.2, z], [0.4, 1.2, z]])   # face 0
    left = right - [1.0, 0.0, 0.0]                                       # face 1
    small = np.array([[0.0, 0.0, z], [0.01, 0.0, z], [0.0, 0.01, z]])
    far_left = np.concatenate([small + [-100.0 - 0.1 * k, 0.0, 0.0] for k in range(127)])
    verts = np.concatenate([right, left, far_left])
    mesh = Mesh(verts, np.arange(len(verts)).reshape(-1, 3))
    a, b = render_both(mesh, cam, w, h, cull="back")
    assert_frames_equal(a, b, "ties drawn in reverse id order")
    only_right = render_cl(Mesh(right, [[0, 1, 2]]), cam, w, h).mask
    only_left = render_cl(Mesh(left, [[0, 1, 2]]), cam, w, h).mask
    both = only_right & only_left
    assert both.sum() > 100 and (only_left & ~only_right).sum() > 100
    # face 1 was drawn first (else this would not test the tie rule): face 0 passed again
    # at every shared pixel
    assert a.stats.fragments_passed == (only_left | only_right).sum() + both.sum()
    ids = a.triangle_id
    assert (ids[both] == 0).all()
    assert (ids[only_left & ~only_right] == 1).all() and (ids[only_right & ~only_left] == 0).all()
    assert (a.depth[both] == a.depth[both][0]).all()   # equal depths: real ties


def test_look_at_camera_depth_matches_eye_distance():
    """Through Camera.look_at (not a raw matrix): a quad facing the camera at distance 5."""
    w, h = 40, 30
    cam = Camera.look_at(eye=(1.0, 2.0, 3.0), target=(1.0, 2.0, -2.0), fov_y=50.0, near=0.2,
                         far=40.0)
    mesh = plane_quad([1.0, 2.0, -2.0], [1, 0, 0], [0, 1, 0], 20.0)
    fr = render_cl(mesh, cam, w, h)
    assert fr.mask.all()
    np.testing.assert_allclose(fr.depth, window_depth(5.0, 0.2, 40.0), atol=1e-6)
