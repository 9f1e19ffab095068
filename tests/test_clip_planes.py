"""User clip planes (issue 16, item 1): ``render(..., clip_planes=[(a, b, c, d), ...])``.

Checked: OpenCL equals the twin (random soups crossing the view volume, random scenes with
mirrored instances, reversed-Z); a box cut open by a plane shows exactly the faces an
analytic ray caster finds (inside walls seen through the cut, as back faces); object culling
by the planes is conservative and counted; occlusion culling and streaming keep the image;
line segments clip against the same planes; bad planes are refused clearly. Coverage
against llvmpipe's gl_ClipDistance is in test_peer_llvmpipe.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MatrixCamera, assert_frames_equal, assert_same_image, get_renderer
from random_scenes import Lens, random_soup, random_view, to_world

from clraster import Camera, Mesh, RasterConfig, Renderer, Scene
from clraster import reference as twin
from clraster.inputs import check_clip_planes
from clraster.lines import render_lines
from clraster.reference.lines import render_lines as twin_lines
from clraster.scenes import random_scene


def _planes_through(rng: np.random.Generator, centre: np.ndarray, k: int) -> np.ndarray:
    """k random planes passing near ``centre`` (each keeps about half of what is around)."""
    n = rng.normal(size=(k, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = centre + rng.normal(scale=0.3, size=(k, 3))
    return np.concatenate([n, -np.einsum("kj,kj->k", n, p)[:, None]], axis=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_soups_with_planes_match_twin(seed):
    rng = np.random.default_rng(100 + seed)
    w, h = 71, 43
    lens = Lens(70.0, 0.5, 100.0)
    v, f, _ = random_soup(rng, 1500, w, h, lens)
    view = random_view(rng)
    world = to_world(v, view)
    mesh = Mesh(world, f)
    cam = MatrixCamera(lens.projection(w / h) @ view)
    planes = _planes_through(rng, np.median(world, axis=0), 1 + seed * 3)
    for cull in ("none", "back"):
        for rz in (False, True):
            a = get_renderer(w, h).render(mesh, cam, cull=cull, frustum=False, cones=False,
                                          clip_planes=planes, reversed_z=rz)
            b = twin.render(mesh, cam, w, h, cull=cull, frustum=False, cones=False,
                            clip_planes=planes, reversed_z=rz)
            assert_frames_equal(a, b, f"seed {seed} cull {cull} reversed_z {rz}")
            plain = get_renderer(w, h).render(mesh, cam, cull=cull, frustum=False,
                                              cones=False, reversed_z=rz)
            # the planes only take coverage away, and they did take some
            assert not ((a.triangle_id >= 0) & (plain.triangle_id < 0)).any()
            assert (a.triangle_id >= 0).sum() < (plain.triangle_id >= 0).sum()
            assert (a.stats.clipped + a.stats.trivially_rejected
                    > plain.stats.clipped + plain.stats.trivially_rejected)


def _box() -> Mesh:
    """[-1, 1]³, 12 outward counter-clockwise triangles; face 2s, 2s + 1 form side s in the
    order −x, +x, −y, +y, −z, +z."""
    c = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], float)
    quads = [(0, 4, 6, 2), (1, 3, 7, 5), (0, 1, 5, 4), (2, 6, 7, 3), (0, 2, 3, 1),
             (4, 5, 7, 6)]
    faces = []
    for a, b, cc, d in quads:
        faces += [(a, b, cc), (a, cc, d)]
    return Mesh(c, np.array(faces))


def _box_oracle(cam: Camera, w: int, h: int, plane: np.ndarray, front_only: bool = False):
    """Per pixel centre: the side (0..5) of the box the ray meets first among the points
    the plane keeps, −1 for none, and whether that side faces away from the eye. With
    ``front_only`` back faces are skipped (cull "back")."""
    inv = np.linalg.inv(cam.view_projection(w, h))
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    xn, yn = 2 * xs / w - 1, 1 - 2 * ys / h
    near = np.stack([xn, yn, -np.ones_like(xn), np.ones_like(xn)], -1) @ inv.T
    far = np.stack([xn, yn, np.ones_like(xn), np.ones_like(xn)], -1) @ inv.T
    o = near[..., :3] / near[..., 3:]
    d = far[..., :3] / far[..., 3:] - o
    best_t = np.full((h, w), np.inf)
    side = np.full((h, w), -1)
    back = np.zeros((h, w), bool)
    for s in range(6):
        axis, sign = s // 2, (-1.0, 1.0)[s % 2]
        with np.errstate(all="ignore"):
            t = (sign - o[..., axis]) / d[..., axis]
        p = o + t[..., None] * d
        others = [a for a in range(3) if a != axis]
        ok = (t > 0) & (np.abs(p[..., others]) <= 1).all(-1)
        ok &= p @ plane[:3] + plane[3] >= 0
        facing_away = (d[..., axis] * sign) > 0   # outward normal along the ray
        if front_only:
            ok &= ~facing_away
        nearer = ok & (t < best_t)
        best_t[nearer] = t[nearer]
        side[nearer] = s
        back[nearer] = facing_away[nearer]
    return side, back


@pytest.mark.parametrize("cull", ["none", "back"])
def test_box_cut_open_shows_the_faces_a_ray_caster_finds(cull):
    """A plane cuts the front of a box away: through the opening the inside walls show as
    back faces (cull "none"), or nothing does (cull "back": only what the plane keeps of
    the front faces). Every pixel more than one pixel from an edge in the oracle's image
    agrees on the side."""
    w, h = 96, 72
    cam = Camera.look_at((4.0, 1.3, 2.2), (0.0, 0.0, 0.0), fov_y=45.0, near=0.1, far=20.0)
    plane = np.array([-1.0, -0.25, 0.1, 0.3])          # keeps x + 0.25 y − 0.1 z <= 0.3
    box = _box()
    f = get_renderer(w, h).render(box, cam, cull=cull, clip_planes=[plane])
    side, back = _box_oracle(cam, w, h, plane)
    if cull == "back":   # back faces culled: the first front face the plane keeps
        side, _ = _box_oracle(cam, w, h, plane, front_only=True)
    got = np.where(f.triangle_id >= 0, f.triangle_id // 2, -1)
    # interior: the oracle's side is the same over the pixel's 3x3 neighbourhood
    pad = np.pad(side, 1, mode="edge")
    same = np.ones_like(side, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            same &= pad[dy:dy + h, dx:dx + w] == side
    assert same.sum() > 0.8 * w * h
    np.testing.assert_array_equal(got[same], side[same])
    if cull == "none":
        assert (back & (side >= 0)).sum() > 200   # the inside really shows
        assert f.stats.clipped > 0


@pytest.mark.parametrize("seed", [3, 4])
def test_scene_culling_by_planes_is_conservative_and_matches_twin(seed):
    """Random scenes (mirrored instances included) with planes through them: clusters wholly
    outside a plane are culled and counted; the image equals the one drawn without object
    culling, and the twin's."""
    scene = random_scene(seed, 40, extent=6.0, mirrors=True)
    cam = Camera.look_at((0.0, 5.0, 22.0), (0.0, 0.0, 0.0), fov_y=55.0, near=0.1, far=60.0)
    planes = np.array([[1.0, 0.0, 0.0, 1.0], [0.2, -1.0, 0.1, 2.0]])
    r = get_renderer(120, 90)
    on = r.render(scene, cam, clip_planes=planes)
    off = r.render(scene, cam, clip_planes=planes, frustum=False, cones=False)
    assert_same_image(on, off, f"seed {seed}", "object culling with clip planes")
    plain = r.render(scene, cam)
    assert on.stats.clusters_frustum_culled > plain.stats.clusters_frustum_culled
    assert on.stats.clusters_drawn < plain.stats.clusters_drawn
    s = on.stats
    assert s.clusters_total == (s.clusters_frustum_culled + s.clusters_cone_culled
                                + s.clusters_drawn)
    b = twin.render(scene, cam, 120, 90, clip_planes=planes)
    assert_frames_equal(on, b, f"seed {seed} (OpenCL vs twin)")


def test_occlusion_and_streaming_keep_the_clipped_image():
    scene = random_scene(5, 60, extent=5.0)
    cam = Camera.look_at((0.0, 3.0, 16.0), (0.0, 0.0, 0.0), fov_y=55.0, near=0.1, far=60.0)
    planes = [[0.0, -1.0, 0.0, 0.5]]
    ref = get_renderer(96, 64).render(scene, cam, clip_planes=planes)
    r = Renderer(96, 64)
    for _ in range(2):
        occ = r.render(scene, cam, clip_planes=planes, occlusion=True)
        assert_same_image(occ, ref, "occlusion", "occlusion culling with clip planes")
    small = Renderer(96, 64, config=RasterConfig(batch_triangles=128, batch_entries=64))
    assert_same_image(small.render(scene, cam, clip_planes=planes), ref, "streamed",
                      "batching with clip planes")


def test_lines_clip_against_the_planes():
    """A fan of segments crossing the plane x = 0.1: fragments only where the plane keeps
    the segment (x <= 0.1, within a pixel), line ids are the input indices, and the twin
    agrees."""
    w, h = 80, 60
    cam = Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=20.0)
    ang = np.linspace(0.1, np.pi - 0.1, 9)
    seg = np.zeros((11, 2, 3), np.float32)
    seg[:9, 0, :2] = np.stack([-1.5 * np.cos(ang), -1.5 * np.sin(ang)], 1)
    seg[:9, 1, :2] = np.stack([1.5 * np.cos(ang), 1.5 * np.sin(ang)], 1)
    seg[9] = [[1.0, 0.5, 0.0], [1.5, -0.5, 0.0]]       # wholly removed
    seg[10] = [[-1.0, 1.0, 0.0], [-1.2, -1.0, 0.0]]    # wholly kept
    plane = [[-1.0, 0.0, 0.0, 0.1]]
    vp = cam.view_projection(w, h)
    a = render_lines(seg, vp, w, h, clip_planes=plane)
    b = twin_lines(seg, vp, w, h, clip_planes=plane)
    np.testing.assert_array_equal(a.line_id, b.line_id)
    np.testing.assert_array_equal(a.depth, b.depth)
    assert a.stats == b.stats
    # the vertical one (x = 0) lies wholly on the kept side; the other 8 cross the plane
    assert a.stats["trivially_rejected"] == 1 and a.stats["clipped"] == 8
    # world x of each fragment's pixel centre on the z = 0 plane
    ys, xs = np.nonzero(a.line_id >= 0)
    x_world = ((xs + 0.5) / w * 2 - 1) * np.tan(np.radians(25.0)) * 5.0 * w / h
    px = 2 * np.tan(np.radians(25.0)) * 5.0 / h
    assert (x_world <= 0.1 + 1.5 * px).all()
    assert set(np.unique(a.line_id[a.line_id >= 0])) <= set(range(9)) | {10}
    full = render_lines(seg, vp, w, h)
    assert (full.line_id >= 0).sum() > (a.line_id >= 0).sum() + 50


@pytest.mark.parametrize("bad, what", [
    ([[0, 0, 0, 1]], "zero normal"), ([[1, 0, 0]], "shape"), ([[1, 0, 0, np.nan]], "finite"),
    (np.ones((9, 4)), "at most 8"), ("x", "numbers"),
])
def test_bad_planes_are_refused(bad, what):
    with pytest.raises(ValueError, match=what):
        check_clip_planes(bad)
    with pytest.raises(ValueError, match=what):
        get_renderer(16, 16).render(_box(), Camera.look_at((0, 0, 5), (0, 0, 0)),
                                    clip_planes=bad)


def test_no_planes_is_the_plain_frame():
    cam = Camera.look_at((3.0, 2.0, 4.0), (0.0, 0.0, 0.0))
    r = get_renderer(48, 32)
    a, b = r.render(_box(), cam), r.render(_box(), cam, clip_planes=[])
    assert_same_image(a, b, "[]", "an empty plane list")
    assert check_clip_planes(None) is None and check_clip_planes([1, 0, 0, 0]).shape == (1, 4)
    scene = Scene([(_box(), np.eye(4))])
    assert_same_image(r.render(scene, cam), r.render(scene, cam, clip_planes=None), "None",
                      "clip_planes=None")
