"""shade() and depth_image(): Lambert shading from triangle ids (flat and smooth, vertex
colours, textures, scenes, RGBA, supersampling via render_shaded); depth visualization."""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from conftest import MatrixCamera

from clraster import Camera
from clraster.output.shade import depth_image, pixel_normals, render_shaded, shade, vertex_normals
from clraster.output.textures import Texture, texture_from_trimesh
from clraster.pipeline import reference
from clraster.world.mesh import Mesh
from clraster.world.scene import Scene

# Two faces: one facing +Z, the same triangle wound the other way (facing −Z), one degenerate.
MESH = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], [[0, 1, 2], [0, 2, 1], [0, 1, 3]])


def frame(ids) -> SimpleNamespace:
    return SimpleNamespace(triangle_id=np.asarray(ids, dtype=np.int32))


def test_shape_dtype_background():
    img = shade(frame([[-1, 0, 1], [2, -1, -1]]), MESH, background=(10, 20, 30))
    assert img.shape == (2, 3, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img[0, 0], [10, 20, 30])
    np.testing.assert_array_equal(img[1, 1:], [[10, 20, 30]] * 2)


def test_two_sided_and_light_direction():
    ids = frame([[0, 1, 2]])
    head_on = shade(ids, MESH, light_dir=(0, 0, 5))
    np.testing.assert_array_equal(head_on[0, 0], head_on[0, 1])  # |n·l|: both sides lit
    grazing = shade(ids, MESH, light_dir=(1, 0, 0))
    assert np.all(grazing[0, 0] < head_on[0, 0])  # ambient only at 90°
    np.testing.assert_array_equal(grazing[0, 0], grazing[0, 2])  # degenerate = ambient
    assert np.all(grazing[0, 0] > 0)


def test_default_light_is_deterministic():
    ids = frame(np.array([[0, 1], [2, -1]]))
    np.testing.assert_array_equal(shade(ids, MESH), shade(ids, MESH))
    np.testing.assert_array_equal(shade(ids, MESH)[1, 1], [255, 255, 255])


@pytest.mark.parametrize("ids, match", [
    ([[0, 3]], r"outside \[-1, 3\)"),
    ([[-2, 0]], r"outside \[-1, 3\)"),
    ([0, 1], r"\(H, W\) integer"),
    ([[0.0, 1.0]], r"\(H, W\) integer"),
])
def test_bad_ids(ids, match):
    with pytest.raises(ValueError, match=match):
        shade(SimpleNamespace(triangle_id=np.asarray(ids)), MESH)


@pytest.mark.parametrize("kw, match", [
    (dict(light_dir=(0, 0, 0)), "light_dir"),
    (dict(light_dir=(0, np.nan, 1)), "light_dir"),
    (dict(light_dir=(1, 0)), "light_dir"),
    (dict(background=(0, 0, 256)), "background"),
    (dict(background=(0, 0)), "background"),
])
def test_bad_options(kw, match):
    with pytest.raises(ValueError, match=match):
        shade(frame([[0]]), MESH, **kw)


def test_depth_image():
    d = np.array([[1.0, 0.2, 0.6], [0.4, 1.0, np.nan]], dtype=np.float32)
    img = depth_image(d)
    assert img.dtype == np.uint8 and img.shape == (2, 3)
    assert img[0, 1] == 0  # nearest: black
    assert img[0, 2] == 235  # farthest covered
    assert 0 < img[1, 0] < 235
    assert img[0, 0] == img[1, 1] == img[1, 2] == 255  # background (and NaN)


def test_depth_image_edge_cases():
    np.testing.assert_array_equal(depth_image(np.ones((2, 2))), 255)
    np.testing.assert_array_equal(depth_image(np.full((2, 2), 0.5)), 0)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        depth_image(np.ones(4))


# -- smooth shading, colours, textures, scenes, RGBA, supersampling -------------------------
# Frames come from the NumPy twin (same ids and barycentrics as the OpenCL renderer). With
# the identity clip matrix (`MatrixCamera(np.eye(4))`) clip = world with w = 1: NDC is world
# x, y, and the quad [-1, 1]² fills the image exactly; pixel (x, y) is sampled at NDC
# ((x + 0.5)/W·2 − 1, 1 − (y + 0.5)/H·2).

HEAD_ON = (0.0, 0.0, 1.0)  # light along the view axis: a quad facing it gets factor 1
QUAD = Mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
QUAD_UV = (np.asarray(QUAD.vertices, np.float64)[:, :2] + 1.0) / 2.0  # u right, v up
IDENTITY = MatrixCamera(np.eye(4))


def checker(h: int, w: int, cell: int) -> np.ndarray:
    """(h, w, 3) uint8 checkerboard whose cells also differ in colour by position, so a
    flipped or shifted lookup does not match."""
    r, c = np.mgrid[0:h, 0:w]
    on = ((r // cell + c // cell) % 2).astype(np.uint8)
    return np.stack([on * 200 + 20, (r // cell * 37) % 256, (c // cell * 53) % 256],
                    axis=-1).astype(np.uint8)


def sphere(subdivisions: int = 3) -> Mesh:
    s = trimesh.creation.icosphere(subdivisions)
    return Mesh(s.vertices, s.faces)


def test_checkerboard_texture_texel_per_pixel():
    # texture and image the same size: every pixel centre is a texel centre, so bilinear
    # filtering returns the texel itself and the image is the texture (row 0 = top = v 1)
    tex = checker(24, 40, 4)
    f = reference.render(QUAD, IDENTITY, 40, 24, cull="none")
    assert np.all(f.triangle_id >= 0)
    img = shade(f, QUAD, texture=(QUAD_UV, tex), light_dir=HEAD_ON)
    np.testing.assert_array_equal(img, tex)
    # RGBA textures: alpha is ignored
    rgba = np.concatenate([tex, np.full(tex.shape[:2] + (1,), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(shade(f, QUAD, texture=(QUAD_UV, rgba), light_dir=HEAD_ON),
                                  tex)


def test_checkerboard_texture_magnified_bilinear():
    # 4×6 texels on 48×32 pixels: each pixel is the bilinear blend of the four nearest
    # texel centres with repeat wrapping, written here with np.interp(period=...)
    th, tw, w, h = 4, 6, 48, 32
    tex = checker(th, tw, 1)
    f = reference.render(QUAD, IDENTITY, w, h, cull="none")
    img = shade(f, QUAD, texture=(QUAD_UV, tex), light_dir=HEAD_ON).astype(np.float64)
    tx = (np.arange(w) + 0.5) / w * tw - 0.5  # texel column coordinate of each pixel centre
    ty = (np.arange(h) + 0.5) / h * th - 0.5  # texel row (v up: top row of the image is v 1)
    t = tex.astype(np.float64)
    rows = np.stack([[np.interp(tx, np.arange(tw), t[r, :, c], period=tw) for c in range(3)]
                     for r in range(th)])  # (th, 3, w)
    expect = np.stack([[np.interp(ty, np.arange(th), rows[:, c, x], period=th)
                        for c in range(3)] for x in range(w)])  # (w, 3, h)
    expect = np.rint(expect.transpose(2, 0, 1))
    assert np.abs(img - expect).max() <= 1.0
    # the texture wraps: u and u + 1 (and v − 2) sample the same colour
    shifted = shade(f, QUAD, texture=(QUAD_UV + [1.0, -2.0], tex), light_dir=HEAD_ON)
    assert np.abs(shifted.astype(int) - img).max() <= 1


def test_texture_factor_and_trimesh_glb_round_trip():
    import PIL.Image
    from trimesh.visual import TextureVisuals
    from trimesh.visual.material import PBRMaterial

    tex = checker(24, 40, 4)
    f = reference.render(QUAD, IDENTITY, 40, 24, cull="none")
    tm = trimesh.Trimesh(np.asarray(QUAD.vertices), np.asarray(QUAD.faces), process=False,
                         visual=TextureVisuals(uv=QUAD_UV, material=PBRMaterial(
                             baseColorTexture=PIL.Image.fromarray(tex),
                             baseColorFactor=[255, 128, 255, 255])))
    # through a GLB file: trimesh flips glTF's v-down UVs back to v up on load
    back = trimesh.load(io.BytesIO(tm.export(file_type="glb")), file_type="glb",
                        process=False, force="mesh")
    t = texture_from_trimesh(back)
    assert isinstance(t, Texture) and t.image is not None
    np.testing.assert_allclose(t.factor, [1.0, 128 / 255, 1.0])
    expect = tex.astype(np.float64)
    expect[..., 1] *= 128 / 255
    for target in (tm, back):
        img = shade(f, target, light_dir=HEAD_ON)  # texture=True: the mesh's own
        assert np.abs(img.astype(np.float64) - expect).max() <= 0.5 + 1e-9
    untextured = shade(f, tm, texture=False, light_dir=HEAD_ON)
    np.testing.assert_array_equal(untextured, shade(f, QUAD, light_dir=HEAD_ON))


def test_smooth_has_no_facet_edges():
    m = sphere(2)
    cam = Camera.look_at(eye=(0, 0, 3.2), target=(0, 0, 0))
    f = reference.render(m, cam, 96, 96)
    light = (0.3, 0.5, 1.0)
    covered = f.triangle_id >= 0
    # the disc inside 85% of the silhouette radius: no background, no limb
    yy, xx = np.mgrid[0:96, 0:96]
    inner = np.hypot(xx - 47.5, yy - 47.5) < 0.85 * np.sqrt(covered.sum() / np.pi)
    assert covered[inner].all()

    def kinks(img):
        # second differences between neighbouring pixels: a facet edge is a kink (a step
        # in the first difference), smooth lighting only bends slowly
        g = img.astype(np.float64).mean(axis=2)
        dx = np.abs(g[:, 2:] - 2 * g[:, 1:-1] + g[:, :-2])[inner[:, 2:] & inner[:, :-2]]
        dy = np.abs(g[2:] - 2 * g[1:-1] + g[:-2])[inner[2:] & inner[:-2]]
        return np.concatenate([dx, dy])

    flat = kinks(shade(f, m, light_dir=light))
    smooth = kinks(shade(f, m, light_dir=light, smooth=True))
    assert flat.max() >= 20  # facets: steps between neighbouring faces
    assert smooth.max() <= 3  # smooth: rounding of a slowly varying gradient only
    assert smooth.mean() < flat.mean() / 5


def test_vertex_normals_area_weighted_and_cached():
    # vertex 0 is shared by a large face in the z = 0 plane and a small one in x = 0: the
    # area weighting tilts its normal towards +z
    m = Mesh([[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 1, 0], [0, 0, 1]],
             [[0, 1, 2], [0, 3, 4]])
    n = vertex_normals(m)
    assert n.dtype == np.float32 and n.shape == (5, 3) and not n.flags.writeable
    expect = np.array([1.0, 0.0, 16.0])  # (b − a) × (c − a): (1, 0, 0)·1 + (0, 0, 1)·16
    np.testing.assert_allclose(n[0], expect / np.linalg.norm(expect), rtol=1e-6)
    np.testing.assert_allclose(n[1], [0, 0, 1])
    assert vertex_normals(m) is n


def test_vertex_colors_interpolated_at_known_pixels():
    m = Mesh([[-0.8, -0.8, 0], [0.8, -0.8, 0], [-0.8, 0.8, 0]], [[0, 1, 2]])
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    w, h = 40, 30
    f = reference.render(m, IDENTITY, w, h, cull="none")
    img = shade(f, m, colors=colors, light_dir=HEAD_ON)
    for x, y in [(10, 20), (5, 5), (12, 12), (15, 25)]:
        assert f.triangle_id[y, x] == 0
        p = np.array([(x + 0.5) / w * 2 - 1, 1 - (y + 0.5) / h * 2])
        # analytic barycentrics of the pixel centre (w = 1: affine)
        b1 = (p[0] + 0.8) / 1.6
        b2 = (p[1] + 0.8) / 1.6
        b = np.array([1 - b1 - b2, b1, b2])
        expect = np.rint(b @ colors.astype(np.float64))
        assert np.abs(img[y, x].astype(int) - expect).max() <= 1, (x, y)
    # float colours in 0..1, and the same colours from a trimesh mesh's vertex colours
    np.testing.assert_array_equal(
        shade(f, m, colors=colors / 255.0, light_dir=HEAD_ON), img)
    tm = trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.faces), process=False,
                         vertex_colors=colors)
    np.testing.assert_array_equal(shade(f, tm, light_dir=HEAD_ON), img)
    np.testing.assert_array_equal(shade(f, tm, colors=False, light_dir=HEAD_ON),
                                  shade(f, m, light_dir=HEAD_ON))


def test_scene_mirrored_instance_outward_normals():
    m = sphere(3)
    shift = np.eye(4)
    shift[0, 3] = -1.3
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[0, 3] = 1.3  # x → 1.3 − x: the mirror image of the left sphere, winding flipped
    scene = Scene([(m, shift), (m, mirror)])
    eye = np.array([0.0, 0.0, 5.0])
    cam = Camera.look_at(eye=eye, target=(0, 0, 0))
    # cull "none": clraster culls by world winding, which a mirroring transform flips (with
    # "back" the mirrored sphere would show its inside), so draw both sides and let depth
    # pick the near one
    f = reference.render(scene, cam, 96, 48, cull="none")
    inst, _ = scene.split_ids(f.triangle_id)
    assert (inst == 0).sum() > 300 and (inst == 1).sum() > 300
    centres = np.array([[-1.3, 0, 0], [1.3, 0, 0]])
    for smooth in (False, True):
        n = pixel_normals(f, scene, smooth=smooth).astype(np.float64)
        for i in (0, 1):
            sel = inst == i
            # outward normals of the visible side point towards the eye: n·(eye − c) ≈ 5
            facing = n[sel] @ (eye - centres[i])
            assert facing.min() > 0.5, (smooth, i, facing.min())
            np.testing.assert_allclose(np.linalg.norm(n[sel], axis=1), 1.0, atol=1e-6)
    # one-sided light from the eye: both spheres lit the same, the image is symmetric
    for smooth in (False, True):
        img = shade(f, scene, light_dir=HEAD_ON, two_sided=False, smooth=smooth)
        g = img.astype(int)
        assert np.mean(np.abs(g - g[:, ::-1]) <= 2) > 0.99
        assert g[24, 19].min() > 180 and g[24, 76].min() > 180  # near the centres: bright


def test_per_instance_colors_array_and_callable():
    left = np.eye(4)
    left[:3, :3] *= 0.5
    left[0, 3] = -0.5
    right = left.copy()
    right[0, 3] = 0.5
    scene = Scene([(QUAD, left), (QUAD, right)])
    f = reference.render(scene, IDENTITY, 20, 10, cull="none")
    tints = np.array([[255, 0, 0], [0, 128, 255]], np.uint8)
    img = shade(f, scene, per_instance_colors=tints, light_dir=HEAD_ON)
    np.testing.assert_array_equal(img[5, 5], [255, 0, 0])
    np.testing.assert_array_equal(img[5, 15], [0, 128, 255])
    seen = []

    def pick(i, instance):
        seen.append(i)
        assert instance.mesh is QUAD
        return tints[i] / 255.0

    np.testing.assert_array_equal(shade(f, scene, per_instance_colors=pick,
                                        light_dir=HEAD_ON), img)
    assert sorted(seen) == [0, 1]
    # a texture shared by the instances (one mesh), tinted per instance
    tex = np.full((2, 2, 3), 128, np.uint8)
    both = shade(f, scene, texture=(QUAD_UV, tex), per_instance_colors=tints,
                 light_dir=HEAD_ON)
    np.testing.assert_array_equal(both[5, 5], [128, 0, 0])
    # per-instance textures as a list
    per = shade(f, scene, texture=[None, (QUAD_UV, tex)], light_dir=HEAD_ON)
    np.testing.assert_array_equal(per[5, 15], [128, 128, 128])
    np.testing.assert_array_equal(per[5, 5], shade(f, scene, light_dir=HEAD_ON)[5, 5])


def test_rgba_transparent_background():
    m = sphere(1)
    cam = Camera.look_at(eye=(0, 0, 3), target=(0, 0, 0))
    f = reference.render(m, cam, 32, 24)
    rgb = shade(f, m, smooth=True)
    rgba = shade(f, m, smooth=True, alpha=True)
    assert rgba.shape == (24, 32, 4) and rgba.dtype == np.uint8
    np.testing.assert_array_equal(rgba[..., :3], rgb)
    np.testing.assert_array_equal(rgba[..., 3], np.where(f.triangle_id >= 0, 255, 0))
    assert (rgba[..., 3] == 0).any() and (rgba[..., 3] == 255).any()


def test_ssaa_size_and_intermediate_edges():
    m = Mesh([[-0.9, -0.7, 0], [0.8, -0.9, 0], [-0.2, 0.85, 0]], [[0, 1, 2]])
    w, h = 40, 30
    renderer = reference.Renderer(w, h)
    one = render_shaded(renderer, m, IDENTITY, ssaa=1, light_dir=HEAD_ON, background=(0, 0, 0))
    f = renderer.render(m, IDENTITY)
    np.testing.assert_array_equal(one, shade(f, m, light_dir=HEAD_ON, background=(0, 0, 0)))
    fg = one[f.triangle_id >= 0][0].astype(int)  # flat, head-on: one colour
    assert set(np.unique(one[..., 0])) == {0, fg[0]}  # aliased: surface or background
    aa = render_shaded(renderer, m, IDENTITY, ssaa=4, light_dir=HEAD_ON, background=(0, 0, 0))
    assert aa.shape == (h, w, 3) and aa.dtype == np.uint8
    mid = (aa[..., 0] > 0) & (aa[..., 0] < fg[0])
    assert mid.sum() > 20  # the edges are blended
    assert (aa[..., 0] == fg[0]).sum() > 100 and (aa[..., 0] == 0).sum() > 100
    # coverage: the mean of the blended image is the triangle's area fraction
    area = 0.5 * abs((0.8 + 0.9) * (0.85 + 0.7) - (-0.2 + 0.9) * (-0.9 + 0.7)) / 4.0
    assert abs(aa[..., 0].mean() / fg[0] - area) < 0.01
    # a factory gives the same image
    again = render_shaded(lambda ww, hh: reference.Renderer(ww, hh), m, IDENTITY, ssaa=4,
                          width=w, height=h, light_dir=HEAD_ON, background=(0, 0, 0))
    np.testing.assert_array_equal(again, aa)
    # RGBA: partial alpha on edges, colour of the surface (straight alpha)
    rgba = render_shaded(renderer, m, IDENTITY, ssaa=4, light_dir=HEAD_ON, alpha=True)
    edge = (rgba[..., 3] > 0) & (rgba[..., 3] < 255)
    assert edge.sum() > 20
    np.testing.assert_array_equal(rgba[edge][:, :3], np.broadcast_to(fg, (edge.sum(), 3)))
    assert np.all(rgba[rgba[..., 3] == 0][:, :3] == 255)


def test_ssaa_keeps_a_size_dependent_camera_view():
    # a camera whose matrix depends on the pixel count is used with its 1× matrix at k×
    class PixelCamera:
        def view_projection(self, width, height):
            m = np.eye(4)
            m[0, 0] = 40.0 / width  # shrinks as the image grows
            return m

    m = Mesh([[-0.9, -0.7, 0], [0.8, -0.9, 0], [-0.2, 0.85, 0]], [[0, 1, 2]])
    renderer = reference.Renderer(40, 30)
    aa = render_shaded(renderer, m, PixelCamera(), ssaa=2, light_dir=HEAD_ON)
    ref = render_shaded(renderer, m, IDENTITY, ssaa=2, light_dir=HEAD_ON)
    np.testing.assert_array_equal(aa, ref)


@pytest.mark.parametrize("kw, match", [
    (dict(colors=np.zeros((2, 3))), r"colors must have shape \(4, 3\)"),
    (dict(colors=np.full((4, 3), 2.0)), r"\[0, 1\]"),
    (dict(colors=np.full((4, 3), 300)), r"0\.\.255"),
    (dict(texture=(np.zeros((3, 2)), np.zeros((2, 2, 3), np.uint8))), "uv has 3 rows"),
    (dict(texture=(QUAD_UV, np.zeros((2, 2, 5), np.uint8))), r"\(H, W, 3\)"),
    (dict(texture=(QUAD_UV * np.nan, np.zeros((2, 2, 3), np.uint8))), "finite"),
    (dict(texture="checker.png"), "texture must be"),
    (dict(per_instance_colors=np.zeros((2, 3))), r"per_instance_colors must have shape"),
    (dict(light=(0, 0, 1), light_dir=(0, 0, 1)), "once"),
])
def test_bad_colour_options(kw, match):
    f = reference.render(QUAD, IDENTITY, 4, 4, cull="none")
    with pytest.raises(ValueError, match=match):
        shade(f, QUAD, **kw)


def test_bad_scene_and_ssaa_options():
    other = Mesh(np.asarray(QUAD.vertices), np.asarray(QUAD.faces))
    scene = Scene([(QUAD, None), (other, None)])
    f = reference.render(scene, IDENTITY, 4, 4, cull="none")
    with pytest.raises(ValueError, match="ambiguous"):
        shade(f, scene, colors=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="one entry per instance"):
        shade(f, scene, colors=[np.zeros((4, 3))])
    with pytest.raises(ValueError, match="barycentrics"):
        shade(frame([[0]]), QUAD, smooth=True)
    renderer = reference.Renderer(4, 4)
    for bad in (0, 9, 2.0, True):
        with pytest.raises(ValueError, match="ssaa"):
            render_shaded(renderer, QUAD, IDENTITY, ssaa=bad)
    with pytest.raises(ValueError, match="width and height"):
        render_shaded(lambda w, h: reference.Renderer(w, h), QUAD, IDENTITY, ssaa=2)


def test_render_shaded_opencl_matches_reference(renderer_for):
    # the OpenCL renderer's supersampling renderer is made with its config and context
    m = sphere(2)
    cam = Camera.look_at(eye=(0.4, 0.3, 3.0), target=(0, 0, 0))
    cl_img = render_shaded(renderer_for(32, 24), m, cam, ssaa=2, smooth=True, alpha=True)
    ref_img = render_shaded(reference.Renderer(32, 24), m, cam, ssaa=2, smooth=True,
                            alpha=True)
    assert cl_img.shape == (24, 32, 4)
    # same ids; barycentrics agree to float32 rounding
    assert np.abs(cl_img.astype(int) - ref_img).max() <= 1


def test_trimesh_scene_colours_and_textures_per_geometry():
    import PIL.Image
    from trimesh.visual import TextureVisuals

    v, fa = np.asarray(QUAD.vertices) * 0.5, np.asarray(QUAD.faces)
    red = trimesh.Trimesh(v, fa, process=False, vertex_colors=[[255, 0, 0]] * 4)
    tex = np.zeros((2, 2, 3), np.uint8)
    tex[:, :, 1] = 200
    tex[1, :, 2] = 100  # bottom row of the image (v = 0) bluish
    textured = trimesh.Trimesh(v, fa, process=False, visual=TextureVisuals(
        uv=QUAD_UV, image=PIL.Image.fromarray(tex)))
    tm_scene = trimesh.Scene()
    tm_scene.add_geometry(red, geom_name="red", node_name="left",
                          transform=trimesh.transformations.translation_matrix([-0.5, 0, 0]))
    tm_scene.add_geometry(textured, geom_name="tex", node_name="right",
                          transform=trimesh.transformations.translation_matrix([0.5, 0, 0]))
    f = reference.render(tm_scene, IDENTITY, 40, 20, cull="none")
    img = shade(f, tm_scene, light_dir=HEAD_ON)
    scene = Scene.from_trimesh(tm_scene)
    names = scene.geometry_of(f.triangle_id)
    assert names[10, 10] == "red" and names[10, 30] == "tex"
    np.testing.assert_array_equal(img[10, 10], [255, 0, 0])
    np.testing.assert_array_equal(img[7, 30], [0, 200, 0])  # v = 0.75: top texel row
    np.testing.assert_array_equal(img[12, 30], [0, 200, 100])  # v = 0.25: bottom row
    plain = shade(f, tm_scene, colors=False, texture=False, light_dir=HEAD_ON)
    assert (plain[10, 10] == plain[10, 30]).all()
