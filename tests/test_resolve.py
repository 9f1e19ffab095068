"""The resolve stage: per-pixel outputs made on the device from ids, barycentrics and the
scene's geometry (`Renderer.render(outputs=...)`, kernels/resolve.cl), against the NumPy twin
(`clraster.pipeline.reference.resolve`), the host outputs of `clraster.output.outputs`, a
float64 ray–plane oracle and hand-made expectations; the batch paths asking for them."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import get_renderer
from test_outputs import grid, pixel_rays, position_tolerance

from clraster import Camera, Mesh
from clraster.base.checks import RESOLVE_OUTPUTS
from clraster.base.config import RasterConfig
from clraster.output import outputs as host_outputs
from clraster.pipeline import reference
from clraster.scale.batch import _render_outputs, iter_views
from clraster.world.scene import Scene

W, H = 83, 61   # not multiples of the tile size or of the resolve span
ALL = ("depth", "ids") + RESOLVE_OUTPUTS


def cube() -> Mesh:
    return Mesh.from_trimesh(trimesh.creation.box(extents=(2.0, 2.0, 2.0)))


@pytest.fixture(scope="module")
def scene() -> Scene:
    """Two meshes; a rotated and scaled instance, a mirrored one (glTF rule) and an empty
    one between them (instances sharing a first triangle id)."""
    sphere = Mesh.from_trimesh(trimesh.creation.icosphere(subdivisions=2, radius=0.9))
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    rot = np.eye(4)
    c, s = np.cos(0.6), np.sin(0.6)
    rot[:3, :3] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ np.diag([1.0, 1.4, 0.8])
    rot[:3, 3] = (-1.7, 0.1, 0.0)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = (1.6, 0.2, -0.3)
    shifted = np.eye(4)
    shifted[:3, 3] = (0.0, -0.2, -2.5)
    return Scene([(cube(), rot), (empty, np.eye(4)), (sphere, mirror), (sphere, shifted)])


def camera() -> Camera:
    return Camera.look_at((1.0, 2.2, 6.0), (0.0, 0.0, -0.6), fov_y=50.0, near=1.0, far=20.0)


def test_device_equals_twin_and_host(scene):
    """Every resolve output, bit for bit: the device, its twin, and the host outputs of a
    frame rendered without them (same ids and barycentrics)."""
    cam = camera()
    dev = get_renderer(W, H).render(scene, cam, cull="none", outputs=ALL)
    twin = reference.Renderer(W, H).render(scene, cam, cull="none", outputs=ALL)
    plain = get_renderer(W, H).render(scene, cam, cull="none")
    np.testing.assert_array_equal(dev.triangle_id, plain.triangle_id)
    np.testing.assert_array_equal(dev.triangle_id, twin.triangle_id)
    inst, _ = scene.split_ids(dev.triangle_id[dev.mask])
    assert set(inst.tolist()) == {0, 2, 3}, "the view should show every non-empty instance"
    assert dev.barycentrics is None and set(dev.resolved) == set(RESOLVE_OUTPUTS)
    for name in RESOLVE_OUTPUTS:
        np.testing.assert_array_equal(dev.resolved[name], twin.resolved[name], err_msg=name)
    host = {
        "mask": plain.triangle_id >= 0,
        "linear_depth": host_outputs.linear_depth(plain, cam, scene),
        "distance": host_outputs.distance(plain, cam, scene),
        "normals": host_outputs.normals(plain, scene),
        "smooth_normals": host_outputs.normals(plain, scene, smooth=True),
        "camera_normals": host_outputs.normals(plain, scene, space="camera", camera=cam),
        "smooth_camera_normals": host_outputs.normals(plain, scene, smooth=True,
                                                      space="camera", camera=cam),
    }
    for name, want in host.items():
        got = dev.resolved[name]
        assert got.dtype == want.dtype and got.shape == want.shape, name
        np.testing.assert_array_equal(got, want, err_msg=name)
    pts = plain.points(scene)
    np.testing.assert_array_equal(dev.resolved["points"][pts.pixels[:, 1], pts.pixels[:, 0]],
                                  pts.points)
    # backgrounds
    bg = ~dev.mask
    assert bg.any()
    assert np.isinf(dev.resolved["linear_depth"][bg]).all()
    assert np.isinf(dev.resolved["distance"][bg]).all()
    for name in ("points", "normals", "smooth_normals", "camera_normals"):
        assert not dev.resolved[name][bg].any(), name


def test_mirrored_normals_point_out(scene):
    """glTF's rule on the device: the mirrored sphere's normals point away from its centre,
    as the unmirrored one's do; camera-space normals face the eye (n · (−p) > 0 in eye
    space: cull none shows only the near side of closed meshes)."""
    cam = camera()
    f = get_renderer(W, H).render(scene, cam, cull="none",
                                  outputs=("normals", "points", "camera_normals"))
    m = f.mask
    inst, _ = scene.split_ids(f.triangle_id[m])
    centres = scene.transforms()[:, :3, 3][inst]
    out = np.einsum("ij,ij->i", f.resolved["normals"][m].astype(np.float64),
                    f.resolved["points"][m] - centres)
    assert (out[inst >= 2] > 0.5).all()
    p_eye = f.resolved["points"][m] @ cam.view[:3, :3].T + cam.view[:3, 3]
    facing = np.einsum("ij,ij->i", f.resolved["camera_normals"][m].astype(np.float64), -p_eye)
    assert (facing > 0).all()
    n = np.linalg.norm(f.resolved["normals"][m].astype(np.float64), axis=1)
    np.testing.assert_allclose(n, 1.0, atol=1e-6)


@pytest.mark.parametrize("tilted", [False, True])
def test_metric_depth_against_a_ray_plane_oracle(tilted):
    """A plane in front of the camera: the device's linear depth and distance against the
    float64 intersection of each pixel's ray with the plane of its float32 vertices, to the
    tolerance of values interpolated within `POSITION_ERROR` pixels of the centre (the
    host's exact path's bound, tests/test_outputs.py); the normal is the plane's."""
    eye = np.array([0.5, 0.25, 3.0])
    cam = Camera.look_at(eye, eye + [0.1, -0.05, -1.0], fov_y=50.0, near=0.5, far=20.0)
    normal = np.array([0.3, 0.2, 1.0]) if tilted else np.array([0.0, 0.0, 1.0])
    normal /= np.linalg.norm(normal)
    a = np.cross(normal, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    centre = np.array([0.5, 0.25, -2.0])
    plane = grid(centre - 20 * a - 20 * b, 40 * a, 40 * b, 64)
    v = plane.vertices.astype(np.float64)
    n32 = np.linalg.svd(v - v.mean(0))[2][2]
    f = get_renderer(W, H).render(plane, cam, cull="none",
                                  outputs=("linear_depth", "distance", "normals", "mask"))
    assert f.resolved["mask"].all()
    rays = pixel_rays(cam, W, H)
    t = ((v.mean(0) - eye) @ n32) / (rays @ n32)
    want = t * (rays @ -cam.view[2, :3])
    f32 = 2.4e-7
    lin, dist = f.resolved["linear_depth"], f.resolved["distance"]
    assert np.all(np.abs(lin - want) <= position_tolerance(want) + f32 * want)
    assert np.all(np.abs(dist - t) <= position_tolerance(t) + f32 * t)
    sign = np.sign(f.resolved["normals"][0, 0] @ n32)
    np.testing.assert_allclose(f.resolved["normals"].reshape(-1, 3),
                               np.broadcast_to(sign * n32, (W * H, 3)), atol=2e-6)


def test_orthographic_distance_is_linear_depth():
    """Parallel rays: distance is the depth from the image plane; a plane z = −1 seen from
    z = 5 is 6 units away everywhere."""
    from conftest import ortho

    view = Camera.look_at((0, 0, 5), (0, 0, 0)).view
    cam = Camera.from_matrices(view, ortho(-2, 2, -1.5, 1.5, 1.0, 10.0))
    plane = grid((-5, -5, -1), (10, 0, 0), (0, 10, 0), 4)
    f = get_renderer(W, H).render(plane, cam, outputs=("linear_depth", "distance"))
    lin, dist = f.resolved["linear_depth"], f.resolved["distance"]
    np.testing.assert_array_equal(lin, dist)
    np.testing.assert_allclose(lin, 6.0, rtol=1e-6)


def test_outputs_on_demand_only():
    """Nothing asked for, nothing made; asked for without "bary", the frame has no
    barycentrics, and depth and ids are those of the default frame."""
    cam = camera()
    r = get_renderer(W, H)
    plain = r.render(cube(), cam)
    assert plain.resolved == {} and plain.resolved_camera is None
    assert "resolve" not in plain.stats.timings_ms
    f = r.render(cube(), cam, outputs=("linear_depth",))
    assert f.barycentrics is None and list(f.resolved) == ["linear_depth"]
    assert "resolve" in f.stats.timings_ms
    np.testing.assert_array_equal(f.depth, plain.depth)
    np.testing.assert_array_equal(f.triangle_id, plain.triangle_id)
    g = r.render(cube(), cam, outputs=("ids", "normals"))
    assert g.resolved_camera is None and list(g.resolved) == ["normals"]


def test_frame_methods_return_the_device_arrays():
    cam = camera()
    mesh = cube()
    f = get_renderer(W, H).render(mesh, cam, outputs=ALL + ("bary",))
    assert f.linear_depth(cam) is f.resolved["linear_depth"]
    assert f.distance(cam, mesh) is f.resolved["distance"]
    assert f.normals(mesh) is f.resolved["normals"]
    assert f.normals(mesh, smooth=True) is f.resolved["smooth_normals"]
    assert f.normals(mesh, space="camera", camera=cam) is f.resolved["camera_normals"]
    assert f.mask is f.resolved["mask"]
    np.testing.assert_array_equal(f.points(mesh).points, f.resolved["points"][f.mask])
    # another camera: not what the arrays were made for, so computed on the host
    other = Camera.look_at((1.0, 2.2, 6.5), (0.0, 0.0, -0.6), fov_y=50.0, near=1.0, far=20.0)
    assert f.linear_depth(other) is not f.resolved["linear_depth"]
    assert f.normals(mesh, space="camera", camera=other) is not f.resolved["camera_normals"]


class _MatrixOnly:
    """A camera with a view-projection but no view: metric outputs cannot be made."""

    def __init__(self, cam: Camera) -> None:
        self.cam = cam

    def view_projection(self, width: int, height: int) -> np.ndarray:
        return self.cam.view_projection(width, height)


def test_camera_without_view_is_refused_before_drawing():
    r = get_renderer(W, H)
    cam = _MatrixOnly(camera())
    with pytest.raises(ValueError, match="linear_depth"):
        r.render(cube(), cam, outputs=("depth", "linear_depth"))
    f = r.render(cube(), cam, outputs=("normals", "mask"))   # need no camera
    assert f.resolved["mask"].any()
    with pytest.raises(ValueError, match="outputs must be"):
        r.render(cube(), camera(), outputs=("depth", "normal"))


def test_empty_streamed_and_occlusion_frames(scene):
    """Nothing in view: background values; a frame streamed in tiny passes or drawn in two
    occlusion phases resolves to the one-pass frame's outputs."""
    away = Camera.look_at((0.0, 0.0, 6.0), (0.0, 0.0, 12.0), fov_y=40.0, near=1.0, far=5.0)
    names = ("mask", "linear_depth", "points", "smooth_normals")
    e = get_renderer(W, H).render(scene, away, outputs=names)
    assert not e.resolved["mask"].any() and np.isinf(e.resolved["linear_depth"]).all()
    assert not e.resolved["points"].any() and not e.resolved["smooth_normals"].any()
    cam = camera()
    one = get_renderer(W, H).render(scene, cam, outputs=names)
    from clraster import Renderer

    small = Renderer(W, H, config=RasterConfig(batch_triangles=256, batch_entries=1024))
    occ = get_renderer(W, H)
    for f in (small.render(scene, cam, outputs=names),
              occ.render(scene, cam, outputs=names, occlusion=True)):
        for n in names:
            np.testing.assert_array_equal(f.resolved[n], one.resolved[n], err_msg=n)


def test_batch_paths_ask_the_device(monkeypatch):
    """iter_views (and render_views, through the same `_render_outputs`) asks the renderer
    for the resolve outputs: with the host's own computations made to fail, the views still
    come, equal to a frame rendered with them."""
    kw = _render_outputs(("linear_depth:png", "normals", "points", "mask", "ids"), {})
    assert kw["outputs"] == ("depth", "ids", "linear_depth", "normals", "points", "mask")
    assert "bary" in _render_outputs(("shaded", "distance"), {})["outputs"]

    def no_host(*a, **k):
        raise AssertionError("computed on the host")

    mesh = cube()
    cams = [camera()]
    want = get_renderer(W, H).render(mesh, cams[0], outputs=ALL)
    monkeypatch.setattr(host_outputs, "pixel_normals", no_host)
    monkeypatch.setattr(host_outputs, "dot_rows", no_host)
    monkeypatch.setattr(host_outputs, "blend_rows", no_host)
    outs = ("linear_depth", "distance", "normals", "smooth_camera_normals", "mask", "points")
    v = next(iter_views(mesh, cams, outs, renderer=get_renderer(W, H)))
    for name in outs[:-1]:
        np.testing.assert_array_equal(v[name], want.resolved[name], err_msg=name)
    m = want.resolved["mask"]
    np.testing.assert_array_equal(v["points"][:, :3], want.resolved["points"][m])
    np.testing.assert_array_equal(v["points"][:, 3:], want.resolved["normals"][m])


def test_resolve_enqueued_behind_the_raster(scene, monkeypatch):
    """A frame drawn in one pass has its resolve enqueued right behind its raster (no
    separate resolve after the frame's wait), also when the pass is drawn twice (a close
    frame after a far one: its bin list outgrows the entry buffer, is scattered and drawn
    again, and the resolve enqueued again behind the second raster); a frame streamed in
    several passes (over the triangle or the entry budget) resolves once, after its last.
    All give the twin's outputs, bit for bit."""
    from clraster import Renderer
    from clraster.pipeline.stages.bin import BinStage
    from clraster.pipeline.stages.resolve import ResolveStage

    after: list[int] = []
    redrawn: list[bool] = []
    run, settle = ResolveStage.run, BinStage.settle

    def counted_run(self, *a, **k):
        after.append(1)
        return run(self, *a, **k)

    def seen_settle(self, *a, **k):
        redrawn.append(settle(self, *a, **k))
        return redrawn[-1]

    monkeypatch.setattr(ResolveStage, "run", counted_run)
    monkeypatch.setattr(BinStage, "settle", seen_settle)
    names = ("mask", "linear_depth", "points", "smooth_normals")
    cam = camera()
    want = reference.Renderer(W, H).render(scene, cam, outputs=names).resolved
    fresh = Renderer(W, H)
    far = Camera.look_at((1.0, 2.2, 60.0), (0.0, 0.0, -0.6), fov_y=50.0, near=1.0, far=90.0)
    fresh.render(scene, far, outputs=names)   # a short bin list: a small entry buffer
    frames = [fresh.render(scene, cam, outputs=names), fresh.render(scene, cam, outputs=names)]
    assert redrawn[-2:] == [True, False], redrawn   # the first close frame was drawn twice
    assert after == []
    small = Renderer(W, H, config=RasterConfig(batch_triangles=256, batch_entries=1024))
    frames.append(small.render(scene, cam, outputs=names))
    assert after == [1]
    # within the triangle budget but over the entry budget: the second pass turns the
    # follow off, and the frame resolves once after its passes
    entries = Renderer(W, H, config=RasterConfig(batch_entries=64))
    frames.append(entries.render(scene, cam, outputs=names))
    assert after == [1, 1]
    for f in frames:
        for n in names:
            np.testing.assert_array_equal(f.resolved[n], want[n], err_msg=n)


def _lane_scene() -> Scene:
    """A bent sheet of 3,200 small faces filling most of the frame (whole groups of 8
    pixels of one instance: kernels/resolve.cl resolve_lanes), part of it doubled by faces
    of the reverse winding drawn after it (its vertices' normals cancel there, to zero or to
    lengths under 1e-6: the smooth normals' fallback to the face normal, in some lanes of a
    group and not in others along the part's edge), and a patch of faces whose normals are
    made zero or NaN (no face the raster draws has one, so they are set by hand in the
    mesh's cached table, which device and twin both read: unit3's zero case for a zero and
    for a non-finite length, in whole groups and in single lanes); a sphere in front of the
    sheet (groups of two instances)."""
    n = 40
    base = grid((-2.4, -1.8, 0.0), (4.8, 0.0, 0.0), (0.0, 3.6, 0.0), n)
    v = base.vertices.astype(np.float64)
    v[:, 2] = 0.3 * np.sin(1.3 * v[:, 0]) * np.cos(0.9 * v[:, 1])
    f = base.faces
    cell = np.concatenate([np.arange(n * n)] * 2)   # cell i * n + j of each face
    doubled = f[(cell // n < 14) & (cell % n < 20)]
    sheet = Mesh(v, np.concatenate([f, doubled[:, ::-1]]))
    fn = sheet.face_normals().copy()
    i, j = cell // n, cell % n
    patch = np.flatnonzero((i >= 4) & (i < 14) & (j >= 24) & (j < 34))
    fn[patch[::2]] = 0.0
    fn[patch[1::2]] = np.nan
    fn.flags.writeable = False
    sheet._face_normals = fn
    sphere = Mesh.from_trimesh(trimesh.creation.icosphere(subdivisions=3, radius=0.55))
    front = np.eye(4)
    front[:3, 3] = (0.9, 0.5, 0.8)
    return Scene([(sheet, np.eye(4)), (sphere, front)])


def _lane_camera(kind: str) -> Camera:
    if kind == "orthographic":
        from conftest import ortho

        view = Camera.look_at((0.2, 0.1, 5.0), (0.2, 0.1, 0.0)).view
        return Camera.from_matrices(view, ortho(-2.3, 2.3, -1.7, 1.7, 1.0, 10.0))
    return Camera.look_at((0.2, 0.1, 4.2), (0.1, 0.0, 0.0), fov_y=50.0, near=1.0, far=20.0)


@pytest.mark.parametrize("kind", ["perspective", "reversed_z", "orthographic"])
def test_lane_groups_equal_twin(kind):
    """Every resolve output, bit for bit against the twin, on a frame with both kinds of
    8-pixel group resolve_pixels meets: all eight covered by the instance found last (its
    lanes), and groups mixing instances, the background and the ragged end of the frame
    (83 × 61 pixels: not multiples of 8 or 16); unit3's zero case and the smooth normals'
    fallback inside whole groups."""
    scene = _lane_scene()
    cam = _lane_camera(kind)
    rz = kind == "reversed_z"
    dev = get_renderer(W, H).render(scene, cam, cull="none", outputs=ALL, reversed_z=rz)
    twin = reference.Renderer(W, H).render(scene, cam, cull="none", outputs=ALL,
                                           reversed_z=rz)
    np.testing.assert_array_equal(dev.triangle_id, twin.triangle_id)
    # the frame has what the test is about (groups of 8 from pixel 0, row-major)
    ids = dev.triangle_id.reshape(-1)
    n8 = ids.size // 8
    base = scene.face_base.reshape(-1)
    inst = np.where(ids >= 0, np.searchsorted(base, ids, side="right") - 1, -1)
    groups = inst[:8 * n8].reshape(n8, 8)
    whole = (groups >= 0).all(1) & (groups == groups[:, :1]).all(1)
    assert whole.sum() > 200 and (whole & (groups[:, 0] == 1)).sum() > 10
    two = (groups >= 0).all(1) & ~whole
    assert two.sum() > 5, "groups of two instances"
    assert ((groups < 0).any(1) & (groups >= 0).any(1)).sum() > 5, "covered and background"
    assert ids.size % 8 and ids[8 * n8:].max() >= 0 or ids.size % 16, "a ragged end"
    nrm, smooth = dev.resolved["normals"], dev.resolved["smooth_normals"]
    in_whole = np.repeat(whole, 8).reshape(-1)
    sheet = in_whole & (inst[:8 * n8] == 0)
    zero = ~nrm.reshape(-1, 3)[:8 * n8].any(1)
    assert (sheet & zero).sum() >= 16 and not (zero & (inst[:8 * n8] == 1)).any()
    same = (smooth.reshape(-1, 3)[:8 * n8] == nrm.reshape(-1, 3)[:8 * n8]).all(1)
    assert (sheet & same).sum() >= 16 and (sheet & ~same).sum() >= 16, "weak smooth normals"
    for name in RESOLVE_OUTPUTS:
        np.testing.assert_array_equal(dev.resolved[name], twin.resolved[name],
                                      err_msg=f"{kind}: {name}")
    if kind != "perspective":
        return
    # and the host's outputs of the same frame
    for name, want in (("distance", host_outputs.distance(dev, cam, scene)),
                       ("smooth_normals", host_outputs.normals(dev, scene, smooth=True)),
                       ("camera_normals",
                        host_outputs.normals(dev, scene, space="camera", camera=cam))):
        np.testing.assert_array_equal(dev.resolved[name], want, err_msg=name)
