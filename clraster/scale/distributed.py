"""Rendering past one machine on Dask (``dask.distributed``): sort-last compositing and
batch views.

Sort-last rendering (Molnar et al. 1994's taxonomy): the scene's (instance, cluster) pairs
are split spatially into N parts (`partition`, a k-d split of their world-box centres);
each part is rendered on a worker as a full frame; the frames are merged by the compositing
operator of `clraster.composite` (per pixel the smallest (depth, id)) in a tree of Dask
tasks, and one frame comes back to the client. It equals the frame one `Renderer` makes
of the whole scene, bit for bit (`clraster.composite` says why). docs/DISTRIBUTED.md
describes the reduction, and binary-swap / radix-k for large frames.

Batch views (`render_views`): many views of one scene, cut into chunks of cameras; each
chunk is one task that runs `clraster.batch.render_views` on a worker with that worker's
Renderer and writes the files there (atomic renames, complete views skipped, so a task can
run twice); only a small `ChunkRecord` per task comes back, and a `ViewsSummary` (views/s
per worker) at the end.

The module has four layers, batch views and sort-last sitting on the same worker state:

* **Client helpers**: `local_cluster` (a LocalCluster of worker processes whose PoCL thread
  count keeps workers × threads <= cores), `pocl_thread_env`, `require_workers` (every
  Dask call here fails with `NoWorkersError` on a cluster with no workers, rather than
  waiting for one forever).
* **Worker side**: `worker_renderer` (one `Renderer` per (width, height, config) per worker
  process, made lazily in that process and never pickled), `worker_target` (a scene file
  loaded once per process), `worker_info`. These are module-level dicts guarded by the pid:
  an OpenCL context does not survive fork(), so a process that finds another pid's entries
  drops them (Dask's workers are spawned by default, `distributed.worker.
  multiprocessing-method: spawn`, so this is the belt to that braces).
* **Sort-last**: `Part`, `partition`, `scatter_parts`, `submit_sort_last`,
  `render_sort_last`.
* **Batch views**: `render_views`, `ChunkRecord`, `WorkerRate`, `ViewsSummary`.

Thread counts. PoCL's CPU device starts one thread per core unless told otherwise; two
worker processes on two cores would each start two. The variable is read once, when PoCL
initializes (the first OpenCL call of the process), so it must be in the worker's
environment before that: `local_cluster` passes it as the Nanny's ``env=`` (the documented
way; on a real cluster set ``distributed.nanny.environ`` in the Dask config, or export it
before ``dask worker``). PoCL 3.x reads ``POCL_MAX_PTHREAD_COUNT`` (the pip
pocl-binary-distribution 3.0 here, checked: the device then reports that many compute
units); PoCL 4 and later read ``POCL_CPU_MAX_CU_COUNT``. Both are set.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..base.config import RasterConfig
from ..output.frame import Frame
from ..pipeline.device import POCL_THREAD_VARS  # re-exported: the worker environment's variables
from ..world.mesh import Mesh
from ..world.scene import Scene
from .batch import RenderSummary, ViewFailure
from .composite import Crop, composite_crops, crop, uncrop

__all__ = ["POCL_THREAD_VARS", "WORKER_WAIT_S", "ChunkRecord", "NoWorkersError", "Part",
           "ScatteredParts", "SortLastFutures", "ViewsSummary", "WorkerRate", "kd_split",
           "local_cluster", "partition", "pocl_thread_env", "render_sort_last",
           "render_views", "require_workers", "scatter_parts", "submit_sort_last",
           "usable_cores", "worker_info", "worker_renderer", "worker_target"]

#: named by the module's public path (users' logging settings name it)
log = logging.getLogger("clraster.distributed")


# -- client helpers --------------------------------------------------------------------------

def usable_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


def pocl_thread_env(threads: int) -> dict[str, str]:
    """Environment for a worker process whose PoCL may start ``threads`` threads (>= 1)."""
    if not isinstance(threads, int) or isinstance(threads, bool) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    return {k: str(threads) for k in POCL_THREAD_VARS}


def local_cluster(n_workers: int = 2, *, threads_per_worker: int = 1,
                  pocl_threads: int | None = None, **kwargs: Any):
    """A `dask.distributed.LocalCluster` of ``n_workers`` worker processes for rendering.

    Args:
        n_workers: worker processes (each one OpenCL context, made on first use).
        threads_per_worker: Dask task threads per worker. 1 is right for rendering: a
            Renderer serializes its frames, and PoCL already spreads one frame over cores.
        pocl_threads: PoCL threads per worker; default ``max(1, cores // n_workers)`` so
            that workers × threads <= cores.
        kwargs: passed on to LocalCluster (e.g. ``dashboard_address=None``); an ``env``
            dict is merged over the PoCL variables.

    Returns:
        The LocalCluster (``processes=True``); connect with ``dask.distributed.Client(c)``
        and close both when done (they are context managers).

    Raises:
        ValueError: ``n_workers`` or ``threads_per_worker`` not a positive integer (Dask
            would start a cluster with no workers, on which every task waits forever).
    """
    from dask.distributed import LocalCluster

    for name, value in (("n_workers", n_workers), ("threads_per_worker", threads_per_worker)):
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{name} must be a positive integer (at least 1), got {value!r}")
    if pocl_threads is None:
        pocl_threads = max(1, usable_cores() // n_workers)
    env = {**pocl_thread_env(pocl_threads), **kwargs.pop("env", {})}
    kwargs.setdefault("dashboard_address", None)
    return LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker,
                        processes=True, env=env, **kwargs)


#: seconds a Dask call of this module waits for a first worker when the client has none (a
#: cluster still starting, `dask worker` processes still connecting) before it gives up
WORKER_WAIT_S = 10.0


class NoWorkersError(ValueError):
    """The Dask client has no workers (none joined within `WORKER_WAIT_S` seconds).

    Dask would accept the tasks and wait for a worker forever; clraster refuses instead."""


def require_workers(client, timeout: float | None = None) -> int:
    """Number of workers of ``client``'s cluster, waiting up to ``timeout`` seconds (default
    `WORKER_WAIT_S`) for a first one when there are none yet.

    Raises:
        NoWorkersError: still no worker after ``timeout`` seconds.
    """
    import asyncio

    # nthreads lists every worker the scheduler knows (paused ones too: they come back)
    n = len(client.nthreads())
    if n:
        return n
    wait_s = WORKER_WAIT_S if timeout is None else float(timeout)
    try:
        client.wait_for_workers(1, timeout=max(wait_s, 1e-3))   # 0 would mean "forever"
    # Dask's WorkerStartTimeoutError is a TimeoutError (older Dask: asyncio's, a separate
    # class before Python 3.11)
    except (TimeoutError, asyncio.TimeoutError):
        address = getattr(client.scheduler, "address", None)
        raise NoWorkersError(
            f"the Dask cluster (scheduler {address}) has no workers: none joined in "
            f"{wait_s:g} s, and its tasks would wait forever. Start workers (`dask worker "
            f"{address}`) or make the cluster with n_workers >= 1 "
            f"(clraster.distributed.local_cluster)") from None
    return max(1, len(client.nthreads()))


# -- worker side: per-process state ----------------------------------------------------------

_STATE_LOCK = threading.Lock()
_STATE_PID: int | None = None
#: (width, height, config) → Renderer of this process
_RENDERERS: dict[tuple[int, int, RasterConfig], Any] = {}
#: (resolved path, mtime_ns) → Scene loaded in this process; (path key, parts) → [Part]
_TARGETS: dict[tuple[str, int], Scene] = {}
_PARTS: dict[tuple[tuple[str, int], int], list[Part]] = {}


def _process_state() -> None:
    """Drop state made by another process (we are a fork() child: its OpenCL contexts are
    unusable here). Call with _STATE_LOCK held."""
    global _STATE_PID
    pid = os.getpid()
    if _STATE_PID != pid:
        _RENDERERS.clear()
        _TARGETS.clear()
        _PARTS.clear()
        _STATE_PID = pid


def worker_renderer(width: int, height: int, config: RasterConfig | None = None):
    """This process's `Renderer` for (width, height, config), made on first use.

    Run it inside the worker (in a task): the Renderer holds an OpenCL context and device
    buffers, which are neither picklable nor valid in another process. It lives as long as
    the process, so its programs, buffers and plan cache serve every later task."""
    from ..pipeline.renderer import Renderer

    key = (int(width), int(height), config or RasterConfig())
    with _STATE_LOCK:
        _process_state()
        r = _RENDERERS.get(key)
        if r is None:
            r = _RENDERERS[key] = Renderer(key[0], key[1], config=key[2])
        return r


def worker_target(path: str | os.PathLike) -> Scene:
    """The scene in ``path`` (`Scene.load`), loaded once per process and file version
    (path and modification time), so tasks that name a file do not each read it."""
    p = Path(path).resolve()
    key = (str(p), p.stat().st_mtime_ns)
    with _STATE_LOCK:
        _process_state()
        scene = _TARGETS.get(key)
        if scene is None:
            scene = _TARGETS[key] = Scene.load(p)
        return scene


def _worker_parts(path: str | os.PathLike, parts: int) -> list[Part]:
    """`partition` of the scene in ``path``, computed once per process (deterministic, so
    every worker makes the same parts)."""
    scene = worker_target(path)
    p = Path(path).resolve()
    key = ((str(p), p.stat().st_mtime_ns), parts)
    with _STATE_LOCK:
        got = _PARTS.get(key)
    if got is None:
        got = partition(scene, parts)
        with _STATE_LOCK:
            _PARTS[key] = got
    return got


def worker_info() -> dict[str, Any]:
    """A small record of this process: pid, the PoCL thread variables in its environment,
    and (if this process has opened one) its OpenCL device's name and compute units. Use
    with ``client.run(worker_info)`` to check a cluster's set-up."""
    info: dict[str, Any] = {"pid": os.getpid(),
                            **{k: os.environ.get(k) for k in POCL_THREAD_VARS}}
    from ..pipeline.device import default_context

    dev = default_context().devices[0]
    info["device"] = dev.name
    info["compute_units"] = int(dev.max_compute_units)
    info["renderers"] = len(_RENDERERS) if _STATE_PID == os.getpid() else 0
    return info


# -- spatial partition -----------------------------------------------------------------------

def kd_split(centres: np.ndarray, weights: np.ndarray, n: int) -> np.ndarray:
    """Split points into ``n`` groups by a k-d tree: recursively cut along the axis of largest
    extent at the weighted quantile that gives each side work in proportion to the number of
    groups it will hold (floor(m/2) : ceil(m/2)).

    Args:
        centres: float64 (K, 3) finite points. weights: (K,) non-negative work per point
            (triangles). n: groups, >= 1.

    Returns:
        int64 (K,) group of each point in [0, n). Deterministic (stable sorts); a group is
        empty only when there are fewer points than groups.
    """
    centres = np.asarray(centres, np.float64)
    weights = np.asarray(weights, np.float64)
    labels = np.zeros(centres.shape[0], np.int64)
    stack = [(np.arange(centres.shape[0]), 0, int(n))]
    while stack:
        idx, first, m = stack.pop()
        if m == 1 or idx.size == 0:
            labels[idx] = first
            continue
        ml = m // 2
        c = centres[idx]
        axis = int(np.argmax(np.ptp(c, axis=0))) if idx.size else 0
        order = idx[np.argsort(c[:, axis], kind="stable")]
        cw = np.cumsum(weights[order])
        k = int(np.searchsorted(cw, cw[-1] * ml / m)) + 1   # points on the left side
        k = min(max(k, 1), max(idx.size - 1, 1)) if idx.size > 1 else idx.size
        stack.append((order[k:], first + ml, m - ml))
        stack.append((order[:k], first, ml))
    return labels


@dataclass(frozen=True)
class Part:
    """One part of a scene for sort-last rendering.

    Attributes:
        scene: a `Scene` of the part's triangles: one instance per original instance that
            has clusters in the part, in the original instance order, with the original
            transform and either the original mesh (all its clusters are in the part) or a
            sub-mesh of the part's faces in their original order (vertices compacted).
        id_map: int32 (scene.n_faces,) the original scene's triangle id of each of this
            part's triangle ids. Strictly increasing, so on equal depth the lower part id
            is the lower original id: a part frame breaks ties as the whole scene would.
        index: this part's number in [0, parts).
    """

    scene: Scene
    id_map: np.ndarray
    index: int

    @property
    def n_faces(self) -> int:
        return int(self.id_map.size)

    def scene_ids(self, ids: np.ndarray) -> np.ndarray:
        """int32 ids of a frame of ``self.scene`` (−1 background) as ids of the original
        scene (−1 stays −1)."""
        ids = np.asarray(ids)
        if self.id_map.size == 0:
            return np.full(ids.shape, -1, np.int32)
        return np.where(ids >= 0, self.id_map[np.maximum(ids, 0)], -1).astype(np.int32)


def _gather_ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """int64 indices ``concat(arange(s, s + l) for s, l in zip(starts, lengths))``."""
    lengths = np.asarray(lengths, np.int64)
    total = int(lengths.sum())
    offs = np.cumsum(lengths) - lengths
    return np.repeat(np.asarray(starts, np.int64) - offs, lengths) + np.arange(total)


def _sub_mesh(mesh: Mesh, faces: np.ndarray) -> Mesh:
    """The faces ``faces`` (sorted int64) of ``mesh`` as a Mesh of the vertices they use
    (same float32 values, so they transform to the same clip positions)."""
    f = mesh.faces[faces]
    used, inverse = np.unique(f, return_inverse=True)
    return Mesh(mesh.vertices[used], inverse.reshape(f.shape).astype(np.int32))


def partition(target: Mesh | Scene, parts: int) -> list[Part]:
    """Split ``target`` spatially into ``parts`` `Part` objects for sort-last rendering.

    The unit is a (instance, cluster) pair (clusters from `clraster.culling.clusters.clusters_of`,
    the renderer's own): their world boxes (`drawlist.key_boxes`) give centres, which a
    `kd_split` weighted by triangle counts divides into ``parts`` groups of about equal
    work and compact extent (so each part covers a small piece of the screen, and occlusion
    culling keeps working inside a part). Clusters with a NaN/Inf vertex have no box and go
    to part 0 (their bad triangles are dropped and counted there, as in one frame).

    Always ``parts`` parts: with fewer (bounded) clusters than parts, or an empty scene,
    some parts are empty (an empty `Scene`, ``n_faces == 0``); they render as background,
    which compositing leaves out, so the frame is still the whole scene's.

    Every triangle of the scene is in exactly one part. A part renders exactly its
    triangles: its own culling (frustum, cones, occlusion) is conservative like the whole
    scene's, and each triangle's depth and barycentrics depend only on the triangle, its
    instance's matrix and the image size. Deterministic: the same scene gives the same
    parts in every process.
    """
    from ..culling.clusters import clusters_of
    from ..pipeline.drawlist import GeometryPool, key_boxes

    if not isinstance(parts, int) or isinstance(parts, bool) or parts < 1:
        raise ValueError(f"parts must be a positive integer, got {parts!r}")
    if isinstance(target, Mesh):
        scene = Scene.from_mesh(target)
    elif isinstance(target, Scene):
        scene = target
    else:
        raise ValueError(f"expected a clraster.Mesh or clraster.Scene, got "
                         f"{type(target).__name__}")
    pool = GeometryPool.build(scene)
    lo, hi, bounded = key_boxes(pool, scene)
    n_keys = np.diff(pool.instance_key_base)
    inst_of_key = np.repeat(np.arange(n_keys.size), n_keys)
    local_of_key = np.arange(inst_of_key.size) - np.repeat(pool.instance_key_base[:-1], n_keys)
    gcl = pool.pool_clusters(inst_of_key, local_of_key)
    weights = pool.clusters[gcl, 1].astype(np.float64)
    centres = np.where(bounded[:, None], 0.5 * (lo + hi), 0.0)
    labels = np.zeros(inst_of_key.size, np.int64)
    if bounded.any():
        labels[bounded] = kd_split(centres[bounded], weights[bounded], parts)

    face_base = np.asarray(scene.face_base, np.int64)
    subs: dict[tuple[int, bytes], Mesh] = {}   # sub-meshes shared by instances
    out = []
    for p in range(parts):
        keys = np.flatnonzero(labels == p)           # ascending: grouped by instance
        insts, starts = np.unique(inst_of_key[keys], return_index=True)
        # one end per start; a part with no cluster (more parts than clusters, an empty
        # scene) has none and becomes an empty Scene, which renders as background
        ends = np.append(starts[1:], keys.size)[:starts.size]
        part_scene = Scene()
        ids = []
        for i, s, e in zip(insts.tolist(), starts.tolist(), ends.tolist(), strict=True):
            inst = scene.instances[i]
            mesh = inst.mesh
            if e - s == n_keys[i]:
                part_scene.add(mesh, inst.transform)
                ids.append(face_base[i] + np.arange(mesh.n_faces, dtype=np.int64))
                continue
            lc = local_of_key[keys[s:e]]
            cm = clusters_of(mesh)
            faces = np.sort(cm.face_ids[_gather_ranges(cm.tri_offset[lc],
                                                       np.diff(cm.tri_offset)[lc])]
                            ).astype(np.int64)
            sk = (id(mesh), lc.tobytes())
            sub = subs.get(sk)
            if sub is None:
                sub = subs[sk] = _sub_mesh(mesh, faces)
            part_scene.add(sub, inst.transform)
            ids.append(face_base[i] + faces)
        id_map = (np.concatenate(ids) if ids else np.zeros(0, np.int64)).astype(np.int32)
        out.append(Part(part_scene, id_map, p))
    return out


# -- sort-last on Dask -----------------------------------------------------------------------

@dataclass(frozen=True)
class ScatteredParts:
    """Parts of one scene held on the workers (`scatter_parts`): reuse it across frames so
    the geometry crosses the network once. futures: one Dask Future per `Part`."""

    futures: tuple
    n_faces: int


def scatter_parts(client, target: Mesh | Scene, parts: int) -> ScatteredParts:
    """`partition` ``target`` on the client and scatter the parts to the workers (spread
    over them, one copy each); pass the result to `render_sort_last` as its target.

    Raises:
        ValueError: a bad ``target`` or ``parts`` (`partition`); NoWorkersError: the client
            has no workers (`require_workers`: Dask's scatter would wait for one forever).
    """
    ps = partition(target, parts)
    require_workers(client)
    futs = client.scatter(ps, hash=False)
    return ScatteredParts(tuple(futs), sum(p.n_faces for p in ps))


def _render_part(part: Part, camera, width: int, height: int, config: RasterConfig | None,
                 render_kwargs: dict[str, Any]) -> Crop:
    """Worker task: render one part, ids mapped back to the original scene's, cropped to
    the rectangle it covers (all that needs to travel)."""
    if part.n_faces == 0:   # more parts than clusters: nothing to draw
        fr = Frame.empty(width, height)
        if render_kwargs.get("overdraw"):
            fr.overdraw = np.zeros((height, width), np.int32)
        return crop(fr)
    t0 = time.perf_counter()
    fr = worker_renderer(width, height, config).render(part.scene, camera, **render_kwargs)
    fr.triangle_id = part.scene_ids(fr.triangle_id)
    fr.fates = None
    out = crop(fr)
    out.frame.stats.timings_ms["part render (wall)"] = (time.perf_counter() - t0) * 1e3
    return out


def _render_part_from_path(path: str, parts: int, index: int, camera, width: int,
                           height: int, config: RasterConfig | None,
                           render_kwargs: dict[str, Any]) -> Crop:
    """Worker task: load and partition the scene file on the worker (once per process),
    then render part ``index``."""
    return _render_part(_worker_parts(path, parts)[index], camera, width, height, config,
                        render_kwargs)


def _composite_task(a: Crop, b: Crop) -> Crop:
    """Worker task: one node of the reduction tree (`clraster.composite.composite_crops`; it
    makes a new crop, because Dask may hold or retry the inputs)."""
    t0 = time.perf_counter()
    out = composite_crops(a, b)
    t = out.frame.stats.timings_ms
    t["composite"] = t.get("composite", 0.0) + (time.perf_counter() - t0) * 1e3
    return out


@dataclass(frozen=True)
class SortLastFutures:
    """The Dask futures of one sort-last frame: ``parts`` (one rendered part each) and
    ``frame`` (the root of the reduction tree), all `clraster.composite.Crop` objects
    (`clraster.composite.uncrop` makes the full frame). Waiting on ``parts`` first separates render
    time from compositing time (bench/sort_last.py)."""

    parts: tuple
    frame: Any


_RENDER_KWARGS = ("cull", "frustum", "cones", "occlusion", "overdraw")


def submit_sort_last(target, camera, client, *, parts: int | None = None, width: int,
                     height: int, config: RasterConfig | None = None,
                     **render_kwargs: Any) -> SortLastFutures:
    """Submit a sort-last frame to ``client`` without waiting; see `render_sort_last`."""
    from ..base.checks import check_size

    width, height = check_size(width, height)
    bad = set(render_kwargs) - set(_RENDER_KWARGS)
    if bad:
        raise ValueError(f"render_sort_last does not take {sorted(bad)}; it takes "
                         f"{list(_RENDER_KWARGS)} (per-cluster fates are not composited)")
    if isinstance(target, (str, os.PathLike)):
        if parts is None:
            raise ValueError("parts is needed when the target is a file")
        if not isinstance(parts, int) or isinstance(parts, bool) or parts < 1:
            raise ValueError(f"parts must be a positive integer, got {parts!r}")
        path = str(Path(target).resolve())
        if not Path(path).is_file():
            raise FileNotFoundError(f"scene file not found: {path!r}")
        require_workers(client)   # else the tasks below wait for a worker forever
        level = [client.submit(_render_part_from_path, path, parts, i, camera, width, height,
                               config, render_kwargs, pure=False) for i in range(parts)]
    else:
        if not isinstance(target, ScatteredParts):
            if parts is None:
                raise ValueError("parts is needed (how many parts to split the scene into)")
            target = scatter_parts(client, target, parts)   # checks for workers
        else:
            if parts is not None and parts != len(target.futures):
                raise ValueError(f"the scattered parts are {len(target.futures)}, not {parts}")
            require_workers(client)
        level = [client.submit(_render_part, f, camera, width, height, config,
                               render_kwargs, pure=False) for f in target.futures]
    rendered = tuple(level)
    while len(level) > 1:   # the reduction tree: neighbours pairwise, an odd one goes up
        nxt = [client.submit(_composite_task, level[k], level[k + 1], pure=False)
               for k in range(0, len(level) - 1, 2)]
        if len(level) % 2:
            nxt.append(level[-1])
        level = nxt
    return SortLastFutures(rendered, level[0])


def render_sort_last(target, camera, client, *, parts: int | None = None, width: int,
                     height: int, config: RasterConfig | None = None,
                     **render_kwargs: Any) -> Frame:
    """Render ``target`` split into ``parts`` parts on the workers of ``client``, composited.

    Args:
        target: a `clraster.Mesh` or `clraster.Scene` (partitioned on the client and
            scattered), a `ScatteredParts` from `scatter_parts` (reused: the geometry is
            already on the workers), or a path to a scene file (each worker loads and
            partitions it once per process; nothing large crosses the network).
        camera: a `clraster.Camera` (or any picklable object with ``view_projection``).
        client: a `dask.distributed.Client`.
        parts: number of parts (spatial k-d split of the clusters, `partition`).
        width, height: image size in pixels.
        config: the workers' `RasterConfig` (never changes the image).
        render_kwargs: ``cull``, ``frustum``, ``cones``, ``occlusion``, ``overdraw`` as in
            `Renderer.render` (each part is culled on its own, conservatively).

    Returns:
        One `Frame`, gathered to the client, equal bit for bit (depth, triangle_id,
        barycentrics) to ``Renderer(width, height).render(target, camera, **render_kwargs)``;
        overdraw is the sum of the parts' (with ``occlusion=False``, per pixel at least one
        frame's, as a part's tile Hi-Z skips only behind its own geometry, and equal to it
        with ``RasterConfig(tile_hiz=False)``; with occlusion a part culls less than the
        whole scene would). Stats: counts added over the parts
        (`clraster.composite.merge_stats`); timings_ms adds "part render (wall)" and
        "composite" (worker milliseconds, summed over the tasks).

    Raises:
        ValueError: bad parts, size or keywords; NoWorkersError (a ValueError): the client
            has no workers, after waiting `WORKER_WAIT_S` seconds for one
            (`require_workers`); FileNotFoundError: a scene file that is not there.
    """
    futs = submit_sort_last(target, camera, client, parts=parts, width=width, height=height,
                            config=config, **render_kwargs)
    return uncrop(futs.frame.result())



# -- batch views on Dask ---------------------------------------------------------------------

@dataclass(frozen=True)
class ChunkRecord:
    """What one chunk task of `render_views` did (the only thing it sends back).

    start: index of the chunk's first camera in the whole list. views: cameras in the chunk.
    rendered / skipped: views written by this task / found complete already. failures: the
    chunk's failed views (`clraster.batch.ViewFailure`, indices in the whole list). seconds:
    wall time of the task on the worker. worker: the worker's address. pid: its process.
    """

    start: int
    views: int
    rendered: int
    skipped: int
    failures: tuple[ViewFailure, ...]
    seconds: float
    worker: str
    pid: int


@dataclass(frozen=True)
class WorkerRate:
    """One worker's share of a `render_views` run: chunks run, views rendered, busy seconds
    (sum of its tasks' wall times) and views rendered per busy second."""

    worker: str
    chunks: int
    rendered: int
    seconds: float

    @property
    def views_per_s(self) -> float:
        return self.rendered / self.seconds if self.seconds > 0 else 0.0


def _per_worker(chunks) -> tuple[WorkerRate, ...]:
    acc: dict[str, list] = {}
    for c in chunks:
        a = acc.setdefault(c.worker, [0, 0, 0.0])
        a[0] += 1
        a[1] += c.rendered
        a[2] += c.seconds
    return tuple(WorkerRate(w, n, r, s) for w, (n, r, s) in sorted(acc.items()))


@dataclass(frozen=True)
class ViewsSummary(RenderSummary):
    """What `render_views` did: a `clraster.batch.RenderSummary` (views, rendered, skipped,
    failures, seconds = wall time on the client, views_per_s, failures_file) plus ``chunks``
    (one `ChunkRecord` per chunk task, in camera order) and `per_worker`."""

    chunks: tuple[ChunkRecord, ...] = ()

    @property
    def per_worker(self) -> tuple[WorkerRate, ...]:
        """Per worker address: chunks, views rendered, busy seconds, views/s. A worker that
        was lost and restarted comes back under a new address."""
        return _per_worker(self.chunks)

    def __str__(self) -> str:
        rates = self.per_worker
        lines = [f"{super().__str__()} on {len(rates)} workers"]
        lines += [f"  {w.worker}: {w.chunks} chunks, {w.rendered} views in {w.seconds:.1f} s "
                  f"busy, {w.views_per_s:.2f} views/s" for w in rates]
        return "\n".join(lines)


def _render_chunk(target, cameras: list, start: int, out_dir: str, outputs: tuple[str, ...],
                  width: int, height: int, config: RasterConfig | None,
                  render_kwargs: dict[str, Any], overwrite: bool = False,
                  depth_scale: float | None = None) -> ChunkRecord:
    """Worker task: `clraster.batch.render_views` of one chunk of cameras with this process's
    Renderer; the files are written here (atomic renames, views already complete skipped),
    so running it twice — Dask recomputing it after a worker was lost — writes every file
    once under its final name and nothing else."""
    from dask.distributed import get_worker

    from .batch import render_views as batch_render_views

    t0 = time.perf_counter()
    if isinstance(target, str):
        target = worker_target(target)
    s = batch_render_views(target, cameras, out_dir, outputs,
                           renderer=worker_renderer(width, height, config), start=start,
                           progress=False, failures_file=False, overwrite=overwrite,
                           depth_scale=depth_scale, **render_kwargs)
    return ChunkRecord(start, s.views, s.rendered, s.skipped, s.failures,
                       time.perf_counter() - t0, get_worker().address, os.getpid())


def _finish_out_dir(out_dir: str, failures: list[ViewFailure]) -> int:
    """Run on every worker at the end of `render_views`: write (or remove) the merged
    ``failures.json`` and delete temporary files a dead writer left (every task is finished
    by then, so no live writer owns one: all of `clraster.batch`'s temporaries go, those of
    other machines too). Returns the files deleted."""
    from .batch import FAILURES_FILE, remove_temporaries, write_failures

    out = Path(out_dir)
    if not out.is_dir():   # a worker on a machine that does not see out_dir
        return 0
    if failures:
        write_failures(out / FAILURES_FILE, failures)
    else:
        (out / FAILURES_FILE).unlink(missing_ok=True)
    return remove_temporaries(out, any_writer=True)


def _prepare_out_dir(out_dir: str, settings: dict[str, Any], overwrite: bool,
                     outputs: dict[str, dict] | None = None,
                     scene_path: str | None = None) -> bool:
    """Run on every worker before the chunks of `render_views`: make ``out_dir``, refuse
    one rendered with other settings or output options (`clraster.batch.prepare_out_dir`:
    OutDirMismatchError, raised by ``client.run`` on the client) and record this run's.
    ``scene_path``: the scene file the chunks load, whose `scene_fingerprint` is made here
    (the client does not load it). False on a worker that does not see the folder's
    parent."""
    from .batch import prepare_out_dir, scene_fingerprint

    out = Path(out_dir)
    if not out.parent.is_dir() or (out.exists() and not out.is_dir()):
        return False   # not seen from here, or not a folder: the chunk tasks say which
    if scene_path is not None:
        settings = {**settings, "scene": scene_fingerprint(worker_target(scene_path))}
    out.mkdir(exist_ok=True)
    prepare_out_dir(out, settings, overwrite=overwrite, outputs=outputs)
    return True


def _chunk_size(n_views: int, n_workers: int) -> int:
    """Default cameras per task: up to 16 (at ~50–100 ms a view, a second or so of work, so
    the ~1 ms a Dask task costs is lost in it, and a lost worker costs at most that much
    redone), fewer so that every worker gets at least two tasks."""
    return max(1, min(16, -(-n_views // max(1, 2 * n_workers))))


def render_views(target, cameras, client, out_dir: str | os.PathLike,
                 outputs=("depth", "ids"), *, chunk: int | None = None,
                 size: tuple[int, int] = (640, 480), config: RasterConfig | None = None,
                 progress: bool | None = None, overwrite: bool = False,
                 depth_scale: float | None = None, **render_kwargs: Any) -> ViewsSummary:
    """Render many views of one scene on the workers of ``client``, each writing its views'
    files; what `clraster.batch.render_views` does on one machine, with the same files.

    The scene goes to the workers once: a `clraster.Mesh` or `clraster.Scene` is scattered
    to every worker (``broadcast=True``; a worker started later fetches it from another),
    and a path to a scene file is loaded by each worker process itself (`worker_target`,
    once per process: nothing large crosses the network). The cameras are cut into chunks
    of ``chunk`` consecutive views; each chunk is one task that runs
    `clraster.batch.render_views` (``start=`` numbers its files) with the worker's
    `worker_renderer` — one Renderer, one OpenCL context per worker process, made there and
    kept — and sends back only a `ChunkRecord`. Frames never reach the client.

    Faults. Files are written to a temporary name and renamed into place, and a view whose
    files all exist is skipped, so a task is idempotent: when a worker is lost, Dask runs
    its tasks again elsewhere and every view ends up written exactly once under its final
    names; temporary files the dead process left are deleted at the end. A camera that
    cannot render fails its own view with a recorded message (``summary.failures`` and
    ``out_dir/failures.json``); the batch goes on. Errors that are not one view's fault (a
    folder that cannot be written) stop the batch: the task's exception is raised here.
    Re-running the same call skips every view already written. What rendered the files is
    recorded in ``out_dir`` as on one machine (`clraster.batch`): a folder rendered with
    another size or other image options is refused (`clraster.batch.OutDirMismatchError`,
    before the scene is sent) unless ``overwrite``; a view whose camera changed is rendered
    again.

    Args:
        target: a `clraster.Mesh` or `clraster.Scene`, or the path of a scene file that
            every worker can read (`clraster.Scene.load`).
        cameras: a list of cameras (`clraster.Camera`, camera entry dicts, picklable objects
            with ``view_projection``) or the path of a camera list file (read here,
            `clraster.views.load_cameras` with ``strict=False``).
        client: a `dask.distributed.Client`.
        out_dir: the folder the workers write into (made absolute here; on a real cluster a
            file system every worker sees under that path, also for the final clean-up).
        outputs: names out of `clraster.scale.batch.OUTPUTS` (depth, ids, bary, shaded,
            linear_depth, distance, normals, smooth_normals, camera_normals,
            smooth_camera_normals, mask, points), each optionally ``"name:format"`` (names
            and formats: `clraster.scale.batch`; "shaded" needs a Mesh target). Computed
            on the workers' hosts from the frames, as on one machine.
        chunk: cameras per task; default up to 16, fewer when there are few views
            (`_chunk_size`). Smaller chunks balance and recover better, larger ones cost
            less scheduling.
        size: (width, height) of the images. config: the workers' `RasterConfig` (never
            changes the images).
        progress: Dask's own progress bar (`dask.distributed.progress`, on stdout) over the
            chunk tasks; default only when stdout is a terminal.
        overwrite: render every view again and record this run's settings over the
            folder's (`clraster.batch.render_views`).
        depth_scale: linear_depth / distance PNG units per scene unit (default 1000:
            millimetres for a scene in metres), as `clraster.batch.render_views`.
        render_kwargs: `Renderer.render`'s keywords (cull, frustum, cones, occlusion, ...).

    Returns:
        a `ViewsSummary`: views, rendered, skipped, failures (in index order), seconds (wall
        time here), views_per_s, failures_file, chunks (records in camera order) and
        per_worker (views/s of each worker). A chunk that Dask recomputed after a worker
        was lost reports the views that worker had already written as skipped.

    Raises:
        ValueError / TypeError: bad outputs, formats, depth_scale, target, chunk, keywords
            or keyword values (the checks `Renderer.render` makes), a format this machine
            cannot write, before anything is submitted;
            OutDirMismatchError (a ValueError): ``out_dir`` holds views of another size or
            other options; CameraFileError: a camera list file that is not a list of entries;
            FileNotFoundError: a scene file that is not there; NoWorkersError (a
            ValueError): the client has no workers, after waiting `WORKER_WAIT_S` seconds
            for one (`require_workers`).
    """
    import functools
    import sys
    import types

    from dask.distributed import as_completed, wait
    from dask.distributed import progress as dask_progress

    from ..base.checks import check_flag, check_size
    from ..pipeline.renderer import Renderer, check_render_kwargs
    from ..world.camera import Camera
    from ..world.inputs import as_target
    from ..world.views import check_target, load_cameras
    from .batch import (
        FAILURES_FILE,
        check_camera_size,
        check_outputs,
        check_writable_outputs,
        outputs_record,
        run_settings,
        scene_fingerprint,
    )

    outs = check_outputs(outputs)
    record = outputs_record(outs, depth_scale)
    check_writable_outputs(outs)   # here: the workers are set up alike
    width, height = check_size(*size)
    if isinstance(target, (str, os.PathLike)):
        target = os.path.abspath(target)
        if not Path(target).is_file():
            raise FileNotFoundError(f"scene file not found: {target!r}")
    else:
        check_target(target)
    if chunk is not None and (isinstance(chunk, bool) or not isinstance(chunk, int)
                              or chunk < 1):
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    # the keywords (names and values) are checked as Renderer.render would, without a context
    probe: Any = types.SimpleNamespace(render=functools.partial(cast(Any, Renderer.render), None),
                                       width=width, height=height)
    check_render_kwargs(probe, render_kwargs)
    check_flag(overwrite, "overwrite")
    # the scene's fingerprint as the chunks will record it: a file's is made where it is
    # loaded (_prepare_out_dir, on the workers)
    scene = None if isinstance(target, str) else scene_fingerprint(as_target(target))
    settings = run_settings(width, height, render_kwargs, scene)
    if isinstance(cameras, (str, os.PathLike)):
        cameras = load_cameras(cameras, strict=False, size=(width, height))
    elif isinstance(cameras, (dict, Camera)):
        raise ValueError("cameras must be a list of cameras (or a camera list file), got one "
                         f"{type(cameras).__name__}; wrap it in a list")
    cams = list(cameras)
    check_camera_size(cams, width, height)
    out = os.path.abspath(out_dir)
    n_workers = require_workers(client)   # none: the chunk tasks would wait forever
    step = chunk or _chunk_size(len(cams), n_workers)
    show = sys.stdout.isatty() if progress is None else bool(progress)

    t0 = time.perf_counter()
    # the folder's record checked (and written) where the files go, before any work; an
    # OutDirMismatchError on a worker is raised here
    client.run(_prepare_out_dir, out, settings, overwrite, record,
               target if isinstance(target, str) else None)
    if isinstance(target, str):
        held = target
    else:
        # broadcast: every worker gets its copy now, not each task its own
        held = client.scatter(target, broadcast=True, hash=False)
    futures = [client.submit(_render_chunk, held, cams[s:s + step], s, out, outs, width,
                             height, config, render_kwargs, overwrite, depth_scale,
                             pure=False)
               for s in range(0, len(cams), step)]
    bar = None
    if show and futures:
        # Dask's text progress bar blocks until the tasks finish: run it beside the loop
        # that collects the records as they come
        bar = threading.Thread(target=dask_progress, args=(futures,), daemon=True,
                               kwargs={"notebook": False, "multi": False, "complete": False,
                                       "scheduler": client.scheduler.address})
        bar.start()
    records: dict[int, ChunkRecord] = {}
    try:
        # records are taken as tasks finish, so one whose worker is lost later is not lost
        # to the summary (Dask may still recompute it: it finds its files and skips them)
        for fut in as_completed(futures):
            rec = fut.result()   # raises a task's error (not one view's: those are records)
            records.setdefault(rec.start, rec)
        # every recomputation done too, so no task is left writing when we clean up
        wait(futures)
    finally:
        if bar is not None:
            bar.join(timeout=5.0)   # it ends (and clears its line) when the tasks do
        client.cancel(futures)
        del futures
        if not isinstance(held, str):
            client.cancel([held])
    chunks = tuple(records[s] for s in sorted(records))
    failures = tuple(f for c in chunks for f in c.failures)
    client.run(_finish_out_dir, out, list(failures), on_error="return")
    seconds = time.perf_counter() - t0
    ffile = Path(out) / FAILURES_FILE if failures else None
    return ViewsSummary(len(cams), sum(c.rendered for c in chunks),
                        sum(c.skipped for c in chunks), failures, seconds, ffile, chunks)
