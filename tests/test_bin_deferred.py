"""The deferred bin list (clraster/stages/bin.py `BinStage.run` with ``defer``): a pass
scatters and rasterizes without waiting for its bin list's length, into the entry buffer as
it is; a list that does not fit is neither written (bin.cl bin_scatter) nor drawn
(raster.cl, BIN_LIST_OVER) and the pass is scattered and drawn again into a larger buffer.

Every path must give the image and counts a renderer that never deferred gives: a fresh
renderer's first frame (its entry buffer is empty, so it sizes the buffer first). The
paths are checked to be taken with a spy on `BinStage.settle` (the real method, counted).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_frames_equal, load_shared_mesh

from clraster import Camera, RasterConfig, Renderer
from clraster.base.layout import PIECE_DTYPE
from clraster.pipeline.params import BinBudgetExceeded
from clraster.pipeline.stages import bin as bin_stage
from clraster.world.generators import plant, plant_inside_camera

W, H = 320, 240


@pytest.fixture
def settles(monkeypatch):
    """Outcomes of BinStage.settle calls: "fit", "again" (scattered again) or "budget"
    (raised BinBudgetExceeded)."""
    seen: list[str] = []
    real = bin_stage.BinStage.settle

    def spy(self, *args, **kwargs):
        try:
            again = real(self, *args, **kwargs)
        except BinBudgetExceeded:
            seen.append("budget")
            raise
        seen.append("again" if again else "fit")
        return again

    monkeypatch.setattr(bin_stage.BinStage, "settle", spy)
    return seen


def _capacity(r: Renderer) -> int:
    return r.chain.binning.buffers.entries.capacity // PIECE_DTYPE.itemsize


def _shrink_entries(r: Renderer) -> None:
    """Leave the renderer's entry buffer with room for 2 records."""
    gb = r.chain.binning.buffers.entries
    gb.buf, gb.capacity = None, 0
    gb.ensure(2 * PIECE_DTYPE.itemsize)


def test_list_outgrowing_the_entry_buffer_is_drawn_again(settles):
    """A small frame, then a frame with a longer bin list on the same renderer: the second
    is scattered into a buffer too small, drawn again, and equals a fresh renderer's."""
    small = load_shared_mesh("spot.ply")
    big = load_shared_mesh("stanford_bunny.ply")
    cam_small = Camera.framing(*small.bounds(), aspect=W / H)
    cam_big = Camera.framing(*big.bounds(), aspect=W / H)
    r = Renderer(W, H)
    r.render(small, Camera.look_at((0, 0, 40), (0, 0, 0), fov_y=10.0))   # spot far away
    assert settles == [] or settles[-1] == "fit"
    before = _capacity(r)
    got = r.render(big, cam_big)
    assert got.stats.binned_entries > before > 0, "the list was meant to outgrow the buffer"
    assert settles[-1] == "again"
    want = Renderer(W, H).render(big, cam_big)
    assert_frames_equal(got, want, "outgrown entry buffer", bary_atol=0.0)
    # the next frame fits the grown buffer: drawn once
    again = r.render(big, cam_big)
    assert settles[-1] == "fit"
    assert_frames_equal(again, want, "grown entry buffer", bary_atol=0.0)
    assert r.render(small, cam_small).stats.binned_entries > 0


def test_deferred_frames_equal_a_fresh_renderers(settles):
    """Frames after the first take the deferred path and fit: identical to a renderer's
    first frame, which sized its buffer first (no settle)."""
    mesh = load_shared_mesh("stanford_dragon_res3.ply")
    cams = [Camera.framing(*mesh.bounds(), aspect=W / H),
            Camera.look_at((0.3, 0.15, 0.25), (0.0, 0.12, 0.0), fov_y=40.0, near=0.01)]
    r = Renderer(W, H)
    r.render(mesh, cams[0])
    for k, cam in enumerate(cams):
        n = len(settles)
        got = r.render(mesh, cam)
        assert settles[n:] and set(settles[n:]) <= {"fit", "again"}, settles[n:]
        fresh = Renderer(W, H)
        want = fresh.render(mesh, cam)
        assert_frames_equal(got, want, f"camera {k}", bary_atol=0.0)


def test_two_phase_passes_drawn_again_keep_the_first_pass(settles):
    """Occlusion culling draws two passes into one image (the second loads the first's
    depth and ids); with the entry buffer left too small before the frame, both passes are
    scattered and drawn again, and a pass that drew nothing must leave the image as it was.
    Same history on both renderers: equal frames."""
    scene = plant(20_000)
    cam = plant_inside_camera(scene, W, H)
    a, b = Renderer(W, H), Renderer(W, H)
    for r in (a, b):
        r.render(scene, cam, occlusion=True)   # history: last frame's visible clusters
    _shrink_entries(b)
    n = len(settles)
    got = b.render(scene, cam, occlusion=True)
    assert settles[n:].count("again") >= 1, settles[n:]
    want = a.render(scene, cam, occlusion=True)
    assert_frames_equal(got, want, "two-phase, drawn again", bary_atol=0.0)
    assert got.stats.fragments_tested > 0


def test_streamed_pass_over_its_budget_is_split(settles):
    """A streamed frame (small entry budget per pass): a deferred pass whose list is over
    the budget raises BinBudgetExceeded after drawing nothing and is split; the frame
    equals the unstreamed one."""
    mesh = load_shared_mesh("stanford_bunny.ply")
    cam = Camera.framing(*mesh.bounds(), aspect=W / H)
    want = Renderer(W, H).render(mesh, cam)
    r = Renderer(W, H, config=RasterConfig(batch_triangles=4096, batch_entries=1000))
    r.render(mesh, cam)   # sizes the entry buffer (to the budget's bound)
    n = len(settles)
    got = r.render(mesh, cam)
    assert "budget" in settles[n:], settles[n:]
    assert_frames_equal(got, want, "streamed", bary_atol=0.0, check_counts=False)
    assert got.stats.binned_entries == want.stats.binned_entries
    assert np.array_equal(got.mask, want.mask)
