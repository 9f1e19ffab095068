"""User clip planes (issue 16, item 1): ``render(..., clip_planes=[(a, b, c, d), ...])``.

Checked: OpenCL equals the twin (random soups crossing the view volume, random scenes with
mirrored instances, reversed-Z); a box cut open by a plane shows exactly the faces an
analytic ray caster finds (inside walls seen through the cut, as back faces); object culling
by the planes is conservative and counted; occlusion culling and streaming keep the image;
line segments clip against the same planes; bad planes are refused clearly. Coverage
against llvmpipe's gl_ClipDistance is in test_peer_llvmpipe.py.

Object culling by the planes goes through the BVH plane masks (user planes appended to the
frustum's, masks up to 14 bits): the traversal equals classifying every box on its own
against every plane; a node wholly inside a user plane drops its bit for its subtree; and
on every culling path (flat, dense, cluster BVH) the drawn set is the plain one minus the
clusters whose object-space box lies wholly outside a plane by `cull.CLIP_PLANE_MARGIN`,
with the image unchanged.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import MatrixCamera, assert_frames_equal, assert_same_image, get_renderer
from random_scenes import Lens, random_soup, random_view, to_world

from clraster import Camera, Mesh, RasterConfig, Renderer, Scene
from clraster.base.checks import check_clip_planes
from clraster.culling import bvh as bvh_module
from clraster.culling import cull as cull_module
from clraster.culling.bvh import BVH, INSIDE, INTERSECTING, MAX_PLANES, OUTSIDE, check_mask
from clraster.culling.clusters import clusters_of
from clraster.culling.cull import CLIP_PLANE_MARGIN, build_draw_list
from clraster.culling.frustum import DEFAULT_MARGIN, frustum_plane_scales, frustum_planes
from clraster.pipeline import reference as twin
from clraster.pipeline.lines import render_lines
from clraster.pipeline.reference.lines import render_lines as twin_lines
from clraster.world.generators import random_scene
from clraster.world.generators.primitives import uv_sphere


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


# -- object culling through the BVH plane masks ------------------------------------------

def _brute_classify(planes, scales, lo, hi, mag, mask, mu_in, mu_out):
    """Every box on its own against every plane set in its mask, one plane at a time (no
    tree, no shared primitive): (state, remaining mask) per box, as the traversal defines
    them (OUTSIDE: some tested plane's max < −μ_out·term; a bit clears where the plane's
    min >= μ_in·term; INSIDE: no bit left)."""
    outside = np.zeros(lo.shape[0], bool)
    left = mask.astype(np.int64)
    for k in range(planes.shape[0]):
        n, d = planes[k, :3], planes[k, 3]
        dmin = np.minimum(lo * n, hi * n).sum(axis=1) + d
        dmax = np.maximum(lo * n, hi * n).sum(axis=1) + d
        term = mag @ scales[k, :3] + scales[k, 3]
        act = ((left >> k) & 1) == 1
        outside |= act & (dmax < -mu_out[k] * term)
        left = np.where(act & (dmin >= mu_in[k] * term), left & ~(1 << k), left)
    state = np.where(outside, OUTSIDE, np.where(left == 0, INSIDE, INTERSECTING))
    return state, left


def _random_view_planes(rng, n_user):
    """(planes, scales, μ_in, μ_out) of a random camera's frustum followed by `n_user`
    random planes through the boxes' region, with the margins cull.py gives them."""
    eye = rng.uniform(-25.0, 25.0, 3)
    cam = Camera.look_at(eye, rng.uniform(-3.0, 3.0, 3), fov_y=rng.uniform(30.0, 100.0),
                         near=0.1, far=rng.uniform(20.0, 80.0))
    vp = cam.view_projection(64, 48)
    user = _planes_through(rng, rng.uniform(-4.0, 4.0, 3), n_user) * rng.uniform(0.1, 10.0)
    planes = np.concatenate([frustum_planes(vp), user])
    scales = np.concatenate([frustum_plane_scales(vp), np.abs(user)])
    mu = np.r_[np.full(6, DEFAULT_MARGIN), np.full(n_user, CLIP_PLANE_MARGIN)]
    return planes, scales, mu, mu * 3.0


@pytest.mark.parametrize("n_items, leaf_size", [(0, 4), (1, 1), (17, 2), (1000, 4),
                                                 (5000, 32)])
def test_bvh_with_user_planes_equals_every_box_against_every_plane(n_items, leaf_size):
    rng = np.random.default_rng(1000 + n_items)
    c = rng.uniform(-10.0, 10.0, (n_items, 3))
    half = rng.exponential(0.6, (n_items, 3))
    lo, hi = c - half, c + half
    mags = np.maximum(np.abs(lo), np.abs(hi)) * rng.uniform(1.0, 3.0, (n_items, 1))
    b = BVH.build(lo, hi, leaf_size=leaf_size, mags=mags)
    for n_user in (0, 1, 3, 8):
        n_p = 6 + n_user
        q = 5
        sets = [_random_view_planes(rng, n_user) for _ in range(q)]
        planes = np.stack([x[0] for x in sets])
        scales = np.stack([x[1] for x in sets])
        mu_in, mu_out = sets[0][2], sets[0][3]
        # starting masks: everything, the user bits only, and random wide ones
        masks = np.array([(1 << n_p) - 1, ((1 << n_p) - 1) & ~63,
                          *rng.integers(0, 1 << n_p, q - 2)], np.int64)
        qq, items, state, got = b.cull_batch(planes, scales, masks, inside_margin=mu_in,
                                             outside_margin=mu_out)
        assert got.dtype == np.uint16 and state.dtype == np.uint8
        for i in range(q):
            bs, bm = _brute_classify(planes[i], scales[i], lo, hi, mags, np.full(n_items,
                                     masks[i]), mu_in, mu_out)
            keep = np.flatnonzero(bs != OUTSIDE)
            ctx = f"{n_items} items, {n_user} user planes, query {i}, mask {masks[i]:#x}"
            np.testing.assert_array_equal(items[qq == i], keep, ctx)
            np.testing.assert_array_equal(state[qq == i], bs[keep], ctx)
            np.testing.assert_array_equal(got[qq == i], bm[keep], ctx)
            # the single-query path (BVH.cull) gives the same
            it1, st1, m1 = b.cull(planes[i], scales[i], mask=int(masks[i]),
                                  inside_margin=mu_in, outside_margin=mu_out,
                                  return_mask=True)
            np.testing.assert_array_equal(it1, keep, ctx)
            np.testing.assert_array_equal(st1, bs[keep], ctx)
            np.testing.assert_array_equal(m1, bm[keep], ctx)


def test_plane_masks_widths_and_backward_compatible_calls():
    # 6-plane calls: int masks 0..63, uint8 check_mask; wider masks need more planes
    assert check_mask(None, 2).tolist() == [63, 63] and check_mask(None, 2).dtype == np.uint8
    assert check_mask(None, 1, MAX_PLANES)[0] == 2**MAX_PLANES - 1
    assert check_mask(2**14 - 1, 1, 14).dtype == np.uint16
    with pytest.raises(ValueError, match="0..63"):
        check_mask(64, 1)
    with pytest.raises(ValueError, match="0..16383"):
        check_mask(2**14, 1, 14)
    lo = np.array([[-1.0, -1, -6], [10, 10, -6]])
    b = BVH.build(lo, lo + 0.5)
    vp = Camera.look_at((0, 0, 0), (0, 0, -1), fov_y=90.0, near=0.1, far=20.0) \
        .view_projection(32, 32)
    items, state = b.cull(frustum_planes(vp), mask=63)
    assert items.tolist() == [0] and state.tolist() == [INSIDE]
    with pytest.raises(ValueError, match="planes must have shape"):
        b.cull(np.zeros((MAX_PLANES + 1, 4)))


def test_a_node_inside_a_user_plane_drops_its_bit_for_its_subtree(monkeypatch):
    """Boxes in a row across the view (some straddle the left / right planes), all of them
    far inside user plane 6 (y >= −50); plane 7 (z <= −7) removes some, keeps some and
    splits some. The root is inside plane 6, so no test below it sees bit 6; the returned
    masks keep frustum bits and bit 7 where they straddle, never bit 6."""
    x = np.linspace(-30.0, 30.0, 64)
    z = np.where(np.arange(64) % 3 == 0, -6.0, np.where(np.arange(64) % 3 == 1, -8.0, -7.2))
    lo = np.stack([x - 0.4, np.full(64, -1.0), z - 0.5], axis=1)
    hi = np.stack([x + 0.4, np.full(64, 1.0), z + 0.5], axis=1)
    b = BVH.build(lo, hi, leaf_size=4)
    vp = Camera.look_at((0, 0, 0), (0, 0, -1), fov_y=90.0, near=0.1, far=50.0) \
        .view_projection(64, 64)
    user = np.array([[0.0, 1.0, 0.0, 50.0], [0.0, 0.0, -1.0, -7.0]])
    planes = np.concatenate([frustum_planes(vp), user])
    scales = np.concatenate([frustum_plane_scales(vp), np.abs(user)])
    mu = np.r_[np.full(6, DEFAULT_MARGIN), np.full(2, CLIP_PLANE_MARGIN)]
    seen = []
    real = bvh_module.classify_extremes

    def spy(dmin, dmax, mterm, mask, mu_in, mu_out):
        seen.append(np.array(mask, np.int64, copy=True))
        return real(dmin, dmax, mterm, mask, mu_in, mu_out)

    monkeypatch.setattr(bvh_module, "classify_extremes", spy)
    items, state, masks = b.cull(planes, scales, inside_margin=mu, outside_margin=mu,
                                 return_mask=True)
    monkeypatch.undo()
    assert seen[0].tolist() == [255]                       # the root tests every plane
    assert all(((m >> 6) & 1 == 0).all() for m in seen[1:])   # its subtree skips plane 6
    assert len(seen) > 3
    bs, bm = _brute_classify(planes, scales, lo, hi, b.item_mag, np.full(64, 255), mu, mu)
    keep = np.flatnonzero(bs != OUTSIDE)
    np.testing.assert_array_equal(items, keep)
    np.testing.assert_array_equal(masks, bm[keep])
    assert ((masks >> 6) & 1 == 0).all()
    z_kept = z[items]
    assert (z_kept < -6.5).all() and (z == -6.0).any()      # wholly behind plane 7: culled
    split = masks[z_kept == -7.2]
    assert ((split >> 7) & 1 == 1).all()                   # straddles plane 7: bit kept
    assert ((masks[z_kept == -8.0] >> 7) & 1 == 0).all()   # wholly kept: bit dropped
    assert (masks & 63).any() and (state == INTERSECTING).any()
    assert ((masks & 63) != 0).sum() < masks.size          # frustum bits where they straddle


def _mixed_scene(seed: int) -> Scene:
    """random_scene's small meshes (mirrored instances, a NaN vertex) plus 12 instances of
    a 50-cluster sphere under random rotations, non-uniform scales and mirrors."""
    scene = random_scene(seed, 24, extent=6.0, mirrors=True)
    sphere = Mesh(*uv_sphere(1.0, 40, 80))
    rng = np.random.default_rng(seed)
    for _ in range(12):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        t = np.eye(4)
        t[:3, :3] = q * rng.uniform(0.4, 2.5, 3)
        t[:3, 3] = rng.uniform(-6.0, 6.0, 3)
        scene.add(sphere, t)
    return scene


def _outside_a_plane(scene: Scene, inst: np.ndarray, cl: np.ndarray,
                     planes: np.ndarray) -> np.ndarray:
    """bool per (instance, cluster) pair: its object-space cluster box lies wholly outside
    one of the world planes moved to the instance's object space (plane · model), by more
    than CLIP_PLANE_MARGIN of the terms' magnitude (the old post-filter's rule)."""
    out = np.zeros(inst.size, bool)
    mats = scene.transforms()
    for j, (i, c) in enumerate(zip(inst.tolist(), cl.tolist(), strict=True)):
        cm = clusters_of(scene.instances[i].mesh, 128, 128)
        lo = cm.aabb_min[c].astype(np.float64)
        hi = cm.aabb_max[c].astype(np.float64)
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            continue
        q = planes @ mats[i]
        top = np.maximum(q[:, :3] * lo, q[:, :3] * hi).sum(axis=1) + q[:, 3]
        mag = np.abs(q[:, :3]) @ np.maximum(np.abs(lo), np.abs(hi)) + np.abs(q[:, 3])
        out[j] = (top < -CLIP_PLANE_MARGIN * mag).any()
    return out


@pytest.mark.parametrize("path", ["flat", "dense", "bvh"])
def test_clip_plane_culling_on_every_path_is_the_plain_list_minus_boxes_outside(
        path, monkeypatch):
    if path != "flat":   # groups through each mesh's cluster tests, dense or BVH
        monkeypatch.setattr(cull_module, "FLAT_CLUSTERS", -1)
    if path == "bvh":
        monkeypatch.setattr(cull_module, "DENSE_CLUSTERS", 0)
        monkeypatch.setattr(cull_module, "DENSE_PAIRS", 0)
    scene = _mixed_scene(11)
    rng = np.random.default_rng(12)
    user_culled_instances = 0
    for view in range(3):
        cam = Camera.look_at(rng.uniform(-18.0, 18.0, 3), (0.0, 0.0, 0.0), fov_y=60.0,
                             near=0.1, far=60.0)
        vp = cam.view_projection(96, 72)
        planes = _planes_through(rng, rng.uniform(-2.0, 2.0, 3), (1, 3, 8)[view])
        for frustum, cones in ((True, True), (True, False), (False, False)):
            plain = build_draw_list(scene, vp, frustum=frustum, cones=cones)
            dl = build_draw_list(scene, vp, frustum=frustum, cones=cones,
                                 clip_planes=planes)
            out = _outside_a_plane(scene, plain.instance, plain.cluster, planes)
            ctx = f"{path} view {view} frustum {frustum} cones {cones}"
            assert out.any(), ctx
            np.testing.assert_array_equal(dl.instance, plain.instance[~out], ctx)
            np.testing.assert_array_equal(dl.cluster, plain.cluster[~out], ctx)
            np.testing.assert_array_equal(dl.inside, plain.inside[~out], ctx)
            if not frustum:
                assert not dl.inside.any()
            c, c0 = dl.counts, plain.counts
            assert c["clusters_drawn"] == len(dl)
            assert c["clusters_total"] == (c["clusters_frustum_culled"]
                                           + c["clusters_cone_culled"] + c["clusters_drawn"])
            # culled by a plane: counted with the frustum-culled clusters (a cluster both
            # facing away and outside a plane now counts as frustum-culled)
            assert c["clusters_cone_culled"] <= c0["clusters_cone_culled"]
            assert (c["clusters_frustum_culled"] + c["clusters_cone_culled"]
                    == c0["clusters_frustum_culled"] + c0["clusters_cone_culled"]
                    + int(out.sum())), ctx
            assert c["instances_frustum_culled"] >= c0["instances_frustum_culled"]
            user_culled_instances += c["instances_frustum_culled"] \
                - c0["instances_frustum_culled"]
    assert user_culled_instances > 0   # whole instances go at the top level too
    # the image: object culling with the planes changes nothing. Reference: no object
    # culling at all (frustum and cones off, and an infinite plane margin: nothing is
    # outside a plane, nothing inside)
    r = get_renderer(96, 72)
    cam = Camera.look_at((4.0, 9.0, 16.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=60.0)
    planes = np.array([[1.0, 0.2, 0.0, 0.5], [-0.1, -1.0, 0.3, 2.0], [0.0, 0.0, 1.0, 3.0]])
    on = r.render(scene, cam, clip_planes=planes)
    planes_only = r.render(scene, cam, clip_planes=planes, frustum=False, cones=False)
    with monkeypatch.context() as m:
        m.setattr(cull_module, "CLIP_PLANE_MARGIN", np.inf)
        ref = r.render(scene, cam, clip_planes=planes, frustum=False, cones=False)
    assert ref.stats.clusters_drawn == ref.stats.clusters_total
    assert_same_image(on, ref, path, "object culling through the plane masks")
    assert_same_image(planes_only, ref, path, "culling by the planes alone")
    assert on.stats.clusters_drawn < planes_only.stats.clusters_drawn \
        < ref.stats.clusters_drawn
