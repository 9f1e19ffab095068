"""Lights and shadow maps (`clraster.output.lights`, render_shaded(lights=..., shadows=True)).

The oracle is a float64 shadow ray per visible pixel, written here: from the frame's exact
surface point (ids + barycentrics) towards the light, Möller–Trumbore against every
triangle of the small scene. The shadow map must agree on ≥ 99% of the pixels farther than
2 pixels from any shadow boundary of the oracle, on scenes with contact shadows, thin
occluders (a one-sided card, a thin pole) and a grazing light; a lit floor shows no acne.
"""

from __future__ import annotations

import numpy as np
import pytest
from lit_scenes import FLOOR, box, mesh_of, quad

import clraster
from clraster.output.lights import Light, LightError
from clraster.output.outputs import points
from clraster.output.shade import DEFAULT_LIGHT_DIR, render_shaded

W, H = 160, 120


CAMERA = clraster.Camera.look_at((3.0, 4.0, 5.0), (0.0, 0.3, 0.0), near=0.5, far=30.0)

SCENES = {
    # a box standing on the floor: its shadow starts at its base
    "contact": (mesh_of(FLOOR, box((-0.6, 0.0, -0.6), (0.6, 1.0, 0.6))),
                Light.directional((0.4, -1.0, 0.3), shadow_size=1024)),
    # a one-sided card and a thin pole (4 cm) above the floor
    "thin": (mesh_of(FLOOR, quad((0.3, 0.8, 0.0), (0.7, 0.1, 0.0), (0.0, 0.0, 0.5)),
                     box((-1.2, 0.0, 0.8), (-1.16, 1.5, 0.84))),
             Light.directional((0.5, -1.0, 0.2), shadow_size=1024)),
    # the sun 12 degrees above the horizon: long shadows, steep bias on the floor
    "grazing": (mesh_of(FLOOR, box((-0.5, 0.0, -0.5), (0.5, 0.8, 0.5))),
                Light.directional((1.0, -0.215, 0.25), shadow_size=1024)),
    "spot": (mesh_of(FLOOR, box((-0.5, 0.0, -0.5), (0.5, 0.8, 0.5))),
             Light.spot((-1.0, 3.0, -1.0), (0.3, -1.0, 0.3), cone=50.0, inner=45.0,
                        shadow_size=1024)),
}


def shadow_oracle(mesh: clraster.Mesh, pts: np.ndarray, light: Light) -> np.ndarray:
    """bool (K,): the float64 ray from each point towards the light hits a triangle."""
    tri = mesh.vertices.astype(np.float64)[mesh.faces]            # (M, 3, 3)
    if light.position is None:
        d = np.broadcast_to(-light.direction, pts.shape)
        tmax = np.full(len(pts), np.inf)
    else:
        d = light.position - pts
        tmax = np.linalg.norm(d, axis=1)
        d = d / tmax[:, None]
    eps = 1e-5
    o = pts + d * eps                      # leave the surface the point lies on
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None, :], e2[None])                          # (K, M, 3)
    det = np.einsum("kmc,mc->km", p, e1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o[:, None, :] - tri[None, :, 0]
    u = np.einsum("kmc,kmc->km", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("kc,kmc->km", d, q) * inv
    t = np.einsum("mc,kmc->km", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-4) & (t < tmax[:, None])
    return hit.any(axis=1)


def far_from_boundary(label: np.ndarray, covered: np.ndarray, r: int = 2) -> np.ndarray:
    """Covered pixels whose covered neighbours within `r` px (Chebyshev) all share their
    oracle label."""
    h, w = label.shape
    ok = covered.copy()
    pad_l = np.pad(label, r, mode="edge")
    pad_c = np.pad(covered, r, mode="constant")
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            nb = pad_l[r + dy:r + dy + h, r + dx:r + dx + w]
            nc = pad_c[r + dy:r + dy + h, r + dx:r + dx + w]
            ok &= ~nc | (nb == label)
    return ok


@pytest.fixture(scope="module")
def renderer():
    return clraster.Renderer(W, H)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_shadows_agree_with_shadow_rays(renderer, name):
    mesh, light = SCENES[name]
    img, layers = render_shaded(renderer, mesh, CAMERA, lights=[light], shadows=True,
                                return_layers=True, render_kwargs={"cull": "none"})
    frame = renderer.render(mesh, CAMERA, cull="none")
    covered = frame.triangle_id >= 0
    pts = points(frame, mesh).points
    shadowed = np.zeros((H, W), bool)
    shadowed[covered] = shadow_oracle(mesh, pts, light)
    lit = layers.lit[..., 0]
    judged = far_from_boundary(shadowed, covered)
    if light.position is not None:   # inside the spot's inner cone only
        cos_in = np.cos(np.radians(light.inner))
        to = pts - light.position
        inner = np.zeros((H, W), bool)
        inner[covered] = (to / np.linalg.norm(to, axis=1)[:, None]) @ light.direction > cos_in
        judged &= inner
    assert judged.sum() > 0.5 * covered.sum(), "the scene must have pixels to judge"
    assert shadowed[judged].sum() > 100 and (~shadowed[judged]).sum() > 100, \
        "the scene must show both lit and shadowed pixels"
    agree = (lit[judged] >= 0.5) != shadowed[judged]
    assert agree.mean() >= 0.99, f"{name}: agreement {agree.mean():.4f}"
    assert img.shape == (H, W, 3)


@pytest.mark.parametrize("elevation", [90.0, 45.0, 20.0, 10.0])
def test_no_acne_on_a_lit_floor(renderer, elevation):
    floor = mesh_of(FLOOR)
    e = np.radians(elevation)
    light = Light.directional((-np.cos(e) * 0.8, -np.sin(e), -np.cos(e) * 0.6),
                              shadow_size=1024)
    _, layers = render_shaded(renderer, floor, CAMERA, lights=light, shadows=True,
                              return_layers=True)
    covered = layers.covered > 0
    dark = layers.lit[..., 0][covered] < 1.0
    assert covered.sum() > 5000
    assert dark.mean() <= 0.001, f"{dark.mean():.4%} of the floor in its own shadow"


def test_one_directional_light_is_shade_lambert(renderer):
    mesh, _ = SCENES["contact"]
    plain = render_shaded(renderer, mesh, CAMERA)
    towards = np.asarray(DEFAULT_LIGHT_DIR) / np.linalg.norm(DEFAULT_LIGHT_DIR)
    lit = render_shaded(renderer, mesh, CAMERA, lights=[Light.directional(-towards)])
    assert np.abs(plain.astype(int) - lit).max() <= 1


def test_shadowed_pixels_keep_the_ambient_term(renderer):
    mesh, light = SCENES["contact"]
    img, layers = render_shaded(renderer, mesh, CAMERA, lights=light, shadows=True,
                                return_layers=True, background=(0, 0, 0))
    dark = (layers.lit[..., 0] == 0) & (layers.covered == 1)
    # albedo (0.80, 0.82, 0.88) × ambient 0.22 → 45, 46, 49
    assert dark.sum() > 100
    np.testing.assert_allclose(img[dark].mean(axis=0), [44.9, 46.0, 49.4], atol=0.6)


def test_spot_cone_darkens_outside(renderer):
    floor = mesh_of(FLOOR)
    light = Light.spot((0.0, 2.0, 0.0), (0.0, -1.0, 0.0), cone=20.0, inner=15.0)
    _, layers = render_shaded(renderer, floor, CAMERA, lights=light, return_layers=True)
    frame = renderer.render(floor, CAMERA)
    pts = points(frame, floor).points
    r = np.hypot(pts[:, 0], pts[:, 2])
    lit = layers.lit[..., 0][frame.triangle_id >= 0]
    assert np.all(lit[r < 2.0 * np.tan(np.radians(14.9))] == 1.0)
    assert np.all(lit[r > 2.0 * np.tan(np.radians(20.1))] == 0.0)


@pytest.mark.parametrize("make, match", [
    (lambda: Light.directional((0, 0, 0)), "direction"),
    (lambda: Light.directional((0, -1, 0), shadow_size=8), "shadow_size"),
    (lambda: Light.directional((0, -1, 0), pcf=9), "pcf"),
    (lambda: Light.spot((0, 1, 0), (0, -1, 0), cone=95), "cone"),
    (lambda: Light.spot((0, 1, 0), (0, -1, 0), cone=30, inner=40), "inner"),
    (lambda: Light.spot((np.nan, 1, 0), (0, -1, 0)), "position"),
    (lambda: Light.directional((0, -1, 0), color=(2, 0, 0)), "color"),
])
def test_bad_lights(make, match):
    with pytest.raises(LightError, match=match):
        make()


def test_bad_lights_option(renderer):
    mesh, _ = SCENES["contact"]
    with pytest.raises(ValueError, match="lights"):
        render_shaded(renderer, mesh, CAMERA, lights=[(0, -1, 0)])
    with pytest.raises(ValueError, match="shadows"):
        render_shaded(renderer, mesh, CAMERA, shadows="yes")
