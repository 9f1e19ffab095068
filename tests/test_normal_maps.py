"""Tangent-space normal maps (`clraster.output.textures`: tangents from UVs, glTF's
convention) on a quad, against the analytic Lambert shading of the mapped normal."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

import clraster
from clraster.output.shade import render_shaded
from clraster.output.textures import NormalMap, vertex_tangents

W, H = 64, 48
QUAD_V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)   # faces +z
QUAD_F = np.array([[0, 1, 2], [0, 2, 3]])
CAMERA = clraster.Camera.look_at((0, 0, 3), (0, 0, 0), fov_y=60.0)
ALBEDO = np.array([0.80, 0.82, 0.88])
AMBIENT = 0.22


def encoded(n) -> np.ndarray:
    """A 4×4 map holding the tangent-space normal `n` (float RGB)."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    return np.tile((n + 1.0) / 2.0, (4, 4, 1))


def expected(normal_world, towards, albedo=ALBEDO) -> np.ndarray:
    lam = abs(np.dot(normal_world, towards / np.linalg.norm(towards)))
    return np.rint(albedo * (AMBIENT + (1 - AMBIENT) * lam) * 255)


# uv layouts: u along +x, v along +y (the usual); u along +y, v along −x (rotated);
# u along −x, v along +y (mirrored: the bitangent flips with the handedness)
LAYOUTS = {
    "plain": (np.array([[0, 0], [1, 0], [1, 1], [0, 1]]), (1, 0, 0), (0, 1, 0)),
    "rotated": (np.array([[0, 1], [0, 0], [1, 0], [1, 1]]), (0, 1, 0), (-1, 0, 0)),
    "mirrored": (np.array([[1, 0], [0, 0], [0, 1], [1, 1]]), (-1, 0, 0), (0, 1, 0)),
}


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
@pytest.mark.parametrize("tangent_normal", [(0.5, 0.0, 0.8), (0.0, -0.6, 0.7)])
def test_constant_map_gives_the_analytic_shading(layout, tangent_normal):
    uv, t, b = LAYOUTS[layout]
    t, b = np.array(t, float), np.array(b, float)
    mesh = clraster.Mesh(QUAD_V, QUAD_F)
    tan = vertex_tangents(mesh.vertices, mesh.faces, uv.astype(float))
    np.testing.assert_allclose(tan[:, :3], np.tile(t, (4, 1)), atol=1e-12)
    nmap = NormalMap.make(uv, encoded(tangent_normal))
    tn = np.asarray(tangent_normal) / np.linalg.norm(tangent_normal)
    world = tn[0] * t + tn[1] * b + tn[2] * np.array([0.0, 0.0, 1.0])
    towards = np.array([0.6, 0.3, 0.7])
    img = render_shaded(clraster.Renderer(W, H), mesh, CAMERA, normal_map=nmap,
                        light=towards)
    ids = clraster.Renderer(W, H).render(mesh, CAMERA).triangle_id
    got = img[ids >= 0].astype(float)
    # the image is bilinear in a constant map: every covered pixel the same colour
    np.testing.assert_allclose(got, np.broadcast_to(expected(world, towards), got.shape),
                               atol=1.0)
    flat = render_shaded(clraster.Renderer(W, H), mesh, CAMERA, light=towards)
    assert np.abs(flat[ids >= 0].astype(float) - got).max() > 5   # the map changed it


def test_gltf_normal_texture_through_trimesh(tmp_path):
    uv = LAYOUTS["plain"][0].astype(float)
    tex = (encoded((0.5, 0.0, 0.8)) * 255).round().astype(np.uint8)
    material = trimesh.visual.material.PBRMaterial(normalTexture=Image.fromarray(tex))
    tm = trimesh.Trimesh(QUAD_V, QUAD_F, process=False,
                         visual=trimesh.visual.TextureVisuals(uv=uv, material=material))
    path = tmp_path / "quad.glb"
    tm.export(path)
    loaded = trimesh.load(path, force="mesh")
    towards = np.array([0.6, 0.3, 0.7])
    r = clraster.Renderer(W, H)
    with_map = render_shaded(r, loaded, CAMERA, light=towards)
    without = render_shaded(r, loaded, CAMERA, light=towards, normal_map=False)
    ids = r.render(loaded, CAMERA).triangle_id
    n = (tex[0, 0] / 255.0) * 2 - 1
    world = n / np.linalg.norm(n)
    white = np.ones(3)   # the material's base colour (no texture, factor 1)
    np.testing.assert_allclose(with_map[ids >= 0].astype(float),
                               np.broadcast_to(expected(world, towards, white),
                                               with_map[ids >= 0].shape), atol=1.5)
    np.testing.assert_allclose(without[ids >= 0].astype(float),
                               np.broadcast_to(expected([0, 0, 1.0], towards, white),
                                               without[ids >= 0].shape), atol=1.0)


def test_bad_normal_map():
    with pytest.raises(ValueError, match="normal_map"):
        render_shaded(clraster.Renderer(W, H), clraster.Mesh(QUAD_V, QUAD_F), CAMERA,
                      normal_map="bumpy")
    with pytest.raises(ValueError, match="uv"):
        NormalMap.make(np.zeros((3, 2)), encoded((0, 0, 1)), n_vertices=4)
