"""Sort-last rendering on Dask (clraster.distributed) and its compositing operator
(clraster.composite).

* The operator, without Dask: associative and commutative on random frames full of ties
  (equal depths, different ids), equal to a brute-force per-pixel lexicographic minimum,
  background as the identity; a hand-made two-frame case with a known answer.
* The partition: every triangle in exactly one part, ids mapped back in increasing order.
* On a real LocalCluster (processes, 2 workers, 1 thread each, started once per module):
  `render_sort_last` equals the one-machine frame bit for bit (ids, depth, barycentrics)
  for 2, 3 and 4 parts on the bunny, an instance grid and the 200K-triangle plant from
  inside; the workers got their PoCL thread count; a file target is loaded on the workers.
* Batch views on the same cluster (`clraster.distributed.render_views`): the files equal
  `clraster.batch.render_views` on one machine byte for byte (failures.json included), a
  re-run skips, broken cameras fail only their views; a worker process killed (SIGKILL)
  mid-batch loses nothing and leaves nothing partial; the CLI with --workers and
  --scheduler writes the one-machine files.

Images are small (96×72) to keep the module fast: the cluster start and each worker's first
OpenCL context are most of its time.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from conftest import MESH_DIR, load_shared_mesh

from clraster import Camera, Mesh, Renderer
from clraster.output.frame import Frame, FrameStats
from clraster.scale.composite import (
    composite,
    composite_crops,
    composite_into,
    composite_tree,
    crop,
    uncrop,
)
from clraster.scale.distributed import (
    POCL_THREAD_VARS,
    kd_split,
    partition,
    pocl_thread_env,
    render_sort_last,
    scatter_parts,
)
from clraster.world.scene import Scene

W, H = 96, 72


# -- the compositing operator ----------------------------------------------------------------

def random_frames(rng, n: int, h: int = 9, w: int = 11) -> list[Frame]:
    """``n`` frames of disjoint id ranges, depths from a small set (many exact ties across
    frames), background (depth 1.0, id −1, barycentrics 0) on about a third of the pixels."""
    out = []
    for k in range(n):
        drawn = rng.random((h, w)) < 0.65
        depth = np.where(drawn, rng.choice([0.0, 0.25, 0.5, 0.5000001, 0.75], (h, w)),
                         1.0).astype(np.float32)
        ids = np.where(drawn, 1000 * k + rng.integers(0, 1000, (h, w)), -1).astype(np.int32)
        bary = np.where(drawn[..., None], rng.random((h, w, 3)), 0.0).astype(np.float32)
        od = rng.integers(0, 5, (h, w)).astype(np.int32)
        out.append(Frame(depth, ids, bary, FrameStats(triangles_total=k + 1), overdraw=od))
    return out


def brute_force(frames: list[Frame]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel the frame with the lexicographically smallest (depth, id as uint32)."""
    d = np.stack([f.depth for f in frames])
    i = np.stack([f.triangle_id.view(np.uint32) for f in frames]).astype(np.int64)
    best = np.lexsort((i, d), axis=0)[0]   # lexsort: last key (depth) is the primary one
    pick = np.take_along_axis
    win = best[None]
    return (pick(d, win, 0)[0],
            pick(np.stack([f.triangle_id for f in frames]), win, 0)[0],
            pick(np.stack([f.barycentrics for f in frames]), win[..., None], 0)[0])


def same(a: Frame, b: Frame) -> bool:
    """Bit-identical depth, ids and barycentrics."""
    return (np.array_equal(a.depth.view(np.uint32), b.depth.view(np.uint32))
            and np.array_equal(a.triangle_id, b.triangle_id)
            and np.array_equal(a.barycentrics.view(np.uint32), b.barycentrics.view(np.uint32)))


def test_composite_matches_brute_force_and_is_commutative_associative():
    rng = np.random.default_rng(12)
    for _ in range(5):
        a, b, c, d = random_frames(rng, 4)
        assert same(composite(a, b), composite(b, a))
        assert same(composite(composite(a, b), c), composite(a, composite(b, c)))
        dd, ii, bb = brute_force([a, b, c, d])
        for perm in itertools.permutations([a, b, c, d]):
            t = composite_tree(list(perm))
            assert np.array_equal(t.depth, dd) and np.array_equal(t.triangle_id, ii)
            assert np.array_equal(t.barycentrics, bb)
            np.testing.assert_array_equal(t.overdraw, a.overdraw + b.overdraw + c.overdraw
                                          + d.overdraw)
            assert t.stats.triangles_total == 1 + 2 + 3 + 4


def test_composite_leaves_inputs_and_handles_ties():
    rng = np.random.default_rng(3)
    a, b = random_frames(rng, 2)
    a0 = Frame(a.depth.copy(), a.triangle_id.copy(), a.barycentrics.copy(), a.stats)
    composite(a, b)
    composite_tree([a, b, a])
    assert same(a, a0)
    # equal depth: the lower id wins whichever side it is on
    ties = a.depth == b.depth
    out = composite(a, b)
    lower = np.minimum(a.triangle_id.view(np.uint32), b.triangle_id.view(np.uint32))
    assert np.array_equal(out.triangle_id.view(np.uint32)[ties], lower[ties])


def test_background_is_the_identity():
    rng = np.random.default_rng(5)
    (a,) = random_frames(rng, 1)
    bg = Frame.empty(a.width, a.height)
    bg.overdraw = np.zeros_like(a.overdraw)
    assert same(composite(a, bg), a) and same(composite(bg, a), a)
    assert same(composite(bg, bg), Frame.empty(a.width, a.height))
    # a drawn fragment exactly at depth 1.0 (the raster stage never makes one) would still
    # beat background through the id: background never wins over a drawn pixel
    one = Frame.empty(2, 1)
    one.triangle_id[0, 0] = 5
    one.barycentrics[0, 0] = (0.25, 0.25, 0.5)
    out = composite(Frame.empty(2, 1), one)
    assert out.triangle_id.tolist() == [[5, -1]]
    assert out.barycentrics[0, 0].tolist() == [0.25, 0.25, 0.5]


def test_hand_made_two_parts():
    """Part A: id 3 at depth 0.5 on the left three columns. Part B: id 8 at depth 0.25 on
    columns 2..3, id 1 at depth 0.5 on column 0 (ties with A: the lower id 1 wins)."""
    a = Frame.empty(5, 2)
    a.depth[:, :3] = 0.5
    a.triangle_id[:, :3] = 3
    a.barycentrics[:, :3] = (1.0, 0.0, 0.0)
    b = Frame.empty(5, 2)
    b.depth[:, 2:4] = 0.25
    b.triangle_id[:, 2:4] = 8
    b.barycentrics[:, 2:4] = (0.0, 1.0, 0.0)
    b.depth[:, 0] = 0.5
    b.triangle_id[:, 0] = 1
    b.barycentrics[:, 0] = (0.0, 0.0, 1.0)
    for out in (composite(a, b), composite(b, a), composite_tree([b, a])):
        assert out.triangle_id.tolist() == [[1, 3, 8, 8, -1]] * 2
        assert out.depth.tolist() == [[0.5, 0.5, 0.25, 0.25, 1.0]] * 2
        assert out.barycentrics[0].tolist() == [[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 1, 0],
                                                [0, 0, 0]]


def test_crops_composite_like_full_frames():
    rng = np.random.default_rng(9)
    frames = random_frames(rng, 3, h=20, w=30)
    for k, f in enumerate(frames):   # each covers its own band of the image, overlapping
        keep = np.zeros(f.depth.shape, bool)
        keep[2 + 3 * k:9 + 4 * k, 4 * k:12 + 5 * k] = True
        f.depth[~keep], f.triangle_id[~keep], f.barycentrics[~keep] = 1.0, -1, 0.0
        f.overdraw[~keep] = 0
    full = composite_tree(frames)
    crops = [crop(f) for f in frames]
    assert crops[0].frame.depth.shape[0] < 20
    for order in ([0, 1, 2], [2, 0, 1]):
        c = composite_crops(composite_crops(crops[order[0]], crops[order[1]]),
                            crops[order[2]])
        out = uncrop(c)
        assert same(out, full)
        np.testing.assert_array_equal(out.overdraw, full.overdraw)
    empty = crop(Frame.empty(30, 20))
    assert empty.frame.depth.shape == (0, 0)
    assert same(uncrop(composite_crops(empty, crops[1])), uncrop(crops[1]))
    assert same(uncrop(composite_crops(crops[1], empty)), uncrop(crops[1]))
    assert same(uncrop(composite_crops(empty, empty)), Frame.empty(30, 20))


def test_composite_refuses_mismatched_frames():
    with pytest.raises(ValueError, match="same size"):
        composite(Frame.empty(4, 3), Frame.empty(3, 4))
    with pytest.raises(ValueError, match="at least one"):
        composite_tree([])
    f = Frame.empty(2, 2)
    f.depth = f.depth.astype(np.float64)
    with pytest.raises(ValueError, match="float32"):
        composite_into(Frame.empty(2, 2), f)


# -- partition ---------------------------------------------------------------------------------

def test_kd_split_balances_and_handles_few_points():
    rng = np.random.default_rng(0)
    pts = rng.random((1000, 3)) * (10.0, 1.0, 1.0)
    lab = kd_split(pts, np.ones(1000), 4)
    assert np.bincount(lab, minlength=4).tolist() == [250, 250, 250, 250]
    # the longest axis (x) is cut first: parts are slabs along x
    assert np.all(np.diff([pts[lab == k, 0].mean() for k in range(4)]) > 0)
    assert sorted(kd_split(pts[:2], np.ones(2), 5).tolist()) in ([0, 1], [0, 2], [0, 3])
    assert kd_split(np.zeros((0, 3)), np.zeros(0), 3).size == 0


@pytest.mark.parametrize("parts", [1, 2, 3, 5])
def test_partition_covers_every_triangle_once(parts):
    from clraster.world.generators import instance_grid

    bunny = load_shared_mesh("stanford_bunny.ply")
    scene = instance_grid(bunny, 2, 1, 2)
    ps = partition(scene, parts)
    assert len(ps) == parts
    ids = np.concatenate([p.id_map for p in ps])
    assert ids.dtype == np.int32
    assert np.array_equal(np.sort(ids), np.arange(scene.n_faces))
    for p in ps:
        assert np.all(np.diff(p.id_map) > 0)
        assert p.scene.n_faces == p.n_faces
        # each part triangle is the original one: same world-space vertices
        if p.n_faces:
            inst, face = scene.split_ids(p.id_map[:50])
            pinst, pface = p.scene.split_ids(np.arange(min(50, p.n_faces)))
            for i, f, pi, pf in zip(inst, face, pinst, pface, strict=True):
                orig = scene.instances[i]
                sub = p.scene.instances[pi]
                assert np.array_equal(orig.transform, sub.transform)
                assert np.array_equal(orig.mesh.vertices[orig.mesh.faces[f]],
                                      sub.mesh.vertices[sub.mesh.faces[pf]])
    with pytest.raises(ValueError, match="positive integer"):
        partition(scene, 0)


# -- on a LocalCluster -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def one_machine():
    return Renderer(W, H)


def check_sort_last(client, renderer, target, camera, parts_list=(2, 3, 4), **kw):
    ref = renderer.render(target, camera, **kw)
    assert (ref.triangle_id >= 0).sum() > 100, "the view should show the scene"
    for parts in parts_list:
        out = render_sort_last(target, camera, client, parts=parts, width=W, height=H, **kw)
        assert out.depth.dtype == np.float32 and out.triangle_id.dtype == np.int32
        assert out.barycentrics.dtype == np.float32
        assert np.array_equal(out.triangle_id, ref.triangle_id), f"{parts} parts: ids"
        assert np.array_equal(out.depth.view(np.uint32), ref.depth.view(np.uint32)), parts
        assert np.array_equal(out.barycentrics.view(np.uint32),
                              ref.barycentrics.view(np.uint32)), parts
        assert out.stats.triangles_total == ref.stats.triangles_total
        if kw.get("overdraw"):
            # the parts' maps summed; each part's tile Hi-Z skips only behind its own
            # geometry, so per pixel at least one machine's count (equal without it)
            assert int(out.overdraw.sum()) == out.stats.fragments_tested, parts
            if not kw.get("occlusion"):
                assert (out.overdraw >= ref.overdraw).all(), parts


def test_workers_get_their_pocl_threads(client):
    from clraster.scale.distributed import worker_info

    info = client.run(worker_info)
    assert len(info) == 2
    for rec in info.values():
        for k in POCL_THREAD_VARS:
            assert rec[k] == "1"
        assert rec["compute_units"] == 1   # PoCL read the variable
    assert pocl_thread_env(3) == {k: "3" for k in POCL_THREAD_VARS}


def test_sort_last_bunny(client, one_machine):
    bunny = load_shared_mesh("stanford_bunny.ply")
    lo, hi = bunny.bounds()
    cam = Camera.framing(lo, hi, fov_y=45.0, aspect=W / H)
    check_sort_last(client, one_machine, bunny, cam, overdraw=True)


def test_sort_last_instance_grid(client, one_machine):
    from clraster.world.generators import grid_camera, instance_grid

    scene = instance_grid(load_shared_mesh("suzanne.ply"), 4, 2, 3, spacing=1.1)
    check_sort_last(client, one_machine, scene, grid_camera(scene, W, H), cull="none")


def test_sort_last_plant_inside(client, one_machine):
    from clraster.world.generators import plant, plant_inside_camera

    scene = plant(200_000)
    cam = plant_inside_camera(scene, W, H)
    check_sort_last(client, one_machine, scene, cam)
    # occlusion culling inside each part stays conservative; scattered parts are reused
    held = scatter_parts(client, scene, 3)
    ref = one_machine.render(scene, cam, occlusion=True)
    for _ in range(2):
        out = render_sort_last(held, cam, client, width=W, height=H, occlusion=True)
        assert same(out, ref)


def test_sort_last_known_answer(client):
    """Two one-triangle instances: a near one (id 0) over the middle, a far one (id 1)
    covering the whole view, so the centre shows 0 and a corner shows 1."""
    near = Mesh([[-1, -1, -3], [1, -1, -3], [0, 1, -3]], [[0, 1, 2]])
    far = Mesh([[-50, -50, -6], [50, -50, -6], [0, 50, -6]], [[0, 1, 2]])
    scene = Scene([(far, None), (near, None)])   # ids: far 0, near 1
    cam = Camera.look_at((0, 0, 0), (0, 0, -1), fov_y=60.0, near=0.5, far=10.0)
    out = render_sort_last(scene, cam, client, parts=2, width=W, height=H)
    assert out.triangle_id[H // 2, W // 2] == 1
    assert out.triangle_id[H - 2, 2] == 0
    assert set(np.unique(out.triangle_id).tolist()) <= {-1, 0, 1}
    assert same(out, Renderer(W, H).render(scene, cam))


def test_sort_last_from_a_file(client, one_machine):
    path = MESH_DIR / "stanford_bunny.ply"
    if not path.is_file():
        pytest.skip("shared meshes absent")
    bunny = Mesh.load(path)
    lo, hi = bunny.bounds()
    cam = Camera.framing(lo, hi, direction=(-1.0, 0.3, 1.0), fov_y=45.0, aspect=W / H)
    out = render_sort_last(str(path), cam, client, parts=3, width=W, height=H)
    assert same(out, one_machine.render(bunny, cam))
    with pytest.raises(ValueError, match="does not take"):
        render_sort_last(bunny, cam, client, parts=2, width=W, height=H, fates=True)


# -- batch views on the LocalCluster -----------------------------------------------------------

VIEW_OUTPUTS = ("depth", "ids", "bary", "shaded")


def orbit_cameras(mesh: Mesh, n: int) -> list:
    lo, hi = mesh.bounds()
    return [Camera.framing(lo, hi, direction=(np.sin(a), 0.2 + 0.3 * np.cos(3 * a), np.cos(a)),
                           fov_y=45.0, aspect=W / H)
            for a in np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)]


def folder_bytes(path) -> dict[str, bytes]:
    """Every file of a folder (hidden ones too) → its bytes."""
    return {p.name: p.read_bytes() for p in sorted(path.iterdir())}


def test_render_views_equals_one_machine_and_reruns_skip(client, one_machine, tmp_path):
    from clraster.scale.batch import render_views as one_machine_views
    from clraster.scale.distributed import ViewsSummary
    from clraster.scale.distributed import render_views as dask_views

    bunny = load_shared_mesh("stanford_bunny.ply")
    cams: list = orbit_cameras(bunny, 11)
    cams[3] = {"eye": [0, 0, 1], "target": [0, 0, 0], "near": -1.0}   # fails its view only
    cams[8] = {"eye": [0, 0, 1], "target": [0, 0, 0], "fovy": 40}      # misspelt field
    ref = one_machine_views(bunny, cams, tmp_path / "one", VIEW_OUTPUTS, renderer=one_machine)
    out = dask_views(bunny, cams, client, tmp_path / "dask", VIEW_OUTPUTS, size=(W, H),
                     chunk=2)
    assert isinstance(out, ViewsSummary)
    assert (out.views, out.rendered, out.skipped) == (11, 9, 0)
    assert [f.index for f in out.failures] == [3, 8]
    assert out.failures == ref.failures   # same messages, indices in the whole list
    assert "field 'near'" in out.failures[0].message
    assert [c.start for c in out.chunks] == [0, 2, 4, 6, 8, 10]
    assert sum(w.rendered for w in out.per_worker) == 9
    assert all(w.views_per_s > 0 for w in out.per_worker if w.rendered)
    assert out.failures_file == tmp_path / "dask" / "failures.json"
    # file by file, byte for byte (failures.json included; no temporary file anywhere)
    assert folder_bytes(tmp_path / "dask") == folder_bytes(tmp_path / "one")
    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "dask").glob("view_*")}
    again = dask_views(bunny, cams, client, tmp_path / "dask", VIEW_OUTPUTS, size=(W, H))
    assert (again.rendered, again.skipped, len(again.failures)) == (0, 9, 2)
    assert stamps == {p.name: p.stat().st_mtime_ns for p in (tmp_path / "dask").glob("view_*")}
    with pytest.raises(ValueError, match="chunk"):
        dask_views(bunny, cams, client, tmp_path / "x", chunk=0)
    with pytest.raises(TypeError, match="fates_please"):
        dask_views(bunny, cams, client, tmp_path / "x", fates_please=True)


def test_render_views_from_a_scene_file(client, one_machine, tmp_path):
    from clraster.scale.batch import render_views as one_machine_views
    from clraster.scale.distributed import render_views as dask_views

    path = MESH_DIR / "stanford_bunny.ply"
    if not path.is_file():
        pytest.skip("shared meshes absent")
    cams = orbit_cameras(Mesh.load(path), 4)
    one_machine_views(Mesh.load(path), cams, tmp_path / "one", renderer=one_machine)
    out = dask_views(str(path), cams, client, tmp_path / "dask", size=(W, H))
    assert out.rendered == 4 and not out.failures
    assert folder_bytes(tmp_path / "dask") == folder_bytes(tmp_path / "one")
    shaded = dask_views(str(path), cams, client, tmp_path / "x", outputs=("shaded",))
    assert shaded.rendered == 4 and not shaded.failures
    assert sorted(p.name for p in (tmp_path / "x").glob("*.png")) == [
        f"view_{k:05d}_shaded.png" for k in range(4)]


def test_render_views_survives_a_lost_worker(client, one_machine, tmp_path):
    """Kill one worker process (SIGKILL: no clean-up of its own) while the chunks run: Dask
    runs its tasks again on the other worker (the Nanny restarts the dead one); every view's
    files exist once, nothing temporary is left, and the files equal one machine's."""
    import os
    import signal
    import threading
    import time

    from clraster.scale.batch import render_views as one_machine_views
    from clraster.scale.distributed import render_views as dask_views

    bunny = load_shared_mesh("stanford_bunny.ply")
    n = 64
    cams = orbit_cameras(bunny, n)
    out_dir = tmp_path / "dask"
    result: list = []

    def run() -> None:
        try:
            result.append(dask_views(bunny, cams, client, out_dir, ("depth", "ids"),
                                     size=(W, H), chunk=2))
        except BaseException as exc:   # handed to the test thread
            result.append(exc)

    pids = client.run(os.getpid)
    thread = threading.Thread(target=run)
    thread.start()
    deadline = time.monotonic() + 60
    while len(list(out_dir.glob("view_*_ids.npy"))) < 6 and time.monotonic() < deadline:
        time.sleep(0.01)
    busy = [w for w, keys in client.processing().items() if keys and w in pids]
    victim = busy[0] if busy else sorted(pids)[0]
    written_before = len(list(out_dir.glob("view_*_ids.npy")))
    os.kill(pids[victim], signal.SIGKILL)
    thread.join(timeout=120)
    assert not thread.is_alive()
    summary = result[0]
    if isinstance(summary, BaseException):
        raise summary
    assert written_before < n, "the worker was killed after the batch had finished"
    assert summary.views == n and not summary.failures
    assert summary.rendered + summary.skipped == n
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == sorted([f"view_{k:05d}_{o}.npy" for k in range(n) for o in ("depth", "ids")]
                           + [f".view_{k:05d}.key" for k in range(n)] + ["render_views.json"])
    one_machine_views(bunny, cams, tmp_path / "one", ("depth", "ids"), renderer=one_machine)
    assert folder_bytes(out_dir) == folder_bytes(tmp_path / "one")
    client.wait_for_workers(2, timeout=60)   # the Nanny's restart, for the tests after this


def test_cli_views_on_workers(client, tmp_path):
    import json

    from clraster.cli import main

    path = MESH_DIR / "stanford_bunny.ply"
    if not path.is_file():
        pytest.skip("shared meshes absent")
    lo, hi = Mesh.load(path).bounds()
    c = ((lo + hi) / 2).tolist()
    r = float(np.linalg.norm(hi - lo))
    entries = [{"eye": [c[0] + 1.5 * r * np.sin(a), c[1] + 0.3 * r, c[2] + 1.5 * r * np.cos(a)],
                "target": c, "near": 0.05 * r, "far": 5.0 * r} for a in (0.0, 1.0, 2.0)]
    entries.append({"eye": c, "target": c})   # broken: eye == target
    cams = tmp_path / "cameras.json"
    cams.write_text(json.dumps(entries))
    common = ["render", str(path), "--views", str(cams), "--size", "48x36",
              "--outputs", "depth,ids,shaded"]
    assert main(common + ["--out", str(tmp_path / "one")]) == 1   # one view failed
    assert main(common + ["--out", str(tmp_path / "local"), "--workers", "2",
                          "--chunk", "1"]) == 1
    assert main(common + ["--out", str(tmp_path / "remote"), "--scheduler",
                          client.scheduler.address]) == 1
    one = folder_bytes(tmp_path / "one")
    # 3 views' files, their keys, failures.json and the run's record (clraster.batch)
    assert len(one) == 3 * 3 + 3 + 1 + 1 and "failures.json" in one
    assert folder_bytes(tmp_path / "local") == one
    assert folder_bytes(tmp_path / "remote") == one
    # a re-run skips everything it wrote; the Dask options need --views
    assert main(common + ["--out", str(tmp_path / "remote"), "--scheduler",
                          client.scheduler.address]) == 1
    assert main(["render", str(path), "--out", str(tmp_path / "x.png"), "--workers", "2"]) == 2
    assert main(common + ["--out", str(tmp_path / "y"), "--chunk", "2"]) == 2
    assert main(common + ["--out", str(tmp_path / "y"), "--workers", "2", "--scheduler",
                          client.scheduler.address]) == 2
