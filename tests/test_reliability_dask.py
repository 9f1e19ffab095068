"""Reliability of clraster.distributed (Dask) on awkward inputs.

* Sort-last with parts that get no cluster (more parts than clusters: a one-triangle mesh in
  5 parts, two one-triangle instances in 4; an empty mesh or scene): `partition` gives
  empty parts, they render as background, and the composite equals the one-machine frame
  bit for bit (ids, depth, barycentrics), for a Mesh, a Scene, scattered parts and a scene
  file.
* Clusters with no workers: `local_cluster` refuses a worker count that is not a positive
  integer; `render_views`, `render_sort_last` / `submit_sort_last` and `scatter_parts` on a
  client whose cluster has no workers raise `NoWorkersError` after waiting a short bounded
  time for one (set to 0.5 s here), instead of waiting forever; a worker that joins during
  the wait is used.

One LocalCluster of 2 worker processes (1 thread each) serves the module, as in
tests/test_distributed.py; the cluster with no workers is a scheduler alone (in this
process, no worker to start).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from clraster import Camera, Mesh, Renderer
from clraster.output.frame import Frame
from clraster.world.scene import Scene

pytest.importorskip("dask.distributed")

from clraster.scale import distributed as cd  # noqa: E402  (after the importorskip)

W, H = 64, 48
#: seconds after which a call on the cluster with no workers counts as hung (it is given a
#: 0.5 s wait for workers: anything near this limit is a call that never returns)
HANG_S = 60.0

CAM = Camera.look_at((0, 0, 0), (0, 0, -1), fov_y=60.0, near=0.5, far=10.0)


def one_triangle() -> Mesh:
    return Mesh([[-1, -1, -3], [1, -1, -3], [0, 1, -3]], [[0, 1, 2]])


def near_far_scene() -> Scene:
    """A far triangle covering the view (id 0) behind a near one in the middle (id 1)."""
    far = Mesh([[-50, -50, -6], [50, -50, -6], [0, 50, -6]], [[0, 1, 2]])
    return Scene([(far, None), (one_triangle(), None)])


def empty_mesh() -> Mesh:
    return Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))


def same(a: Frame, b: Frame) -> bool:
    """Bit-identical depth, ids and barycentrics."""
    return (np.array_equal(a.depth.view(np.uint32), b.depth.view(np.uint32))
            and np.array_equal(a.triangle_id, b.triangle_id)
            and np.array_equal(a.barycentrics.view(np.uint32), b.barycentrics.view(np.uint32)))


# -- partition: empty parts (no cluster needed) ------------------------------------------------

@pytest.mark.parametrize(("make", "parts", "faces"), [
    (one_triangle, 5, 1), (near_far_scene, 4, 2), (empty_mesh, 3, 0), (Scene, 2, 0),
    (empty_mesh, 1, 0)])
def test_partition_with_more_parts_than_clusters(make, parts, faces):
    ps = cd.partition(make(), parts)
    assert [p.index for p in ps] == list(range(parts))
    ids = np.concatenate([p.id_map for p in ps])
    assert ids.dtype == np.int32
    assert np.array_equal(np.sort(ids), np.arange(faces))   # every triangle once
    empty = [p for p in ps if p.n_faces == 0]
    assert len(empty) >= parts - max(faces, 1)
    for p in empty:
        assert p.scene.n_faces == 0 and p.id_map.shape == (0,)
        assert p.scene_ids(np.array([[-1, 0]])).tolist() == [[-1, -1]]


# -- sort-last on a LocalCluster ---------------------------------------------------------------


@pytest.fixture(scope="module")
def one_machine():
    return Renderer(W, H)


@pytest.mark.parametrize(("make", "parts"), [
    (one_triangle, 5), (near_far_scene, 4), (near_far_scene, 7), (empty_mesh, 3), (Scene, 2)])
def test_sort_last_with_empty_parts_equals_one_machine(client, one_machine, make, parts):
    target = make()
    ref = one_machine.render(target, CAM)
    out = cd.render_sort_last(target, CAM, client, parts=parts, width=W, height=H)
    assert out.depth.dtype == np.float32 and out.triangle_id.dtype == np.int32
    assert same(out, ref)
    assert out.stats.triangles_total == ref.stats.triangles_total
    if target.n_faces == 0:
        assert same(out, Frame.empty(W, H))
    else:
        assert (out.triangle_id >= 0).any()


def test_sort_last_empty_parts_with_overdraw_and_scattered_parts(client, one_machine):
    tri = one_triangle()
    ref = one_machine.render(tri, CAM, overdraw=True)
    out = cd.render_sort_last(tri, CAM, client, parts=5, width=W, height=H, overdraw=True)
    assert same(out, ref)
    # one part holds the whole mesh and renders what one machine does; the others add 0
    np.testing.assert_array_equal(out.overdraw, ref.overdraw)
    assert int(out.overdraw.sum()) == out.stats.fragments_tested
    scene = near_far_scene()
    held = cd.scatter_parts(client, scene, 6)
    assert len(held.futures) == 6 and held.n_faces == 2
    ref = one_machine.render(scene, CAM)
    for _ in range(2):   # scattered parts are reused
        assert same(cd.render_sort_last(held, CAM, client, width=W, height=H), ref)


def test_sort_last_file_with_more_parts_than_clusters(client, one_machine, tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("v -50 -50 -6\nv 50 -50 -6\nv 0 50 -6\n"
                    "v -1 -1 -3\nv 1 -1 -3\nv 0 1 -3\nf 1 2 3\nf 4 5 6\n")
    ref = one_machine.render(Scene.load(path), CAM)
    assert set(np.unique(ref.triangle_id).tolist()) == {0, 1}
    out = cd.render_sort_last(str(path), CAM, client, parts=5, width=W, height=H)
    assert same(out, ref)
    with pytest.raises(ValueError, match="positive integer"):
        cd.render_sort_last(str(path), CAM, client, parts=0, width=W, height=H)


# -- clusters with no workers ------------------------------------------------------------------

@pytest.mark.parametrize("n", [0, -1, 1.5, "2", True, None])
def test_local_cluster_refuses_bad_worker_counts(n):
    with pytest.raises(ValueError, match="n_workers must be a positive integer"):
        cd.local_cluster(n)
    with pytest.raises(ValueError, match="threads_per_worker must be a positive integer"):
        cd.local_cluster(1, threads_per_worker=0)


@pytest.fixture(scope="module")
def idle():
    """A cluster with a scheduler and no worker, and its client."""
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as c:
        yield cluster, c


@pytest.fixture
def short_wait(monkeypatch):
    monkeypatch.setattr(cd, "WORKER_WAIT_S", 0.5)


def bounded(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a thread: its result or exception, or a test failure if it
    has not returned after HANG_S seconds (the thread is left behind, a daemon)."""
    box: list = []

    def run() -> None:
        try:
            box.append(fn(*args, **kwargs))
        except BaseException as exc:   # handed to the test thread
            box.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(HANG_S)
    assert not t.is_alive(), f"{fn.__name__} still waiting after {HANG_S} s with no workers"
    return box[0]


def check_no_workers(got, address) -> None:
    assert isinstance(got, cd.NoWorkersError), f"expected NoWorkersError, got {got!r}"
    assert isinstance(got, ValueError)
    msg = str(got)
    assert "no workers" in msg and address in msg and "dask worker" in msg


def test_render_views_with_no_workers_fails_fast(idle, short_wait, tmp_path):
    _, c = idle
    path = tmp_path / "tri.obj"
    path.write_text("v -1 -1 -3\nv 1 -1 -3\nv 0 1 -3\nf 1 2 3\n")
    for target in (str(path), one_triangle()):
        got = bounded(cd.render_views, target, [CAM, CAM], c, tmp_path / "out", size=(W, H))
        check_no_workers(got, c.scheduler.address)
    assert not list(tmp_path.glob("out/view_*"))   # nothing was rendered


def test_sort_last_with_no_workers_fails_fast(idle, client, short_wait, tmp_path):
    _, c = idle
    address = c.scheduler.address
    path = tmp_path / "tri.obj"
    path.write_text("v -1 -1 -3\nv 1 -1 -3\nv 0 1 -3\nf 1 2 3\n")
    tri = one_triangle()
    for target in (tri, str(path)):
        check_no_workers(bounded(cd.render_sort_last, target, CAM, c, parts=2, width=W,
                                 height=H), address)
        check_no_workers(bounded(cd.submit_sort_last, target, CAM, c, parts=2, width=W,
                                 height=H), address)
    check_no_workers(bounded(cd.scatter_parts, c, tri, 2), address)
    # parts scattered on a cluster that has workers, submitted through one that has none
    held = cd.scatter_parts(client, tri, 2)
    check_no_workers(bounded(cd.render_sort_last, held, CAM, c, width=W, height=H), address)


def test_a_worker_that_joins_during_the_wait_is_used(idle):
    """The cluster gets a worker while `require_workers` waits (it has 60 s): it returns
    the count instead of failing. Last in the module: it leaves the idle cluster a worker
    only until it scales it back to none."""
    cluster, c = idle
    assert len(c.nthreads()) == 0
    timer = threading.Timer(0.3, cluster.scale, args=(1,))
    timer.start()
    try:
        assert bounded(cd.require_workers, c, timeout=HANG_S) == 1
    finally:
        timer.join()
        cluster.scale(0)
