"""The datasets sweep of the benchmark harness (``clraster bench --sweeps datasets``): views per
second of a dataset job — metric depth, triangle ids and face normals of many views of one
mesh — with clraster and with Open3D's ``RaycastingScene`` (Embree), side by side in one run.

The job, as a user writes it: clraster's many-view generator for training loops,
``clraster.batch.iter_views(mesh, cameras, ("linear_depth", "ids", "normals"), cull=...)``
(``cull`` back, then none), yields per view a dict of host arrays made on the device in the
resolve stage (two views in flight: `RasterConfig.views_in_flight`); Open3D casts one ray
per pixel (``create_rays_pinhole``, whose rays have z = 1 in the camera frame, so ``t_hit``
is the linear depth) and returns ``t_hit``, ``primitive_ids`` and ``primitive_normals`` as
NumPy arrays. Both get the same K: Open3D puts
pixel (u, v)'s centre at (u + ½, v + ½), OpenCV (clraster's `Camera.from_intrinsics`) at
(u, v), so Open3D's K is clraster's with cx, cy + ½, and the two agree on the id of almost
every pixel (the first view's agreement is recorded).

The cameras (:func:`sphere_poses`) sit on a Fibonacci lattice of a sphere around the mesh,
looking at its centre, framing its bounding sphere with a 40° vertical field of view. Each
job is warmed up on the first view (kernel builds, Embree's BVH), then the jobs run
``repeat`` rounds in ABBA order (A B C, C B A, …: a drift of the shared machine's speed hits
all alike), each round every view once; views/s per round, medians, and clraster's median
over Open3D's. Open3D is used where ``import open3d`` works in the harness's Python
(``pip install 'clraster[open3d]'``, which needs the system's libusb-1.0); without it only
clraster is timed and the rows say why.

:func:`run_sweep` measures a list of meshes into the summary that results.json keeps under
``"datasets"``; :func:`datasets_targets` turns it into issue 32's speed targets (met / missed
/ not measured). ``bench/datasets.py`` is the same measurement for one mesh file.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: The meshes of the sweep (aliases of `clraster.bench.spec.MESH_ALIASES`): the 871K dragon
#: of the issue's headline targets and three under 100K triangles (86K, 69K, 5.9K).
DATASETS_MESHES = ["dragon", "armadillo", "bunny", "spot"]
#: Image size of the job (the issue's).
DATASETS_SIZE = (640, 480)
#: Views per round in a full run (the issue's measurement used 200).
DATASETS_VIEWS = 200
#: Views per round with --quick (checks the sweep runs, not a speed).
QUICK_VIEWS = 6
#: clraster's face-culling modes of the sweep, in the order they are timed.
DATASETS_CULLS = ("back", "none")
#: The issue's "meshes under 100K triangles" (the ≥ 2× target).
SMALL_MESH_TRIANGLES = 100_000
#: The job names of a row's rounds.
OPEN3D = "open3d"
#: What clraster's job makes per view (`clraster.batch.iter_views` output names).
JOB_OUTPUTS = ("linear_depth", "ids", "normals")

METHOD = ("Views per second of the dataset job (linear depth + triangle ids + face normals "
          "per view, as host arrays): clraster's clraster.batch.iter_views(mesh, cameras, "
          "(\"linear_depth\", \"ids\", \"normals\")) (made on the device, two views in "
          "flight) for cull back and cull none; "
          "Open3D's RaycastingScene (Embree) casts one ray per pixel with the same K "
          "(pixel centres matched) and returns t_hit, primitive_ids, primitive_normals. "
          "Cameras on a Fibonacci sphere around the mesh, framing it. Each job warmed up on "
          "the first view, then {repeat} rounds in ABBA order, every view once per round; "
          "medians of the rounds. Ratio = clraster's median views/s / Open3D's. Ids agree: "
          "fraction of the first view's pixels where clraster's id equals Open3D's "
          "(background −1 on both). Both use every core (PoCL's and Embree's threads).")


class DatasetsError(ValueError):
    """Bad settings of the datasets sweep (views, repeat, size or culling mode)."""


# =======================================================================================
# Cameras and jobs
# =======================================================================================

def sphere_poses(mesh: Any, n: int, width: int, height: int, fov_y: float = 40.0
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
    """K (OpenCV: pixel (u, v)'s centre at (u, v), float64 (3, 3)) and ``n`` camera → world
    poses (float64 (4, 4), OpenCV axes: +x right, +y down, +z forward) on a Fibonacci
    sphere around the mesh's bounding box, each looking at its centre from the distance at
    which its bounding sphere fits the vertical field of view ``fov_y`` (degrees), plus 5%."""
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    f = 0.5 * height / math.tan(math.radians(fov_y) / 2.0)
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0, 0, 1.0]])
    dist = radius / math.sin(math.radians(fov_y) / 2.0) * 1.05
    poses = []
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for i in range(n):
        y = 1.0 - 2.0 * (i + 0.5) / n
        r = math.sqrt(1.0 - y * y)
        d = np.array([math.cos(golden * i) * r, y, math.sin(golden * i) * r])
        eye = centre + dist * d
        z = (centre - eye) / np.linalg.norm(centre - eye)        # OpenCV: +z forward
        up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
        x = np.cross(z, -up)                                     # +x right, +y down
        x /= np.linalg.norm(x)
        yv = np.cross(z, x)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, yv, z, eye
        poses.append(pose)
    return k, poses


def near_far(mesh: Any, poses: list[np.ndarray]) -> tuple[float, float]:
    """Near and far planes that hold the whole mesh from every pose of :func:`sphere_poses`
    (all at one distance from its centre)."""
    lo, hi = mesh.bounds()
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    dist = float(np.linalg.norm(poses[0][:3, 3] - (lo + hi) / 2.0))
    return max(dist - 1.5 * radius, 1e-3 * dist), dist + 1.5 * radius


def clraster_job(mesh: Any, k: np.ndarray, poses: list[np.ndarray], width: int, height: int,
                 cull: str, near: float, far: float, renderer: Any = None
                 ) -> tuple[Callable[[], None], np.ndarray]:
    """(run, ids): ``run()`` does the job for every pose with clraster
    (`clraster.batch.iter_views`); ``ids`` is the first view's triangle ids (int32
    (height, width), −1 background), from the warm-up here: the first four views, so that
    both renderers of the views in flight have drawn the mesh. ``renderer``: a
    `clraster.Renderer` of this size to reuse."""
    from clraster import Camera, Renderer
    from clraster.scale.batch import iter_views

    r = renderer if renderer is not None else Renderer(width, height)
    cams = [Camera.from_intrinsics(k, width, height, pose=p, near=near, far=far)
            for p in poses]

    def views(cameras: list[Any]) -> list[dict[str, Any]]:
        return list(iter_views(mesh, cameras, JOB_OUTPUTS, renderer=r, cull=cull))

    first = np.array(views(cams[:4])[0]["ids"], np.int32)

    def run() -> None:
        for _ in iter_views(mesh, cams, JOB_OUTPUTS, renderer=r, cull=cull):
            pass
    return run, first


def open3d_status() -> tuple[bool, str]:
    """(available, reason): whether ``import open3d`` works here, and its version or why
    not."""
    try:
        import open3d as o3d
    except Exception as exc:   # ImportError, or OSError for a missing libusb-1.0
        return False, (f"Open3D skipped: cannot import open3d ({type(exc).__name__}: {exc}; "
                       "pip install 'clraster[open3d]', which needs the system's libusb-1.0)")
    return True, f"Open3D {o3d.__version__} RaycastingScene (Embree)"


def open3d_job(mesh: Any, k: np.ndarray, poses: list[np.ndarray], width: int, height: int
               ) -> tuple[Callable[[], None], np.ndarray]:
    """(run, ids) as :func:`clraster_job`, with Open3D's RaycastingScene (its scene built
    and the first view cast here). ImportError without Open3D."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, np.int32))
    scene.add_triangles(tm)
    k_o3d = k.copy()
    k_o3d[:2, 2] += 0.5          # Open3D's pixel centres at (u + 0.5, v + 0.5)
    intr = o3d.core.Tensor(k_o3d)
    extrs = [o3d.core.Tensor(np.linalg.inv(p)) for p in poses]

    def one(extr: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rays = scene.create_rays_pinhole(intr, extr, width, height)
        ans = scene.cast_rays(rays)
        return (ans["t_hit"].numpy(), ans["primitive_ids"].numpy().astype(np.int64),
                ans["primitive_normals"].numpy())

    ids = one(extrs[0])[1]
    first = np.where(ids == np.iinfo(np.uint32).max, -1, ids).astype(np.int32)

    def run() -> None:
        for e in extrs:
            one(e)
    return run, first


def time_rounds(jobs: dict[str, Callable[[], None]], n_views: int, repeat: int,
                log: Callable[[str], None] | None = None) -> dict[str, list[float]]:
    """Views/s of each job in each of ``repeat`` rounds, the jobs in ABBA order (the order
    reverses every round)."""
    rates: dict[str, list[float]] = {name: [] for name in jobs}
    names = list(jobs)
    for rep in range(repeat):
        for name in names if rep % 2 == 0 else names[::-1]:
            t0 = time.perf_counter()
            jobs[name]()
            rates[name].append(n_views / (time.perf_counter() - t0))
            if log:
                log(f"round {rep + 1}: {name:<16} {rates[name][-1]:7.2f} views/s")
    return rates


# =======================================================================================
# One mesh, the sweep
# =======================================================================================

def _check(views: int, repeat: int, size: tuple[int, int], culls: tuple[str, ...]) -> None:
    bad = [c for c in culls if c not in ("back", "front", "none")]
    if views < 1 or repeat < 1 or min(size) < 1 or bad or not culls:
        raise DatasetsError(f"datasets sweep: need views >= 1 (got {views}), repeat >= 1 "
                            f"(got {repeat}), a positive size (got {size}) and culling "
                            f"modes among back/front/none (got {list(culls)})")


def measure_mesh(mesh: Any, name: str, *, views: int = DATASETS_VIEWS,
                 size: tuple[int, int] = DATASETS_SIZE, repeat: int = 3,
                 culls: tuple[str, ...] = DATASETS_CULLS, use_open3d: bool = True,
                 source: str = "", log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One row of the sweep: the job on ``mesh`` (a `clraster.Mesh`) for each culling mode
    of clraster and, with ``use_open3d`` and where it imports, Open3D.

    Returns a dict: mesh, source, triangles, views, size [w, h], repeat; ``clraster``:
    {cull: {runs_views_per_s, median_views_per_s, covered_fraction (first view),
    ids_agree_open3d (first view; None without Open3D)}}; ``open3d``: {runs_views_per_s,
    median_views_per_s, covered_fraction} or {skipped: reason}; ``ratio_vs_open3d``:
    {cull: clraster median / Open3D median} (empty without Open3D). DatasetsError for bad
    settings."""
    from clraster import Renderer

    culls = tuple(culls)
    _check(views, repeat, size, culls)
    w, h = size
    k, poses = sphere_poses(mesh, views, w, h)
    near, far = near_far(mesh, poses)
    renderer = Renderer(w, h)
    jobs: dict[str, Callable[[], None]] = {}
    firsts: dict[str, np.ndarray] = {}
    for cull in culls:
        jobs[f"clraster {cull}"], firsts[cull] = clraster_job(mesh, k, poses, w, h, cull,
                                                              near, far, renderer)
    o3d_ok, o3d_reason = open3d_status() if use_open3d else (
        False, "Open3D skipped: --no-peer")
    ref = None
    if o3d_ok:
        jobs[OPEN3D], ref = open3d_job(mesh, k, poses, w, h)
    rates = time_rounds(jobs, views, repeat, log)
    med = {n: statistics.median(v) for n, v in rates.items()}
    cl: dict[str, dict[str, Any]] = {}
    for cull in culls:
        ids = firsts[cull]
        cl[cull] = {"runs_views_per_s": rates[f"clraster {cull}"],
                    "median_views_per_s": med[f"clraster {cull}"],
                    "covered_fraction": float(np.mean(ids >= 0)),
                    "ids_agree_open3d": None if ref is None else float(np.mean(ids == ref))}
    o3d: dict[str, Any] = {"skipped": o3d_reason}
    ratio: dict[str, float] = {}
    if ref is not None:
        o3d = {"runs_views_per_s": rates[OPEN3D], "median_views_per_s": med[OPEN3D],
               "covered_fraction": float(np.mean(ref >= 0))}
        ratio = {cull: med[f"clraster {cull}"] / med[OPEN3D] for cull in culls}
    return {"mesh": name, "source": source, "triangles": int(mesh.n_faces), "views": views,
            "size": [w, h], "repeat": repeat, "clraster": cl, "open3d": o3d,
            "ratio_vs_open3d": ratio}


def run_sweep(names: list[str], meshes_dir: Path, *, views: int = DATASETS_VIEWS,
              size: tuple[int, int] = DATASETS_SIZE, repeat: int = 3,
              use_open3d: bool = True, log: Callable[[str], None] | None = None,
              start: Callable[[str], None] | None = None,
              done: Callable[[], None] | None = None) -> dict[str, Any]:
    """The sweep over the meshes ``names`` (aliases, files in ``meshes_dir``, paths, or
    ``example``), one :func:`measure_mesh` row each. A missing mesh is skipped and a
    failing one recorded, with the others measured. ``start(label)`` / ``done()`` bracket
    each mesh (the harness's progress bar). Returns {method, settings, open3d: {available,
    reason}, rows, skipped, failed}; DatasetsError for bad settings or a name that is not a
    mesh (a grid, a plant)."""
    from clraster.bench.spec import SceneMissing, SceneSpec, load_scene

    _check(views, repeat, size, DATASETS_CULLS)
    specs = [SceneSpec.parse(n) for n in names]
    bad = [s.text for s in specs if s.kind not in ("mesh", "example") or s.view != "framing"]
    if bad:
        raise DatasetsError(f"datasets sweep: {bad} are not meshes; name meshes (an alias "
                            "such as dragon, a file in --meshes, a path, or example)")
    o3d_ok, o3d_reason = open3d_status() if use_open3d else (
        False, "Open3D skipped: --no-peer")
    rows: list[dict[str, Any]] = []
    skipped: list[str] = []
    failed: list[str] = []
    for spec in specs:
        label = f"datasets {spec.text} {size[0]}x{size[1]} x{views} views"
        if start:
            start(label)
        try:
            loaded = load_scene(spec, meshes_dir)
            rows.append(measure_mesh(loaded.target, spec.text, views=views, size=size,
                                     repeat=repeat, use_open3d=use_open3d,
                                     source=loaded.source, log=log))
        except SceneMissing as exc:
            skipped.append(f"{label}: {exc}")
        except Exception as exc:   # keep the other meshes of the sweep
            failed.append(f"{label}: {type(exc).__name__}: {exc}")
        if done:
            done()
    return {"method": METHOD.format(repeat=repeat),
            "settings": {"meshes": list(names), "views": views, "size": list(size),
                         "repeat": repeat, "culls": list(DATASETS_CULLS)},
            "open3d": {"available": o3d_ok, "reason": o3d_reason},
            "rows": rows, "skipped": skipped, "failed": failed}


# =======================================================================================
# Targets
# =======================================================================================

def _is_dragon(row: dict) -> bool:
    return row["source"].endswith("stanford_dragon_vrip.ply") or row["mesh"] == "dragon"


def datasets_targets(summary: dict | None) -> list[dict]:
    """Issue 32's speed targets of the dataset job, in the harness's target records (name,
    description, config, value, threshold, comparison, met, unit, note; met None = not
    measured): clraster ≥ 1.5× Open3D's views/s on the dragon with cull back, ≥ 1.0× with
    cull none, ≥ 2× on meshes under 100K triangles (the smallest ratio over those meshes
    and both culling modes)."""
    rows = (summary or {}).get("rows") or []
    why_none = ("no datasets sweep in this run (--sweeps datasets)" if summary is None else
                (summary.get("open3d") or {}).get("reason") or "Open3D not measured")
    timed = [r for r in rows if r["ratio_vs_open3d"]]
    out = []

    def target(name: str, desc: str, row: dict | None, cull: str | None, threshold: float,
               note: str) -> None:
        value = row["ratio_vs_open3d"].get(cull) if row and cull else None
        cfg = f"datasets {row['mesh']} cull={cull}" if row and cull else None
        out.append({"name": name, "description": desc, "config": cfg, "value": value,
                    "threshold": threshold, "comparison": ">=",
                    "met": None if value is None else bool(value >= threshold),
                    "unit": "×", "note": None if value is not None else note})

    dragon = next((r for r in timed if _is_dragon(r)), None)
    no_dragon = why_none if not timed else "no dragon (stanford_dragon_vrip.ply) row timed " \
                                           "against Open3D in this run"
    for cull, thr in (("back", 1.5), ("none", 1.0)):
        target(f"datasets_dragon_{cull}_vs_open3d", f"dataset job, dragon, cull {cull}: "
               "clraster views/s / Open3D RaycastingScene views/s (issue 32)", dragon,
               cull, thr, no_dragon)
    small = [(r, c, v) for r in timed if r["triangles"] < SMALL_MESH_TRIANGLES
             for c, v in r["ratio_vs_open3d"].items()]
    worst = min(small, key=lambda t: t[2], default=None)
    target("datasets_small_vs_open3d", f"dataset job, meshes under {SMALL_MESH_TRIANGLES:,} "
           "triangles, both culling modes: smallest clraster views/s / Open3D views/s "
           "(issue 32)", worst[0] if worst else None, worst[1] if worst else None, 2.0,
           why_none if not timed else "no mesh under 100K triangles timed against Open3D "
                                      "in this run")
    return out
