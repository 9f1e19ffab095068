"""Watertightness on closed meshes.

For a closed, consistently wound mesh seen from outside, every ray through a pixel centre
enters the surface as often as it leaves it. With exact integer edge functions and the
top-left rule (which decides a centre on an edge or vertex as if it were nudged by the same
infinitesimal offset for every triangle), this holds *exactly* for the snapped triangles:

* the coverage of front faces only (cull="back"), back faces only (cull="front") and all
  faces (cull="none") are the same mask, pixel for pixel;
* front-face and back-face fragment counts are equal (each ray crosses as many of each);
* no background pixel is enclosed by covered ones (no pinholes);
* cull="none" depth is the minimum of the two culled depths, and its ids follow.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import NDC_CAMERA, assert_frames_equal, load_shared_mesh, render_both, render_cl

from clraster import Camera, Mesh

VIEWS = [(1.0, 0.6, 1.6), (0.0, 0.0, 1.0), (-1.0, -0.3, -0.2), (0.2, -1.0, 0.1)]


def pinholes(mask: np.ndarray) -> np.ndarray:
    """Background pixels whose four neighbours are all covered."""
    m = mask
    inner = np.zeros_like(m)
    inner[1:-1, 1:-1] = (~m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2]
                         & m[1:-1, 2:])
    return inner


def check_closed(mesh: Mesh, camera, w: int, h: int, min_covered: int) -> None:
    # without the tile Hi-Z, fragments_tested counts every covered pixel centre: the
    # crossings below (with it, a face behind its tile's farthest depth is not tested)
    fb = render_cl(mesh, camera, w, h, cull="back", hiz=False)
    ff = render_cl(mesh, camera, w, h, cull="front", hiz=False)
    fn = render_cl(mesh, camera, w, h, cull="none", hiz=False)
    assert fb.mask.sum() >= min_covered
    np.testing.assert_array_equal(fb.mask, fn.mask, err_msg="back-face culling changed coverage")
    np.testing.assert_array_equal(ff.mask, fn.mask, err_msg="front faces alone leave holes")
    assert fb.stats.fragments_tested == ff.stats.fragments_tested, (
        "front and back crossings differ: a crack or a double hit")
    assert fn.stats.fragments_tested == fb.stats.fragments_tested + ff.stats.fragments_tested
    holes = pinholes(fb.mask)
    assert not holes.any(), f"pinholes at {np.argwhere(holes)[:10].tolist()}"
    # cull="none" is the depth-min of its two halves; ties go to the lower face index
    np.testing.assert_array_equal(fn.depth, np.minimum(fb.depth, ff.depth))
    exp_id = np.where(fb.depth < ff.depth, fb.triangle_id,
                      np.where(ff.depth < fb.depth, ff.triangle_id,
                               np.minimum(fb.triangle_id, ff.triangle_id)))
    exp_id = np.where(fn.mask, exp_id, -1)
    np.testing.assert_array_equal(fn.triangle_id, exp_id)
    # every visible face with cull="back" is front-facing: it is also culled with "front"
    vis = fb.visible_faces()
    assert np.intersect1d(vis, ff.visible_faces()).size == 0


@pytest.mark.parametrize("name, size", [("spot.ply", (160, 120)), ("igea.ply", (256, 200))])
@pytest.mark.parametrize("view", VIEWS)
def test_shared_mesh_watertight(name, size, view):
    mesh = load_shared_mesh(name)
    w, h = size
    lo, hi = mesh.bounds()
    cam = Camera.framing(lo, hi, direction=view, aspect=w / h)
    check_closed(mesh, cam, w, h, min_covered=w * h // 10)
    assert render_cl(mesh, cam, w, h).stats.clipped == 0  # framing never needs the clipper


@pytest.mark.parametrize("name", ["spot.ply", "igea.ply"])
def test_shared_mesh_matches_twin(name):
    mesh = load_shared_mesh(name)
    w, h = 129, 96
    lo, hi = mesh.bounds()
    cam = Camera.framing(lo, hi, direction=(0.3, 0.2, 1.0), aspect=w / h)
    for cull in ("back", "none"):
        a, b = render_both(mesh, cam, w, h, cull=cull, tile_log2=5)
        assert_frames_equal(a, b, f"{name} cull={cull}")
        assert a.mask.sum() > 1000


@pytest.mark.parametrize("scale, subdiv", [((3e5, 0.8, 0.5), 3), ((0.7, 4e6, 0.4), 2),
                                            ((0.9, 0.9, 0.5), 4)])
def test_stretched_sphere_through_guard_band(scale, subdiv):
    """A closed icosphere seen through an identity clip matrix, stretched so that most
    triangles leave the guard band (±2**19 px): the guard-band clipper must keep it
    watertight. (z stays inside ±1: no near/far clipping.)"""
    sphere = trimesh.creation.icosphere(subdivisions=subdiv)
    assert sphere.is_watertight and sphere.volume > 0
    mesh = Mesh(sphere.vertices * np.array(scale), sphere.faces)
    w, h = 64, 48
    check_closed(mesh, NDC_CAMERA, w, h, min_covered=w * h // 4)
    st = render_cl(mesh, NDC_CAMERA, w, h, cull="none").stats
    if max(scale) > 1e4:
        assert st.clipped > 0
    a, b = render_both(mesh, NDC_CAMERA, w, h, cull="back")
    assert_frames_equal(a, b, f"sphere {scale}")


@pytest.mark.parametrize("sections", [7, 24])
def test_inside_closed_tube_near_clipped_is_crack_free(sections):
    """The camera inside a closed cylinder, looking along its axis: the long side faces
    run from behind the eye to far ahead, so they are cut by the near plane (some vertices
    have w < 0); every ray still meets the inside of the tube beyond the near plane, so every
    pixel must be covered, by back faces only."""
    tube = trimesh.creation.cylinder(radius=1.0, height=10.0, sections=sections)
    assert tube.is_watertight and tube.volume > 0
    mesh = Mesh(tube.vertices, tube.faces)
    w, h = 64, 48
    cam = Camera.look_at((0.05, -0.1, 1.0), (0.1, 0.0, -4.0), fov_y=80.0, near=0.3, far=20.0)
    inside = render_cl(mesh, cam, w, h, cull="front")
    assert inside.mask.all(), f"{(~inside.mask).sum()} uncovered pixels"
    assert inside.stats.clipped > 0 and inside.stats.clip_pieces > 0
    assert not render_cl(mesh, cam, w, h, cull="back").mask.any()
    none = render_cl(mesh, cam, w, h, cull="none")
    np.testing.assert_array_equal(none.triangle_id, inside.triangle_id)
    assert_frames_equal(*render_both(mesh, cam, w, h, cull="front"), f"tube {sections}")
