"""Clipping against an independent oracle: ray casting in float64.

A pixel centre is covered by an eye-space triangle iff the ray from the eye through it hits
the triangle at an eye depth in [near, far]. This needs no clipper at all, so it checks the
clipped pieces (near, far, guard band, w ≤ 0) independently of both the kernels and the
twin. Pixels whose ray passes within a small angle of a triangle edge, or hits it within a
hair of the near/far plane, are left out as ambiguous (the 1/256 snap and float32 may
decide them either way).
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

from clraster import Mesh

#: Angular margin around triangle edges, in pixels at the image centre.
EDGE_MARGIN_PX = 0.02
#: Relative margin around the near and far planes (float32 clipping of triangles whose
#: vertices are far from the plane leaves relative errors of this order; the huge ground
#: plane cases below once went past where it stops being small).
DEPTH_MARGIN = 1e-3
#: Margin in window depth: near the far plane of a deep frustum float32 depth cannot tell
#: the far plane from a point a little in front of it, and a fragment at depth ≥ 1.0 fails
#: LESS against the cleared 1.0.
WINDOW_DEPTH_MARGIN = 1e-5


def ray_cast(tri: np.ndarray, w: int, h: int, fov: float, near: float, far: float):
    """(inside, ambiguous) boolean (H, W) masks for one eye-space triangle (3, 3)."""
    xc, yc = pixel_centres(w, h)
    ty = math.tan(math.radians(fov) / 2)
    d = np.stack([(xc / w * 2 - 1) * ty * w / h, (1 - yc / h * 2) * ty, -np.ones_like(xc)],
                 axis=-1)
    v0, v1, v2 = (np.asarray(p, dtype=np.float64) for p in tri)
    focal_px = (h / 2) / ty
    # sides of the three planes through the eye and each edge
    sides, close = [], np.zeros((h, w), bool)
    for a, b in ((v0, v1), (v1, v2), (v2, v0)):
        n = np.cross(a, b)
        nn = np.linalg.norm(n)
        if nn == 0:
            return np.zeros((h, w), bool), np.ones((h, w), bool)
        s = d @ n / (nn * np.linalg.norm(d, axis=-1))
        sides.append(s)
        close |= np.abs(s) * focal_px < EDGE_MARGIN_PX
    s0, s1, s2 = sides
    in_cone = ((s0 > 0) & (s1 > 0) & (s2 > 0)) | ((s0 < 0) & (s1 < 0) & (s2 < 0))
    # depth along the ray (z = −1 per unit t): the plane of the triangle
    nrm = np.cross(v1 - v0, v2 - v0)
    denom = d @ nrm
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(denom != 0, (v0 @ nrm) / denom, np.nan)
    # inside the cone through the eye, the plane is hit at t > 0 iff the triangle is in front
    hit = in_cone & (t > 0)
    in_depth = (t > near * (1 + DEPTH_MARGIN)) & (t < far * (1 - DEPTH_MARGIN))
    with np.errstate(divide="ignore", invalid="ignore"):
        wd = ((far + near) / (far - near) - 2 * far * near / ((far - near) * t)) * 0.5 + 0.5
    near_bound = ((np.abs(t - near) <= near * 2 * DEPTH_MARGIN)
                  | (np.abs(t - far) <= far * 2 * DEPTH_MARGIN)
                  | (np.abs(wd) < WINDOW_DEPTH_MARGIN) | (np.abs(wd - 1) < WINDOW_DEPTH_MARGIN))
    inside = hit & in_depth
    ambiguous = close | (hit & near_bound) | ~np.isfinite(t)
    return inside, ambiguous


def random_eye_triangle(rng: np.random.Generator, near: float, far: float) -> np.ndarray:
    kind = rng.integers(5)
    if kind == 0:  # crossing the near plane, some vertices behind the eye
        tri = rng.uniform(-30 * near, 30 * near, (3, 3))
        tri[:, 2] = rng.uniform(-40 * near, 10 * near, 3)
    elif kind == 1:  # crossing the far plane
        tri = rng.uniform(-far, far, (3, 3))
        tri[:, 2] = -rng.uniform(0.5 * far, 1.5 * far, 3)
    elif kind == 2:  # big, in front, leaving the guard band: x/w up to ~1e7
        z = -rng.uniform(near, 4 * near, 3)
        xy = rng.normal(size=(3, 2)) * 10 ** rng.uniform(0, 7, (3, 1)) * near
        tri = np.concatenate([xy, z[:, None]], axis=1)
    elif kind == 3:  # everything at once: big, through near and behind the eye
        tri = rng.normal(size=(3, 3)) * 10 ** rng.uniform(-1, 3, (3, 1)) * near * 10
    else:  # ordinary, on screen
        z = -rng.uniform(near, far / 4)
        tri = np.column_stack([rng.uniform(-0.8, 0.8, (3, 2)) * -z, np.full(3, z)])
        tri[:, 2] *= rng.uniform(0.9, 1.1, 3)
    return tri


@pytest.mark.parametrize("seed, size, fov, near, far", [
    (1, (48, 32), 70.0, 0.5, 100.0),
    (2, (33, 33), 120.0, 0.01, 50.0),
    (3, (64, 17), 30.0, 1.0, 1e4),
])
def test_coverage_matches_ray_casting(seed, size, fov, near, far):
    w, h = size
    rng = np.random.default_rng(seed)
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    decided = clipped = 0
    for i in range(120):
        tri = random_eye_triangle(rng, near, far)
        mesh = Mesh(tri, [[0, 1, 2]])
        fr = render_cl(mesh, cam, w, h, cull="none")
        inside, amb = ray_cast(tri, w, h, fov, near, far)
        got = fr.mask
        wrong = (got != inside) & ~amb
        assert not wrong.any(), (
            f"triangle {i} {tri.tolist()}: {int((wrong & got).sum())} pixels covered outside "
            f"it, {int((wrong & ~got).sum())} inside it left empty; first at "
            f"{np.argwhere(wrong)[0].tolist()} (stats {fr.stats.counts()})")
        decided += int((~amb).sum())
        clipped += fr.stats.clipped
    assert decided > 0.9 * 120 * w * h
    assert clipped > 40


def test_clipped_soup_matches_twin():
    """The same kinds of triangles all in one mesh: OpenCL vs twin, exact."""
    rng = np.random.default_rng(9)
    w, h = 47, 31
    near, far, fov = 0.2, 80.0, 90.0
    tris = np.array([random_eye_triangle(rng, near, far) for _ in range(1500)])
    mesh = Mesh(tris.reshape(-1, 3), np.arange(tris.shape[0] * 3).reshape(-1, 3))
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    for cull in ("none", "back"):
        a, b = render_both(mesh, cam, w, h, cull=cull, tile_log2=3)
        assert_frames_equal(a, b, f"cull={cull}")
        # back faces are culled before clipping (homogeneous facing test), so fewer reach it
        assert a.stats.clipped > (500 if cull == "none" else 250)


# --- float32 limits of the clipper -------------------------------------------------------

def ground_plane_expected(w, h, fov, near, far, half, height=1.0):
    """Pixels whose ray meets the plane y = −height inside |x|, |z| < half and depth range
    (inside) and those clearly not (outside), by ray casting in float64."""
    xc, yc = pixel_centres(w, h)
    ty = math.tan(math.radians(fov) / 2)
    dx = (xc / w * 2 - 1) * ty * w / h
    dy = (1 - yc / h * 2) * ty
    with np.errstate(divide="ignore"):
        t = np.where(dy < 0, height / -dy, np.inf)  # ray (dx, dy, −1)·t hits y = −height
    x, z = dx * t, -t

    def within(k):
        return (t > near * (1 + k)) & (t < far * (1 - k)) & (np.abs(x) < half * (1 - k)) & (
            np.abs(z) < half * (1 - k))

    return within(1e-3), ~within(-1e-3)


GROUND_CASES = [
    pytest.param(0.1, 1e3, 1e4, id="near0.1-half1e4"),
    pytest.param(0.1, 1e3, 1e6, id="near0.1-half1e6"),
    pytest.param(1e-3, 1e3, 1e4, id="near1e-3-half1e4"),
    # Failed while the clipper's inputs were the vertex stage's float32 clip positions: at
    # |w| ≈ 1e5 their rounding (≈ 4e-3) exceeds the near distance 1e-3, so the near-plane
    # crossing landed at w ≤ 0 and the pieces were dropped. The clipper now recomputes them
    # in double from the object-space vertices (setup.cl object_clip).
    pytest.param(1e-3, 1e3, 1e5, id="near1e-3-half1e5"),
    pytest.param(0.1, 1e3, 1e7, id="near0.1-half1e7"),
]


@pytest.mark.parametrize("near, far, half", GROUND_CASES)
def test_huge_ground_plane_through_near_plane(near, far, half):
    """A square ground plane 1 unit below the eye, with half-size `half`: two triangles that
    reach behind the eye and beyond the far plane. Everything below the horizon (up to the
    far plane) must be covered."""
    w, h, fov = 64, 48, 60.0
    cam = MatrixCamera(perspective(fov, w / h, near, far))
    s = half
    v = np.array([[-s, -1, -s], [s, -1, -s], [s, -1, s], [-s, -1, s]])
    mesh = Mesh(v, [[0, 2, 1], [0, 3, 2]])  # facing up (+Y): seen from above, CCW
    fr = render_cl(mesh, cam, w, h, cull="back")
    inside, outside = ground_plane_expected(w, h, fov, near, far, half)
    assert inside.sum() > w * h // 3
    assert not (inside & ~fr.mask).any(), f"{int((inside & ~fr.mask).sum())} holes"
    assert not (outside & fr.mask).any(), f"{int((outside & fr.mask).sum())} extra pixels"


@pytest.mark.parametrize("scale", [
    1e5, 1e10, 1e12,
    1e15,  # failed while the clipper interpolated in float32 (cancellation ≈ 7e7)
    # Failed while a clipped vertex kept its interpolated coordinate across the plane: at
    # ±1e30 double interpolation errs by ~1e14, far beyond the guard band (±2**19 px), and
    # the clipped polygon missed the window. It is now put exactly on the plane
    # (setup.cl onto_plane).
    1e30,
])
def test_huge_finite_triangle_covers_window(scale):
    """A finite triangle around the whole window (identity clip matrix, w = 1): every pixel
    is inside it."""
    w, h = 24, 16
    v = np.array([[-scale, -scale, 0], [scale, -scale, 0], [0, scale, 0]])
    a, b = render_both(Mesh(v, [[0, 1, 2]]), MatrixCamera(np.eye(4)), w, h)
    assert_frames_equal(a, b, f"scale {scale}")
    assert a.stats.invalid == 0 and a.stats.clipped == 1
    assert a.mask.all(), f"{int((~a.mask).sum())} of {w * h} pixels uncovered"
