"""``Renderer.render(outputs=...)``: frames without barycentrics are the same frames, less the
barycentrics — depth, ids, stats and overdraw identical — on the OpenCL renderer and its
twin, for whole frames, streamed frames, two-phase occlusion culling and empty frames; and
the tile-row raster kernel clears every pixel of a reused or fresh image exactly once."""

from __future__ import annotations

import numpy as np
import pytest

import clraster
from clraster import Camera, RasterConfig, Renderer
from clraster.world.generators import plant, plant_inside_camera


@pytest.fixture(scope="module")
def scene():
    return plant(20_000)


def _same(a, b):
    assert np.array_equal(a.triangle_id, b.triangle_id)
    assert np.array_equal(a.depth, b.depth)
    assert a.stats.counts() == b.stats.counts()


@pytest.mark.parametrize("size, tile_log2", [((161, 97), 4), ((200, 150), 3), ((129, 65), 6)])
@pytest.mark.parametrize("occlusion", [False, True])
def test_without_bary_same_frame(scene, size, tile_log2, occlusion):
    w, h = size
    cam = plant_inside_camera(scene, w, h)
    r1 = Renderer(w, h, config=RasterConfig(tile_log2=tile_log2))
    r2 = Renderer(w, h, config=RasterConfig(tile_log2=tile_log2))
    for _ in range(2):   # the second frame: occlusion from history, reused buffers
        full = r1.render(scene, cam, occlusion=occlusion, overdraw=True)
        lean = r2.render(scene, cam, occlusion=occlusion, overdraw=True,
                         outputs=("depth", "ids"))
        assert lean.barycentrics is None and full.barycentrics is not None
        _same(full, lean)
        assert np.array_equal(full.overdraw, lean.overdraw)
    twin = clraster.reference.Renderer(w, h, config=RasterConfig(tile_log2=tile_log2))
    t = twin.render(scene, cam, occlusion=occlusion, outputs=["ids", "depth"])
    assert t.barycentrics is None
    assert np.array_equal(t.triangle_id, full.triangle_id)


def test_streamed_without_bary(scene):
    w, h = 160, 120
    cam = plant_inside_camera(scene, w, h)
    full = Renderer(w, h).render(scene, cam)
    small = Renderer(w, h, config=RasterConfig(batch_triangles=512, batch_entries=1024))
    lean = small.render(scene, cam, outputs=("depth", "ids"))
    _same(full, lean)
    assert lean.barycentrics is None


def test_empty_frame_outputs(scene):
    cam = Camera.look_at(eye=(0, 0, -1e4), target=(0, 0, -2e4), up=(0, 1, 0))
    r = Renderer(64, 48)
    f = r.render(scene, cam, outputs="depth")
    assert f.barycentrics is None and (f.depth == 1).all() and (f.triangle_id == -1).all()
    g = r.render(scene, cam)
    assert g.barycentrics is not None and not g.barycentrics.any()
    with pytest.raises(ValueError, match="without barycentrics"):
        f.need_barycentrics()


@pytest.mark.parametrize("bad", [(), ("depth", "depth"), ("normal",), 3, ("ids", None)])
def test_bad_outputs(scene, bad):
    cam = plant_inside_camera(scene, 32, 32)
    with pytest.raises(ValueError, match="outputs must be"):
        Renderer(32, 32).render(scene, cam, outputs=bad)


def test_frames_do_not_share_arrays(scene):
    """Every frame owns its arrays: a later frame (another view) never writes into an
    earlier one's."""
    w, h = 96, 64
    r = Renderer(w, h)
    a = r.render(scene, plant_inside_camera(scene, w, h))
    keep = a.triangle_id.copy(), a.depth.copy(), a.barycentrics.copy()
    r.render(scene, Camera.look_at(eye=(0, 0, -1e4), target=(0, 0, -2e4), up=(0, 1, 0)))
    r.render(scene, Camera.framing(*scene.bounds(), aspect=w / h))
    assert np.array_equal(a.triangle_id, keep[0]) and np.array_equal(a.depth, keep[1])
    assert np.array_equal(a.barycentrics, keep[2])


def test_pool_recycles_only_dropped_arrays():
    """A block comes back to the pool only when the last view of its array is gone, and a
    new array never shares memory with one still referenced."""
    from clraster.pipeline.arraypool import ArrayPool

    pool = ArrayPool(1 << 20)
    a = pool.empty((64, 32), np.float32)
    a.fill(7.0)
    view = a[3:5, ::2].T       # a view outlives its array
    addr = a.ctypes.data
    assert a.ctypes.data % 4096 == 0 and a.flags.writeable and a.flags.c_contiguous
    del a
    b = pool.empty((64, 32), np.float32)
    assert b.ctypes.data != addr and (view == 7.0).all()
    del view
    c = pool.empty((32, 64), np.int32)   # same size: the freed block
    assert c.ctypes.data == addr and pool.free_bytes == 0
    del b, c
    assert pool.free_bytes == 2 * 64 * 32 * 4
    small = ArrayPool(100)   # over its bound, a block goes back to the allocator
    d = small.empty((64,), np.float64)
    del d
    assert small.free_bytes == 0


def test_renderer_frames_survive_recycling(scene):
    """Frames kept while the renderer makes many more keep their values."""
    w, h = 80, 60
    r = Renderer(w, h)
    cam = plant_inside_camera(scene, w, h)
    kept = r.render(scene, cam)
    ref = kept.depth.copy(), kept.triangle_id.copy(), kept.barycentrics.copy()
    for _ in range(4):
        r.render(scene, cam)   # dropped at once: their memory is recycled
        r.render(scene, Camera.look_at(eye=(0, 0, -1e4), target=(0, 0, -2e4), up=(0, 1, 0)))
    assert np.array_equal(kept.depth, ref[0]) and np.array_equal(kept.triangle_id, ref[1])
    assert np.array_equal(kept.barycentrics, ref[2])
    assert r.chain.raster.pool.free_bytes > 0


def test_resized_renderer_shares_device_state_and_draws_fresh_frames(scene):
    """`Renderer.resized`: the queue, stage chain, plan cache and lock are the base's (the
    occlusion history too unless share_history=False), and every frame, at either size and
    in any order, is exactly a fresh renderer's (occlusion culling is conservative, so a
    shared history changes no pixel)."""
    base = Renderer(96, 64)
    small = base.resized(48, 32)
    other = base.resized(40, 30, share_history=False)
    for r in (small, other):
        assert (r.queue, r.chain, r.pyramid, r._plans, r._lock, r._outputs) == (
            base.queue, base.chain, base.pyramid, base._plans, base._lock, base._outputs)
    assert small._history is base._history and other._history is not base._history
    for occlusion in (False, True, True):
        for r in (base, small, other, small):
            cam = plant_inside_camera(scene, r.width, r.height)
            got = r.render(scene, cam, occlusion=occlusion)
            want = Renderer(r.width, r.height).render(scene, cam, occlusion=occlusion)
            assert got.depth.shape == (r.height, r.width)
            assert np.array_equal(got.triangle_id, want.triangle_id)
            assert np.array_equal(got.depth, want.depth)
