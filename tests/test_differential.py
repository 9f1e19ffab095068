"""Differential tests: the OpenCL pipeline against its NumPy twin, on random triangle soups.

Every example draws an image size on both sides of a power of two (2^k − 1, 2^k, 2^k + 1,
k in 4..7, width and height independent), a tile size (8..64 px), a cull mode, a lens and a
seed; the seed generates a soup of `TRIS_PER_EXAMPLE` triangles of every kind in
random_scenes.KINDS (slivers, specks, huge, near/far-crossing, w ≤ 0, behind the eye,
degenerate, duplicates, connected grids through the near plane), and Hypothesis adds a few
triangles of its own from "interesting" coordinates (0, ±near, tiny offsets, NaN/Inf).
The twin does the same float32 operations in the same order, so ids and depth must be
identical and all stat counts equal.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import (
    TILE_LOG2S,
    MatrixCamera,
    assert_frames_equal,
    get_renderer,
    render_both,
    render_cl,
)
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from random_scenes import KINDS, Lens, _eye_point, random_soup, random_view, to_world

from clraster import Mesh

TRIS_PER_EXAMPLE = 2500
EXAMPLES = 44
#: Default-run floor on random triangles compared triangle by triangle (counted, see below).
MIN_TRIANGLES = 100_000

SIZES = st.builds(lambda kw, dw, kh, dh: ((1 << kw) + dw, (1 << kh) + dh),
                  st.integers(4, 7), st.sampled_from([-1, 0, 1]),
                  st.integers(4, 7), st.sampled_from([-1, 0, 1]))
LENSES = st.builds(Lens, st.sampled_from([20.0, 60.0, 90.0, 150.0]),
                   st.sampled_from([0.01, 0.5, 2.0]), st.sampled_from([10.0, 1000.0]))

_INTERESTING = st.one_of(
    st.floats(-4.0, 4.0, allow_nan=False, width=32),
    st.sampled_from([0.0, -1.0, 1.0, -1e-7, 1e-7, -0.5, 1e-30, 3.0e4]),
)
#: A hand-made eye-space triangle in units of the near distance; rarely a NaN/Inf vertex.
EXTRA_TRIANGLE = st.tuples(*([_INTERESTING] * 9)).map(lambda t: np.reshape(t, (3, 3)))
NONFINITE = st.sampled_from([math.nan, math.inf, -math.inf])


def _scene(seed: int, size, lens: Lens, extras, bad, world_view: bool):
    w, h = size
    rng = np.random.default_rng(seed)
    v, f, kinds = random_soup(rng, TRIS_PER_EXAMPLE, w, h, lens)
    if extras:
        ev = np.concatenate(extras) * lens.near
        if bad is not None:
            ev[0, 0] = bad
        f = np.concatenate([np.arange(ev.shape[0]).reshape(-1, 3), f + ev.shape[0]])
        v = np.concatenate([ev, v])
    view = random_view(rng) if world_view else np.eye(4)
    cam = MatrixCamera(lens.projection(w / h) @ view)
    return Mesh(to_world(v, view), f), cam, kinds


_counted = {"triangles": 0, "examples": 0, "clipped": 0, "pieces": 0, "fragments": 0,
            "hiz_skipped": 0}


# No shrinking: a seed drives the whole soup, so shrinking cannot simplify it much and takes
# minutes; the failure message names the example (seed, size, tile size, cull, lens).
@settings(deadline=None, max_examples=EXAMPLES, derandomize=True, database=None,
          phases=(Phase.explicit, Phase.generate), suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), size=SIZES, tile_log2=st.sampled_from(TILE_LOG2S),
       cull=st.sampled_from(["back", "front", "none"]), lens=LENSES,
       extras=st.lists(EXTRA_TRIANGLE, max_size=6), bad=st.one_of(st.none(), NONFINITE),
       world_view=st.booleans())
def _differential(seed, size, tile_log2, cull, lens, extras, bad, world_view):
    mesh, cam, _ = _scene(seed, size, lens, extras, bad, world_view)
    a, b = render_both(mesh, cam, *size, cull=cull, tile_log2=tile_log2)
    ctx = f"seed={seed} size={size} tile_log2={tile_log2} cull={cull} lens={lens}"
    assert_frames_equal(a, b, ctx + f" world_view={world_view}")
    # barycentrics bit for bit: the raster's scalar and 8-lane resolves (raster.cl
    # resolve1 / resolve8 / resolve8_mixed) do the twin's float32 operations in its order
    np.testing.assert_array_equal(a.barycentrics.view(np.uint32),
                                  b.barycentrics.view(np.uint32), err_msg=ctx)
    s = a.stats
    assert s.triangles_in == mesh.n_faces
    # the tile Hi-Z (on above, on both sides) never changes the image; without it every
    # covered fragment is tested
    c = render_cl(mesh, cam, *size, cull=cull, tile_log2=tile_log2, hiz=False)
    assert_frames_equal(a, c, "tile Hi-Z on/off", bary_atol=0.0, check_counts=False)
    ca, cc = s.counts(), c.stats.counts()
    assert ca.pop("fragments_tested") <= cc.pop("fragments_tested")
    assert ca == cc
    _counted["triangles"] += mesh.n_faces
    _counted["examples"] += 1
    _counted["clipped"] += s.clipped
    _counted["pieces"] += s.clip_pieces
    _counted["fragments"] += c.stats.fragments_tested
    _counted["hiz_skipped"] += c.stats.fragments_tested - s.fragments_tested


def test_random_soups_match_twin():
    """≥ 100,000 random triangles, OpenCL vs twin, exact ids/depth/counts (the fragments
    the tile Hi-Z skips included)."""
    for k in _counted:
        _counted[k] = 0
    _differential()
    # the soup really exercised what it claims to (not vacuous)
    assert _counted["triangles"] >= MIN_TRIANGLES, _counted
    assert _counted["clipped"] > 1000 and _counted["pieces"] > 1000, _counted
    assert _counted["fragments"] > 1_000_000, _counted
    # ... and the tile Hi-Z skipped a good share of them, the twin agreeing on each count
    assert _counted["hiz_skipped"] > 100_000, _counted
    print(f"differential: {_counted}")


def test_soup_has_every_kind():
    """The generator makes every kind of triangle the differential test relies on."""
    rng = np.random.default_rng(1)
    lens = Lens(60.0, 0.5, 100.0)
    v, f, kinds = random_soup(rng, TRIS_PER_EXAMPLE, 65, 33, lens)
    assert f.shape == (TRIS_PER_EXAMPLE, 3) and f.max() < v.shape[0]
    assert set(np.unique(kinds)) == set(range(len(KINDS)))
    z = v[:, 2]
    assert (z == 0.0).any(), "some vertex at w = 0"
    assert (z > 0.0).any(), "some vertex behind the eye"
    assert (z == -lens.near).any(), "some vertex exactly on the near plane"
    a = Mesh(v, f)
    frame = render_cl(a, MatrixCamera(lens.projection(65 / 33)), 65, 33, cull="none")
    s = frame.stats
    assert s.clipped > 50 and s.trivially_rejected > 50 and s.degenerate > 50
    assert s.no_sample > 50 and s.rasterized > 500


def _large_triangles(kind: str, w: int, h: int, lens: Lens) -> Mesh:
    """A few triangles far larger than a tile (eye space): most tiles' lists are one piece
    covering them, which the raster draws without its tile buffers (raster.cl
    sole_piece_tile)."""
    near, far = lens.near, lens.far

    def p(px, py, d):
        return _eye_point(px * w, py * h, d * near, w, h, lens)

    if kind == "quad":   # slanted, past the image's edges on every side
        v = [p(-0.3, -0.2, 3), p(1.3, -0.25, 8), p(1.35, 1.2, 20), p(-0.2, 1.3, 5)]
        f = [[0, 3, 2], [0, 2, 1]]
    elif kind == "inside":   # inside the image: partial tiles along every edge
        v = [p(0.05, 0.1, 2), p(0.9, 0.2, 4), p(0.3, 0.95, 3)]
        f = [[0, 2, 1]]
    elif kind == "near":   # through the near plane: clipped pieces (parent barycentrics)
        v = [p(0.5, -0.5, 0.25), p(-0.4, 1.1, 6), p(1.4, 1.2, 9)]
        f = [[0, 1, 2]]
    elif kind == "far":   # through the far plane
        v = [p(-0.2, 0.1, 2), p(1.3, 0.0, far / near * 1.5), p(0.4, 1.2, far / near * 0.999)]
        f = [[0, 1, 2]]
    else:   # "farthest": just inside the far plane, at a depth that rounds to 1 (the clear
        # value, which nothing beats: tested, never passing)
        d = far / near * (1.0 - 1e-7)
        v = [p(-0.2, -0.1, d), p(1.3, 0.0, d), p(0.4, 1.2, d)]
        f = [[0, 1, 2]]
    return Mesh(np.array(v, dtype=np.float64), np.array(f))


@pytest.mark.parametrize("kind", ["quad", "inside", "near", "far", "farthest"])
@pytest.mark.parametrize("size", [(131, 77), (200, 120)])
def test_large_triangles_match_twin(kind, size):
    """Triangles far larger than a tile, at every tile size, with and without the tile
    Hi-Z, both windings: OpenCL and twin identical (ids, depth, barycentrics bit for bit,
    counts), and depth and ids the same without barycentrics."""
    w, h = size
    lens = Lens(70.0, 0.5, 40.0)
    mesh = _large_triangles(kind, w, h, lens)
    cam = MatrixCamera(lens.projection(w / h))
    for faces in (mesh.faces, mesh.faces[:, ::-1]):
        m = Mesh(mesh.vertices, np.ascontiguousarray(faces))
        for t in TILE_LOG2S:
            for hiz in (True, False):
                a, b = render_both(m, cam, w, h, cull="none", tile_log2=t, hiz=hiz)
                ctx = f"{kind} size={size} tile_log2={t} hiz={hiz}"
                if kind != "farthest":
                    assert (a.triangle_id >= 0).mean() > 0.15, ctx   # large, as claimed
                assert_frames_equal(a, b, ctx)
                np.testing.assert_array_equal(a.barycentrics.view(np.uint32),
                                              b.barycentrics.view(np.uint32), err_msg=ctx)
                lean = get_renderer(w, h, t, hiz).render(m, cam, cull="none",
                                                         outputs=("depth", "ids"))
                np.testing.assert_array_equal(lean.triangle_id, a.triangle_id, err_msg=ctx)
                np.testing.assert_array_equal(lean.depth, a.depth, err_msg=ctx)
    if kind == "far":   # the far plane really cuts it
        assert a.stats.clipped >= 1
    if kind == "farthest":   # covered, tested, and not drawn
        assert a.stats.fragments_tested > w * h // 4 and a.stats.fragments_passed == 0


@pytest.mark.parametrize("size", [(127, 65), (33, 17), (64, 129)])
def test_tile_size_does_not_change_output(size):
    """The same scene at tile_log2 3, 4, 5, 6 on the OpenCL side: identical images and,
    without the tile Hi-Z, identical counts except binned_entries (which depends on the
    tile size by design). With it (the default), the same images again; only
    fragments_tested may change (a tile's farthest depth depends on the tile), and it is
    never more than without."""
    w, h = size
    rng = np.random.default_rng(w * 1000 + h)
    lens = Lens(75.0, 0.3, 300.0)
    v, f, _ = random_soup(rng, 4000, w, h, lens)
    mesh = Mesh(v, f)
    cam = MatrixCamera(lens.projection(w / h))
    for cull in ("back", "none"):
        frames = [render_cl(mesh, cam, w, h, cull=cull, tile_log2=t, hiz=False)
                  for t in TILE_LOG2S]
        base = frames[0]
        assert (base.triangle_id >= 0).sum() > w * h // 4
        for t, fr in zip(TILE_LOG2S[1:], frames[1:], strict=True):
            assert_frames_equal(base, fr, f"tile_log2 3 vs {t} cull={cull}", bary_atol=0.0,
                                check_counts=False)
            ca, cb = base.stats.counts(), fr.stats.counts()
            ca.pop("binned_entries")
            cb.pop("binned_entries")
            assert ca == cb
        # smaller tiles never bin fewer entries
        entries = [fr.stats.binned_entries for fr in frames]
        assert entries == sorted(entries, reverse=True)
        for t, off in zip(TILE_LOG2S, frames, strict=True):
            on = render_cl(mesh, cam, w, h, cull=cull, tile_log2=t)
            assert_frames_equal(off, on, f"tile Hi-Z tile_log2 {t} cull={cull}",
                                bary_atol=0.0, check_counts=False)
            ca, cb = off.stats.counts(), on.stats.counts()
            assert cb["fragments_tested"] <= ca.pop("fragments_tested")
            cb.pop("fragments_tested")
            assert ca == cb


def test_repeated_renders_reuse_buffers():
    """A renderer reused across frames of different sizes of input gives the same frames as
    the twin each time (grown device buffers, stale contents must not leak)."""
    w, h = 65, 33
    lens = Lens(60.0, 0.5, 50.0)
    cam = MatrixCamera(lens.projection(w / h))
    meshes = []
    for seed, n in ((11, 3000), (12, 10), (13, 1500), (14, 1)):
        v, f, _ = random_soup(np.random.default_rng(seed), n, w, h, lens)
        meshes.append(Mesh(v, f))
    for rep in range(2):
        for i, mesh in enumerate(meshes):
            a, b = render_both(mesh, cam, w, h, cull="back", tile_log2=4)
            assert_frames_equal(a, b, f"mesh {i} repetition {rep}")
