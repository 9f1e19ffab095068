"""Frustum planes, sphere/box classification, the BVH, the eye of a view-projection matrix,
and draw lists (counts, order, conservativeness) on constructed scenes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import ortho
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clraster.culling.bvh import BVH, classify_extremes, classify_one
from clraster.culling.clusters import clusters_of
from clraster.culling.cull import COUNT_NAMES, ViewCull, build_draw_list
from clraster.culling.frustum import (
    Visibility,
    classify_aabbs,
    classify_spheres,
    eye_from_view_proj,
    frustum_plane_scales,
    frustum_planes,
    view_proj_flips,
)
from clraster.world.camera import Camera
from clraster.world.mesh import Mesh
from clraster.world.scene import Scene

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
IN, X, OUT = Visibility.INSIDE, Visibility.INTERSECTING, Visibility.OUTSIDE
S2 = math.sqrt(0.5)

# gluPerspective(fov 90°, aspect 1, near 1, far 10), identity view, written out by hand:
# f = 1/tan(45°) = 1, P[2, 2] = (10 + 1)/(1 − 10) = −11/9, P[2, 3] = 2·10·1/(1 − 10) = −20/9.
P90 = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, -11 / 9, -20 / 9], [0, 0, -1.0, 0]])
# Its planes, by hand (row3 ± row_i, normalized): left x − z >= 0, right −x − z >= 0,
# bottom y − z >= 0, top −y − z >= 0, near −z − 1 >= 0, far z + 10 >= 0.
P90_PLANES = np.array([[S2, 0, -S2, 0], [-S2, 0, -S2, 0], [0, S2, -S2, 0], [0, -S2, -S2, 0],
                       [0, 0, -1, -1], [0, 0, 1, 10]])


def translation(x, y, z) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def cube_mesh(half: float = 0.5) -> Mesh:
    """Closed cube centred at the origin, counter-clockwise seen from outside."""
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    f = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return Mesh(v, f)


def quad_mesh(normal: str) -> Mesh:
    """A unit quad centred at the origin facing +y, −y or +x (two triangles)."""
    if normal == "+y":  # counter-clockwise seen from +y
        v = [[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]]
    elif normal == "-y":
        v = [[-0.5, 0, -0.5], [0.5, 0, -0.5], [0.5, 0, 0.5], [-0.5, 0, 0.5]]
    else:  # +x
        v = [[0, -0.5, -0.5], [0, 0.5, -0.5], [0, 0.5, 0.5], [0, -0.5, 0.5]]
    return Mesh(v, [[0, 1, 2], [0, 2, 3]])


# -- planes -------------------------------------------------------------------------------

def test_frustum_planes_hand_computed():
    np.testing.assert_allclose(frustum_planes(P90), P90_PLANES, atol=1e-15)
    # Camera moved to z = 5 (view = translation(0, 0, −5)): offsets shift by the normal · 5.
    shifted = frustum_planes(P90 @ translation(0, 0, -5))
    expect = P90_PLANES.copy()
    expect[:, 3] -= expect[:, :3] @ [0, 0, 5]
    np.testing.assert_allclose(shifted, expect, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(shifted[:, :3], axis=1), 1.0)


def test_frustum_planes_are_signed_distances():
    cam = Camera.look_at((3, -2, 7), (0.5, 0.2, -1), fov_y=60, near=0.5, far=40)
    vp = cam.view_projection(640, 360)
    planes = frustum_planes(vp)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-40, 40, (2000, 3))
    clip = np.column_stack([pts, np.ones(len(pts))]) @ vp.T
    x, y, z, w = clip.T
    inside = (np.abs(x) <= w) & (np.abs(y) <= w) & (np.abs(z) <= w)
    d = pts @ planes[:, :3].T + planes[:, 3]
    np.testing.assert_array_equal((d >= 0).all(axis=1), inside)
    assert inside.any() and not inside.all()
    # Distance: a point moved by t along the unit normal changes the value by t.
    np.testing.assert_allclose(((pts + planes[0, :3]) @ planes[0, :3] + planes[0, 3]) - d[:, 0],
                               1.0, atol=1e-9)


def test_plane_scales():
    # |row3| + |row_i| over the normal length: left plane (1, 0, 1, 0)/|(1, 0, −1)|.
    s = frustum_plane_scales(P90)
    np.testing.assert_allclose(s[0], [S2, 0, S2, 0], atol=1e-15)
    np.testing.assert_allclose(s[4], [0, 0, (1 + 11 / 9) / (20 / 9), 1.0], atol=1e-15)
    # With an object transform, scales use |VP| @ |M| (>= |VP @ M|).
    m = translation(0, 0, -5) @ np.diag([2.0, 1.0, 1.0, 1.0])
    sm = frustum_plane_scales(P90, m)
    raw_norm = np.linalg.norm((np.array([[1, 0, -1, 0]]) @ m)[0, :3])
    np.testing.assert_allclose(sm[0], (np.array([1, 0, 1, 0]) @ np.abs(m)) / raw_norm)


# -- spheres and boxes ---------------------------------------------------------------------

SPHERE_CASES = [  # centre, radius, state, remaining mask (exact test: margins 0)
    ((0, 0, -5), 1.0, IN, 0),
    ((-20, 0, -5), 1.0, OUT, None),  # left
    ((20, 0, -5), 1.0, OUT, None),  # right
    ((0, -20, -5), 1.0, OUT, None),  # bottom
    ((0, 20, -5), 1.0, OUT, None),  # top
    ((0, 0, 0.5), 0.25, OUT, None),  # near (in front of the eye plane, outside near)
    ((0, 0, -20), 1.0, OUT, None),  # far
    ((0, 0, -1), 0.5, X, 1 << 4),  # straddles near only
    ((-4, 0, -5), 1.5, X, 1 << 0),  # straddles left only: d = (−4 + 5)·S2 = 0.707
    ((0, 0, -11), 1.0, X, 1 << 5),  # touches far from outside: max value exactly 0
    ((0, 0, -9), 1.0, IN, 0),  # touches far from inside: closed, inside
    ((0, 0, 0), 3.0, X, 31),  # the eye inside the sphere: crosses all but far (z + 10 >= 7)
]


@pytest.mark.parametrize("centre, radius, state, mask", SPHERE_CASES)
def test_classify_spheres_exact(centre, radius, state, mask):
    s, m = classify_spheres(P90_PLANES, [centre], [radius], inside_margin=0.0,
                            outside_margin=0.0)
    assert s.dtype == np.uint8 and m.dtype == np.uint8
    assert s[0] == state
    if mask is not None:
        assert m[0] == mask


def test_classify_spheres_margins_and_masks():
    c = np.array([[0, 0, -9.0], [0, 0, -11.0], [0, 0, -11.0 - 1e-5], [0, 0, -1.0]])
    r = np.array([1.0, 1.0, 1.0, 0.5])
    # Default margins (1e-5 of the term magnitude; with the default scales |plane| that is
    # 1e-5 · (|z| + r + |d|) = 1e-5 · (12 + 10) = 2.2e-4 for the far plane here): touching
    # the far plane from inside is no longer INSIDE, and a sphere 1e-5 outside is not
    # OUTSIDE (it could touch after float32 rounding).
    s, m = classify_spheres(P90_PLANES, c, r)
    assert s.tolist() == [X, X, X, X] and m[0] == 1 << 5
    # ... but clearly outside is OUTSIDE: 1e-2 beyond, more than the 2.2e-4 margin.
    s, _ = classify_spheres(P90_PLANES, c[2:3] - [0, 0, 1e-2], r[2:3])
    assert s[0] == OUT
    # A clear mask bit skips that plane: the near-straddling sphere with near (bit 4)
    # already known inside becomes INSIDE; with only near to test, it stays INTERSECTING.
    s, m = classify_spheres(P90_PLANES, c[3:], r[3:], mask=63 & ~(1 << 4))
    assert s[0] == IN and m[0] == 0
    s, m = classify_spheres(P90_PLANES, c[3:], r[3:], mask=1 << 4)
    assert s[0] == X and m[0] == 1 << 4
    # mask 0: nothing to test, INSIDE, whatever the sphere.
    s, _ = classify_spheres(P90_PLANES, [[0, 0, 100.0]], [1.0], mask=0)
    assert s[0] == IN


def test_classify_aabbs_constructed():
    lo = np.array([[-0.5, -0.5, -5.5], [-20, -1, -6], [-0.2, -0.2, -1.5], [-3, -3, -3],
                   [2, 0, -2.5], [-1, -1, -12], [4, 4, -3], [0.0, 0.0, -3.0]])
    hi = np.array([[0.5, 0.5, -4.5], [-15, 1, -4], [0.2, 0.2, -0.5], [3, 3, 3],
                   [3, 1, -1.5], [1, 1, -10], [5, 5, -2], [0.0, 0.0, -3.0]])
    s, m = classify_aabbs(P90_PLANES, lo, hi, inside_margin=0.0, outside_margin=0.0)
    # 0: well inside (|x|, |y| <= 0.5 < 4.5 <= −z). 1: x − z <= −15 + 6 < 0: left of the
    # left plane. 2: −z − 1 spans [−0.5, 0.5]: straddles near only (|x| <= 0.2 < 0.5 <= −z).
    # 3: the eye inside the box: crosses all planes but far (z + 10 >= 7).
    # 4: right plane −x − z spans [−3 + 1.5, −2 + 2.5] = [−1.5, 0.5]: straddles right only.
    # 5: far plane z + 10 spans [−2, 0]: touches it from outside (max exactly 0): kept.
    # 6: −x − z <= −4 + 3 < 0: right of the right plane. 7: a point (zero-size box) inside.
    assert s.tolist() == [IN, OUT, X, X, X, X, OUT, IN]
    assert m[2] == 1 << 4 and m[4] == 1 << 1 and m[5] == 1 << 5
    assert m[3] == 63 & ~(1 << 5)  # inside the far plane only
    # An infinite box is never culled (and never INSIDE).
    s, _ = classify_aabbs(P90_PLANES, [[-np.inf] * 3], [[np.inf] * 3])
    assert s[0] == X


def test_sphere_off_a_frustum_edge_is_kept():
    # Centre c = (−6, 6, −5), beyond the edge where the left and top planes meet (the line
    # x = z, y = −z). Its distance to each plane is 1·sqrt(1/2) ≈ 0.707 and to the edge
    # line |(−1, 1, 0)⊥(−1, 1, −1)| = sqrt(2/3) ≈ 0.816. Radius 0.75: it misses the frustum
    # but is outside no single plane, so the plane test keeps it (conservative: never a
    # wrong cull, as with every plane test).
    s, m = classify_spheres(P90_PLANES, [[-6, 6, -5]], [0.75], inside_margin=0.0,
                            outside_margin=0.0)
    assert s[0] == X and m[0] == (1 << 0) | (1 << 3)


def test_classify_validation():
    with pytest.raises(ValueError, match="planes must have shape"):
        classify_spheres(np.zeros((5, 4)), [[0, 0, 0]], [1])
    with pytest.raises(ValueError, match="radii"):
        classify_spheres(P90_PLANES, [[0, 0, 0]], [1, 2])
    with pytest.raises(ValueError, match="mask"):
        classify_spheres(P90_PLANES, [[0, 0, 0]], [1], mask=64)
    with pytest.raises(ValueError, match=r"shape \(K, 3\)"):
        classify_aabbs(P90_PLANES, [[0, 0]], [[1, 1]])


# -- eye ------------------------------------------------------------------------------------

def test_eye_of_perspective_and_ortho():
    cam = Camera.look_at((1, 2, 3), (0, 0, 0), fov_y=50, near=0.1, far=50)
    vp = cam.view_projection(800, 600)
    np.testing.assert_allclose(eye_from_view_proj(vp), [1, 2, 3, 1], atol=1e-9)
    assert not view_proj_flips(vp)
    assert view_proj_flips(np.diag([-1.0, 1, 1, 1]) @ vp)  # mirrored x
    assert view_proj_flips(np.diag([1.0, -1, 1, 1]) @ vp)  # mirrored y
    assert not view_proj_flips(np.diag([-1.0, -1, 1, 1]) @ vp)  # rotated 180°: no mirror
    # glOrtho with the identity view looks down −z.
    o = ortho(-2, 2, -1, 1, 0.5, 20)
    np.testing.assert_allclose(eye_from_view_proj(o), [0, 0, -1, 0], atol=1e-15)
    assert not view_proj_flips(o)
    assert view_proj_flips(np.diag([-1.0, 1, 1, 1]) @ o)
    with pytest.raises(ValueError, match="linearly dependent"):
        eye_from_view_proj(np.zeros((4, 4)))


@pytest.mark.parametrize("kind", ["perspective", "ortho", "mirrored"])
def test_eye_predicts_ndc_orientation(kind):
    # A face is clockwise in NDC (culled by "back") iff dot(n, p − e) > 0 (perspective) or
    # dot(n, d) > 0 (orthographic), swapped when the projection mirrors.
    rng = np.random.default_rng(1)
    view = Camera.look_at((2, 1, 6), (0, 0, 0)).view
    if kind == "ortho":
        vp = ortho(-3, 3, -2, 2, 0.1, 30) @ view
    else:
        vp = Camera.look_at((2, 1, 6), (0, 0, 0), near=0.1, far=30).view_projection(4, 3)
        if kind == "mirrored":
            vp = np.diag([-1.0, 1, 1, 1]) @ vp
    eye = eye_from_view_proj(vp)
    flips = view_proj_flips(vp)
    tri = rng.uniform(-2, 2, (500, 3, 3))
    clip = np.einsum("ij,tkj->tki", vp, np.concatenate([tri, np.ones((500, 3, 1))], axis=2))
    assert (clip[..., 3] > 0).all()
    ndc = clip[..., :2] / clip[..., 3:]
    e1, e2 = ndc[:, 1] - ndc[:, 0], ndc[:, 2] - ndc[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if eye[3] == 0.0:
        back = n @ eye[:3] > 0
    else:
        back = np.einsum("ij,ij->i", n, tri[:, 0] - eye[:3]) > 0
    assert flips == (kind == "mirrored")
    np.testing.assert_array_equal(area < 0, back ^ flips)


# -- BVH ------------------------------------------------------------------------------------

def random_boxes(rng, k):
    c = rng.uniform(-10, 10, (k, 3))
    e = rng.uniform(0, 1.5, (k, 3)) * (rng.random((k, 1)) < 0.9)  # 10 % zero-size
    return c - e, c + e


def random_view(rng):
    eye = rng.uniform(-8, 8, 3)  # often inside the cloud of boxes
    target = rng.uniform(-5, 5, 3)
    cam = Camera.look_at(eye, target + [0.0, 0.0, 1e-3], fov_y=float(rng.uniform(20, 100)),
                         near=float(rng.uniform(0.05, 2)), far=float(rng.uniform(5, 40)))
    return cam.view_projection(int(rng.integers(100, 2000)), int(rng.integers(100, 2000)))


def check_bvh_structure(b: BVH, lo, hi):
    k = lo.shape[0]
    assert b.n_items == k
    np.testing.assert_array_equal(np.sort(b.order), np.arange(k))
    if k == 0:
        assert b.n_nodes == 0
        return
    assert b.first[0] == 0 and b.count[0] == k
    inner = np.flatnonzero(b.left >= 0)
    lc, rc = b.left[inner], b.left[inner] + 1
    np.testing.assert_array_equal(b.first[lc], b.first[inner])
    np.testing.assert_array_equal(b.first[rc], b.first[inner] + b.count[lc])
    np.testing.assert_array_equal(b.count[lc] + b.count[rc], b.count[inner])
    assert (np.abs(b.count[lc] - b.count[rc]) <= 1).all()  # median split: balanced
    leaves = b.left < 0
    assert (b.count[leaves] <= b.leaf_size).all() and b.count[leaves].sum() == k
    # Node boxes contain their items' boxes.
    node_of = np.repeat(np.flatnonzero(leaves), b.count[leaves])
    pos = np.concatenate([np.arange(f, f + c) for f, c in zip(b.first[leaves],
                                                               b.count[leaves], strict=True)])
    items = b.order[pos]
    assert (b.node_min[node_of] <= lo[items]).all() and (b.node_max[node_of] >= hi[items]).all()
    assert (b.node_min[lc] >= b.node_min[inner]).all()
    assert (b.node_max[rc] <= b.node_max[inner]).all()


@pytest.mark.parametrize("k", [0, 1, 2, 3, 17, 1000])
@settings(max_examples=6, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), leaf_size=st.sampled_from([1, 2, 4, 8]),
       mask=st.sampled_from([63, 63, 0, 1, 16, 47]))
def test_bvh_cull_equals_brute_force(k, seed, leaf_size, mask):
    rng = np.random.default_rng(seed)
    lo, hi = random_boxes(rng, k)
    b = BVH.build(lo, hi, leaf_size=leaf_size)
    check_bvh_structure(b, lo, hi)
    for _ in range(4):
        vp = random_view(rng)
        planes, scales = frustum_planes(vp), frustum_plane_scales(vp)
        items, state, masks = b.cull(planes, scales, mask=mask, return_mask=True)
        bs, bm = classify_aabbs(planes, lo, hi, mask, scales=scales)
        keep = np.flatnonzero(bs != OUT)
        np.testing.assert_array_equal(items, keep)
        np.testing.assert_array_equal(state, bs[keep])
        np.testing.assert_array_equal(masks[state == X], bm[keep][state == X])


@pytest.mark.parametrize("k", [6, 8, 14])
def test_classify_one_equals_classify_extremes(k):
    """The one-volume classification in Python floats (`classify_one`: a bare Mesh's root
    box) gives `classify_extremes`' state and mask for every mask, with values on the
    margins' edges (products and comparisons exactly at equality), NaN, and per-plane
    margins (user planes), from the same `box_extremes`."""
    rng = np.random.default_rng(k)
    margins = [(1e-5, 2e-5), (0.0, 0.0),
               (np.r_[np.full(6, 1e-5), np.full(k - 6, 3e-4)],
                np.r_[np.full(6, 2e-5), np.full(k - 6, 3e-4)])]
    seen = set()
    for trial in range(400):
        mi, mo = margins[trial % 3]
        m = rng.uniform(0.5, 2.0, (k, 1))
        lo = rng.normal(size=(k, 1))
        hi = lo + np.abs(rng.normal(size=(k, 1)))
        edge = rng.random((k, 1)) < 0.3   # some planes exactly on a margin's edge
        lo = np.where(edge, m * np.broadcast_to(mi, (k,))[:, None], lo)
        hi = np.where(rng.random((k, 1)) < 0.3,
                      m * -np.broadcast_to(mo, (k,))[:, None], hi)
        if trial % 17 == 0:
            lo[rng.integers(k)] = np.nan
        mask = int(rng.integers(0, 1 << k)) if trial % 5 else (1 << k) - 1
        ref_st, ref_mask = classify_extremes(lo, hi, m, np.full(1, mask, np.uint16), mi, mo)
        st_, mk = classify_one(lo, hi, m, mask, mi, mo)
        assert (st_, mk) == (int(ref_st[0]), int(ref_mask[0])), trial
        seen.add(st_)
    assert seen == {IN, X, OUT}


def test_bvh_100k_and_batches():
    rng = np.random.default_rng(5)
    lo, hi = random_boxes(rng, 100_000)
    b = BVH.build(lo, hi)
    check_bvh_structure(b, lo, hi)
    vps = [random_view(rng) for _ in range(3)]
    planes = np.stack([frustum_planes(v) for v in vps])
    scales = np.stack([frustum_plane_scales(v) for v in vps])
    q, items, state, _ = b.cull_batch(planes, scales, np.array([63, 63, 7], np.uint8))
    for i in range(3):
        bs, _ = classify_aabbs(planes[i], lo, hi, 63 if i < 2 else 7, scales=scales[i])
        keep = np.flatnonzero(bs != OUT)
        np.testing.assert_array_equal(items[q == i], keep)
        np.testing.assert_array_equal(state[q == i], bs[keep])
        assert 0 < keep.size < 100_000


def test_bvh_degenerate_inputs():
    # All boxes identical (zero-size): centroids tie on every axis.
    lo = np.zeros((50, 3))
    b = BVH.build(lo, lo, leaf_size=4)
    check_bvh_structure(b, lo, lo)
    items, state = b.cull(frustum_planes(P90 @ translation(0, 0, -5)))  # eye at z = 5
    assert items.tolist() == list(range(50)) and (state == IN).all()
    items, _ = b.cull(frustum_planes(P90))  # the points sit at the eye: outside near
    assert items.size == 0
    with pytest.raises(ValueError, match="finite"):
        BVH.build([[0, 0, np.nan]], [[1, 1, 1]])
    with pytest.raises(ValueError, match="mins > maxs"):
        BVH.build([[0, 0, 2]], [[1, 1, 1]])
    with pytest.raises(ValueError, match="leaf_size"):
        BVH.build(lo, lo, leaf_size=0)


# -- draw lists ----------------------------------------------------------------------------

def cube_grid_scene(n: int = 10, pitch: float = 3.0) -> Scene:
    cube = cube_mesh()
    scene = Scene()
    for i in range(n):
        for j in range(n):
            scene.add(cube, translation(pitch * i, 0.0, pitch * j))
    return scene


def check_counts(dl, scene):
    c = dl.counts
    assert set(c) == set(COUNT_NAMES)
    assert c["instances_total"] == scene.n_instances
    assert c["triangles_total"] == scene.n_faces
    assert c["clusters_total"] == (c["clusters_frustum_culled"] + c["clusters_cone_culled"]
                                   + c["clusters_drawn"])
    assert c["triangles_total"] == (c["triangles_frustum_culled"]
                                    + c["triangles_cone_culled"] + c["triangles_drawn"])
    assert c["clusters_drawn"] == len(dl)
    tri = 0
    for i, cl in zip(dl.instance, dl.cluster, strict=True):
        cm = clusters_of(scene.instances[i].mesh)
        tri += int(cm.tri_offset[cl + 1] - cm.tri_offset[cl])
    assert tri == c["triangles_drawn"]
    key = dl.instance.astype(np.int64) * 1_000_000 + dl.cluster
    assert (np.diff(key) > 0).all()  # scene order, then cluster order
    assert dl.instance.dtype == np.int32 and dl.cluster.dtype == np.int32
    assert dl.inside.dtype == bool


def check_same_lists(a, b, scene):
    """Draw lists ``a`` and ``b`` (made with keep_cone_culled) are the same: pairs, inside
    flags, cone-culled pairs and counts; ``a``'s counts and order are checked too."""
    np.testing.assert_array_equal(a.instance, b.instance)
    np.testing.assert_array_equal(a.cluster, b.cluster)
    np.testing.assert_array_equal(a.inside, b.inside)
    np.testing.assert_array_equal(a.cone_culled, b.cone_culled)
    assert a.counts == b.counts
    check_counts(a, scene)


def test_grid_of_cubes_orthographic_top_view():
    # Cubes of side 1 at (3i, 0, 3j). Looking down −y (eye above, up = −z) with an
    # orthographic box covering x in [−1.5, 7.5], z in [−1.5, 4.5]: exactly the cubes with
    # i in {0, 1, 2}, j in {0, 1} are inside, all by >= 1 unit; the others are >= 1 unit out.
    scene = cube_grid_scene()
    view = Camera.look_at((0, 10, 0), (0, 0, 0), up=(0, 0, -1)).view
    # In eye space x = world x, y = −world z: x in [−1.5, 7.5], y in [−4.5, 1.5].
    vp = ortho(-1.5, 7.5, -4.5, 1.5, 1.0, 20.0) @ view
    dl = build_draw_list(scene, vp)
    check_counts(dl, scene)
    expect = sorted(10 * i + j for i in range(3) for j in range(2))
    assert dl.instance.tolist() == expect and dl.cluster.tolist() == [0] * 6
    assert dl.inside.all()
    assert dl.counts["instances_frustum_culled"] == 94
    assert dl.counts["clusters_drawn"] == 6 and dl.counts["triangles_drawn"] == 72
    assert dl.counts["clusters_cone_culled"] == 0  # a closed cube's cone never culls
    # Frustum off: everything, nothing marked inside.
    dl = build_draw_list(scene, vp, frustum=False)
    check_counts(dl, scene)
    assert len(dl) == 100 and not dl.inside.any()


def test_grid_of_cubes_perspective_counts():
    # Camera inside cube 0, looking along +x with a 90° frustum (near 1, far 10); which cubes
    # are culled, drawn and INSIDE is computed below from their 8 corners (for a box, the
    # plane test's answer: all corners outside one plane = culled, all inside = INSIDE).
    scene = cube_grid_scene()
    vp = P90 @ Camera.look_at((-0.2, 0.1, 0.37), (1, 0.1, 0.37)).view
    dl = build_draw_list(scene, vp, cones=False)
    check_counts(dl, scene)
    # Expected by brute force over the 8 corners of each cube (exact; the margins, ~1e-5 of
    # coordinates of size ~10, do not matter: no corner is within 0.01 of a plane).
    corners = np.array([[x, y, z] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5)])
    planes = frustum_planes(vp)
    vis, ins = [], []
    for k, inst in enumerate(scene.instances):
        pts = corners + inst.transform[:3, 3]
        d = pts @ planes[:, :3].T + planes[:, 3]
        assert np.abs(d).min() > 0.01
        if not (d < 0).all(axis=0).any():
            vis.append(k)
            ins.append(bool((d > 0).all()))
    assert dl.instance.tolist() == vis
    assert dl.inside.tolist() == ins
    assert dl.counts["instances_frustum_culled"] == 100 - len(vis)
    # The eye's own cube lies before the near plane (x <= 0.5 < −0.2 + 1): culled. Both
    # kinds of drawn cubes occur: fully inside and crossing a plane.
    assert 0 not in vis and any(ins) and not all(ins)


def test_cone_culling_of_quads_and_mirrored_instances():
    up, down, side = quad_mesh("+y"), quad_mesh("-y"), quad_mesh("+x")
    scene = Scene()
    scene.add(up, translation(0, 0, 0))  # faces the eye above: drawn
    scene.add(down, translation(2, 0, 0))  # faces away: cone-culled
    scene.add(side, translation(4, 0, 0))  # edge-on: kept (margin)
    mirror = np.diag([1.0, -1.0, 1.0, 1.0]) @ translation(0, -1, 0)
    # Mirrored instances keep their faces' outward side (glTF): the "up" quad's outward
    # normal becomes −y (faces away: culled), the "down" quad's +y (drawn).
    scene.add(up, translation(6, 0, 0) @ mirror)
    scene.add(down, translation(8, 0, 0) @ mirror)
    for kind in ("ortho", "perspective"):
        if kind == "ortho":
            view = Camera.look_at((4, 10, 0), (4, 0, 0), up=(0, 0, -1)).view
            vp = ortho(-6, 6, -2, 2, 1, 20) @ view
        else:
            vp = Camera.look_at((4, 30, 0.01), (4, 0, 0), fov_y=40, near=1,
                                far=60).view_projection(400, 200)
        dl = build_draw_list(scene, vp)
        check_counts(dl, scene)
        assert dl.instance.tolist() == [0, 2, 4], kind
        assert dl.counts["clusters_cone_culled"] == 2 and dl.counts["triangles_cone_culled"] == 4
        # Front culling keeps the opposite ones (and the edge-on quad).
        dl = build_draw_list(scene, vp, cull="front")
        assert dl.instance.tolist() == [1, 2, 3], kind
        # No face culling, or cones off: no cone culling.
        assert len(build_draw_list(scene, vp, cull="none")) == 5
        assert len(build_draw_list(scene, vp, cones=False)) == 5
        # A mirroring projection disables cone culling.
        assert len(build_draw_list(scene, np.diag([-1.0, 1, 1, 1]) @ vp)) == 5


def test_nonfinite_and_empty_instances():
    cube = cube_mesh()
    v = np.array(cube.vertices)
    v[0] = np.nan
    broken = Mesh(v, cube.faces)
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
    scene = Scene()
    scene.add(empty)
    scene.add(broken, translation(100, 0, 0))  # its finite part is far outside the view
    scene.add(cube, translation(100, 0, 0))
    vp = P90 @ translation(0, 0, -5)
    dl = build_draw_list(scene, vp)
    check_counts(dl, scene)
    c = dl.counts
    assert c["instances_empty"] == 1 and c["instances_frustum_culled"] == 1
    # The broken instance is drawn (the renderer drops and counts its NaN triangles).
    assert dl.instance.tolist() == [1] * len(dl) and len(dl) >= 1
    cm = clusters_of(broken)
    assert set(np.flatnonzero(~cm.bounded)) <= set(dl.cluster.tolist())
    assert not dl.inside.any()


@pytest.mark.parametrize("path", ["flat", "dense", "bvh"])
def test_instances_of_one_mesh_many_and_few(path, monkeypatch):
    # 40 × 40 instances of a small mesh and a few rotated, non-uniformly scaled instances of
    # a bigger one, through each cluster path (world boxes of every (instance, cluster)
    # pair / object-space planes against every cluster box / batched BVH traversal):
    # a pair is culled only if the exact object-space box test says OUTSIDE, and every pair
    # clearly outside (by 1e-3 relative) is culled.
    import clraster.culling.cull as cull_mod

    flat, dense = {"flat": (10**9, 0), "dense": (0, 10**9), "bvh": (0, 0)}[path]
    monkeypatch.setattr(cull_mod, "FLAT_CLUSTERS", flat)
    monkeypatch.setattr(cull_mod, "DENSE_CLUSTERS", dense)
    monkeypatch.setattr(cull_mod, "DENSE_PAIRS", dense)
    rng = np.random.default_rng(3)
    small = cube_mesh()
    big = Mesh(rng.uniform(-1, 1, (3 * 4000, 3)), np.arange(3 * 4000).reshape(-1, 3))
    scene = Scene()
    for i in range(40):
        for j in range(40):
            scene.add(small, translation(3 * i, 0, 3 * j))
    for _ in range(5):
        t = np.eye(4)
        t[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * rng.uniform(0.5, 3, 3)
        t[:3, 3] = rng.uniform(0, 120, 3) * [1, 0, 1]
        scene.add(big, t)
    vp = Camera.look_at((60, 8, -10), (60, 0, 60), fov_y=60, near=0.5,
                        far=80).view_projection(640, 480)
    dl = build_draw_list(scene, vp, cones=False)
    check_counts(dl, scene)
    assert 0 < len(dl) < dl.counts["clusters_total"]
    planes = frustum_planes(vp)
    drawn = np.zeros((scene.n_instances, max(clusters_of(big).n_clusters, 1)), bool)
    drawn[dl.instance, dl.cluster] = True
    for i, inst in enumerate(scene.instances):
        cm = clusters_of(inst.mesh)
        oplanes = planes @ inst.transform
        oplanes /= np.linalg.norm(oplanes[:, :3], axis=1)[:, None]
        exact, _ = classify_aabbs(oplanes, cm.aabb_min, cm.aabb_max, inside_margin=0.0,
                                  outside_margin=0.0)
        clear, _ = classify_aabbs(oplanes, cm.aabb_min, cm.aabb_max, outside_margin=1e-3)
        d = drawn[i, :cm.n_clusters]
        assert (exact[~d] == OUT).all(), i
        assert not d[clear == OUT].any(), i


@pytest.fixture(scope="module")
def bunny() -> Mesh:
    path = MESHES / "stanford_bunny.ply"
    if not path.is_file():
        pytest.skip(f"shared mesh stanford_bunny.ply not found in {MESHES} (the shared mesh "
                    f"folder next to the repository is absent)")
    return Mesh.load(path)


@pytest.mark.parametrize("seed, path", [(0, "dense"), (1, "dense"), (2, "dense"),
                                        (3, "bvh"), (4, "bvh"), (5, "flat"), (6, "flat")])
def test_draw_list_is_conservative_on_the_bunny(seed, path, monkeypatch, bunny):
    # Random views and transforms: every culled cluster is really culled (all vertices
    # outside one plane, or every usable triangle showing its culled side, also in NDC) and
    # every INSIDE cluster is inside in float32, as the renderer computes clip coordinates.
    import clraster.culling.cull as cull_mod

    if path == "bvh":
        monkeypatch.setattr(cull_mod, "DENSE_PAIRS", 0)
    elif path == "flat":
        monkeypatch.setattr(cull_mod, "FLAT_CLUSTERS", 10**9)
    mesh = bunny
    rng = np.random.default_rng(seed)
    t = np.eye(4)
    t[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * rng.uniform(5, 15, 3)
    if seed % 2:
        t[:3, :3] = t[:3, :3] @ np.diag([1.0, 1.0, -1.0])  # mirrored instance
    t[:3, 3] = rng.uniform(-1, 1, 3)
    scene = Scene.from_mesh(mesh, t)
    lo, hi = scene.bounds()
    c = (lo + hi) / 2
    size = float(np.linalg.norm(hi - lo))
    eye = c + rng.normal(size=3) / 1.0 * size * rng.uniform(0.3, 1.5)
    cam = Camera.look_at(eye, c + rng.normal(size=3) * size * 0.2, fov_y=float(rng.uniform(20, 70)),
                         near=size * 0.01, far=size * 3)
    vp = cam.view_projection(640, 480)
    cull = ("back", "front")[seed % 3 == 2]
    dl = build_draw_list(scene, vp, cull=cull)
    check_counts(dl, scene)
    cm = clusters_of(mesh)
    mvp = vp @ t
    v = np.column_stack([mesh.vertices.astype(np.float64), np.ones(mesh.n_vertices)])
    clip = v @ mvp.T
    clip32 = (mesh.vertices @ mvp[:, :3].astype(np.float32).T) + mvp[:, 3].astype(np.float32)
    drawn = np.zeros(cm.n_clusters, bool)
    drawn[dl.cluster] = True
    inside = np.zeros(cm.n_clusters, bool)
    inside[dl.cluster[dl.inside]] = True
    tri_cluster = np.repeat(np.arange(cm.n_clusters), np.diff(cm.tri_offset))
    faces = mesh.faces[cm.face_ids]
    x, y, z, w = (clip[faces][..., k] for k in range(4))  # (M, 3) each
    out_plane = np.stack([x < -w, x > w, y < -w, y > w, z < -w, z > w])  # (6, M, 3)
    # A cluster is outside if all its vertices are outside one common plane.
    tri_out = out_plane.all(axis=2)  # (6, M)
    cl_out = np.ones((6, cm.n_clusters), bool)
    np.logical_and.at(cl_out.T, tri_cluster, tri_out.T)
    ndc = clip[faces][..., :2] / clip[faces][..., 3:]
    e1, e2 = ndc[:, 1] - ndc[:, 0], ndc[:, 2] - ndc[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    front_w = (clip[faces][..., 3] > 0).all(axis=1)
    pw = mesh.vertices[faces].astype(np.float64) @ t[:3, :3].T + t[:3, 3]  # world, (M, 3, 3)
    # world outward normal: the winding normal, reversed for a mirroring instance (its
    # faces keep their outward side, the Scene rule)
    nw = np.cross(pw[:, 1] - pw[:, 0], pw[:, 2] - pw[:, 0]) * np.sign(np.linalg.det(t[:3, :3]))
    po = mesh.vertices[faces].astype(np.float64)
    e1, e2 = po[:, 1] - po[:, 0], po[:, 2] - po[:, 0]
    usable = np.linalg.norm(np.cross(e1, e2), axis=1) > 1e-8 * np.linalg.norm(
        e1, axis=1) * np.linalg.norm(e2, axis=1)
    sign = 1.0 if cull == "back" else -1.0
    ray = pw - cam.eye
    ray /= np.linalg.norm(ray, axis=2)[..., None]
    with np.errstate(invalid="ignore"):
        unit_nw = nw / np.linalg.norm(nw, axis=1)[:, None]
    # > 0: the culled side; >= sin(1e-3): seen at least the default cone margin (in world
    # space) away from edge-on, although the instance's scale is not uniform.
    facing = sign * np.einsum("tk,tjk->tj", unit_nw, ray)
    # the screen area's sign, reversed for a mirroring instance (setup swaps its cull sense)
    area = area * np.sign(np.linalg.det(t[:3, :3]))
    culled_side = (area < 0) if cull == "back" else (area > 0)
    n_cone = 0
    for k in np.flatnonzero(~drawn):
        sel = tri_cluster == k
        if cl_out[:, k].any():
            continue  # frustum-culled correctly
        n_cone += 1  # otherwise cone-culled: every usable triangle shows its culled side
        assert (facing[sel & usable] >= math.sin(1e-3)).all(), k
        assert culled_side[sel & usable & front_w].all(), k
    assert 0 < n_cone <= dl.counts["clusters_cone_culled"]  # not vacuous
    c32 = clip32[faces]
    for k in np.flatnonzero(inside):
        sel = tri_cluster == k
        q = c32[sel].reshape(-1, 4)
        assert (np.abs(q[:, :3]) < q[:, 3:4]).all()


@pytest.mark.parametrize("mesh_name", ["quad", "cube", "spot", "bunny"])
def test_one_flat_instance_path_equals_the_general_path(mesh_name, monkeypatch, request):
    # A flat path of one instance (a bare Mesh of up to FLAT_CLUSTERS clusters) takes the
    # flat tables as they are (cull._flat_one) instead of the general path's per-instance
    # ranges and gathers. Over random transforms (mirrored ones too) and views from inside,
    # across and outside the mesh, perspective and orthographic, each cull mode with cones
    # on and off: the same pairs, inside flags, cone-culled pairs and counts both ways.
    import clraster.culling.cull as cull_mod

    monkeypatch.setattr(cull_mod, "FLAT_CLUSTERS", 10**9)   # the bunny's 540 clusters too
    if mesh_name == "bunny":
        mesh = request.getfixturevalue("bunny")
    elif mesh_name == "spot":
        if not (MESHES / "spot.ply").is_file():
            pytest.skip(f"shared mesh spot.ply not found in {MESHES}")
        mesh = Mesh.load(MESHES / "spot.ply")
    else:
        mesh = quad_mesh("+y") if mesh_name == "quad" else cube_mesh()
    rng = np.random.default_rng(len(mesh_name))
    n_views = n_cut = 0
    for k in range(40):
        t = np.eye(4)
        t[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * rng.uniform(0.5, 2.0, 3)
        if k % 3 == 1:
            t[:3, :3] = t[:3, :3] @ np.diag([1.0, -1.0, 1.0])   # mirrored
        t[:3, 3] = rng.uniform(-1, 1, 3)
        scene = Scene.from_mesh(mesh, t)
        lo, hi = scene.bounds()
        c, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
        eye = c + rng.normal(size=3) * size * rng.uniform(0.05, 2.0)
        look = c + rng.normal(size=3) * size * rng.uniform(0.0, 1.5)
        if k % 5 == 4:
            vp = ortho(-size / 3, size / 3, -size / 4, size / 4, 0.01, 4 * size) @ \
                Camera.look_at(eye, look).view
        else:
            vp = Camera.look_at(eye, look, fov_y=float(rng.uniform(20, 90)), near=size * 0.01,
                                far=size * rng.uniform(0.5, 4)).view_projection(640, 480)
        for cull, cones in (("back", True), ("front", True), ("none", True), ("back", False)):
            lists = []
            for one in (True, False):
                monkeypatch.setattr(cull_mod, "FLAT_ONE", one)
                lists.append(build_draw_list(scene, vp, cull=cull, cones=cones,
                                             keep_cone_culled=True))
            a, b = lists
            check_same_lists(a, b, scene)
            n_views += len(a) > 0
            n_cut += 0 < len(a) + a.counts["clusters_cone_culled"] < a.counts["clusters_total"]
    assert n_views > 40 and (n_cut > 10 or mesh_name in ("quad", "cube"))   # not vacuous


@pytest.mark.parametrize("traversal", [False, True])
def test_one_instance_of_a_big_mesh_lists_its_clusters_in_order(traversal, monkeypatch, bunny):
    # A bare Mesh over FLAT_CLUSTERS clusters goes through its mesh's group, whose
    # clusters, when they come in order, are not sorted again (cull._PathResult.ordered):
    # drawn whole (INSIDE, or the frustum test off) and across the frustum, through the
    # BVH's dense rows or its traversal, the list is in draw order, and the clusters drawn
    # whole are the same with the frustum test on and off.
    import clraster.culling.cull as cull_mod

    if traversal:   # the cluster BVH's batched traversal, not its dense rows
        monkeypatch.setattr(cull_mod, "DENSE_PAIRS", 0)
    scene = Scene.from_mesh(bunny)
    assert clusters_of(bunny).n_clusters > cull_mod.FLAT_CLUSTERS
    lo, hi = scene.bounds()
    c, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    far = Camera.look_at(c + [0, 0, 3 * size], c, fov_y=40, near=size * 0.1, far=size * 10)
    close = Camera.look_at(c + [0, 0, 0.4 * size], c, fov_y=40, near=size * 0.01,
                           far=size * 10)
    off = build_draw_list(scene, far.view_projection(640, 480), frustum=False)
    whole = build_draw_list(scene, far.view_projection(640, 480))
    cut = build_draw_list(scene, close.view_projection(640, 480))
    assert whole.inside.all() and not off.inside.any()
    assert 0 < len(cut) and cut.counts["clusters_frustum_culled"] > 0
    for dl in (off, whole, cut):
        check_counts(dl, scene)   # (draw order included)
    np.testing.assert_array_equal(whole.cluster, off.cluster)
    assert set(cut.cluster.tolist()) <= set(range(clusters_of(bunny).n_clusters))


def test_draw_order_is_fixed():
    # A mixed scene (small meshes on the flat path, a bigger one through its BVH, a NaN
    # instance, an empty one): with nothing culled the list enumerates every (instance,
    # cluster) in scene order then cluster order; culled lists keep that order, and two
    # calls give identical lists.
    rng = np.random.default_rng(11)
    big = Mesh(rng.uniform(-1, 1, (3 * 9000, 3)), np.arange(3 * 9000).reshape(-1, 3))
    v = np.array(cube_mesh().vertices)
    v[3] = np.inf
    scene = Scene()
    scene.add(cube_mesh(), translation(0, 0, -5))
    scene.add(big, translation(3, 0, -6))
    scene.add(Mesh(v, cube_mesh().faces), translation(-3, 0, -5))
    scene.add(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32)))
    scene.add(quad_mesh("+y"), translation(0, -2, -4))
    scene.add(big, translation(-40, 0, -6))
    n_c = [clusters_of(i.mesh).n_clusters if i.mesh.n_faces else 0 for i in scene.instances]
    full = [(i, c) for i in range(scene.n_instances) for c in range(n_c[i])]
    dl = build_draw_list(scene, P90, frustum=False, cones=False)
    assert list(zip(dl.instance.tolist(), dl.cluster.tolist(), strict=True)) == full
    for kw in ({}, {"cull": "front"}, {"cones": False}):
        a = build_draw_list(scene, P90, **kw)
        b = build_draw_list(scene, P90, **kw)
        check_counts(a, scene)
        np.testing.assert_array_equal(a.instance, b.instance)
        np.testing.assert_array_equal(a.cluster, b.cluster)
        np.testing.assert_array_equal(a.inside, b.inside)
        pairs = list(zip(a.instance.tolist(), a.cluster.tolist(), strict=True))
        assert pairs == [p for p in full if p in set(pairs)]
        assert 5 not in a.instance  # far to the left: culled
        assert 2 in a.instance  # the NaN instance is never culled as a whole


@pytest.mark.parametrize("threads", [False, True])
def test_culling_threads_give_the_same_draw_list(threads, monkeypatch):
    # The culling paths (flat path, one group per bigger mesh) run on threads above
    # THREAD_PAIRS pairs (cull._run_tasks). Forced on (threshold 0) and off, over the
    # procedural plant (many small meshes on the flat path and several bigger ones) seen
    # from inside, with cones, culled back and front faces and a user clip plane: the same
    # pairs in the same order, the same inside flags, cone-culled pairs and counts.
    import clraster.culling.cull as cull_mod
    from clraster.world.generators import plant, plant_inside_camera

    scene = plant(200_000)
    vp = plant_inside_camera(scene, 640, 480).view_projection(640, 480)
    cases = ({}, {"cull": "front"}, {"clip_planes": np.array([[0.3, 0.0, 1.0, -2.0]])})
    lists = {}
    monkeypatch.setattr(cull_mod, "_NCPU", max(2, cull_mod._NCPU))   # threads on 1 CPU too
    for on in (threads, not threads):   # the parametrized mode first
        monkeypatch.setattr(cull_mod, "THREAD_PAIRS", 0 if on else 1 << 62)
        lists[on] = [build_draw_list(scene, vp, keep_cone_culled=True, **kw) for kw in cases]
    for a, b in zip(lists[True], lists[False], strict=True):
        assert len(a) > 0 and a.counts["clusters_frustum_culled"] > 0
        check_same_lists(a, b, scene)
    assert len(lists[True][0].cone_culled) > 0   # the cone paths ran


def test_instances_classified_densely_or_through_the_bvh_alike(monkeypatch):
    # Up to DENSE_INSTANCES bounded instances, `_classify_instances` tests every instance
    # box on its own instead of traversing the instance BVH (`BVH.cull` equals that by
    # contract). Both ways over the procedural plant from inside, with the frustum off and
    # on, user clip planes (16-bit masks) and without: the same draw lists and counts.
    import clraster.culling.cull as cull_mod
    from clraster.world.generators import plant, plant_inside_camera

    scene = plant(200_000)
    assert 100 < scene.n_instances <= cull_mod.DENSE_INSTANCES
    vp = plant_inside_camera(scene, 640, 480).view_projection(640, 480)
    planes = np.array([[0.3, 0.0, 1.0, -2.0], [0.0, -1.0, 0.0, 4.0]])
    cases = ({}, {"clip_planes": planes}, {"frustum": False, "clip_planes": planes})
    out = {}
    for dense in (True, False):
        monkeypatch.setattr(cull_mod, "DENSE_INSTANCES", 1 << 30 if dense else 0)
        out[dense] = [build_draw_list(scene, vp, **kw) for kw in cases]
    for a, b in zip(out[True], out[False], strict=True):
        assert 0 < a.counts["instances_frustum_culled"] < scene.n_instances
        np.testing.assert_array_equal(a.instance, b.instance)
        np.testing.assert_array_equal(a.cluster, b.cluster)
        np.testing.assert_array_equal(a.inside, b.inside)
        assert a.counts == b.counts


def test_draw_list_validation_and_timings():
    scene = cube_grid_scene(2)
    with pytest.raises(ValueError, match="view_proj"):
        build_draw_list(scene, np.eye(3))
    with pytest.raises(ValueError, match="NaN"):
        build_draw_list(scene, np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="cull"):
        build_draw_list(scene, P90, cull="both")
    with pytest.raises(ValueError, match="scene"):
        build_draw_list(cube_mesh(), P90)
    dl = build_draw_list(scene, P90)
    assert {"prepare", "instances", "clusters", "cones", "order", "total"} <= set(dl.timings_ms)
    empty = build_draw_list(Scene(), P90)
    assert len(empty) == 0 and empty.counts["instances_total"] == 0


@pytest.mark.parametrize("seed", range(4))
def test_view_cull_pairs_decide_each_pair_alone(seed):
    """`ViewCull.pairs` (hierarchical occlusion culling's cluster tests) decides every pair
    on its own: a random half of a scene's pairs gets exactly the verdicts (kept, inside,
    cone-culled) those pairs get among all of them, and the counts partition the pairs.
    Against `all` on the same view: the instance test is shared, so the pairs of culled
    instances are culled by both, and INSIDE instances keep all their pairs, inside."""
    from clraster.world.generators import random_scene
    scene = random_scene(seed, 48, extent=4.0, mirrors=bool(seed % 2))
    rng = np.random.default_rng(seed)
    d = rng.normal(size=3)
    cam = Camera.look_at(d / np.linalg.norm(d) * rng.uniform(1.0, 8.0),
                         rng.uniform(-1.5, 1.5, 3), (0.0, 1.0, 0.0), fov_y=60.0, near=0.05,
                         far=60.0)
    vp = cam.view_projection(96, 64)
    vc = ViewCull(scene, vp, keep_cone_culled=True)
    n = np.array([clusters_of(i.mesh).n_clusters if i.mesh.n_faces else 0
                  for i in scene.instances])
    inst = np.repeat(np.arange(n.size), n)
    cl = np.concatenate([np.arange(k) for k in n]) if n.size else np.zeros(0, np.int64)
    full = vc.pairs(inst, cl)
    half = np.sort(rng.choice(inst.size, inst.size // 2, replace=False))
    part = vc.pairs(inst[half], cl[half])

    def decided(dl):
        kept = {(int(a), int(b)): bool(c) for a, b, c in
                zip(dl.instance, dl.cluster, dl.inside, strict=True)}
        cone = {(int(a), int(b)) for a, b in dl.cone_culled}
        return kept, cone

    kept_all, cone_all = decided(full)
    kept, cone = decided(part)
    chosen = {(int(a), int(b)) for a, b in zip(inst[half], cl[half], strict=True)}
    assert kept == {k: v for k, v in kept_all.items() if k in chosen}
    assert cone == cone_all & chosen
    for dl, size in ((full, inst.size), (part, half.size)):
        c = dl.counts
        assert c["clusters_total"] == size == (c["clusters_frustum_culled"]
                                               + c["clusters_cone_culled"]
                                               + c["clusters_drawn"]) and len(dl) == \
            c["clusters_drawn"], c
        assert c["triangles_total"] == (c["triangles_frustum_culled"]
                                        + c["triangles_cone_culled"] + c["triangles_drawn"])
    ref = vc.all()
    st = vc.inst_state
    for (i, c), ins in kept_all.items():
        assert st[i] != 2, (i, c)   # OUTSIDE instances keep nothing
        if st[i] == 0:              # INSIDE instances: every pair kept, inside
            assert ins
    assert {(int(a), int(b)) for a, b in zip(ref.instance, ref.cluster, strict=True)
            if st[a] == 0} <= set(kept_all) | cone_all
