"""Shading on the device (kernels/shade.cl shade_pixels, shade_ssaa) against its twin, the
NumPy path of `clraster.output.shade.shade` (and of render_shaded's supersampling) on the
same frame: equal within 1/255 per channel in every mode (flat, smooth, one- and two-sided,
RGBA, per-instance colours as arrays or callables, vertex and face colours, bilinear
textures with factors, ssaa), for a Mesh and a Scene with a mirrored instance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import get_renderer

from clraster import Camera, Mesh
from clraster.output import shade as shade_mod
from clraster.output.frame import Frame
from clraster.output.shade import render_shaded, shade
from clraster.world.scene import Scene

W, H = 83, 61


@pytest.fixture(scope="module")
def scene() -> Scene:
    """A sphere, a mirrored copy (glTF rule: outward normals) and a sheared box."""
    sphere = Mesh.from_trimesh(trimesh.creation.icosphere(subdivisions=2, radius=0.9))
    box = Mesh.from_trimesh(trimesh.creation.box(extents=(1.2, 1.6, 1.0)))
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = (1.3, 0.0, 0.0)
    left = np.eye(4)
    left[:3, 3] = (-1.3, 0.0, 0.0)
    shear = np.eye(4)
    shear[0, 1] = 0.4
    shear[:3, 3] = (0.0, 0.2, -2.0)
    return Scene([(sphere, left), (sphere, mirror), (box, shear)])


def camera() -> Camera:
    return Camera.look_at((0.8, 1.9, 5.0), (0.0, 0.0, -0.5), fov_y=55.0, near=0.5, far=20.0)


def host_twin(frame: Frame) -> Frame:
    """The same buffers without a device to shade on: `shade` takes its NumPy path."""
    return Frame(frame.depth, frame.triangle_id, frame.barycentrics, frame.stats)


MODES = [{}, {"smooth": True}, {"two_sided": False}, {"light_dir": (-0.4, 0.2, 0.9)},
         {"alpha": True, "background": (10, 200, 30)},
         {"per_instance_colors": np.array([[230, 50, 20], [40, 120, 250], [128, 128, 128]],
                                          np.uint8)},
         {"per_instance_colors": [[0.9, 0.2, 0.1], [0.1, 0.9, 0.2], [0.3, 0.3, 1.0]],
          "smooth": True, "alpha": True, "two_sided": False}]


@pytest.mark.parametrize("kw", MODES, ids=lambda kw: ",".join(kw) or "flat")
@pytest.mark.parametrize("target", ["mesh", "scene"])
def test_device_shading_equals_the_host_path(scene, kw, target, monkeypatch):
    geom = scene if target == "scene" else scene.instances[2].mesh
    if target == "mesh" and "per_instance_colors" in kw:
        kw = {**kw, "per_instance_colors": kw["per_instance_colors"][:1]}
    frame = get_renderer(W, H).render(geom, camera(), cull="none")
    assert frame.source is not None and frame.source() is not None
    want = shade(host_twin(frame), geom, **kw)

    def no_host(*a, **k):
        raise AssertionError("shaded on the host")

    monkeypatch.setattr(shade_mod, "_shade_covered", no_host)
    got = shade(frame, geom, **kw)
    assert got.dtype == np.uint8 and got.shape == want.shape
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    covered = frame.triangle_id >= 0
    assert covered.any() and (~covered).any()
    if "background" in kw:
        assert (got[~covered, :3] == kw["background"]).all() and (got[~covered, 3] == 0).all()
        assert (got[covered, 3] == 255).all()


def test_render_shaded_uses_the_device(scene, monkeypatch):
    r = get_renderer(W, H)
    want = render_shaded(r, scene, camera(), smooth=True)   # before the patch: any path

    def no_host(*a, **k):
        raise AssertionError("shaded on the host")

    monkeypatch.setattr(shade_mod, "_shade_covered", no_host)
    got = render_shaded(r, scene, camera(), smooth=True)
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


def _no_host(monkeypatch):
    def no_host(*a, **k):
        raise AssertionError("shaded on the host")

    monkeypatch.setattr(shade_mod, "_shade_covered", no_host)


def _sources(scene: Scene) -> dict[str, dict]:
    """Colour-source modes for the scene (per instance) and for its sphere mesh."""
    sphere = scene.instances[0].mesh
    box = scene.instances[2].mesh
    rng = np.random.default_rng(7)
    vc_s = rng.random((sphere.n_vertices, 3))
    vc_b = (rng.random((box.n_vertices, 3)) * 255).astype(np.uint8)
    # a small asymmetric texture with sharp texel steps, UVs beyond [0, 1] (repeat)
    img = rng.integers(0, 256, (5, 7, 3), np.uint8)
    uv_s = rng.random((sphere.n_vertices, 2)) * 3.0 - 1.0
    uv_b = rng.random((box.n_vertices, 2))
    return {
        "vertex_colors": {"mesh": {"colors": vc_s},
                          "scene": {"colors": [vc_s, vc_s[::-1].copy(), vc_b]}},
        "texture": {"mesh": {"texture": (uv_s, img)},
                    "scene": {"texture": [(uv_s, img), (uv_s, img, (0.5, 1.0, 0.2)),
                                          (uv_b, img[::-1].copy())]}},
        "texture_factor_only": {"mesh": {"texture": (None, None, (200, 30, 90))},
                                "scene": {"texture": [None, (None, None, (0.1, 0.9, 0.5)),
                                                      None]}},
        "colors_texture_tints": {
            "mesh": {"colors": vc_s, "texture": (uv_s, img),
                     "per_instance_colors": [[0.9, 0.6, 0.3]], "smooth": True},
            "scene": {"colors": [vc_s, None, vc_b], "texture": [(uv_s, img), None, None],
                      "per_instance_colors": [[0.9, 0.6, 0.3], [0.2, 0.5, 1.0],
                                              [1.0, 1.0, 1.0]],
                      "alpha": True, "two_sided": False}},
        "callable_tints": {
            "mesh": {"per_instance_colors": lambda i, inst: (0.3 + 0.1 * i, 0.7, 0.2)},
            "scene": {"per_instance_colors": lambda i, inst: (
                (1.0, 0.2, 0.1) if np.linalg.det(inst.transform[:3, :3]) < 0
                else (0.1 + 0.3 * i, 0.8, 0.4)), "smooth": True}},
    }


@pytest.mark.parametrize("mode", ["vertex_colors", "texture", "texture_factor_only",
                                  "colors_texture_tints", "callable_tints"])
@pytest.mark.parametrize("target", ["mesh", "scene"])
def test_colour_sources_on_the_device(scene, mode, target, monkeypatch):
    geom = scene if target == "scene" else scene.instances[0].mesh
    kw = _sources(scene)[mode][target]
    frame = get_renderer(W, H).render(geom, camera(), cull="none")
    want = shade(host_twin(frame), geom, **kw)
    _no_host(monkeypatch)
    got = shade(frame, geom, **kw)
    assert got.shape == want.shape
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    covered = frame.triangle_id >= 0
    # the sources show: covered pixels are not one flat colour
    assert len(np.unique(got[covered][:, :3], axis=0)) > 20


def test_face_colours_of_a_trimesh_on_the_device(monkeypatch):
    tm = trimesh.creation.icosphere(subdivisions=2, radius=0.9)
    rng = np.random.default_rng(3)
    tm.visual.face_colors = rng.integers(0, 256, (len(tm.faces), 4), np.uint8)
    r = get_renderer(W, H)
    frame = r.render(tm, camera())
    want = shade(host_twin(frame), tm)
    _no_host(monkeypatch)
    got = shade(frame, tm)
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    ids = frame.triangle_id
    px = np.argwhere(ids >= 0)[len(np.argwhere(ids >= 0)) // 2]
    # a hand check at one pixel: face colour · (ambient + (1 − ambient)·|n·l|)
    f = ids[tuple(px)]
    n = Mesh.from_trimesh(tm).face_normals()[f].astype(np.float64)
    light = np.asarray(shade_mod.DEFAULT_LIGHT_DIR) / np.linalg.norm(shade_mod.DEFAULT_LIGHT_DIR)
    lam = abs(n @ light)
    expect = tm.visual.face_colors[f, :3] / 255.0 * (0.22 + 0.78 * lam) * 255.0
    assert np.abs(got[tuple(px)].astype(float) - expect).max() <= 1.0


def test_callable_tints_are_called_for_seen_instances_only(scene, monkeypatch):
    """The callable is evaluated on the host once per instance seen in the frame (the
    device finds which), never for an instance outside the view."""
    far = np.eye(4)
    far[:3, 3] = (0.0, 0.0, 50.0)   # behind the camera
    sphere = scene.instances[0].mesh
    sc = Scene([*((inst.mesh, inst.transform) for inst in scene.instances), (sphere, far)])
    calls: list[int] = []

    def tint(i, inst):
        calls.append(i)
        return (0.2 * i, 0.5, 0.9)

    frame = get_renderer(W, H).render(sc, camera())
    want = shade(host_twin(frame), sc, per_instance_colors=tint)
    host_calls = sorted(calls)
    calls.clear()
    _no_host(monkeypatch)
    got = shade(frame, sc, per_instance_colors=tint)
    assert sorted(calls) == host_calls == [0, 1, 2]
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


SSAA_MODES = [{}, {"alpha": True, "background": (0, 40, 200), "smooth": True},
              {"per_instance_colors": np.array([[250, 10, 10], [10, 250, 10], [10, 10, 250]],
                                               np.uint8), "two_sided": False}]


@pytest.mark.parametrize("k", [2, 3])
@pytest.mark.parametrize("kw", SSAA_MODES, ids=lambda kw: ",".join(kw) or "flat")
@pytest.mark.parametrize("target", ["mesh", "scene"])
def test_ssaa_on_the_device(scene, kw, k, target, monkeypatch):
    geom = scene if target == "scene" else scene.instances[2].mesh
    if target == "mesh" and "per_instance_colors" in kw:
        kw = {**kw, "per_instance_colors": kw["per_instance_colors"][:1]}
    r = get_renderer(W, H)
    with monkeypatch.context() as m:   # the host path: the twin of the device's
        m.setattr(shade_mod, "_shade_on_device", lambda *a, **k: None)
        want = render_shaded(r, geom, camera(), ssaa=k, **kw)
    _no_host(monkeypatch)
    got = render_shaded(r, geom, camera(), ssaa=k, **kw)
    assert got.shape == want.shape == (H, W, 4 if kw.get("alpha") else 3)
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1
    if kw.get("alpha"):   # partial coverage on the edges
        a = got[..., 3]
        assert ((a > 0) & (a < 255)).any() and (a == 255).any() and (a == 0).any()


def test_ssaa_with_colour_sources_on_the_device(scene, monkeypatch):
    kw = _sources(scene)["colors_texture_tints"]["scene"]
    r = get_renderer(W, H)
    with monkeypatch.context() as m:
        m.setattr(shade_mod, "_shade_on_device", lambda *a, **k: None)
        want = render_shaded(r, scene, camera(), ssaa=2, **kw)
    _no_host(monkeypatch)
    got = render_shaded(r, scene, camera(), ssaa=2, **kw)
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


def test_device_background_is_exact_on_odd_sizes(scene, monkeypatch):
    """Runs of 16 background pixels are vector stores, the rest pixel by pixel: every
    background pixel is the colour given, whatever the width (not a multiple of 16)."""
    for w, h in ((17, 5), (33, 31), (W, H)):
        frame = get_renderer(w, h).render(scene, camera())
        _no_host(monkeypatch)
        for alpha in (False, True):
            got = shade(frame, scene, background=(1, 2, 3), alpha=alpha)
            bg = frame.triangle_id < 0
            assert bg.any()
            assert (got[bg, :3] == (1, 2, 3)).all()
            if alpha:
                assert (got[bg, 3] == 0).all() and (got[~bg, 3] == 255).all()


def test_bad_ids_are_refused_as_on_the_host(scene):
    frame = get_renderer(W, H).render(scene, camera())
    small = Mesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(ValueError, match="ids outside"):
        shade(frame, small)
    frame = get_renderer(W, H).render(scene.instances[0].mesh, camera())
    with pytest.raises(ValueError, match="ids outside"):
        shade(frame, small, per_instance_colors=lambda i, inst: (1, 0, 0))
    with pytest.raises(ValueError, match="ids outside"):
        shade(frame, small, smooth=True)


# -- the 8-pixel lanes of shade_pixels (flat and smooth without colour sources) -------------

@pytest.fixture(scope="module")
def crowd() -> Scene:
    """48 small instances (spheres and boxes; mirrored, scaled, rotated, sheared) packed
    side by side, so that many groups of 8 consecutive pixels span two or more instances
    and the lanes gather a different instance matrix and tint per lane."""
    sphere = Mesh.from_trimesh(trimesh.creation.icosphere(subdivisions=1, radius=0.3))
    box = Mesh.from_trimesh(trimesh.creation.box(extents=(0.5, 0.4, 0.3)))
    rng = np.random.default_rng(11)
    items = []
    for j in range(48):
        t = np.eye(4)
        a = rng.uniform(0.0, 2.0 * np.pi)
        t[:3, :3] = trimesh.transformations.rotation_matrix(a, rng.normal(size=3))[:3, :3]
        t[:3, :3] = t[:3, :3] @ np.diag(rng.uniform(0.6, 1.3, 3))
        if j % 5 == 0:
            t[:3, :3] = t[:3, :3] @ np.diag([-1.0, 1.0, 1.0])   # mirrored
        t[:3, 3] = (-2.1 + 0.6 * (j % 8), -1.3 + 0.55 * (j // 8), -0.5)
        items.append((sphere if j % 2 else box, t))
    return Scene(items)


CROWD_MODES = [{}, {"smooth": True}, {"two_sided": False, "light_dir": (0.2, -0.5, 0.8)},
               {"smooth": True, "alpha": True, "background": (3, 250, 7)},
               {"per_instance_colors": "random"},
               {"per_instance_colors": "random", "smooth": True, "two_sided": False}]


@pytest.mark.parametrize("kw", CROWD_MODES, ids=lambda kw: ",".join(kw) or "flat")
def test_lanes_across_instances_equal_the_host_path(crowd, kw, monkeypatch):
    if kw.get("per_instance_colors") == "random":
        tints = np.random.default_rng(5).integers(0, 256, (len(crowd.instances), 3), np.uint8)
        kw = {**kw, "per_instance_colors": tints}
    frame = get_renderer(W, H).render(crowd, Camera.look_at(
        (0.0, 0.0, 4.2), (0.0, 0.0, -0.5), fov_y=60.0, near=0.5, far=20.0))
    ids = frame.triangle_id
    inst, _ = crowd.split_ids(ids[ids >= 0])
    # the case under test happens: groups of 8 (row-major, as the kernel takes them)
    # holding pixels of two instances
    flat_inst = np.full(ids.size, -1)
    flat_inst[(ids >= 0).reshape(-1)] = inst
    groups = flat_inst[: ids.size // 8 * 8].reshape(-1, 8)
    mixed = [len(set(g[g >= 0].tolist())) > 1 for g in groups]
    assert sum(mixed) >= 20 and len(np.unique(inst)) >= 30
    want = shade(host_twin(frame), crowd, **kw)
    _no_host(monkeypatch)
    got = shade(frame, crowd, **kw)
    assert got.shape == want.shape
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1


@pytest.mark.parametrize("smooth", [False, True])
def test_lanes_on_a_plane_match_the_lambert_formula(smooth, monkeypatch):
    """A quad filling the frame, tilted: every pixel's colour is the analytic
    round(255 · albedo · (ambient + (1 − ambient) · |n · l|)) of its one normal (a planar
    quad's vertex normals are its face normal), computed here in float64."""
    quad = Mesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64),
                np.array([[0, 1, 2], [0, 2, 3]]))
    tilt = np.eye(4)
    tilt[:3, :3] = trimesh.transformations.rotation_matrix(0.5, (1.0, 0.3, 0.0))[:3, :3]
    tilt[:3, :3] *= 4.0
    sc = Scene([(quad, tilt)])
    frame = get_renderer(W, H).render(sc, Camera.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0),
                                                         fov_y=50.0, near=0.5, far=20.0))
    assert (frame.triangle_id >= 0).all()
    light = np.array([0.3, -0.4, 0.85])
    tint = np.array([[0.9, 0.5, 0.25]])
    _no_host(monkeypatch)
    got = shade(frame, sc, smooth=smooth, light_dir=light, per_instance_colors=tint)
    n = tilt[:3, :3] @ np.array([0.0, 0.0, 1.0])   # a rotation times 4: M⁻ᵀ n ∥ M n
    n /= np.linalg.norm(n)
    lam = abs(n @ (light / np.linalg.norm(light)))
    want = np.rint(255.0 * tint[0] * (0.22 + 0.78 * lam))
    assert np.abs(got.reshape(-1, 3).astype(float) - want).max() <= 1.0


@pytest.mark.parametrize("lane", range(8))
def test_a_bad_id_in_any_lane_is_refused(scene, lane):
    """An id out of range at any position of a group of 8 covered pixels raises (the
    lanes hand such a group to the per-pixel path, which flags it)."""
    frame = get_renderer(W, H).render(scene, camera())
    ids = frame.triangle_id.reshape(-1)
    groups = np.flatnonzero((ids[: ids.size // 8 * 8].reshape(-1, 8) >= 0).all(axis=1))
    assert groups.size
    g = groups[groups.size // 2]
    for bad in (-2, scene.n_faces):
        keep = int(ids[8 * g + lane])
        ids[8 * g + lane] = bad
        for smooth in (False, True):
            with pytest.raises(ValueError, match="ids outside"):
                shade(frame, scene, smooth=smooth)
        ids[8 * g + lane] = keep
    shade(frame, scene)   # restored: no error
