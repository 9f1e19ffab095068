"""Two-phase occlusion culling in `Renderer.render(..., occlusion=True)`.

Occlusion culling must be conservative: the frame is the same as without it — triangle ids
and depth bit for bit, barycentrics within 1e-6 — whatever the renderer saw before. Checked
on

* random scenes (`random_scene`, several seeds, with and without mirroring transforms and
  with their degenerate instances), big enough ones for the first frame to draw only the
  nearest clusters and test the rest, and a dense instance grid, seen by single random
  cameras and along camera paths (one renderer for the whole path, so phase 1 of every
  frame is the previous frame's visible set), perspective and orthographic, cull "back" and
  "none";
* the power plant (`plant(20_000)`): the corridor and the overview camera, single frames
  and walks / orbits;
* hand-built pop-in cases: a box behind a wall that the camera uncovers by moving sideways
  (it was occlusion-culled in frame k and must be drawn in phase 2 of frame k+1), and the
  reverse: an occluder that was outside the view (or not yet in the scene) appears;
* exact depth ties across the phases (duplicate geometry uncovered in phase 2 must still
  win by the lower id), the eye inside a closed room, a scene ~3e4 from the world origin,
  sizes 2^k ± 1 down to 1×1 with several tile sizes, occlusion with frustum and/or cone
  culling off;
* switching scenes and targets with one renderer (the history of one scene must not be
  used for another), and frames without occlusion culling in between.

Each frame is compared with a render without occlusion culling by a separate renderer.
Every occlusion frame also checks the partition clusters_drawn = clusters_phase1 +
clusters_phase2 + clusters_occlusion_culled, and that the culling before it is unchanged.

Counts: a wall in front of the camera and N boxes (one cluster each) behind it: on the
second frame all N are occlusion-culled. Overdraw: the per-pixel map sums to
fragments_tested, is exactly 3 on three full-screen layers, and with occlusion culling it is
the work that was done (never more than without, at least 1 on covered pixels).

Efficiency (printed with ``-s``): on plant(100_000) seen from the corridor, the share of the
truly invisible clusters of the draw list that a second frame culls
(bench/occlusion_efficiency.py computes and prints the same figure).

A regression test pins a fixed bug: the occlusion state (world boxes of the clusters, last
visible set) must follow the scene object, not its id(), which a new scene can reuse.

The NumPy twin runs the same two-phase schedule (`clraster.twophase`) with its own pyramid and
Hi-Z test: one `clraster.reference.Renderer` fed the same camera path as one OpenCL
`Renderer` gives the same frames (ids and depth exactly) and the same counts, occlusion rows
(clusters/triangles occlusion-culled, phase 1, phase 2) included — on random scenes and
instance grids of real meshes, along paths with camera cuts (the first-frame fallback).
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import (
    MatrixCamera,
    assert_frames_equal,
    assert_same_image,
    get_renderer,
    load_shared_mesh,
    window_mesh,
)

from clraster import Camera, Mesh, RasterConfig, Renderer
from clraster.culling.clusters import clusters_of
from clraster.culling.fates import Fate
from clraster.pipeline import reference as twin
from clraster.world.generators import (
    instance_grid,
    plant,
    plant_inside_camera,
    plant_overview_camera,
    random_scene,
)
from clraster.world.scene import Scene

SIZE = (96, 64)
PLANT_SIZE = (160, 120)

#: Counts fixed before occlusion culling: equal with and without it.
PRE_OCCLUSION = ("instances_total", "instances_frustum_culled", "instances_empty",
                 "clusters_total", "clusters_frustum_culled", "clusters_cone_culled",
                 "clusters_drawn", "triangles_total", "triangles_frustum_culled",
                 "triangles_cone_culled")


# -- helpers ------------------------------------------------------------------------------

def occ_renderer(size=SIZE, tile_log2: int | None = None, hiz: bool = True,
                 groups: int | None = None) -> Renderer:
    """A renderer of its own for occlusion frames (its history is the test's business; the
    programs are cached per context, so this is cheap). tile_log2 None: the default tile
    size. groups: `occlusion_groups` (None: the default, hierarchical; 0: flat two-phase)."""
    kw = {} if groups is None else {"occlusion_groups": groups}
    if tile_log2 is None:
        tile_log2 = RasterConfig().tile_log2
    return Renderer(*size, config=RasterConfig(tile_log2=tile_log2, tile_hiz=hiz, **kw))


def reference(target, camera, size=SIZE, cull="back", overdraw=False, hiz=True, **kw):
    """The frame without occlusion culling (the session's shared renderer, which never
    renders with occlusion)."""
    return get_renderer(*size, hiz=hiz).render(target, camera, cull=cull, overdraw=overdraw,
                                               **kw)


#: Counts equal with and without hierarchical occlusion culling, which decides some
#: clusters by their group (occlusion-culled untested) and tests the others on their own.
PRE_OCCLUSION_GROUPED = ("instances_total", "instances_frustum_culled", "instances_empty",
                         "clusters_total", "triangles_total")


def check_stats(on, off, context: str, flat: bool = False) -> None:
    """The occlusion rows partition the draw list; culling before them is unchanged (flat
    two-phase, ``flat``), or, hierarchically, at least the instance test and the totals."""
    s, o = on.stats, off.stats
    for k in PRE_OCCLUSION if flat else PRE_OCCLUSION_GROUPED:
        assert getattr(s, k) == getattr(o, k), f"{context}: {k} {getattr(s, k)} vs " \
                                               f"{getattr(o, k)}"
    assert s.clusters_total == (s.clusters_frustum_culled + s.clusters_cone_culled
                                + s.clusters_drawn), f"{context}: {s.counts()}"
    assert min(s.clusters_phase1, s.clusters_phase2, s.clusters_occlusion_culled,
               s.triangles_occlusion_culled) >= 0, f"{context}: {s.counts()}"
    assert s.clusters_drawn == (s.clusters_phase1 + s.clusters_phase2
                                + s.clusters_occlusion_culled), f"{context}: {s.counts()}"
    if flat:
        assert s.triangles_in + s.triangles_occlusion_culled == o.triangles_in, \
            f"{context}: {s.triangles_in} + {s.triangles_occlusion_culled} != " \
            f"{o.triangles_in}"
    assert s.triangles_total == (s.triangles_frustum_culled + s.triangles_cone_culled
                                 + s.triangles_occlusion_culled + s.triangles_in), \
        f"{context}: {s.counts()}"
    assert s.triangles_occlusion_culled >= s.clusters_occlusion_culled, s.counts()
    if s.clusters_occlusion_culled == 0:
        assert s.triangles_occlusion_culled == 0, f"{context}: {s.counts()}"
    # without occlusion culling the rows stay zero
    assert (o.clusters_phase1, o.clusters_phase2, o.clusters_occlusion_culled,
            o.triangles_occlusion_culled) == (0, 0, 0, 0), f"{context}: {o.counts()}"


def check_path(target, cameras, *, size=SIZE, cull="back", renderer=None, context="",
               **kw):
    """Render ``cameras`` in order with ONE occlusion renderer; compare every frame with a
    render without occlusion (same other arguments ``kw``). Returns [(on, off), ...]."""
    r = renderer or occ_renderer(size)
    out = []
    for k, cam in enumerate(cameras):
        on = r.render(target, cam, cull=cull, occlusion=True, **kw)
        off = reference(target, cam, size, cull, **kw)
        ctx = f"{context} frame {k}"
        assert_same_image(on, off, ctx)
        check_stats(on, off, ctx, flat=r.config.occlusion_groups == 0)
        out.append((on, off))
    return out


def box_mesh(lo, hi) -> Mesh:
    """Closed box [lo, hi], 12 faces wound counter-clockwise seen from outside."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                  for i in (0, 1) for j in (0, 1) for k in (0, 1)])   # index 4i + 2j + k
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    faces = []
    c = (lo + hi) / 2
    for a, b, cc, d in quads:
        for tri in ((a, b, cc), (a, cc, d)):
            p = v[list(tri)]
            n = np.cross(p[1] - p[0], p[2] - p[0])
            faces.append(tri if n @ (p.mean(0) - c) > 0 else tri[::-1])
    return Mesh(v, np.array(faces))


UNIT_BOX = box_mesh((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))


def placed(centre, size=1.0) -> np.ndarray:
    """Transform: scale the unit box to ``size`` (scalar or 3), move it to ``centre``."""
    m = np.diag([*np.broadcast_to(np.asarray(size, np.float64), (3,)), 1.0])
    m[:3, 3] = centre
    return m


def face_ids_of(scene: Scene, instance: int) -> np.ndarray:
    base = int(scene.face_base[instance])
    return np.arange(base, base + scene.instances[instance].mesh.n_faces)


def shows(frame, scene: Scene, instance: int) -> bool:
    """Whether any face of ``instance`` is visible in ``frame``."""
    return bool(np.isin(frame.triangle_id, face_ids_of(scene, instance)).any())


def random_camera(rng: np.random.Generator, extent: float = 5.0) -> Camera:
    """Outside, at the edge of, or inside the scene, looking somewhere into it."""
    d = rng.normal(size=3)
    eye = d / np.linalg.norm(d) * rng.uniform(0.3, 3.0) * extent
    target = rng.uniform(-0.4, 0.4, 3) * extent
    return Camera.look_at(eye, target, (0.0, 1.0, 0.0), fov_y=float(rng.uniform(30, 100)),
                          near=float(rng.uniform(0.02, 0.5)), far=60.0)


def random_path(rng: np.random.Generator, n: int, extent: float = 5.0) -> list[Camera]:
    """n cameras along a straight line with a turning gaze: moves through the scene."""
    a, b = (rng.uniform(-1.6, 1.6, 3) * extent for _ in range(2))
    ta, tb = (rng.uniform(-0.5, 0.5, 3) * extent for _ in range(2))
    fov = float(rng.uniform(40, 90))
    cams = []
    for t in np.linspace(0.0, 1.0, n):
        eye = a + t * (b - a)
        target = ta + t * (tb - ta)
        if np.linalg.norm(target - eye) < 1e-3:
            target = eye + (1.0, 0.0, 0.0)
        cams.append(Camera.look_at(eye, target, (0.0, 1.0, 0.0), fov_y=fov, near=0.05,
                                   far=60.0))
    return cams


def orbit(centre, eye0, n: int, degrees: float, *, fov_y=45.0, near=0.1, far=100.0):
    """n cameras turning ``eye0`` around the vertical axis through ``centre``."""
    centre, eye0 = np.asarray(centre, float), np.asarray(eye0, float)
    cams = []
    for a in np.radians(np.linspace(0.0, degrees, n)):
        c, s = math.cos(a), math.sin(a)
        d = eye0 - centre
        eye = centre + [c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]]
        cams.append(Camera.look_at(eye, centre, (0.0, 1.0, 0.0), fov_y=fov_y, near=near,
                                   far=far))
    return cams


def ortho_camera(eye, target, half_h: float, aspect: float, near: float, far: float):
    """An orthographic camera (fixed aspect) as a MatrixCamera: w = 1 everywhere, so the
    first frame orders clusters along the view direction instead of by distance."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, (0.0, 1.0, 0.0))
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = s, u, -f
    view[:3, 3] = -view[:3, :3] @ eye
    p = np.diag([1.0 / (half_h * aspect), 1.0 / half_h, -2.0 / (far - near), 1.0])
    p[2, 3] = -(far + near) / (far - near)
    return MatrixCamera(p @ view)


# -- 1. conservative: random scenes -------------------------------------------------------

@pytest.mark.parametrize("cull", ["back", "none"])
@pytest.mark.parametrize("mirrors", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_random_scene_single_frames(seed, mirrors, cull):
    """A first frame (no history) and a repeat (phase 1 = the first frame's visible set)
    for several random cameras; a fresh renderer per camera."""
    scene = random_scene(seed, 64, extent=4.0, mirrors=mirrors)
    rng = np.random.default_rng(1000 + seed)
    culled = 0
    for j in range(4):
        cam = random_camera(rng, 4.0)
        frames = check_path(scene, [cam, cam], cull=cull, context=f"seed {seed} camera {j}")
        culled += frames[1][0].stats.clusters_occlusion_culled
    assert culled > 0   # the second frames did cull something


@pytest.mark.parametrize("mirrors", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_flat_schedule_camera_path(seed, mirrors):
    """The flat two-phase schedule (`occlusion_groups=0`) along a camera path: besides the
    images, the culling before occlusion is exactly the frame's without it (every cluster
    that survives the frustum and cone tests is Hi-Z tested, none decided by a group)."""
    scene = random_scene(seed, 96, extent=4.0, mirrors=mirrors)
    rng = np.random.default_rng(2500 + seed)
    frames = check_path(scene, random_path(rng, 6, 4.0), renderer=occ_renderer(groups=0),
                        context=f"flat seed {seed} path")
    assert sum(on.stats.clusters_occlusion_culled for on, _ in frames) > 0


@pytest.mark.parametrize("cull", ["back", "none"])
@pytest.mark.parametrize("mirrors", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_random_scene_camera_path(seed, mirrors, cull):
    """8 cameras flying through the scene, one renderer: every frame but the first draws
    last frame's visible set first and tests the rest against its pyramid."""
    scene = random_scene(seed, 96, extent=4.0, mirrors=mirrors)
    rng = np.random.default_rng(2000 + seed)
    frames = check_path(scene, random_path(rng, 8, 4.0), cull=cull,
                        context=f"seed {seed} path")
    assert sum(f.stats.clusters_occlusion_culled for f, _ in frames) > 0
    if seed == 0 and not mirrors:
        rows = [(f.stats.clusters_phase1, f.stats.clusters_phase2,
                 f.stats.clusters_occlusion_culled) for f, _ in frames]
        print(f"\npath seed 0 ({cull}): (phase 1, phase 2, occlusion culled) per frame {rows}")


@pytest.mark.parametrize("seed", range(3))
def test_random_scene_orthographic_path(seed):
    scene = random_scene(seed, 32)
    eyes = [(-12.0 + 3 * k, 4.0, 12.0) for k in range(7)]
    cams = [ortho_camera(e, (0.0, 0.0, 0.0), 6.0, SIZE[0] / SIZE[1], 0.5, 40.0)
            for e in eyes]
    check_path(scene, cams, context=f"ortho seed {seed}")


@pytest.mark.parametrize("cull", ["back", "none"])
@pytest.mark.parametrize("seed", range(3))
def test_big_random_scene_first_frame_draws_nearest(seed, cull):
    """More clusters than the first-frame budget (256): phase 1 draws the nearest ones,
    the rest go through the Hi-Z test on the very first frame."""
    scene = random_scene(seed, 400, extent=7.0, mirrors=True)
    rng = np.random.default_rng(3000 + seed)
    cams = [Camera.look_at((0.0, 1.0, 24.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=80.0),
            random_camera(rng, 7.0)]
    for j, cam in enumerate(cams):
        (f1, off), _ = check_path(scene, [cam, cam], cull=cull,
                                  context=f"seed {seed} camera {j}")
        s = f1.stats
        if j == 0:   # the outside view really exceeds the budget
            assert s.clusters_drawn > 256, s.counts()
        if s.clusters_drawn > 256:
            assert 256 <= s.clusters_phase1 < s.clusters_drawn, s.counts()


@pytest.mark.parametrize("cull", ["back", "none"])
def test_instance_grid_of_boxes(cull):
    """576 boxes, each its own instance and cluster, seen from the grid's edge at a low
    angle (heavy mutual occlusion), then walking into the grid."""
    scene = instance_grid(UNIT_BOX, 12, 4, 12, spacing=1.7)
    cams = [Camera.look_at((-14.0 + 2.0 * k, 1.5, 14.0 - 2.5 * k), (2.0, 0.0, -2.0),
                           fov_y=60.0, near=0.05, far=80.0) for k in range(7)]
    frames = check_path(scene, cams, cull=cull, context=f"grid {cull}")
    assert frames[0][0].stats.clusters_phase1 < frames[0][0].stats.clusters_drawn
    assert sum(f.stats.clusters_occlusion_culled for f, _ in frames) > 0


@pytest.mark.parametrize("frustum,cones", [(False, False), (True, False), (False, True)])
def test_occlusion_without_frustum_or_cone_culling(frustum, cones):
    """Occlusion culling alone (every cluster reaches the Hi-Z test; those outside the view
    come back VIEW_CULLED and are skipped too) or with only one of the other two."""
    scene = random_scene(4, 96, extent=4.0, mirrors=True)
    rng = np.random.default_rng(4)
    frames = check_path(scene, random_path(rng, 7, 4.0), frustum=frustum, cones=cones,
                        context=f"frustum={frustum} cones={cones}")
    if not frustum:
        # with the frustum test off nothing counts as frustum-culled, hierarchically
        # either (a group the Hi-Z test finds outside the view is occlusion-culled)
        assert all(off.stats.clusters_frustum_culled == 0
                   and on.stats.clusters_frustum_culled == 0 for on, off in frames)
    assert sum(f.stats.clusters_occlusion_culled for f, _ in frames) > 0


@pytest.mark.parametrize("groups", [0, 16])
def test_a_frame_with_nothing_in_view_keeps_the_history(groups):
    """Looking away for one frame (nothing in view) and back: the frame after draws last
    visible set in phase 1 (not a first frame's nearest-clusters budget) and nothing in
    phase 2, as before looking away."""
    rng = np.random.default_rng(7)
    scene = Scene([(box_mesh((-3, -3, 7.9), (3, 3, 8.0)), None)])   # a wall, boxes behind
    for _ in range(12):
        scene.add(UNIT_BOX, placed(rng.uniform((-3, -3, -3), (3, 3, 5)),
                                   rng.uniform(0.2, 1.0, 3)))
    cam = Camera.look_at((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
    away = Camera.look_at((0.0, 0.0, 10.0), (0.0, 0.0, 20.0), fov_y=60.0, near=0.1,
                          far=50.0)   # turned round: nothing in view
    r = occ_renderer(groups=groups)
    (_, _), (f2, _), (f_away, off_away), (f3, _) = check_path(
        scene, [cam, cam, away, cam], renderer=r, context=f"groups {groups}")
    assert off_away.stats.clusters_drawn == 0 and f_away.stats.clusters_phase1 == 0
    assert (f2.stats.clusters_phase1, f2.stats.clusters_occlusion_culled) == (1, 12)
    assert (f3.stats.clusters_phase1, f3.stats.clusters_phase2,
            f3.stats.clusters_occlusion_culled) == (1, 0, 12), f3.stats.counts()


# -- 1. conservative: the plant -----------------------------------------------------------

@pytest.fixture(scope="module")
def plant20k():
    return plant(20_000)


def corridor_walk(scene, size, n: int = 8, storey: int = 0) -> list[Camera]:
    """Down the corridor, 1.5 m a frame, glancing left and right into the rooms."""
    cam0 = plant_inside_camera(scene, *size, storey=storey)
    yaws = [0, 0, 25, 50, 0, -35, -70, 10, 0, 0][:n]
    cams = []
    for k, yaw in enumerate(yaws):
        eye = cam0.eye + (1.5 * k, 0.0, 0.0)
        d = np.array([math.cos(math.radians(yaw)), 0.0, math.sin(math.radians(yaw))])
        cams.append(Camera.look_at(eye, eye + d, fov_y=cam0.fov_y, near=cam0.near,
                                   far=cam0.far))
    return cams


def overview_orbit(scene, size, n: int = 7) -> list[Camera]:
    cam0 = plant_overview_camera(scene, *size)
    lo, hi = scene.bounds()
    return orbit((np.asarray(lo) + hi) / 2, cam0.eye, n, 75.0, fov_y=cam0.fov_y,
                 near=cam0.near, far=cam0.far)


@pytest.mark.parametrize("cull", ["back", "none"])
@pytest.mark.parametrize("view", ["inside", "overview"])
def test_plant_single_frame(plant20k, view, cull):
    make = plant_inside_camera if view == "inside" else plant_overview_camera
    cam = make(plant20k, *PLANT_SIZE)
    frames = check_path(plant20k, [cam, cam, cam], size=PLANT_SIZE, cull=cull,
                        context=f"plant {view}")
    if view == "inside":   # most of the building is behind the corridor walls
        assert frames[1][0].stats.clusters_occlusion_culled > 0


@pytest.mark.parametrize("cull", ["back", "none"])
def test_plant_corridor_walk(plant20k, cull):
    frames = check_path(plant20k, corridor_walk(plant20k, PLANT_SIZE), size=PLANT_SIZE,
                        cull=cull, context="plant walk")
    assert sum(f.stats.clusters_phase2 for f, _ in frames[1:]) > 0   # things came into view


def test_plant_overview_orbit(plant20k):
    check_path(plant20k, overview_orbit(plant20k, PLANT_SIZE), size=PLANT_SIZE,
               context="plant orbit")


def test_plant_switch_views(plant20k):
    """Alternate between the corridor and the overview with one renderer: each frame's
    phase 1 is the other view's visible set."""
    a = plant_inside_camera(plant20k, *PLANT_SIZE)
    b = plant_overview_camera(plant20k, *PLANT_SIZE)
    c = corridor_walk(plant20k, PLANT_SIZE)[6]
    check_path(plant20k, [a, b, a, c, b, c, a], size=PLANT_SIZE, context="plant switch")


@pytest.mark.slow
@pytest.mark.parametrize("cull", ["back", "none"])
def test_plant_100k_paths(cull):
    scene = plant(100_000)
    size = (320, 240)
    check_path(scene, corridor_walk(scene, size, 10), size=size, cull=cull,
               context="plant 100K walk")
    check_path(scene, corridor_walk(scene, size, 8, storey=1), size=size, cull=cull,
               context="plant 100K walk, storey 1")
    check_path(scene, overview_orbit(scene, size, 8), size=size, cull=cull,
               context="plant 100K orbit")


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(6, 30))
def test_random_scene_camera_path_more_seeds(seed):
    scene = random_scene(seed, 64, mirrors=seed % 2 == 1)
    rng = np.random.default_rng(4000 + seed)
    for cull in ("back", "none"):
        check_path(scene, random_path(rng, 10), cull=cull, context=f"seed {seed} {cull}")


# -- 1. pop-in and occluders that appear -------------------------------------------------

def wall_and_box_scene():
    """Instance 0: a 4 × 4 wall (a thin box) at z ∈ [−0.1, 0]; instance 1: a 0.5 box
    centred at (0, 0, −3) behind it."""
    return Scene([(box_mesh((-2, -2, -0.1), (2, 2, 0)), None),
                  (UNIT_BOX, placed((0.0, 0.0, -3.0), 0.5))])


@pytest.mark.parametrize("cull", ["back", "none"])
def test_pop_in_when_camera_moves_sideways(cull):
    """Hidden behind the wall while the camera is in front of it (occlusion-culled from the
    second frame on), uncovered as the camera slides sideways: the frame in which it
    appears must draw it in phase 2."""
    scene = wall_and_box_scene()
    xs = [0.0, 0.0, 2.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0]
    cams = [Camera.look_at((x, 0.0, 6.0), (0.0, 0.0, -3.0), fov_y=60.0, near=0.1, far=50.0)
            for x in xs]
    frames = check_path(scene, cams, cull=cull, context="pop-in")
    seen = [shows(off, scene, 1) for _, off in frames]
    assert not seen[0] and seen[-1], seen                  # the set-up does what it says
    k = seen.index(True)
    on_prev, on_new = frames[k - 1][0], frames[k][0]
    assert on_prev.stats.clusters_occlusion_culled >= 1, on_prev.stats.counts()
    assert on_new.stats.clusters_phase2 >= 1, on_new.stats.counts()
    assert shows(on_new, scene, 1)
    # and back: it disappears again, and is culled again after one frame
    back = check_path(scene, [cams[-1], cams[0], cams[0]], cull=cull, context="pop-out")
    assert back[2][0].stats.clusters_occlusion_culled >= 1


def test_pop_in_single_jump():
    """The whole sideways move in one frame."""
    scene = wall_and_box_scene()
    a = Camera.look_at((0.0, 0.0, 6.0), (0.0, 0.0, -3.0), fov_y=60.0, near=0.1, far=50.0)
    b = Camera.look_at((9.0, 0.0, 6.0), (0.0, 0.0, -3.0), fov_y=60.0, near=0.1, far=50.0)
    frames = check_path(scene, [a, a, b], context="jump")
    assert frames[1][0].stats.clusters_occlusion_culled == 1
    assert shows(frames[2][1], scene, 1) and frames[2][0].stats.clusters_phase2 == 1


@pytest.mark.parametrize("cull", ["back", "none"])
def test_occluder_appears_from_the_side(cull):
    """The box is visible and the wall outside the view; the camera slides sideways (looking
    straight ahead) until the wall, never drawn before, hides the box."""
    scene = Scene([(UNIT_BOX, placed((4.0, 0.0, 0.0), 0.8)),
                   (box_mesh((2.0, -2.0, 5.9), (6.0, 2.0, 6.0)), None)])
    cams = [Camera.look_at((x, 0.0, 8.0), (x, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
            for x in (0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 4.0)]
    frames = check_path(scene, cams, cull=cull, context="occluder from the side")
    first = frames[0][1].stats
    assert first.clusters_frustum_culled == 1, first.counts()   # the wall is out of view
    seen = [shows(off, scene, 0) for _, off in frames]
    assert seen[0] and not seen[-1], seen
    assert frames[-1][0].stats.clusters_occlusion_culled == 1   # steady again: box culled


def test_occluder_appears_behind_the_camera_moving_back():
    """The camera backs out through a wall: in frame k the wall is behind the eye (frustum
    culled), in frame k+1 it is between the eye and the box."""
    scene = Scene([(UNIT_BOX, placed((0.0, 0.0, 0.0), 0.8)),
                   (box_mesh((-2.0, -2.0, 3.9), (2.0, 2.0, 4.0)), None)])
    cams = [Camera.look_at((0.0, 0.0, z), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
            for z in (2.0, 2.5, 3.5, 5.0, 6.0, 6.0)]
    frames = check_path(scene, cams, context="backing out")
    seen = [shows(off, scene, 0) for _, off in frames]
    assert seen[:3] == [True] * 3 and not any(seen[3:]), seen
    assert frames[-1][0].stats.clusters_occlusion_culled == 1


def test_occluder_added_to_scene():
    """Scene.add (a new version) between frames: an occluder appears in front of the box
    that was visible; then a box appears behind it."""
    scene = Scene([(UNIT_BOX, placed((0.0, 0.0, -2.0), 1.0))])
    cam = Camera.look_at((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
    r = occ_renderer()
    check_path(scene, [cam, cam], renderer=r, context="before")
    scene.add(box_mesh((-3, -3, 1.9), (3, 3, 2.0)))
    frames = check_path(scene, [cam, cam], renderer=r, context="occluder added")
    assert not shows(frames[0][1], scene, 0)
    assert frames[1][0].stats.clusters_occlusion_culled == 1
    scene.add(UNIT_BOX, placed((1.0, 0.0, -4.0), 1.0))
    frames = check_path(scene, [cam, cam], renderer=r, context="hidden box added")
    assert frames[1][0].stats.clusters_occlusion_culled == 2


def quads_mesh(rects, z: float = 0.0) -> Mesh:
    """Axis-aligned rectangles (x0, x1, y0, y1) in the plane z, facing +z, 2 faces each."""
    v, f = [], []
    for x0, x1, y0, y1 in rects:
        o = len(v)
        v += [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
        f += [(o, o + 1, o + 2), (o, o + 2, o + 3)]
    return Mesh(np.array(v, np.float64), np.array(f))


def test_duplicate_geometry_uncovered_in_phase_2_still_wins_ties():
    """Exact depth ties across the two phases. X (instance 0) is a small quad; Y (instance
    1) has the very same quad plus one far to the right; Z is a slab in front of X. While
    X is hidden it is not in the visible set; when the camera uncovers it, Y (visible all
    along) is drawn in phase 1 and X in phase 2 at exactly Y's depth. Without occlusion
    culling the lower triangle id (X's) wins the tie; it must win it in phase 2 too."""
    x = quads_mesh([(-0.4, 0.0, -0.2, 0.2)])
    y = quads_mesh([(-0.4, 0.0, -0.2, 0.2), (3.0, 5.0, -1.0, 1.0)])
    scene = Scene([(x, None), (y, None), (box_mesh((-4, -4, 1.0), (1.0, 4, 1.1)), None)])
    cams = [Camera.look_at((ex, 0.0, 6.0), (-0.2, 0.0, 0.0), fov_y=60.0, near=0.1,
                           far=50.0) for ex in (0.0, 0.0, 2.0, 4.0, 6.0, 8.0, 10.0)]
    frames = check_path(scene, cams, context="tie")
    seen = [shows(off, scene, 0) for _, off in frames]
    assert not seen[1] and True in seen, seen
    k = seen.index(True)
    assert frames[k - 1][0].stats.clusters_occlusion_culled == 1
    assert frames[k][0].stats.clusters_phase2 == 1
    # X's faces 0, 1 win where the duplicate (Y's faces 0, 1 = ids 2, 3) lies at equal depth
    assert not np.isin(frames[k][0].triangle_id, [2, 3]).any()


def test_camera_inside_a_closed_room():
    """The eye inside a closed box (the room's cluster box contains the eye: never
    occluded) with cull "none": from the second frame on, everything outside the room is
    occlusion-culled (but for what the conservative test cannot prove hidden), the room
    and the objects inside it are kept."""
    room = box_mesh((-4, -3, -4), (4, 3, 4))
    scene = Scene([(room, None)])
    for c in [(-2.0, 0.0, -2.0), (2.0, -1.0, -3.0)]:
        scene.add(UNIT_BOX, placed(c, 0.8))                 # inside
    for c in [(0.0, 0.0, -8.0), (6.0, 0.0, 0.0), (0.0, 5.0, -1.0), (-9.0, 1.0, 3.0)]:
        scene.add(UNIT_BOX, placed(c, 1.5))                 # outside
    cams = [Camera.look_at((0.0, 0.0, 2.0), (0.3 * k - 0.6, 0.1, -1.0), fov_y=90.0,
                           near=0.05, far=50.0) for k in range(5)]
    frames = check_path(scene, cams, cull="none", context="room")
    for on, off in frames[1:]:
        s = on.stats
        assert not any(shows(off, scene, i) for i in range(3, 7))
        assert 1 <= s.clusters_occlusion_culled <= s.clusters_drawn - 1, s.counts()
        # what is culled is outside: the room's 12 and the inside boxes' faces are drawn
        inside_drawn = sum(shows(off, scene, i) for i in (1, 2))
        assert s.triangles_in >= 12 * (1 + inside_drawn)


def offset_scene(scene: Scene, offset) -> Scene:
    t = np.eye(4)
    t[:3, 3] = offset
    return Scene([(i.mesh, t @ i.transform) for i in scene.instances])


@pytest.mark.parametrize("seed", range(3))
def test_far_from_the_world_origin(seed):
    """Scene and cameras shifted by ~3e4: float32 rounding of the cluster boxes and of the
    transformed vertices is ~1e-3 there; the Hi-Z test must still never cull a winner."""
    off = np.array([3.1e4, -1.7e3, -2.3e4])
    scene = offset_scene(random_scene(seed, 96, extent=4.0, mirrors=True), off)
    rng = np.random.default_rng(6000 + seed)
    cams = []
    for c in random_path(rng, 7, 4.0):
        eye = c.eye + off
        fwd = -c.view[2, :3]
        cams.append(Camera.look_at(eye, eye + fwd, fov_y=c.fov_y, near=c.near, far=c.far))
    frames = check_path(scene, cams, context=f"far seed {seed}")
    assert sum(f.stats.clusters_occlusion_culled for f, _ in frames) > 0


@pytest.mark.parametrize("size,tile_log2", [((65, 33), 3), ((31, 65), 5), ((17, 63), 4),
                                            ((129, 1), 4), ((1, 1), 3)])
def test_odd_sizes_and_tiles(size, tile_log2):
    """Image sizes 2^k ± 1 (pyramid levels with clamped last rows/columns), a 1-pixel-high
    image and a single pixel, with several tile sizes."""
    scene = random_scene(11, 96, extent=4.0, mirrors=True)
    rng = np.random.default_rng(7000)
    check_path(scene, random_path(rng, 7, 4.0), size=size,
               renderer=occ_renderer(size, tile_log2), context=f"{size}")


# -- 1. switching scenes and targets ------------------------------------------------------

WALL = box_mesh((-3, -3, -0.1), (3, 3, 0))


def wall_items(box_z: float, n_boxes: int = 4) -> list:
    """(mesh, transform) pairs: a wall at z ∈ [−0.1, 0] and n boxes at depth box_z (behind
    it if < 0, in front of it if > 0)."""
    return [(WALL, None)] + [(UNIT_BOX, placed((-1.5 + i, 0.3 * i - 0.5, box_z), 0.6))
                             for i in range(n_boxes)]


def wall_scene(box_z: float, n_boxes: int = 4) -> Scene:
    """Scenes with the same instance count (hence version) but different boxes."""
    return Scene(wall_items(box_z, n_boxes))


WALL_CAM = Camera.look_at((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)


def test_switching_scenes_does_not_leak_history():
    """Scene A (boxes behind the wall: culled from frame 2) and B (same instance count and
    version, boxes in front of the wall) alternate with one renderer; A's boxes or visible
    set applied to B would cull B's visible boxes. Both scenes stay alive (so they cannot
    share an id: see the xfail below)."""
    a, b = wall_scene(-3.0), wall_scene(2.0)
    assert a.version == b.version
    r = occ_renderer()
    fa = check_path(a, [WALL_CAM, WALL_CAM], renderer=r, context="A")
    assert fa[1][0].stats.clusters_occlusion_culled == 4
    for rep in range(2):
        fb = check_path(b, [WALL_CAM, WALL_CAM], renderer=r, context=f"B {rep}")
        assert all(shows(fb[0][1], b, i) for i in range(1, 5))
        assert fb[0][0].stats.clusters_occlusion_culled == 0
        check_path(a, [WALL_CAM, WALL_CAM], renderer=r, context=f"A again {rep}")


def test_switching_mesh_targets_and_scenes():
    """Bare meshes (wrapped in a one-instance scene by the renderer), a scene, and the same
    meshes again, interleaved with one renderer, every frame with occlusion culling."""
    a, b = wall_scene(-3.0), wall_scene(2.0)
    grid = random_scene(5, 40)
    mesh_a = grid.instances[0].mesh
    mesh_b = grid.instances[1].mesh
    cam = Camera.look_at((0.0, 0.5, 3.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.05, far=50.0)
    r = occ_renderer()
    seq = [(a, WALL_CAM), (mesh_a, cam), (b, WALL_CAM), (mesh_a, cam), (mesh_b, cam),
           (grid, WALL_CAM), (a, WALL_CAM), (grid, cam), (b, WALL_CAM)]
    for k, (target, c) in enumerate(seq):
        check_path(target, [c, c], renderer=r, context=f"step {k}")


def test_occlusion_off_frames_in_between():
    """Frames without occlusion culling on the same renderer neither use nor break the
    history: the next occlusion frame is still correct."""
    a = wall_scene(-3.0)
    r = occ_renderer()
    check_path(a, [WALL_CAM, WALL_CAM], renderer=r)
    side = Camera.look_at((9.0, 0.0, 6.0), (0.0, 0.0, -3.0), fov_y=60.0, near=0.1, far=50.0)
    plain = r.render(a, side)
    assert plain.stats.clusters_phase1 == plain.stats.clusters_occlusion_culled == 0
    assert_same_image(plain, reference(a, side), "occlusion off")
    check_path(a, [side, WALL_CAM, side], renderer=r, context="after an off frame")


# Was a bug: the occlusion state was keyed by (id(scene), version) with no reference to the
# scene, so a new scene at a freed one's address inherited its boxes and history. The
# renderer now keeps the scene and compares it with `is`.
def test_freed_scene_id_reuse_does_not_leak_history():
    """Exact repro: render A = Scene(wall + 4 boxes behind it) with occlusion; render
    another scene without occlusion (the renderer's plan cache lets A go); ``del a``;
    immediately build B = Scene(wall + 4 boxes in front of the wall) (same version 5) —
    CPython usually gives it A's address (retried until it does) — and render B with
    occlusion. Expected: B's image = B without occlusion culling; actual: B's 4 boxes are
    occlusion-culled and missing from the image."""
    r = occ_renderer()
    other = wall_scene(-3.0, 2)
    items_a, items_b = wall_items(-3.0), wall_items(2.0)
    for _ in range(40):
        a = Scene(items_a)
        r.render(a, WALL_CAM, occlusion=True)
        r.render(other, WALL_CAM)        # the renderer drops its reference to A
        ida = id(a)
        del a
        b = Scene(items_b)               # allocated first thing after A is freed
        if id(b) == ida:
            break
    else:
        pytest.skip("could not make CPython reuse the freed scene's address")
    on = r.render(b, WALL_CAM, occlusion=True)
    off = reference(b, WALL_CAM)
    assert all(shows(off, b, i) for i in range(1, 5))
    assert_same_image(on, off, "new scene at a freed scene's address")


# -- 2. counts ----------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 10, 40])
def test_boxes_behind_a_wall_are_all_culled(n):
    """A wall filling the view 2 m from the eye and n boxes (instances of one 12-face box
    mesh: one cluster each) behind it. First frame: everything is within the first-frame
    budget, drawn in phase 1. Second frame: the wall (the visible set) in phase 1, all n
    boxes occlusion-culled, only the wall's front face rasterized."""
    rng = np.random.default_rng(n)
    w, h = SIZE
    scene = Scene([(box_mesh((-3, -3, 7.9), (3, 3, 8.0)), None)])
    for _ in range(n):
        scene.add(UNIT_BOX, placed(rng.uniform((-3, -3, -3), (3, 3, 5)),
                                   rng.uniform(0.2, 1.0, 3)))
    cam = Camera.look_at((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
    (f1, off), (f2, _), (f3, _) = check_path(scene, [cam, cam, cam], context=f"{n} boxes")
    assert off.stats.clusters_drawn == n + 1
    assert off.visible_faces().max() < 12                     # only the wall is seen
    assert (f1.stats.clusters_phase1, f1.stats.clusters_phase2,
            f1.stats.clusters_occlusion_culled) == (n + 1, 0, 0)
    for f in (f2, f3):
        s = f.stats
        assert s.clusters_occlusion_culled >= n
        assert (s.clusters_phase1, s.clusters_phase2, s.clusters_occlusion_culled,
                s.triangles_occlusion_culled) == (1, 0, n, 12 * n), s.counts()
        assert s.triangles_in == 12
        assert s.fragments_tested == w * h          # one face per pixel, nothing behind


def test_box_in_front_of_the_wall_is_kept():
    """Same, plus one box in front of the wall (and one half outside its shadow at the
    wall's edge): those stay drawn, the hidden ones are culled."""
    scene = Scene([(box_mesh((-2, -2, -0.1), (2, 2, 0.0)), None)])
    hidden = [(-1.0, 0.0, -2.0), (0.5, 0.5, -3.0), (0.0, -1.0, -1.0)]
    for c in hidden:
        scene.add(UNIT_BOX, placed(c, 0.5))
    scene.add(UNIT_BOX, placed((0.5, 0.0, 2.0), 0.5))       # in front
    scene.add(UNIT_BOX, placed((2.0, 0.0, -1.0), 0.8))      # peeks out at the right edge
    cam = Camera.look_at((0.0, 0.0, 6.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
    (_, off), (f2, _) = check_path(scene, [cam, cam], context="mixed")
    assert shows(off, scene, 4) and shows(off, scene, 5)
    assert not any(shows(off, scene, i) for i in (1, 2, 3))
    s = f2.stats
    assert (s.clusters_phase1, s.clusters_phase2, s.clusters_occlusion_culled,
            s.triangles_occlusion_culled) == (3, 0, 3, 36), s.counts()


def merged_boxes(centres, size: float) -> Mesh:
    """One mesh of boxes of edge ``size`` at ``centres`` (12 faces each, in order)."""
    vs, fs = [], []
    for k, c in enumerate(centres):
        b = box_mesh(np.asarray(c) - size / 2, np.asarray(c) + size / 2)
        vs.append(b.vertices)
        fs.append(b.faces + 8 * k)
    return Mesh(np.concatenate(vs), np.concatenate(fs))


@pytest.mark.parametrize("seed", range(3))
def test_grouped_fates_match_the_counts(seed):
    """Hierarchical frames along a camera path with fates: every cluster's fate agrees with
    the counts (drawn = phase 1 + phase 2, frustum-culled — instances, clusters tested
    alone and groups wholly outside a plane —, cone-culled, occlusion-culled — hidden
    groups untested and clusters hidden alone), and the images are the frames without
    occlusion culling."""
    scene = random_scene(seed, 96, extent=4.0)
    rng = np.random.default_rng(3000 + seed)
    r = occ_renderer(groups=4)
    for k, cam in enumerate(random_path(rng, 6, 4.0)):
        f = r.render(scene, cam, occlusion=True, fates=True)
        assert_same_image(f, reference(scene, cam), f"seed {seed} frame {k}")
        s, fc = f.stats, f.fates.counts()
        assert (fc[Fate.DRAWN], fc[Fate.FRUSTUM_CULLED], fc[Fate.BACKFACE_CULLED],
                fc[Fate.OCCLUSION_CULLED]) == (
            s.clusters_phase1 + s.clusters_phase2, s.clusters_frustum_culled,
            s.clusters_cone_culled, s.clusters_occlusion_culled), (k, fc, s.counts())


def recording_hiz(r: Renderer) -> list[int]:
    """Boxes each Hi-Z test of ``r`` gets, appended per call (wraps its `_hiz`)."""
    sizes: list[int] = []
    inner = r._hiz

    def hiz(out, rows, vp32, zoff=0.5, same_depth=False):
        sizes.append(int(rows.shape[1]))
        return inner(out, rows, vp32, zoff=zoff, same_depth=same_depth)

    r._hiz = hiz
    return sizes


@pytest.mark.parametrize("groups", [8, 32])
def test_hidden_groups_are_culled_without_their_clusters_tests(groups):
    """A wall and, behind it, one mesh of 900 small boxes (~85 clusters of at most 128
    faces). Second frame, hierarchical: the big mesh's groups are Hi-Z tested and found
    hidden, so its clusters are occlusion-culled without being tested one by one — the Hi-Z
    tests of the frame get about clusters / groups boxes plus the wall's, where the flat
    schedule tests every cluster — and the counts and fates say so. Images as without
    occlusion culling (check_path)."""
    g = np.stack(np.meshgrid(np.arange(30), np.arange(30), indexing="ij"), -1).reshape(-1, 2)
    centres = np.column_stack([g * 0.2 - 2.9, np.full(len(g), -2.0)])
    big = merged_boxes(centres, 0.1)
    scene = Scene([(box_mesh((-10, -10, -0.1), (10, 10, 0.0)), None), (big, None)])
    n_big = clusters_of(big).n_clusters
    cam = Camera.look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), fov_y=60.0, near=0.1, far=50.0)
    flat, grouped = occ_renderer(groups=0), occ_renderer(groups=groups)
    tested = {}
    frames = {}
    for name, r in (("flat", flat), ("grouped", grouped)):
        check_path(scene, [cam], renderer=r, context=name)
        sizes = recording_hiz(r)
        (on, off), = check_path(scene, [cam], renderer=r, context=name)
        tested[name] = sum(sizes)
        frames[name] = r.render(scene, cam, occlusion=True, fates=True)
        assert_same_image(frames[name], off, name)
    assert n_big > 2 * groups
    for name, f in frames.items():
        s = f.stats
        assert (s.clusters_phase1, s.clusters_phase2, s.clusters_occlusion_culled) \
            == (1, 0, n_big), (name, s.counts())
        fc = f.fates.counts()
        assert fc[Fate.OCCLUSION_CULLED] == n_big and fc[Fate.DRAWN] == 1, (name, fc)
        assert fc[Fate.FRUSTUM_CULLED] == s.clusters_frustum_culled == 0, (name, fc)
    # flat: every big-mesh cluster (padded to 8) and the wall twice; grouped: its groups
    n_groups = -(-n_big // groups)
    assert tested["flat"] >= n_big, tested
    assert tested["grouped"] <= 3 * 8 + -(-n_groups // 8) * 8, (tested, n_groups)


# -- 3. overdraw --------------------------------------------------------------------------

def test_overdraw_three_full_screen_layers():
    """Three full-screen quads (two triangles each, the shared diagonal drawn once by the
    fill rule) at NDC depths −0.5, 0, 0.5: exactly 3 fragments per pixel. With occlusion
    culling (an orthographic view: the first frame orders clusters along the view
    direction), the second frame draws only the front layer: 1 per pixel."""
    w, h = SIZE
    quad = [[(0, 0), (w, h), (w, 0)], [(0, 0), (0, h), (w, h)]]
    scene = Scene([(window_mesh(quad, w, h, z), None) for z in (0.5, 0.0, -0.5)])
    cam = MatrixCamera(np.eye(4))
    off = reference(scene, cam, cull="none", overdraw=True)
    assert off.overdraw.shape == (h, w) and off.overdraw.dtype == np.int32
    assert (off.overdraw == 3).all(), np.unique(off.overdraw)
    assert off.stats.fragments_tested == 3 * w * h
    assert np.isin(off.triangle_id, [4, 5]).all()           # the front layer (instance 2)
    r = occ_renderer()
    seen = []
    for k in range(3):
        on = r.render(scene, cam, cull="none", occlusion=True, overdraw=True)
        assert_same_image(on, off, f"layers frame {k}")
        assert int(on.overdraw.sum()) == on.stats.fragments_tested
        seen.append(np.unique(on.overdraw).tolist())
    assert seen == [[3], [1], [1]], seen
    assert r.render(scene, cam, cull="none", occlusion=True).overdraw is None


@pytest.mark.parametrize("seed", range(4))
def test_overdraw_sums_to_fragments_tested(seed):
    """On random scenes and a camera path: sum(overdraw) == fragments_tested without and
    with occlusion culling; with it, per pixel, at most the count without it and at least 1
    wherever a triangle is visible. Those per-pixel bounds compare every covered fragment
    (tile Hi-Z off: with it, the two frames' different draw orders skip different pieces);
    with the tile Hi-Z the occlusion frame tests at most what it tests without."""
    scene = random_scene(seed, 32, mirrors=True)
    rng = np.random.default_rng(5000 + seed)
    r, rh = occ_renderer(hiz=False), occ_renderer()
    for k, cam in enumerate(random_path(rng, 6)):
        off = reference(scene, cam, overdraw=True, hiz=False)
        on = r.render(scene, cam, occlusion=True, overdraw=True)
        onh = rh.render(scene, cam, occlusion=True, overdraw=True)   # same history as r
        ctx = f"seed {seed} frame {k}"
        assert_same_image(on, off, ctx)
        assert_same_image(onh, off, ctx)
        assert off.overdraw.dtype == np.int32 and on.overdraw.shape == SIZE[::-1]
        assert int(off.overdraw.sum()) == off.stats.fragments_tested, ctx
        for fr in (on, onh):
            assert int(fr.overdraw.sum()) == fr.stats.fragments_tested, ctx
            assert (fr.overdraw[fr.mask] >= 1).all(), ctx
            assert (fr.overdraw >= 0).all()
        assert (on.overdraw <= off.overdraw).all(), ctx
        assert (onh.overdraw <= on.overdraw).all(), ctx
    # without overdraw=True there is no map, and asking for it changes nothing else
    plain = reference(scene, cam, hiz=False)
    assert plain.overdraw is None
    assert_same_image(plain, off, "overdraw flag")
    assert plain.stats.counts() == off.stats.counts()


def test_overdraw_on_an_empty_frame():
    scene = Scene([(UNIT_BOX, placed((0.0, 0.0, 50.0)))])     # behind the camera
    on = occ_renderer().render(scene, WALL_CAM, occlusion=True, overdraw=True)
    assert on.overdraw.shape == SIZE[::-1] and not on.overdraw.any()
    assert on.stats.fragments_tested == 0 and not on.mask.any()


# -- 4. efficiency ------------------------------------------------------------------------

def _bench():
    path = Path(__file__).resolve().parents[1] / "bench" / "occlusion_efficiency.py"
    spec = importlib.util.spec_from_file_location("occlusion_efficiency", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_occlusion_efficiency_plant_100k():
    """On plant(100_000) from the corridor (320×240): among the draw list's clusters, the
    truly invisible ones (no triangle id in the frame without occlusion culling), and the
    share of them a second frame culls. The culled set is rebuilt from the algorithm
    (Hi-Z test of each cluster's world box against the final depth, via
    `clraster.occlusion.query`); it must have exactly the renderer's count, lie inside the
    truly invisible set, and the figure must be in [0, 1]."""
    bench = _bench()
    size = (320, 240)
    scene = plant(100_000)
    cam = plant_inside_camera(scene, *size)
    m = bench.measure(scene, cam, *size, renderer=occ_renderer(size, groups=0),
                      reference=get_renderer(*size))
    bench.check(m)
    s = m["sets"]
    # the truly invisible set is computed independently of the renderer's culling
    assert s["invisible"].sum() == m["truly_invisible"] > 0
    assert m["culled_frame2"] <= m["truly_invisible"]
    assert m["phase2_frame2"] == 0                      # same view: nothing new to draw
    assert m["phase1_frame2"] + m["culled_frame2"] == m["draws"]
    # the Hi-Z verdict never culls what the exact box query sees
    assert not (s["culled"] & ~s["box_invisible"]).any()
    print("\nplant(100_000) 320x240, corridor:\n" + bench.report(m))
    assert 0.0 <= m["efficiency"] <= 1.0


# -- 6. the NumPy twin runs the same schedule ---------------------------------------------

def check_twin_path(target, cameras, *, size=SIZE, cull="back", tile_log2: int = 4,
                    context: str = "") -> list:
    """One OpenCL renderer and one twin renderer (`clraster.reference.Renderer`), both with
    occlusion culling, fed ``cameras`` in order: every frame equal (ids and depth exactly,
    barycentrics within 1e-5) with equal counts, occlusion rows included. Returns the
    OpenCL frames."""
    config = RasterConfig(tile_log2=tile_log2)
    r = Renderer(*size, config=config)
    t = twin.Renderer(*size, config=config)
    frames = []
    for k, cam in enumerate(cameras):
        a = r.render(target, cam, cull=cull, occlusion=True)
        b = t.render(target, cam, cull=cull, occlusion=True)
        assert_frames_equal(a, b, f"{context} frame {k} (OpenCL vs twin)")
        frames.append(a)
    return frames


#: x offset of the second site of `two_sites`: far enough that a camera on one site sees
#: nothing of the other (far plane 80).
SITE_DX = 200.0


def two_sites(a: Scene, b: Scene) -> Scene:
    """Scene ``a`` at the origin and scene ``b`` moved by SITE_DX along x."""
    t = np.eye(4)
    t[0, 3] = SITE_DX
    return Scene([(i.mesh, i.transform) for i in a.instances]
                 + [(i.mesh, t @ i.transform) for i in b.instances])


def site_path(n: int, radius: float, site: int) -> list:
    """n cameras orbiting 30 degrees around the centre of site 0 or 1, looking at it."""
    centre = np.array([SITE_DX * site, 0.0, 0.0])
    return orbit(centre, centre + (0.0, 0.3 * radius, radius), n, 30.0, near=0.05,
                 far=6.0 * radius)


@pytest.fixture()
def fallbacks(monkeypatch):
    """Counts the first-frame fallbacks of the two-phase schedule (both renderers): a list
    that grows by one per fallback (a first frame or a camera cut)."""
    import clraster.pipeline.twophase as twophase

    calls: list[int] = []
    real = twophase.eye_position

    def spy(view_proj):
        calls.append(1)
        return real(view_proj)

    monkeypatch.setattr(twophase, "eye_position", spy)
    return calls


@pytest.mark.parametrize("cull", ["back", "none"])
@pytest.mark.parametrize("seed", range(3))
def test_twin_random_scene_path_with_cuts(seed, cull, fallbacks):
    """Two random scenes far apart; the camera path looks at the first, cuts to the second
    (none of last frame's visible clusters is drawn: the nearest-first fallback) and back."""
    # no degenerate instances: a cluster with non-finite vertices is drawn from every
    # viewpoint (it has no box to cull), so it would carry the history across the cut
    scene = two_sites(random_scene(seed, 64, extent=4.0, mirrors=seed == 1, degenerate=False),
                      random_scene(seed + 10, 64, extent=4.0, degenerate=False))
    cams = site_path(3, 12.0, 0) + site_path(2, 12.0, 1) + site_path(2, 12.0, 0)[1:]
    frames = check_twin_path(scene, cams, cull=cull, context=f"seed {seed} {cull}")
    assert len(fallbacks) == 2 * 3   # frame 0 and the two cuts, on both sides
    assert sum(f.stats.clusters_occlusion_culled for f in frames) > 0


def test_twin_big_random_scene_first_frame():
    """More clusters than the first-frame budget: phase 1 is the nearest 256, the rest are
    Hi-Z tested on the first frame — on both sides alike."""
    scene = random_scene(1, 400, extent=7.0, mirrors=True)
    cam = Camera.look_at((0.0, 1.0, 24.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=80.0)
    (f1, _) = check_twin_path(scene, [cam, cam], context="400 instances")
    assert 256 <= f1.stats.clusters_phase1 < f1.stats.clusters_drawn


def test_twin_orthographic_path():
    scene = random_scene(2, 32)
    cams = [ortho_camera((-12.0 + 4 * k, 4.0, 12.0), (0.0, 0.0, 0.0), 6.0, SIZE[0] / SIZE[1],
                         0.5, 40.0) for k in range(4)]
    check_twin_path(scene, cams, context="ortho")


@pytest.mark.parametrize("name", ["spot.ply", "stanford_bunny.ply"])
def test_twin_real_mesh_grids_path_with_cuts(name, fallbacks):
    """Instance grids of a real mesh (copies hide each other) at two sites; an orbit around
    the first, a cut to the second and back; odd size and 8 px tiles."""
    mesh = load_shared_mesh(name)
    lo, hi = mesh.bounds()
    mesh_size = float(np.max(np.asarray(hi) - lo))
    grid = instance_grid(mesh, 4, 1, 4, spacing=1.3)
    # scale the grid to ~6 units across, centred, so both sites share the camera paths
    glo, ghi = grid.bounds()
    s = 6.0 / float(np.max(np.asarray(ghi) - glo))
    t = np.diag([s, s, s, 1.0])
    t[:3, 3] = -s * (np.asarray(glo) + ghi) / 2
    grid = Scene([(i.mesh, t @ i.transform) for i in grid.instances])
    scene = two_sites(grid, grid)
    cams = site_path(3, 9.0, 0) + site_path(2, 9.0, 1) + site_path(2, 9.0, 0)[1:]
    frames = check_twin_path(scene, cams, size=(101, 67), tile_log2=3,
                             context=f"{name} ({mesh_size:.3g} units)")
    assert len(fallbacks) == 2 * 3
    assert sum(f.stats.clusters_occlusion_culled for f in frames) > 0


def test_twin_bare_mesh_target():
    """A bare Mesh target (each renderer makes and keeps a scene for it) over a path: the
    history carries from frame to frame on both sides."""
    mesh = load_shared_mesh("spot.ply")
    lo, hi = mesh.bounds()
    centre = (np.asarray(lo) + hi) / 2
    path = orbit(centre, centre + (0.0, 0.5, 2.5), 4, 90.0, near=0.05, far=20.0)
    frames = check_twin_path(mesh, path, size=(80, 60), context="spot mesh")
    assert all(f.stats.clusters_phase1 > 0 for f in frames)


def test_twin_render_function_is_a_first_frame():
    """`clraster.reference.render(..., occlusion=True)` keeps no history: it equals a fresh
    OpenCL renderer's first occlusion frame, and the same image as without occlusion."""
    scene = random_scene(4, 400, extent=7.0)
    cam = Camera.look_at((0.0, 1.0, 24.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.1, far=80.0)
    a = occ_renderer().render(scene, cam, occlusion=True)
    b = twin.render(scene, cam, *SIZE, occlusion=True)
    assert_frames_equal(a, b, "first frame")
    assert b.stats.clusters_phase1 >= 256
    off = twin.render(scene, cam, *SIZE)
    assert_same_image(b, off, "twin occlusion on vs off")


def test_camera_cut_close_ups_of_one_mesh():
    """The reported crash: the dragon's head in close-up, then its tail — none of the
    clusters visible in the first frame is drawn in the second, and the first phase was
    empty ("AssertionError: a first pass always has triangles", then on every later frame
    of that view, even after a plain frame). Each frame must equal the frame without
    occlusion culling."""
    mesh = load_shared_mesh("stanford_dragon_res2.ply")
    lo, hi = mesh.bounds()
    c = (np.asarray(lo) + hi) / 2
    head = Camera.look_at(c + (-0.09, 0.05, 0.1), c + (-0.09, 0.05, 0.0), fov_y=10.0,
                          near=0.01, far=10.0)
    tail = Camera.look_at(c + (0.09, -0.02, 0.1), c + (0.09, -0.02, 0.0), fov_y=10.0,
                          near=0.01, far=10.0)
    r = Renderer(160, 120)
    for k, cam in enumerate((head, tail, tail, head, tail)):
        if k == 3:
            r.render(mesh, tail)   # a plain frame between two cuts
        on = r.render(mesh, cam, occlusion=True)
        off = r.render(mesh, cam)
        assert on.mask.sum() > 5000
        assert_same_image(on, off, f"frame {k}")


def test_phase_draws_are_the_frame_draws_they_select():
    # FramePlan.draws_of (each occlusion phase's records, laid out without the rest) gives
    # the selected records of FramePlan.frame in the same order, with their vertex and
    # triangle stream places counted from the subset's own cluster sizes, and the same
    # per-instance matrices.
    from clraster.pipeline.drawlist import PlanCache, plan_frame
    from clraster.world.generators import plant_inside_camera

    scene = plant(200_000)
    cam = plant_inside_camera(scene, 320, 240)
    plan = plan_frame(scene, cam, 320, 240, cull="back", frustum=True, cones=True,
                      cache=PlanCache())
    full = plan.frame
    assert full.draws.size == len(plan.draw_list) > 100 and not plan.empty
    mask = np.random.default_rng(5).random(full.draws.size) < 0.3
    part = plan.draws_of(mask)
    want = full.draws[mask]
    sizes = plan.pool.clusters[want["cluster"]].astype(np.int64)   # (n_tris, n_verts) at 1, 3
    for f in ("cluster", "instance", "face_base", "flags"):
        np.testing.assert_array_equal(part.draws[f], want[f])
    np.testing.assert_array_equal(part.draws["tri_base"], np.cumsum(sizes[:, 1]) - sizes[:, 1])
    np.testing.assert_array_equal(part.draws["vert_base"],
                                  np.cumsum(sizes[:, 3]) - sizes[:, 3])
    assert (part.n_tris, part.n_verts) == (sizes[:, 1].sum(), sizes[:, 3].sum())
    for f in ("mvps", "mvps64", "zrows", "uplanes"):
        np.testing.assert_array_equal(getattr(part, f), getattr(full, f))
    assert part.uclip == full.uclip
    assert plan.draws_of(np.zeros(full.draws.size, bool)).n_tris == 0
