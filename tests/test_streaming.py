"""Streamed frames (clraster.streaming): a frame drawn in bounded batches is the unbatched
frame, bit for bit, and the renderer's memory stays within the budget's bound.

* Tiny triangle budgets (128 = one cluster, 300, 1000) and tiny bin-entry budgets, odd image
  sizes, a camera whose near plane cuts the mesh (clipped pieces), occlusion culling,
  overdraw and cluster fates: ids, depth, barycentrics, overdraw and every FrameStats count
  equal the frame of a budget larger than the scene — on shared meshes, random scenes and
  a 200K-triangle plant. A spy on the stage chain checks that the frame really was split.
* The NumPy twin streams with the same batching function: same images and counts.
* 2,000 full-screen quads at 640x480 with a small entry budget: every pixel shows the
  nearest quad, and no device buffer exceeds what the budget allows (GrowBuffer
  capacities); after a frame with one outsized draw the buffers are back under the bound.
* `stream_draws` alone, on fake passes: batches in draw order, within the budget, split
  and retried (never dropped) when the entries overflow.
* Frame buffers that cannot fit the device fail in the constructor, naming size and limit.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import NDC_CAMERA, assert_frames_equal, load_shared_mesh

import clraster
from clraster import Camera, Mesh, RasterConfig, Renderer
from clraster.base.layout import DRAW_DTYPE, PIECE_DTYPE
from clraster.pipeline import reference
from clraster.pipeline.draws import FrameDraws
from clraster.pipeline.params import BinBudgetExceeded
from clraster.pipeline.streaming import draw_range, stream_draws
from clraster.world.generators import plant, plant_inside_camera, random_scene

#: A budget larger than any scene here: the unbatched frame.
UNBATCHED = RasterConfig(tile_log2=4, batch_triangles=2**31 - 1, batch_entries=2**31 - 1)


def _config(tris: int, entries: int = 2**31 - 1) -> RasterConfig:
    # 16 px tiles: the entry budgets and counts of these tests were chosen for them (a
    # full-screen quad makes ~16x as many entries as with the default 64 px tiles)
    return RasterConfig(tile_log2=4, batch_triangles=tris, batch_entries=entries)


def _passes(renderer: Renderer) -> list[int]:
    """Spy on renderer.chain.draw: the list fills with each successful pass's triangles."""
    seen: list[int] = []
    real = renderer.chain.draw

    def draw(queue, pool, fd, *a, **kw):
        out = real(queue, pool, fd, *a, **kw)
        seen.append(fd.n_tris)
        return out

    renderer.chain.draw = draw
    return seen


def _check(target, camera, width, height, config, *, occlusion=False, cull="back",
           frames=1, context=""):
    """Render ``frames`` frames with a fresh batched and a fresh unbatched renderer (the
    occlusion history must match too) and compare everything; returns the pass sizes."""
    a = Renderer(width, height, config=UNBATCHED)
    b = Renderer(width, height, config=config)
    passes = _passes(b)
    for k in range(frames):
        kw = dict(cull=cull, occlusion=occlusion, overdraw=True, fates=True)
        fa, fb = a.render(target, camera, **kw), b.render(target, camera, **kw)
        ctx = f"{context} {config} frame {k}"
        assert_frames_equal(fb, fa, ctx, bary_atol=0.0)
        np.testing.assert_array_equal(fb.overdraw, fa.overdraw, err_msg=ctx)
        for name in ("instance", "cluster", "fate"):
            np.testing.assert_array_equal(getattr(fb.fates, name), getattr(fa.fates, name),
                                          err_msg=ctx)
    assert max(passes) <= max(config.batch_triangles, 128)
    return passes


def _clipping_camera(mesh: Mesh) -> Camera:
    """A camera whose near plane cuts through the mesh (clipped triangles)."""
    lo, hi = mesh.bounds()
    c = 0.5 * (lo + hi)
    size = float(np.max(hi - lo))
    eye = c + np.array([0.0, 0.1, 0.9]) * size
    return Camera.look_at(eye, c, fov_y=60.0, near=0.75 * size, far=4.0 * size)


@pytest.mark.parametrize("tris,entries", [(128, 2**31 - 1), (300, 400), (1000, 2000),
                                          (1000, 50)])
@pytest.mark.parametrize("occlusion", [False, True])
def test_shared_mesh_batches_equal_unbatched(tris, entries, occlusion):
    mesh = load_shared_mesh("stanford_dragon_res4.ply")   # 11K triangles
    w, h = 203, 131
    cam = Camera.framing(*mesh.bounds(), aspect=w / h)
    passes = _check(mesh, cam, w, h, _config(tris, entries), occlusion=occlusion,
                    frames=2 if occlusion else 1, context="dragon res4")
    assert len(passes) >= mesh.faces.shape[0] // max(tris, 1) // (2 if occlusion else 1)


@pytest.mark.parametrize("tris,entries", [(128, 100), (1000, 3000)])
def test_clipped_mesh_batches_equal_unbatched(tris, entries):
    mesh = load_shared_mesh("stanford_bunny.ply")
    w, h = 257, 97
    cam = _clipping_camera(mesh)
    ref = Renderer(w, h, config=UNBATCHED).render(mesh, cam, cull="none")
    assert ref.stats.clipped > 0 and ref.stats.clip_pieces > 0   # the near plane cuts it
    _check(mesh, cam, w, h, _config(tris, entries), cull="none", context="bunny clipped")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_scene_batches_equal_unbatched(seed):
    scene = random_scene(seed, 48, extent=3.0, mirrors=seed == 1)
    cam = Camera.look_at((0.5, 0.8, 2.0), (0.0, 0.0, -1.0), near=0.3, far=30.0)
    w, h = 161, 119
    for tris, entries in ((128, 64), (300, 2**31 - 1), (1000, 500)):
        for occlusion in (False, True):
            _check(scene, cam, w, h, _config(tris, entries), occlusion=occlusion,
                   frames=2 if occlusion else 1, context=f"random scene {seed}")


def test_plant_batches_equal_unbatched():
    scene = plant(200_000)
    w, h = 320, 181
    cam = plant_inside_camera(scene, w, h)
    passes = _check(scene, cam, w, h, _config(4096, 20_000), occlusion=True, frames=2,
                    context="plant 200K")
    assert len(passes) > 4


def test_twin_streams_like_the_renderer():
    mesh = load_shared_mesh("suzanne.ply")
    w, h = 97, 71
    cam = _clipping_camera(mesh)
    cfg = _config(128, 200)
    whole = reference.render(mesh, cam, w, h, cull="none", config=UNBATCHED)
    batched = reference.render(mesh, cam, w, h, cull="none", config=cfg)
    assert_frames_equal(batched, whole, "twin batched vs unbatched", bary_atol=0.0)
    device = Renderer(w, h, config=cfg).render(mesh, cam, cull="none")
    assert_frames_equal(device, batched, "OpenCL vs twin, both batched")


def _quads(n: int, seed: int = 1) -> tuple[Mesh, np.ndarray]:
    """n full-screen quads (2 triangles each) at distinct NDC depths, in random order, for
    NDC_CAMERA; and their depths."""
    z = np.random.default_rng(seed).permutation(np.linspace(-0.9, 0.9, n))
    v = np.zeros((n, 4, 3))
    v[:, :, 0] = [-1, 1, 1, -1]
    v[:, :, 1] = [-1, -1, 1, 1]
    v[:, :, 2] = z[:, None]
    f = (np.arange(n)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])).reshape(-1, 3)
    return Mesh(v.reshape(-1, 3), f), z


def _assert_bounded(r: Renderer) -> None:
    for gb, bound in r.chain.budget_bounds().items():
        assert gb.capacity <= max(bound, 256), (gb.capacity, bound)


def test_full_screen_quads_small_entry_budget():
    """2,000 full-screen quads (2.5M bin entries): passes of at most 200K entries."""
    w, h = 640, 480
    mesh, z = _quads(2000)
    cfg = _config(1 << 20, 200_000)
    r = Renderer(w, h, config=cfg)
    passes = _passes(r)
    fr = r.render(mesh, NDC_CAMERA, cull="none")
    assert len(passes) >= 12   # 2.5M entries / 200K
    assert fr.stats.binned_entries > 2_000_000
    near = int(np.argmin(z))
    assert np.all(fr.triangle_id // 2 == near)
    assert np.abs(fr.depth - (z[near] + 1) / 2).max() < 1e-6
    _assert_bounded(r)
    assert r.chain.binning.buffers.entries.capacity <= PIECE_DTYPE.itemsize * 200_000


def test_buffers_shrink_after_outsized_draw():
    """One cluster of 64 full-screen quads needs ~80K bin entries, far over a 2,000-entry
    budget: it is drawn alone (never refused), and the bin list it grew is released after
    the frame."""
    w, h = 320, 240
    cfg = _config(128, 2_000)
    r = Renderer(w, h, config=cfg)
    big, z = _quads(64)
    fr = r.render(big, NDC_CAMERA, cull="none")
    assert np.all(fr.triangle_id // 2 == int(np.argmin(z)))
    assert fr.stats.binned_entries > 2_000
    _assert_bounded(r)
    small = Mesh(np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]]),
                 np.array([[0, 1, 2]]))
    r.render(small, NDC_CAMERA)
    _assert_bounded(r)
    assert r.chain.device_bytes() < 4 * 2**20


# -- the batching function alone ------------------------------------------------------------

def _fake_draws(tris: list[int]) -> FrameDraws:
    d = np.zeros(len(tris), DRAW_DTYPE)
    t = np.asarray(tris, np.int64)
    d["tri_base"] = np.cumsum(t) - t
    d["vert_base"] = 2 * d["tri_base"]
    d["cluster"] = np.arange(len(tris))
    return FrameDraws(d, int(2 * t.sum()), int(t.sum()), np.zeros((1, 16), np.float32),
                      np.zeros((1, 16)), np.zeros((1, 4)))


@pytest.mark.parametrize("max_tris,max_entries", [(128, 10**9), (300, 10**9), (1000, 700),
                                                  (1000, 1)])
def test_stream_draws_covers_every_draw_in_order(max_tris, max_entries):
    rng = np.random.default_rng(max_tris + max_entries)
    tris = rng.integers(1, 129, 300).tolist()
    entries = rng.integers(0, 40, 300)   # bin entries of each draw
    fd = _fake_draws(tris)
    drawn: list[int] = []
    refused = 0

    def one_pass(batch, limit, into):
        nonlocal refused
        assert batch.draws["tri_base"][0] == 0 and batch.draws["vert_base"][0] == 0
        assert batch.n_tris == int(sum(tris[c] for c in batch.draws["cluster"]))
        assert batch.n_tris <= max_tris or batch.draws.size == 1
        need = int(entries[batch.draws["cluster"]].sum())
        if limit is not None and need > limit:
            refused += 1
            raise BinBudgetExceeded(need, limit)
        assert limit is None or limit == max_entries
        drawn.extend(batch.draws["cluster"].tolist())
        return (into or 0) + 1

    n_passes = stream_draws(fd, max_tris, max_entries, one_pass)
    assert drawn == list(range(300))   # every draw once, in order
    assert n_passes >= sum(tris) // max_tris
    if max_entries == 1:
        assert refused > 0


def test_draw_range_rebases():
    fd = _fake_draws([5, 7, 9, 11])
    sub = draw_range(fd, 1, 3)
    assert sub.n_tris == 16 and sub.n_verts == 32
    assert sub.draws["tri_base"].tolist() == [0, 7]
    assert sub.draws["vert_base"].tolist() == [0, 14]
    assert draw_range(fd, 2, 2).n_tris == 0


# -- configuration and bad input -------------------------------------------------------------

@pytest.mark.parametrize("kw", [{"batch_triangles": 127}, {"batch_triangles": 2**31},
                                {"batch_entries": 0}, {"batch_entries": 1.5},
                                {"batch_triangles": True}])
def test_budget_validated(kw):
    with pytest.raises(ValueError, match="batch_"):
        RasterConfig(**kw)


class _SmallDevice:
    name = "a small device"
    max_mem_alloc_size = 64 * 2**20
    global_mem_size = 80 * 2**20


def test_frame_that_cannot_fit_fails_before_allocating(monkeypatch):
    from clraster.pipeline import renderer as renderer_mod

    ctx = clraster.device.default_context()
    monkeypatch.setattr(renderer_mod, "StageChain", None)   # nothing may be built
    # (PoCL's per-buffer limit is a share of the machine's memory: with 4 GiB or more the
    # largest image fits, and only the small device below is refused)
    if 12 * 16384 * 16384 > ctx.devices[0].max_mem_alloc_size:
        with pytest.raises(ValueError, match=r"16384x16384 needs a 3,072 MiB barycentric "
                                             r"buffer.*allocates at most"):
            Renderer(16384, 16384, context=ctx)
    # every frame array counts: 2400x2400 has 66 MiB of barycentrics (over 64 MiB), and
    # 2000x2000's 46 MiB fit one buffer but not the 80 MiB of depth + ids + barycentrics
    # + overdraw + tile buffers
    check = renderer_mod._check_frame_fits
    with pytest.raises(ValueError, match="66 MiB barycentric buffer; a small device "
                                         "allocates at most 64 MiB per buffer"):
        check(_SmallDevice, 2400, 2400, RasterConfig())
    with pytest.raises(ValueError, match=r"set of frame buffers .*overdraw.*at most 80 MiB "
                                         "in all"):
        check(_SmallDevice, 2000, 2000, RasterConfig())
    check(_SmallDevice, 1000, 1000, RasterConfig())
