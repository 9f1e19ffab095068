"""`clraster demo` and the per-cluster fates behind its culling inspector.

* Fates: one per (instance, cluster) of the scene, counts equal to the culling funnel on
  plant frames (with and without occlusion, first and warm frames); asking for them
  changes nothing else; hand-built scenes where the fate of each instance is known: in
  front (drawn), behind the eye (every cluster frustum-culled), facing away (cone-culled),
  hidden behind a wall (occlusion-culled on the second frame).
* The demo: writes the four images at the requested size; the inspector shows fate colours
  and the frustum lines, and cuts the plant with a horizontal clip plane (instances crossing
  it are cut open: their faces below it drawn, none wholly above); bad arguments exit with
  2 and a message; a triangle count above the cap is refused while the arguments are
  parsed, before the plant is built.
* The picture helpers (`clraster.annotate`): text lands where the layout puts it, in its
  colour, clipped at the edges; colour ramps hit their stops; tick steps are 1, 2, 5 × 10^k.
"""

from __future__ import annotations

import numpy as np
import pytest

from clraster import Camera, Mesh, Renderer
from clraster.culling.clusters import clusters_of
from clraster.culling.fates import ClusterFates, Fate
from clraster.world.generators import plant, plant_inside_camera, plant_overview_camera
from clraster.world.scene import Scene

W, H = 200, 120


@pytest.fixture(scope="module")
def small_plant() -> Scene:
    return plant(20_000)


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(W, H)


def _funnel_matches(frame) -> None:
    st, c = frame.stats, frame.fates.counts()
    assert len(frame.fates) == st.clusters_total
    assert c[Fate.FRUSTUM_CULLED] == st.clusters_frustum_culled
    assert c[Fate.BACKFACE_CULLED] == st.clusters_cone_culled
    assert c[Fate.OCCLUSION_CULLED] == st.clusters_occlusion_culled
    assert c[Fate.DRAWN] == st.clusters_drawn - st.clusters_occlusion_culled
    # triangles too, through the clusters' sizes
    f = frame.fates
    sizes = np.concatenate([clusters_of(i.mesh).n_triangles
                            for i in f.scene.instances]).astype(np.int64)
    tri = np.bincount(f.fate, weights=sizes, minlength=4).astype(np.int64)
    assert tri[Fate.FRUSTUM_CULLED] == st.triangles_frustum_culled
    assert tri[Fate.BACKFACE_CULLED] == st.triangles_cone_culled
    assert tri[Fate.OCCLUSION_CULLED] == st.triangles_occlusion_culled


@pytest.mark.parametrize("occlusion", [False, True])
def test_fate_counts_equal_the_funnel(small_plant, occlusion):
    r = Renderer(W, H)  # fresh: the first occlusion frame has no history
    cams = [plant_inside_camera(small_plant, W, H),
            plant_overview_camera(small_plant, W, H)]
    for cam in cams:
        for _ in range(2):
            fr = r.render(small_plant, cam, occlusion=occlusion, fates=True)
            _funnel_matches(fr)
            f = fr.fates
            assert f.fate.dtype == np.uint8 and f.fate.shape == f.instance.shape
            # keys: instance_key_base[instance] + cluster, every key once
            np.testing.assert_array_equal(f.key(f.instance, f.cluster), np.arange(len(f)))
            # every pixel's cluster was drawn
            fate = f.id_fate(fr.triangle_id)
            assert (fate[fr.mask] == Fate.DRAWN).all() and (fate[~fr.mask] == -1).all()
    if occlusion:
        assert fr.stats.clusters_occlusion_culled > 0


def test_fates_change_nothing_else(small_plant, renderer):
    cam = plant_inside_camera(small_plant, W, H)
    a = renderer.render(small_plant, cam, occlusion=True)
    b = renderer.render(small_plant, cam, occlusion=True, fates=True)
    c = renderer.render(small_plant, cam, occlusion=True)
    assert a.fates is None and c.fates is None and isinstance(b.fates, ClusterFates)
    for x in (a, c):
        np.testing.assert_array_equal(x.triangle_id, b.triangle_id)
        np.testing.assert_array_equal(x.depth, b.depth)
    assert b.stats.counts() == c.stats.counts()


def _boxes(centres, half) -> Mesh:
    """Closed axis-aligned boxes (12 outward, counter-clockwise triangles each) as one mesh."""
    bits = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], np.float64)
    faces = np.array([[0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [0, 1, 5], [0, 5, 4],
                      [2, 6, 7], [2, 7, 3], [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6]])
    c = np.atleast_2d(np.asarray(centres, np.float64))
    h = np.broadcast_to(np.asarray(half, np.float64), c.shape)
    v = (c[:, None, :] - h[:, None, :] + 2 * h[:, None, :] * bits[None]).reshape(-1, 3)
    f = (faces[None] + 8 * np.arange(c.shape[0])[:, None, None]).reshape(-1, 3)
    return Mesh(v, f)


def _translate(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def test_hand_built_fates(renderer):
    """Eye at the origin looking down −z. 0: a box in front (drawn); 1: a row of 40 boxes
    behind the eye (several clusters, all frustum-culled); 2: a quad facing away (its
    normal cone: back-face culled); 3: a wall; 4: a box hidden behind the wall."""
    row = _boxes([[x, 0, 0] for x in np.linspace(-4, 4, 40)], 0.05)
    assert clusters_of(row).n_clusters > 1
    away = Mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 2, 1], [0, 3, 2]])
    scene = Scene([(_boxes([0, 0, 0], 0.5), _translate(-2.0, 0.0, -8.0)),
                   (row, _translate(0.0, 0.0, 6.0)),
                   (away, _translate(2.0, 0.0, -8.0)),
                   (_boxes([0, 0, 0], [30.0, 30.0, 0.1]), _translate(0.0, 0.0, -20.0)),
                   (_boxes([0, 0, 0], 1.0), _translate(0.0, 0.0, -30.0))])
    cam = Camera.look_at((0, 0, 0), (0, 0, -1), (0, 1, 0), fov_y=60.0, near=0.1, far=100.0)
    r = Renderer(W, H, context=renderer.context)
    first = r.render(scene, cam, occlusion=True, fates=True)
    second = r.render(scene, cam, occlusion=True, fates=True)
    for fr in (first, second):
        _funnel_matches(fr)
        f = fr.fates
        by_inst = [f.fate[f.instance == i] for i in range(scene.n_instances)]
        assert (by_inst[0] == Fate.DRAWN).all()
        assert by_inst[1].size > 1 and (by_inst[1] == Fate.FRUSTUM_CULLED).all()
        assert (by_inst[2] == Fate.BACKFACE_CULLED).all()
        assert (by_inst[3] == Fate.DRAWN).all()
        # per face: every face of the row behind the eye, the quad
        assert (f.face_fate(np.full(row.n_faces, 1), np.arange(row.n_faces))
                == Fate.FRUSTUM_CULLED).all()
        assert list(f.face_fate([2, 2], [0, 1])) == [Fate.BACKFACE_CULLED] * 2
    # first frame: no history, the nearest clusters (all of them here) are drawn; the
    # hidden box is found hidden then, so the second frame tests and culls it
    assert (first.fates.fate[first.fates.instance == 4] == Fate.DRAWN).all()
    assert (second.fates.fate[second.fates.instance == 4] == Fate.OCCLUSION_CULLED).all()
    assert second.stats.clusters_occlusion_culled == 1
    # without occlusion the hidden box is drawn
    third = r.render(scene, cam, fates=True)
    assert (third.fates.fate[third.fates.instance == 4] == Fate.DRAWN).all()
    # lookups check their arguments
    with pytest.raises(ValueError, match="face indices"):
        first.fates.face_fate([0], [12])
    with pytest.raises(ValueError, match="instance indices"):
        first.fates.face_fate([5], [0])


def test_fates_when_nothing_is_drawn(renderer):
    scene = Scene([(_boxes([0, 0, 0], 0.5), _translate(0.0, 0.0, 5.0))])
    cam = Camera.look_at((0, 0, 0), (0, 0, -1), (0, 1, 0), fov_y=60.0, near=0.1, far=100.0)
    fr = renderer.render(scene, cam, fates=True)
    assert fr.fates.counts() == {Fate.DRAWN: 0, Fate.FRUSTUM_CULLED: 1,
                                 Fate.BACKFACE_CULLED: 0, Fate.OCCLUSION_CULLED: 0}


# -- the demo --------------------------------------------------------------------------

def test_demo_writes_the_images(tmp_path, capsys):
    pytest.importorskip("clraster.lines")
    import imageio.v3 as iio

    from clraster import demo

    out = tmp_path / "d"
    assert demo.main(["--out", str(out), "--size", f"{W}x{H}", "--triangles", "20000",
                      "--frames", "2"]) == 0
    text = capsys.readouterr().out
    for word in ("frustum culled", "occlusion culled", "frame 2", "cluster fates",
                 "inspector.png", "cut open"):
        assert word in text
    imgs = {}
    for name in ("shaded", "depth", "overdraw", "inspector"):
        imgs[name] = iio.imread(out / f"{name}.png")
        assert imgs[name].shape == (H, W, 3) and imgs[name].dtype == np.uint8
    # depth and overdraw show structure, not a flat fill
    assert len(np.unique(imgs["depth"].reshape(-1, 3), axis=0)) > 40
    assert len(np.unique(imgs["overdraw"].reshape(-1, 3), axis=0)) > 10
    insp = imgs["inspector"].reshape(-1, 3).astype(np.int64)
    # the frustum, drawn in its exact colours
    for col in (demo.FRUSTUM_COLOR, demo.FRUSTUM_HIDDEN_COLOR):
        assert (insp == col).all(axis=1).sum() > 20
    # geometry is lit fate colours: a shade of one fate colour each (hue kept); drawn and
    # occlusion-culled clusters both show from this view
    pal = np.array([demo.FATE_COLORS[f] for f in Fate], np.float64)
    lit = insp[(insp != demo.INSPECTOR_BACKGROUND).any(axis=1)]
    unit = lit / np.maximum(np.linalg.norm(lit, axis=1, keepdims=True), 1)
    pal_unit = pal / np.linalg.norm(pal, axis=1, keepdims=True)
    best = (unit @ pal_unit.T).argmax(axis=1)
    close = (unit @ pal_unit.T).max(axis=1) > 0.999
    seen = np.bincount(best[close], minlength=4)
    assert seen[Fate.DRAWN] > 500 and seen[Fate.OCCLUSION_CULLED] > 50


def test_inspector_picture_colours_by_fate(small_plant, renderer):
    pytest.importorskip("clraster.lines")
    from clraster import demo

    cam = plant_inside_camera(small_plant, W, H)
    fr = renderer.render(small_plant, cam, occlusion=True, fates=True)
    plane = demo.inspector_plane(0.0)
    np.testing.assert_array_equal(plane, [[0.0, -1.0, 0.0, demo.INSPECTOR_CUT]])
    crossing, above = demo.cut_instances(small_plant, plane)
    assert crossing > 0 and above > 0
    icam = demo.inspector_camera(small_plant, 0.0, W, H)
    ifr = renderer.render(small_plant, icam, clip_planes=plane)
    world = demo.world_mesh(small_plant)
    img, per_fate = demo.inspector_picture(
        ifr, fr.fates, world, small_plant, icam.view_projection(W, H),
        cam.view_projection(W, H), W, H, context=renderer.context, note="clip plane")
    assert sum(per_fate.values()) == int(ifr.mask.sum())
    # cut, not dropped: faces crossing the plane are drawn (their lower part), no face
    # wholly above it is
    y = world.vertices[world.faces[np.unique(ifr.triangle_id[ifr.mask])], 1]
    top = demo.INSPECTOR_CUT
    assert (y.min(axis=1) <= top + 1e-4).all()
    assert ((y.min(axis=1) < top) & (y.max(axis=1) > top + 0.05)).sum() > 5
    # a covered pixel away from the legend and the lines: its colour is its fate's, lit
    inst, face = small_plant.split_ids(ifr.triangle_id)
    fate = np.full(inst.shape, -1)
    fate[inst >= 0] = fr.fates.face_fate(inst[inst >= 0], face[inst >= 0])
    ys, xs = np.nonzero(fate >= 0)
    pal = np.array([demo.FATE_COLORS[f] for f in Fate], np.float64)
    checked = 0
    legend_rows = 90  # the legend panel covers the top rows at this size (no note line)
    for y, x in zip(ys[::29], xs[::29], strict=True):
        px = img[y, x].astype(np.float64)
        if y < legend_rows or tuple(px) in (demo.FRUSTUM_COLOR, demo.FRUSTUM_HIDDEN_COLOR):
            continue
        ref = pal[fate[y, x]]
        k = px.sum() / ref.sum()
        assert 0.4 < k <= 1.01 and np.abs(px - k * ref).max() <= 2.5, (y, x, px, ref)
        checked += 1
    assert checked > 10


def test_world_mesh_ids_are_scene_ids(small_plant):
    from clraster import demo

    m = demo.world_mesh(small_plant)
    assert m.n_faces == small_plant.n_faces
    i = small_plant.n_instances - 1
    inst = small_plant.instances[i]
    t = inst.transform
    f0 = int(small_plant.face_base[i])
    np.testing.assert_allclose(m.vertices[m.faces[f0]],
                               inst.mesh.vertices[inst.mesh.faces[0]] @ t[:3, :3].T
                               + t[:3, 3], rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("args, message", [
    (["--size", "0x10"], "must be in 1.."),
    (["--size", "wide"], "WIDTHxHEIGHT"),
    (["--triangles", "10"], ">= 2000"),
    (["--frames", "0"], ">= 1"),
    (["--bogus"], "unrecognized"),
])
def test_bad_arguments(args, message, capsys):
    from clraster import cli, demo

    assert demo.main(args) == 2
    assert message in capsys.readouterr().err
    assert cli.main(["demo", *args]) == 2
    assert message in capsys.readouterr().err


def test_help(capsys):
    from clraster import demo

    assert demo.main(["--help"]) == 0
    assert "inspector" in capsys.readouterr().out


class _PlantBuilt(Exception):
    """Raised by the stand-in plant: the command got past argument parsing."""


@pytest.mark.parametrize("count", ["50_000_001", "1000000000000"])
def test_triangle_cap_is_checked_at_parsing(count, tmp_path, capsys, monkeypatch):
    """--triangles above `demo.MAX_TRIANGLES` is a usage error (exit 2) naming the cap and
    the reason; the plant is never built (with no cap, 10**12 triangles ran until the host
    ran out of memory)."""
    from clraster import cli, demo
    from clraster.world import generators as scenes

    def plant(*args, **kwargs):
        raise _PlantBuilt("the demo built the plant instead of refusing the count")

    monkeypatch.setattr(scenes, "plant", plant)
    args = ["--triangles", count, "--out", str(tmp_path / "d")]
    for run in (demo.main, lambda a: cli.main(["demo", *a])):
        assert run(args) == 2
        err = capsys.readouterr().err
        assert "at most 50,000,000 triangles" in err and "memory" in err, err
    assert not (tmp_path / "d").exists()
    # the cap itself and the default are accepted
    p = demo._parser()
    assert p.parse_args(["--triangles", "50,000,000"]).triangles == demo.MAX_TRIANGLES
    assert p.parse_args([]).triangles <= demo.MAX_TRIANGLES


def test_annotate_text_panel_ramp():
    from clraster.output import annotate

    img = np.zeros((40, 200, 3), np.uint8)
    img[:] = (50, 60, 70)
    col = (250, 10, 120)
    w = annotate.text_width("hello 123", 1)
    assert 20 < w < 100 and annotate.text_width("hello 123", 2) > w
    annotate.draw_text(img, 10, 5, "hello 123", col, 1)
    changed = (img != (50, 60, 70)).any(axis=2)
    ys, xs = np.nonzero(changed)
    # the ink sits on the line: top of the line at row 5, baseline at 5 + TEXT_HEIGHT
    # (descenders and anti-aliasing a pixel or two beyond), pen from column 10
    assert ys.min() >= 5 - 2 and ys.max() <= 5 + annotate.TEXT_HEIGHT + 3
    assert xs.min() >= 10 - 1 and xs.max() <= 10 + w + 1
    # glyph cores in the text's colour (anti-aliased one-pixel strokes cover a pixel
    # not quite fully: within 10 % of the way from the background)
    assert (np.abs(img.astype(np.int64) - col).max(axis=2) <= 20).sum() > 10
    # clipped at every edge, nothing raised, nothing outside touched
    for x, y in ((-30, -4), (190, 35), (-500, 0), (0, 500)):
        annotate.draw_text(img, x, y, "clipped", col, 2)
    # the panel darkens towards 12, clipped
    annotate.panel(img, -5, -5, 3, 3)
    assert (img[:3, :3] == int(50 * 0.25 + 12 * 0.75)).any()
    # ramps hit their stops; steps are 1, 2, 5 × 10^k
    r = annotate.ramp(np.array([0.0, 0.15, 1.0, 2.0]), annotate.HEAT)
    assert r.dtype == np.uint8 and r.shape == (4, 3)
    assert [tuple(c) for c in r] == [(0, 0, 4), (40, 11, 84), (252, 255, 210), (252, 255, 210)]
    assert [annotate.nice_step(s) for s in (15, 7, 120, 0.3)] == [5, 2, 50, 0.1]
