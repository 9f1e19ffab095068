"""Stage-level differential tests: each OpenCL stage's output buffers against the NumPy twin's.

The whole-frame comparisons (test_differential.py) say *that* a frame differs; these say
*where*: random triangle soups (tests/random_scenes.py: slivers, specks, huge and
near-crossing triangles, w = 0 vertices, degenerate ones, duplicates, a clipped grid) go
through the OpenCL `StageChain` (geometry → setup → bin) and through the twin's vertex,
setup and bin functions over the very same draw records, and the stage boundaries are
compared record by record, in pipeline order, so the first failing assertion names the
stage:

* setup → bin (setup makes its draws' vertices itself, in private memory: their clip
  positions, outcodes and window positions are checked through what setup makes of them):
  status of every triangle, clip_count (clipped triangles) / clip_offset, the
  setup record of every unclipped survivor, the clipped pieces and their parent
  barycentrics (all exact, bytes);
* bin → raster: tile_start and every tile list (exact, bytes: same records, same order).
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from conftest import MatrixCamera
from random_scenes import Lens, random_soup, random_view, to_world

from clraster import Mesh, RasterConfig
from clraster.base.layout import (
    DRAW_INSIDE,
    OC_INVALID,
    OC_NEEDS_CLIP,
    OC_W_NONPOS,
    PIECE_DTYPE,
    ST_CLIPPED,
    ST_INVALID,
    ST_RASTER,
)
from clraster.pipeline.device import default_context
from clraster.pipeline.drawlist import PlanCache, plan_frame
from clraster.pipeline.params import FrameParams, FrameTotals
from clraster.pipeline.reference import bin as ref_bin
from clraster.pipeline.reference import setup as ref_setup
from clraster.pipeline.reference import vertex as ref_vertex
from clraster.pipeline.stages import setup as setup_stage
from clraster.pipeline.stages.chain import StageChain

#: (seed, (width, height), tile_log2, cull, lens): sizes on both sides of powers of two,
#: tiles that do not divide the image, every cull mode, near planes from 0.01 to 2.
CASES = [
    (1, (64, 48), 4, "back", Lens(60.0, 0.5, 1000.0)),
    (2, (65, 33), 3, "none", Lens(90.0, 0.01, 10.0)),
    (3, (127, 129), 5, "front", Lens(20.0, 2.0, 1000.0)),
    (4, (31, 17), 4, "back", Lens(150.0, 0.5, 10.0)),
    (5, (200, 120), 6, "none", Lens(60.0, 0.01, 1000.0)),
    (6, (96, 64), 4, "back", Lens(90.0, 0.5, 1000.0)),
]
TRIS = 3000


@pytest.fixture(scope="module")
def device():
    ctx = default_context()
    queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    return ctx, queue


def _read(queue, gb, dtype, n: int, shape=()) -> np.ndarray:
    """The first ``n`` records of a stage buffer (a GrowBuffer) as a host array."""
    out = np.zeros((n, *shape), dtype)
    if out.nbytes:
        cl.enqueue_copy(queue, out, gb.buf, is_blocking=True)
    return out


def _first_diff(a: np.ndarray, b: np.ndarray) -> tuple[int, np.ndarray]:
    """Number of differing records (compared as bytes) and their indices."""
    ab = np.ascontiguousarray(a).view(np.uint8).reshape(a.shape[0], -1)
    bb = np.ascontiguousarray(b).view(np.uint8).reshape(b.shape[0], -1)
    bad = np.nonzero(np.any(ab != bb, axis=1))[0]
    return bad.size, bad


def _assert_records(stage: str, what: str, got: np.ndarray, want: np.ndarray) -> None:
    assert got.shape == want.shape, f"{stage}: {what} has {got.shape} records, twin {want.shape}"
    n, bad = _first_diff(got, want)
    if n:
        i = int(bad[0])
        raise AssertionError(f"{stage}: {what} differs in {n} of {got.shape[0]} records; "
                             f"first at {i}: OpenCL {got[i]!r} vs twin {want[i]!r}")


@pytest.mark.parametrize("clip_once", [True, False], ids=["clip-once", "clip-twice"])
@pytest.mark.parametrize("seed, size, tile_log2, cull, lens", CASES)
def test_stage_outputs_match_twin(device, seed, size, tile_log2, cull, lens, clip_once,
                                  monkeypatch):
    """clip_once: the clipper run once into scratch rows and its pieces then moved to their
    places (the default), or, with no scratch budget (CLIP_SCRATCH_BYTES 0), run twice,
    counting first: the same bytes either way."""
    if not clip_once:
        monkeypatch.setattr(setup_stage, "CLIP_SCRATCH_BYTES", 0)
    ctx, queue = device
    w, h = size
    rng = np.random.default_rng(seed)
    v, f, _ = random_soup(rng, TRIS, w, h, lens)
    view = random_view(rng) if seed % 2 else np.eye(4)
    cam = MatrixCamera(lens.projection(w / h) @ view)
    mesh = Mesh(to_world(v, view), f)
    config = RasterConfig(tile_log2=tile_log2)
    plan = plan_frame(mesh, cam, w, h, cull=cull, frustum=False, cones=False,
                      cache=PlanCache())
    pool, fd = plan.pool, plan.frame
    params = FrameParams.make(w, h, config, cull)

    chain = StageChain(ctx, config, raster=False)
    bins = chain.bin(queue, pool, fd, params, FrameTotals())
    queue.finish()
    setup = chain.setup.buffers
    m = fd.n_tris
    assert setup.n_tris == m

    # -- setup (its vertices made per draw, as the twin's vertex stage) → bin ---------------
    clip, oc, win = ref_vertex.transform_draws(pool, fd, params.kx, params.ky, w, h)
    tri_verts, ids = ref_setup.draw_triangles(pool, fd)
    st = ref_setup.setup(clip, oc, win, tri_verts, ids, w, h, cull, params.kx, params.ky,
                         ref_setup.object_clip(pool, fd), ref_setup.draw_mirrored(pool, fd))
    _assert_records("setup", "status", _read(queue, setup.status, np.uint8, m), st.status)
    # clip_count is written for clipped triangles only, clip_offset only when there are any
    # (SetupBuffers); the twin has 0 elsewhere
    clipped = st.status == ST_CLIPPED
    _assert_records("setup", "clip_count (clipped triangles)",
                    _read(queue, setup.clip_count, np.int32, m)[clipped], st.clip_count[clipped])
    if clipped.any():
        _assert_records("setup", "clip_offset", _read(queue, setup.clip_offset, np.int32, m),
                        st.clip_offset)
    live = st.status == ST_RASTER
    _assert_records("setup", "setup record (unclipped)",
                    _read(queue, setup.pieces, PIECE_DTYPE, m)[live], st.pieces[live])
    p = setup.n_clip_pieces
    assert p == st.clip_pieces.size, f"setup: {p} clipped pieces, twin {st.clip_pieces.size}"
    _assert_records("setup", "clipped piece", _read(queue, setup.clip_pieces, PIECE_DTYPE, p),
                    st.clip_pieces)
    _assert_records("setup", "clipped piece barycentrics",
                    _read(queue, setup.clip_bary, np.float32, p, (3, 3)), st.clip_bary)

    # -- bin → raster -----------------------------------------------------------------------
    order = ref_bin.unified_order(st.status, st.clip_count, st.clip_offset)
    allp = np.concatenate([st.pieces, st.clip_pieces])
    tile_start, entries = ref_bin.bin_pieces(allp, order, w, h, config)
    _assert_records("bin", "tile_start",
                    _read(queue, bins.tile_start, np.int32, params.n_tiles + 1), tile_start)
    assert bins.n_entries == entries.size, f"bin: {bins.n_entries} entries, twin {entries.size}"
    got = _read(queue, bins.entries, PIECE_DTYPE, bins.n_entries)
    n_bad, bad = _first_diff(got, entries)
    if n_bad:   # name the tile whose list differs first
        t = int(np.searchsorted(tile_start, bad[0], side="right")) - 1
        s0, s1 = int(tile_start[t]), int(tile_start[t + 1])
        _assert_records("bin", f"list of tile {t} (x {t % params.tiles_x}, "
                        f"y {t // params.tiles_x})", got[s0:s1], entries[s0:s1])
    # the soup really reached every boundary (not vacuous), through the path asked for
    assert live.any() and p > 0 and entries.size > 0, (int(live.sum()), p, entries.size)
    assert (chain.setup.scratch.buf is not None) == clip_once


@pytest.mark.parametrize("frustum", [False, True])
def test_vertex_lanes_match_twin_on_invalid_and_w0_vertices(device, frustum):
    """Setup's vertices made in full sets of eight lanes (kernels/setup.cl draw_vertices)
    against the twin's vertex stage, through what setup makes of them (each triangle's
    status and, for a piece, its record: snapped corners, box and value planes): NaN and
    infinite coordinates (OC_INVALID), vertices in the eye plane (w = 0) and behind it, far
    outside the guard band, mixed into the sets of lanes; with the frustum test on, clusters
    of a dense patch inside the frustum by a margin skip the plane tests (DRAW_INSIDE; a
    cluster with a non-finite vertex never is one)."""
    ctx, queue = device
    w, h = 96, 64
    lens = Lens(70.0, 0.5, 100.0)
    rng = np.random.default_rng(23)
    v, f, _ = random_soup(rng, 1500, w, h, lens)
    v = v.copy()
    pick = rng.choice(v.shape[0], size=(5, v.shape[0] // 40), replace=False)
    v[pick[0], 0] = np.nan
    v[pick[1], 1] = np.inf
    v[pick[2], 2] = -np.inf
    v[pick[3], 2] = 0.0   # in the eye plane: w = 0
    v[pick[4], :2] *= 1e7   # far past the guard band
    # and a dense patch well inside the view: clusters inside the frustum by a margin
    g = np.linspace(-1.0, 1.0, 31)
    gx, gy = np.meshgrid(g, g)
    gv = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -5.0)], axis=1)
    q = (np.arange(30)[:, None] * 31 + np.arange(30)[None, :]).ravel()
    gf = np.concatenate([np.stack([q, q + 1, q + 32], 1), np.stack([q, q + 32, q + 31], 1)])
    f = np.concatenate([f, gf + v.shape[0]])
    v = np.concatenate([v, gv])
    cam = MatrixCamera(lens.projection(w / h))
    config = RasterConfig()
    plan = plan_frame(Mesh(v, f), cam, w, h, cull="none", frustum=frustum, cones=False,
                      cache=PlanCache())
    pool, fd = plan.pool, plan.frame
    params = FrameParams.make(w, h, config, "none")
    chain = StageChain(ctx, config, raster=False)
    chain.bin(queue, pool, fd, params, FrameTotals())
    queue.finish()
    setup, n, m = chain.setup.buffers, fd.n_verts, fd.n_tris
    clip, oc, win = ref_vertex.transform_draws(pool, fd, params.kx, params.ky, w, h)
    tri_verts, ids = ref_setup.draw_triangles(pool, fd)
    st = ref_setup.setup(clip, oc, win, tri_verts, ids, w, h, "none", params.kx, params.ky,
                         ref_setup.object_clip(pool, fd), ref_setup.draw_mirrored(pool, fd))
    _assert_records("setup", "status", _read(queue, setup.status, np.uint8, m), st.status)
    live = st.status == ST_RASTER
    _assert_records("setup", "setup record (unclipped)",
                    _read(queue, setup.pieces, PIECE_DTYPE, m)[live], st.pieces[live])
    # not vacuous: full sets of eight lanes hold each kind of vertex, and triangles of each
    # kind reach setup's decisions
    full = np.zeros(n, bool)
    for d in fd.draws:
        nv = int(pool.clusters[d["cluster"]][3])   # (tri_offset, n_tris, vert_offset, n_verts)
        full[d["vert_base"]:d["vert_base"] + nv // 8 * 8] = True
    plain = (oc & (OC_NEEDS_CLIP | OC_INVALID | OC_W_NONPOS)) == 0
    for kind in (OC_INVALID, OC_W_NONPOS):
        assert (full & ((oc & kind) != 0)).any(), kind
    assert (full & plain).any()
    assert {ST_INVALID, ST_CLIPPED, ST_RASTER} <= set(np.unique(st.status).tolist())
    if frustum:
        assert (fd.draws["flags"] & DRAW_INSIDE).any()
