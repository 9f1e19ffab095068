"""Benchmark harness: the OpenCL pipeline vs its NumPy twin (and Mesa llvmpipe), one run.

    clraster bench                 # the full matrix (about 10-20 min on 2 cores)
    clraster bench --quick         # the smoke mode CI runs (< 1 min; asserts it works)
    clraster bench --list          # print the configurations and exit

The matrix is three sweeps, each a list of configurations (scene × image size × culling
mode); a configuration that belongs to two sweeps runs once:

* ``triangles`` (time vs triangles): meshes from ``--meshes`` (spot … the 871K dragon), an
  instance grid of the dragon and the procedural plant up to ≥ 10M triangles, at ``--size``;
* ``pixels`` (time vs pixels): ``--pixels-scene`` at each of ``--sizes``;
* ``culling``: ``--culling-scene`` (the ≥ 10M plant seen from inside) at ``--size`` in each
  of ``--modes``: off (no object culling), frustum (BVH frustum + normal cones) and occlusion
  (those + two-phase Hi-Z occlusion culling).

Per configuration: one Renderer, warm-up frames of the OpenCL path (occlusion gets
``--occlusion-warmup`` more, so its visible set from the previous frame is warm) and one of
the twin, then ``--repeat`` rounds interleaved (OpenCL, twin, OpenCL, twin, ...), so machine
noise hits both alike; medians. A frame's time is the wall time of ``render()`` (host
culling and the read-back of depth, ids and barycentrics included); per-stage times are
the device times from OpenCL profiling events (``frame.stats.timings_ms``). The twin gets a
time budget per configuration (``--twin-budget``): once spent, it stops after ≥ 1 timed run
and the JSON says how many it made. The twin has no occlusion culling: in the occlusion
configuration it renders the frustum mode (the same image). The OpenCL and twin images are
compared (triangle ids identical, largest depth difference). The llvmpipe peer
(`clraster.bench.peer_llvmpipe`) draws the whole scene with back-face culling once per
(scene, size), on the same view-projection; its coverage is compared with clraster's.

Also measured: cold start (fresh, empty PoCL and pyopencl kernel caches) and warm start of a
fresh process, and the peak memory (ru_maxrss) of a fresh process rendering one frame of
each scene, the OpenCL path and the twin separately.

Outputs in ``--out``: results.json, results.md, and PNG plots (with matplotlib).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SCHEMA = "clraster-bench/1"

#: Short names of the meshes in ../shared/meshes (see meshes.json there).
MESH_ALIASES = {
    "spot": "spot.ply",
    "bunny": "stanford_bunny.ply",
    "armadillo": "armadillo_86k.ply",
    "lucy": "stanford_lucy_100k.ply",
    "dragon202k": "stanford_dragon_res2.ply",
    "igea": "igea.ply",
    "dragon": "stanford_dragon_vrip.ply",
}

#: Renderer.render keyword arguments per culling mode.
MODES: dict[str, dict[str, bool]] = {
    "off": {"frustum": False, "cones": False},
    "frustum": {"frustum": True, "cones": True},
    "occlusion": {"frustum": True, "cones": True, "occlusion": True},
}
#: The twin has no occlusion culling; occlusion culling never changes the image, so in the
#: occlusion configuration it renders the frustum mode.
TWIN_MODE = {"off": "off", "frustum": "frustum", "occlusion": "frustum"}

# plant(10_000_000) has 9,999,960 triangles: ask for a little more to be >= 10M.
FULL_TRIANGLE_SCENES = ["spot", "bunny", "armadillo", "lucy", "dragon202k", "dragon",
                        "grid:dragon:2x2x1", "plant:1M@overview", "plant:5M@overview",
                        "plant:10.1M@overview"]
FULL_PIXEL_SIZES = ["640x480", "1280x720", "1920x1080", "3840x2160"]
TEN_MILLION = 10_000_000
#: Default twin cutoff of the full run. The twin's raster dominates its frame on the plant
#: (about 20 s per frame for 1M triangles seen from outside at 1920x1080, measured here), so
#: a single frame of the 10M plant takes minutes and its configurations (4, plus a memory
#: probe) would double the run; they are recorded as "twin skipped" with this reason.
FULL_TWIN_MAX_TRIANGLES = 6_000_000


# =======================================================================================
# Scenes
# =======================================================================================

class SceneMissing(Exception):
    """A scene's mesh file is not there: the configuration is skipped, not the run."""


@dataclass(frozen=True)
class SceneSpec:
    """A scene named on the command line.

    Forms: ``NAME`` (an alias of :data:`MESH_ALIASES`, a file in ``--meshes`` with or without
    ``.ply``, or a path), ``example`` (the built-in example mesh), ``grid:MESH:NXxNYxNZ``
    (`clraster.scenes.instance_grid`), ``plant:N[@inside|@overview]`` (`clraster.scenes.plant`,
    N may end in K or M; the camera is `plant_inside_camera` (default) or
    `plant_overview_camera`).
    """

    text: str
    kind: str                     # mesh | example | grid | plant
    mesh: str = ""                # mesh name (mesh, grid)
    count: int = 0                # plant triangles
    grid: tuple[int, int, int] = (1, 1, 1)
    view: str = "framing"         # framing | grid | inside | overview

    @property
    def geometry(self) -> tuple:
        """What is loaded or built (the view aside): specs with the same geometry share one
        loaded scene, so its clusters and BVHs are built once."""
        return (self.kind, self.mesh, self.count, self.grid)

    @staticmethod
    def parse(text: str) -> SceneSpec:
        t = text.strip()
        if t == "example":
            return SceneSpec(t, "example")
        if t.startswith("plant:"):
            body, _, view = t[6:].partition("@")
            view = view or "inside"
            if view not in ("inside", "overview"):
                raise ValueError(f"plant view must be inside or overview, got {view!r}")
            return SceneSpec(t, "plant", count=_count(body), view=view)
        if t.startswith("grid:"):
            parts = t.split(":")
            if len(parts) != 3:
                raise ValueError(f"expected grid:MESH:NXxNYxNZ, got {t!r}")
            dims = tuple(int(v) for v in parts[2].lower().split("x"))
            if len(dims) != 3 or min(dims) < 1:
                raise ValueError(f"expected three positive counts NXxNYxNZ, got {parts[2]!r}")
            return SceneSpec(t, "grid", mesh=parts[1], grid=dims, view="grid")
        if not t:
            raise ValueError("empty scene name")
        return SceneSpec(t, "mesh", mesh=t)


def _count(text: str) -> int:
    m = re.fullmatch(r"\s*([\d.]+)\s*([kKmM]?)\s*", text)
    if not m:
        raise ValueError(f"expected a triangle count like 20000, 20K or 10.1M, got {text!r}")
    return int(round(float(m.group(1)) * {"": 1, "k": 1e3, "m": 1e6}[m.group(2).lower()]))


def mesh_path(name: str, meshes: Path) -> Path | None:
    """File of mesh `name` (alias, file in `meshes` with or without .ply, or a path)."""
    cands = [meshes / MESH_ALIASES.get(name, name), meshes / f"{name}.ply", Path(name)]
    return next((p for p in cands if p.is_file()), None)


def estimated_triangles(spec: SceneSpec, meshes: Path) -> int:
    """Triangles of `spec` without loading it (for the progress bar's ETA)."""
    if spec.kind == "plant":
        return spec.count
    if spec.kind == "example":
        return 60_000
    n = 100_000
    p = mesh_path(spec.mesh, meshes) if spec.mesh != "example" else None
    try:
        info = json.loads((meshes / "meshes.json").read_text())
        n = next(int(m["triangles"]) for m in info if p is not None and m["name"] == p.name)
    except (OSError, ValueError, StopIteration, KeyError, TypeError):
        if p is not None:
            n = max(1000, p.stat().st_size // 20)
    return n * math.prod(spec.grid)


@dataclass
class LoadedScene:
    spec: SceneSpec
    target: Any                   # Mesh or Scene
    triangles: int
    instances: int
    build_s: float
    source: str

    def camera(self, width: int, height: int, view: str | None = None):
        """The camera of `view` (default the loading spec's view)."""
        from clraster import Camera
        from clraster import scenes as sc

        v = view or self.spec.view
        if v == "inside":
            return sc.plant_inside_camera(self.target, width, height)
        if v == "overview":
            return sc.plant_overview_camera(self.target, width, height)
        if v == "grid":
            return sc.grid_camera(self.target, width, height)
        lo, hi = self.target.bounds()   # as bench/frame_time.py frames a mesh
        return Camera.framing(lo, hi, aspect=width / height)

    def describe(self, spec: SceneSpec | None = None) -> dict[str, Any]:
        spec = spec or self.spec
        return {"name": spec.text, "kind": spec.kind, "view": spec.view,
                "source": self.source, "triangles": self.triangles,
                "instances": self.instances, "build_s": round(self.build_s, 4)}


def _load_mesh(name: str, meshes: Path):
    import clraster

    if name == "example":
        from clraster.examples import example_mesh

        return example_mesh(), "clraster.examples.example_mesh()"
    p = mesh_path(name, meshes)
    if p is None:
        raise SceneMissing(f"mesh {name!r} not found (looked for "
                           f"{meshes / MESH_ALIASES.get(name, name)}; set --meshes DIR)")
    return clraster.Mesh.load(p), str(p)


def load_scene(spec: SceneSpec, meshes: Path) -> LoadedScene:
    """Load or build `spec` (SceneMissing when its file is not there)."""
    from clraster import scenes as sc

    t0 = time.perf_counter()
    if spec.kind == "plant":
        target = sc.plant(spec.count)
        source = f"clraster.scenes.plant({spec.count})"
    elif spec.kind == "grid":
        mesh, src = _load_mesh(spec.mesh, meshes)
        target = sc.instance_grid(mesh, *spec.grid)
        source = f"instance_grid({src}, {', '.join(map(str, spec.grid))})"
    else:
        target, source = _load_mesh(spec.mesh if spec.kind == "mesh" else "example", meshes)
    build = time.perf_counter() - t0
    return LoadedScene(spec, target, int(target.n_faces),
                       int(getattr(target, "n_instances", 1)), build, source)


# =======================================================================================
# Configurations
# =======================================================================================

@dataclass
class Config:
    scene: SceneSpec
    width: int
    height: int
    mode: str
    sweeps: list[str] = field(default_factory=list)

    @property
    def key(self) -> tuple:
        return (self.scene.text, self.width, self.height, self.mode)

    @property
    def id(self) -> str:
        return f"{self.scene.text}/{self.width}x{self.height}/{self.mode}"


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"sizes must be positive, got {text!r}")
    return w, h


def _limit(text: str) -> int:
    """--twin-max-triangles: a count (20K, 6M) or 'none' (-1: no limit)."""
    if text.strip().lower() == "none":
        return -1
    try:
        return _count(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _list(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def build_matrix(a: argparse.Namespace) -> list[Config]:
    """The configurations of the requested sweeps, duplicates merged, grouped by scene."""
    out: dict[tuple, Config] = {}

    def add(scene: str, size: tuple[int, int], mode: str, sweep: str) -> None:
        c = Config(SceneSpec.parse(scene), size[0], size[1], mode)
        c = out.setdefault(c.key, c)
        if sweep not in c.sweeps:
            c.sweeps.append(sweep)

    if "triangles" in a.sweeps:
        for s in a.scenes:
            add(s, a.size, "frustum", "triangles")
    if "pixels" in a.sweeps:
        for size in a.sizes:
            add(a.pixels_scene, size, "frustum", "pixels")
    if "culling" in a.sweeps:
        for m in a.modes:
            add(a.culling_scene, a.size, m, "culling")
    order: dict[tuple, int] = {}
    for c in out.values():
        order.setdefault(c.scene.geometry, len(order))
    mode_rank = {m: i for i, m in enumerate(MODES)}
    return sorted(out.values(), key=lambda c: (order[c.scene.geometry], c.scene.view,
                                               c.width * c.height, mode_rank[c.mode]))


# =======================================================================================
# Progress bar (stderr)
# =======================================================================================

def _hms(s: float) -> str:
    s = int(round(max(0.0, s)))
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class Progress:
    """``[#####-----] k/n label | elapsed, ETA`` on stderr; steps carry a cost estimate, so
    the ETA weighs a 10M-triangle configuration more than a 6K one. Redraws in place on a
    terminal, one line per step otherwise (logs)."""

    def __init__(self, weights: list[float], stream=None) -> None:
        self.weights = [max(w, 1e-9) for w in weights]
        self.total = sum(self.weights)
        self.done_w = 0.0
        self.k = 0
        self.t0 = time.perf_counter()
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.label = ""

    def start(self, label: str, detail: str = "") -> None:
        self.label = label
        n = len(self.weights)
        el = time.perf_counter() - self.t0
        eta = (el / self.done_w * (self.total - self.done_w)) if self.done_w > 0 else None
        frac = self.done_w / self.total if self.total else 1.0
        bar = "#" * int(round(20 * frac))
        line = (f"[{bar:<20}] {self.k + 1}/{n} {label} | {_hms(el)} elapsed, ETA "
                f"{_hms(eta) if eta is not None else '?'}" + (f" | {detail}" if detail else ""))
        if self.tty:
            self.stream.write("\r\x1b[2K" + line[:160])
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def detail(self, text: str) -> None:
        """Where the current step is (redrawn on a terminal only, to keep logs short)."""
        if self.tty:
            self.start(self.label, text)

    def finish_step(self) -> None:
        if self.k < len(self.weights):
            self.done_w += self.weights[self.k]
        self.k += 1

    def close(self) -> None:
        el = time.perf_counter() - self.t0
        line = f"[{'#' * 20}] {len(self.weights)}/{len(self.weights)} done in {_hms(el)}"
        self.stream.write(("\r\x1b[2K" if self.tty else "") + line + "\n")
        self.stream.flush()

    def log(self, text: str) -> None:
        """A message that does not break the bar."""
        self.stream.write(("\r\x1b[2K" if self.tty else "") + text + "\n")
        self.stream.flush()


# =======================================================================================
# Measuring one configuration
# =======================================================================================

def _median(xs: list[float]) -> float | None:
    return float(statistics.median(xs)) if xs else None


def _stage_medians(runs: list[dict[str, float]]) -> dict[str, float]:
    keys: list[str] = []
    for r in runs:
        keys += [k for k in r if k not in keys]
    return {k: float(statistics.median(r[k] for r in runs if k in r)) for k in keys}


def _rate(n: float, ms: float | None) -> float | None:
    return n / (ms * 1e-3) if ms else None


def run_config(cfg: Config, sc: LoadedScene, a: argparse.Namespace, peer: PeerRunner,
               log, note=lambda text: None) -> dict[str, Any]:
    """Measure one configuration (see the module docstring); returns its JSON record."""
    import numpy as np

    import clraster

    w, h = cfg.width, cfg.height
    cam = sc.camera(w, h, cfg.scene.view)
    kw = MODES[cfg.mode]
    twin_mode = TWIN_MODE[cfg.mode]
    twin_kw = {k: v for k, v in MODES[twin_mode].items() if k != "occlusion"}
    rec: dict[str, Any] = {
        "id": cfg.id, "sweeps": list(cfg.sweeps), "scene": sc.describe(cfg.scene),
        "triangles": sc.triangles, "size": [w, h], "pixels": w * h, "mode": cfg.mode,
        "render_args": {"cull": a.cull, **kw},
    }
    r = clraster.Renderer(w, h)
    n_warm = a.warmup + (a.occlusion_warmup if cfg.mode == "occlusion" else 0)
    warm_ms = []
    f = None
    note("OpenCL warm-up")
    for _ in range(max(1, n_warm)):
        t0 = time.perf_counter()
        f = r.render(sc.target, cam, cull=a.cull, **kw)
        warm_ms.append((time.perf_counter() - t0) * 1e3)

    twin_skip = None
    if a.no_twin:
        twin_skip = "twin skipped: --no-twin"
    elif a.twin_max_triangles is not None and sc.triangles > a.twin_max_triangles:
        twin_skip = (f"twin skipped: {sc.triangles:,} triangles > --twin-max-triangles "
                     f"{a.twin_max_triangles:,}")
    g = None
    twin_warm_ms: list[float] = []
    twin_spent = 0.0
    if twin_skip is None:
        note("twin warm-up")
        t0 = time.perf_counter()
        g = clraster.reference.render(sc.target, cam, w, h, cull=a.cull, **twin_kw)
        twin_spent = time.perf_counter() - t0
        twin_warm_ms.append(twin_spent * 1e3)

    cl_ms, cl_stages, tw_ms, tw_stages = [], [], [], []
    budget_hit = False
    for i in range(a.repeat):
        note(f"round {i + 1}/{a.repeat}")
        t0 = time.perf_counter()
        f = r.render(sc.target, cam, cull=a.cull, **kw)
        cl_ms.append((time.perf_counter() - t0) * 1e3)
        cl_stages.append(dict(f.stats.timings_ms))
        if g is not None and not budget_hit:
            if tw_ms and twin_spent > a.twin_budget:
                budget_hit = True
                continue
            t0 = time.perf_counter()
            g = clraster.reference.render(sc.target, cam, w, h, cull=a.cull, **twin_kw)
            dt = time.perf_counter() - t0
            twin_spent += dt
            tw_ms.append(dt * 1e3)
            tw_stages.append(dict(g.stats.timings_ms))
    assert f is not None
    cl_med = _median(cl_ms)
    counts = f.stats.counts()
    rec["opencl"] = {
        "runs_ms": cl_ms, "median_ms": cl_med, "warmup_ms": warm_ms,
        "warmup_frames": len(warm_ms),
        "stages_median_ms": _stage_medians(cl_stages), "stages_runs_ms": cl_stages,
        "host_cull_ms": _stage_medians(cl_stages).get("cull (host)"),
        "triangles_per_s": _rate(sc.triangles, cl_med), "pixels_per_s": _rate(w * h, cl_med),
        "counts": counts,
    }
    if cfg.mode == "occlusion":
        rec["opencl"]["note"] = (f"{len(warm_ms)} warm-up frames before timing, so the "
                                 f"occlusion history (last frame's visible set) is warm")
    if g is None:
        rec["twin"] = {"skipped": twin_skip, "runs_ms": [], "median_ms": None, "n_runs": 0}
        rec["speedup_vs_twin"] = None
        rec["agreement"] = None
    else:
        tw_med = _median(tw_ms)
        rec["twin"] = {
            "mode": twin_mode, "runs_ms": tw_ms, "n_runs": len(tw_ms), "median_ms": tw_med,
            "warmup_ms": twin_warm_ms, "stages_median_ms": _stage_medians(tw_stages),
            "budget_s": a.twin_budget, "budget_exceeded": budget_hit,
            "triangles_per_s": _rate(sc.triangles, tw_med),
            "pixels_per_s": _rate(w * h, tw_med),
        }
        if budget_hit:
            rec["twin"]["note"] = (f"time budget {a.twin_budget:g} s spent: {len(tw_ms)} of "
                                   f"{a.repeat} timed runs made")
        if twin_mode != cfg.mode:
            rec["twin"]["note_mode"] = (f"the twin has no {cfg.mode} culling: it rendered "
                                        f"the {twin_mode} mode (the same image)")
        rec["speedup_vs_twin"] = tw_med / cl_med if tw_med and cl_med else None
        ids_equal = bool(np.array_equal(f.triangle_id, g.triangle_id))
        diff = float(np.abs(f.depth.astype(np.float64) - g.depth).max())
        rec["agreement"] = {"ids_equal": ids_equal, "max_depth_diff": diff,
                            "agree": ids_equal, "pixels_differing": int(
                                np.count_nonzero(f.triangle_id != g.triangle_id))}
        if not ids_equal:
            log(f"WARNING {cfg.id}: OpenCL and twin triangle ids differ in "
                f"{rec['agreement']['pixels_differing']} pixels")
    note("llvmpipe")
    rec["peer"] = peer.measure(cfg, sc, cam, f.depth, a, cl_med)
    del r, f, g
    return rec


# =======================================================================================
# The llvmpipe peer
# =======================================================================================

class PeerRunner:
    """Runs `clraster.bench.peer_llvmpipe` once per (scene, size) and caches the result."""

    def __init__(self, enabled: bool, disabled_reason: str = "--no-peer") -> None:
        self.mod = None
        self.renderer: str | None = None
        self.cache: dict[tuple, dict] = {}
        if not enabled:
            self.ok, self.reason = False, f"peer skipped: {disabled_reason}"
            return
        try:
            from clraster.bench import peer_llvmpipe as mod
        except ImportError as exc:
            self.ok, self.reason = False, f"peer skipped: cannot import peer_llvmpipe ({exc})"
            return
        try:
            ok, why = mod.probe()
        except Exception as exc:  # a probe must not take the benchmark down
            ok, why = False, f"probe raised {type(exc).__name__}: {exc}"
        self.ok = bool(ok)
        self.reason = str(why) if ok else f"peer skipped: {why}"
        self.mod = mod if ok else None

    def status(self) -> dict[str, Any]:
        return {"available": self.ok, "reason": self.reason, "renderer": self.renderer}

    def measure(self, cfg: Config, sc: LoadedScene, cam, cl_depth, a, cl_med) -> dict:
        if not self.ok:
            return {"skipped": self.reason}
        key = (cfg.scene.text, cfg.width, cfg.height, a.cull)
        if key not in self.cache:
            self.cache[key] = self._run(cfg, sc, cam, cl_depth, a)
        rec = dict(self.cache[key])
        if rec.get("median_ms") and cl_med:
            rec["ratio_clraster_over_llvmpipe"] = cl_med / rec["median_ms"]
            rec["speedup_vs_llvmpipe"] = rec["median_ms"] / cl_med
        return rec

    def _run(self, cfg: Config, sc: LoadedScene, cam, cl_depth, a) -> dict:
        import numpy as np

        peer = None
        try:
            t0 = time.perf_counter()
            peer = self.mod.LlvmpipePeer(cfg.width, cfg.height)
            peer.upload(sc.target)
            t_up = time.perf_counter() - t0
            vp = np.asarray(cam.view_projection(cfg.width, cfg.height), np.float64)
            pf = peer.render(vp, cull=a.cull, repeat=a.repeat, warmup=1)
            times = [float(t) for t in pf.times_ms]
            self.renderer = str(pf.renderer)
            cov = _jsonable(self.mod.coverage_agreement(cl_depth, pf.depth))
            return {"runs_ms": times, "median_ms": _median(times),
                    "readback_ms": _jsonable(pf.readback_ms), "renderer": str(pf.renderer),
                    "threads": _jsonable(pf.threads), "upload_s": t_up,
                    "draws": "everything (no object culling), back-face culling "
                             f"{a.cull}", "coverage": cov}
        except Exception as exc:  # the peer is a comparison, not the thing under test
            return {"error": f"{type(exc).__name__}: {exc}"}
        finally:
            if peer is not None:
                try:
                    peer.release()
                except Exception:
                    pass


def _jsonable(v: Any) -> Any:
    """Plain JSON values from NumPy scalars/arrays, dicts and lists (NaN/Inf → None)."""
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if hasattr(v, "tolist") and not isinstance(v, (str, bytes)):
        return _jsonable(v.tolist())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


# =======================================================================================
# Subprocess probes: cold/warm start and peak memory
# =======================================================================================

def _status_mib(key: str) -> float | None:
    """A ``/proc/self/status`` memory line (VmRSS, VmHWM) in MiB; None off Linux."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    m = re.search(rf"^{key}:\s*(\d+)\s*kB", text, re.M)
    return int(m.group(1)) / 1024 if m else None


def _peak_rss_mib() -> float | None:
    """Peak resident set of this process image. VmHWM, not ru_maxrss: Linux carries
    ru_maxrss over exec(), so a child would report its parent's peak at fork time."""
    peak = _status_mib("VmHWM")
    if peak is not None:
        return peak
    import resource

    ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return ru / 2**20 if sys.platform == "darwin" else ru / 1024   # bytes on macOS


def _reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux >= 4.0: ``echo 5 > /proc/self/clear_refs``)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _probe(task: dict) -> dict:
    """Body of a probe subprocess (``--probe JSON``); returns what it measured."""
    meshes = Path(task["meshes"])
    w, h = task["size"]
    spec = SceneSpec.parse(task["scene"])
    if task["task"] == "startup":
        t0 = time.perf_counter()
        import numpy  # noqa: F401
        import pyopencl  # noqa: F401

        import clraster
        from clraster.device import default_context
        from clraster.renderer import Renderer
        t1 = time.perf_counter()
        ctx = default_context()
        t2 = time.perf_counter()
        r = Renderer(w, h, context=ctx)
        t3 = time.perf_counter()
        sc = load_scene(spec, meshes)
        cam = sc.camera(w, h)
        t4 = time.perf_counter()
        r.render(sc.target, cam, cull=task["cull"])
        t5 = time.perf_counter()
        r.render(sc.target, cam, cull=task["cull"], occlusion=True)
        t6 = time.perf_counter()
        r.render(sc.target, cam, cull=task["cull"])
        t7 = time.perf_counter()
        del clraster
        return {"import_s": t1 - t0, "context_s": t2 - t1, "renderer_programs_s": t3 - t2,
                "scene_load_s": t4 - t3, "first_frame_s": t5 - t4,
                "first_occlusion_frame_s": t6 - t5, "next_frame_s": t7 - t6,
                "to_first_frame_s": (t3 - t0) + (t5 - t4), "triangles": sc.triangles}
    # memory: the path's modules (and, for OpenCL, the context) before the baseline, so
    # that "rendering adds" is the rendering itself
    import clraster

    if task["path"] == "opencl":
        from clraster.device import default_context
        from clraster.renderer import Renderer

        default_context()
    else:
        from clraster import reference  # noqa: F401
    base = _status_mib("VmRSS")
    sc = load_scene(spec, meshes)
    cam = sc.camera(w, h)
    after_scene = _status_mib("VmRSS")
    peak_load = _peak_rss_mib()
    reset = _reset_peak()
    kw = MODES[task["mode"]]
    if task["path"] == "opencl":
        r = Renderer(w, h)
        for _ in range(2 if kw.get("occlusion") else 1):
            r.render(sc.target, cam, cull=task["cull"], **kw)
    else:
        tkw = {k: v for k, v in MODES[TWIN_MODE[task["mode"]]].items() if k != "occlusion"}
        clraster.reference.render(sc.target, cam, w, h, cull=task["cull"], **tkw)
    peak_render = _peak_rss_mib()
    peak = max(v for v in (peak_load, peak_render) if v is not None) \
        if (peak_load or peak_render) else None
    return {"baseline_rss_mib": base, "scene_rss_mib": after_scene, "peak_rss_mib": peak,
            "render_peak_rss_mib": peak_render if reset else None,
            "render_extra_mib": (peak_render - after_scene) if reset and peak_render
            and after_scene else None, "triangles": sc.triangles}


def _run_probe(task: dict, env: dict[str, str] | None = None, timeout: float = 900
               ) -> dict:
    cmd = [sys.executable, "-m", "clraster.bench.harness", "--probe", json.dumps(task)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"probe timed out after {timeout:g} s"}
    wall = time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("PROBE ")]
    if p.returncode != 0 or not lines:
        tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
        return {"error": f"probe exited {p.returncode}: {' | '.join(tail)}"}
    out = json.loads(lines[-1][6:])
    out["process_wall_s"] = wall
    return out


def measure_startup(scene: str, size: tuple[int, int], a: argparse.Namespace) -> dict:
    """Cold start (fresh empty kernel caches) then warm start (the caches it filled)."""
    tmp = Path(tempfile.mkdtemp(prefix="clraster-bench-cache-"))
    try:
        env = dict(os.environ)
        env.pop("PYOPENCL_NO_CACHE", None)
        env["POCL_CACHE_DIR"] = str(tmp / "pocl")
        env["PYOPENCL_CACHE_DIR"] = str(tmp / "pyopencl")
        (tmp / "pocl").mkdir()
        (tmp / "pyopencl").mkdir()
        task = {"task": "startup", "scene": scene, "size": list(size),
                "meshes": str(a.meshes), "cull": a.cull}
        cold = _run_probe(task, env)
        warm = _run_probe(task, env)
        return {"scene": scene, "size": list(size), "cold": cold, "warm": warm,
                "method": "a fresh Python process each; cold: POCL_CACHE_DIR and "
                          "PYOPENCL_CACHE_DIR point to new empty directories; warm: the "
                          "same directories, filled by the cold run. first_frame_s includes "
                          "PoCL's per-local-size kernel specialization; to_first_frame_s = "
                          "import + context + programs + first frame (scene load excluded)."}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def measure_memory(scene: str, size: tuple[int, int], mode: str,
                   a: argparse.Namespace, twin_ok: bool) -> dict:
    base = {"task": "memory", "scene": scene, "size": list(size), "mode": mode,
            "meshes": str(a.meshes), "cull": a.cull}
    rec: dict[str, Any] = {"scene": scene, "size": list(size), "mode": mode,
                           "opencl": _run_probe({**base, "path": "opencl"})}
    rec["twin"] = (_run_probe({**base, "path": "twin"}) if twin_ok
                   else {"skipped": "twin skipped (--no-twin or --twin-max-triangles)"})
    return rec


# =======================================================================================
# Targets
# =======================================================================================

def _find(configs: list[dict], pred) -> dict | None:
    found = [c for c in configs if pred(c)]
    return max(found, key=lambda c: c["triangles"]) if found else None


def evaluate_targets(configs: list[dict]) -> list[dict]:
    """The issue's targets, each met / missed / not measured (met None) with the figures."""
    out = []

    def target(name, desc, cfg, value, threshold, ok_if, why_none):
        met = None if value is None else bool(value >= threshold if ok_if == ">=" else
                                               value <= threshold)
        out.append({"name": name, "description": desc, "config": cfg["id"] if cfg else None,
                    "value": value, "threshold": threshold, "comparison": ok_if, "met": met,
                    "note": None if value is not None else why_none})

    dragon = _find(configs, lambda c: c["scene"]["source"].endswith("stanford_dragon_vrip.ply")
                   and c["scene"]["kind"] == "mesh" and c["size"] == [1920, 1080]
                   and c["mode"] == "frustum")
    nodragon = "no dragon (stanford_dragon_vrip.ply) config at 1920x1080 in this run"
    sp = dragon.get("speedup_vs_twin") if dragon else None
    target("dragon_vs_twin", "dragon (871K) at 1920x1080: NumPy twin time / OpenCL time",
           dragon, sp, 50.0, ">=", nodragon if not dragon else "twin not measured")
    pr = (dragon.get("peer") or {}).get("ratio_clraster_over_llvmpipe") if dragon else None
    target("dragon_vs_llvmpipe", "dragon at 1920x1080: clraster time / llvmpipe time",
           dragon, pr, 0.5, "<=", nodragon if not dragon else
           (dragon.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    plant = _find(configs, lambda c: c["scene"]["kind"] == "plant"
                  and c["triangles"] >= TEN_MILLION and c["mode"] == "occlusion")
    ps = (plant.get("peer") or {}).get("speedup_vs_llvmpipe") if plant else None
    target("plant10m_occlusion_vs_llvmpipe",
           "plant ≥ 10M triangles, occlusion culling: llvmpipe (drawing it all) time / "
           "clraster time", plant, ps, 10.0, ">=",
           "no plant ≥ 10M triangles with occlusion mode in this run" if not plant else
           (plant.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    return out


# =======================================================================================
# Markdown
# =======================================================================================

def _f(v: Any, spec: str = ".1f", none: str = "—") -> str:
    if v is None:
        return none
    if isinstance(v, float) and not math.isfinite(v):
        return none
    return format(v, spec)


def _x(v: float | None, spec: str = ".1f") -> str:
    return "—" if v is None else f"{v:{spec}}×"


def _si(v: float | None) -> str:
    if v is None:
        return "—"
    for div, suf in ((1e9, "G"), (1e6, "M"), (1e3, "K")):
        if abs(v) >= div:
            return f"{v / div:.2f}{suf}"
    return f"{v:.0f}"


def markdown(res: dict) -> str:
    from clraster.bench.machine import summary

    L = ["# clraster benchmark results", "",
         f"Run {res['created']} ({_hms(res['elapsed_s'])}); command: "
         f"`{' '.join(res['command'])}`.", "",
         f"Machine: {summary(res['machine'])}", "",
         "Frame time = wall time of `render()` (host culling and read-back included), median "
         f"of {res['settings']['repeat']} frames after warm-up, OpenCL and the NumPy twin "
         "interleaved. Stage times are OpenCL profiling-event device times (median). "
         f"llvmpipe: {res['peer']['reason']}.", ""]
    L += ["## Targets", "", "| target | configuration | measured | threshold | status |",
          "|---|---|---:|---:|---|"]
    for t in res["targets"]:
        st = {True: "**met**", False: "**missed**", None: "not measured"}[t["met"]]
        if t["met"] is None and t["note"]:
            st += f" ({t['note']})"
        L.append(f"| {t['description']} | {t['config'] or '—'} | {_x(t['value'], '.2f')} | "
                 f"{t['comparison']} {t['threshold']:g}× | {st} |")
    L += ["", "## Configurations", "",
          "| sweep | scene | triangles | size | mode | OpenCL ms | twin ms (runs) | "
          "speedup | llvmpipe ms | clraster/llvmpipe | tri/s | px/s | twin agrees |",
          "|---|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    notes = []
    for c in res["configs"]:
        tw, pe, ag = c["twin"], c["peer"], c["agreement"]
        if tw.get("median_ms") is not None:
            tws = f"{tw['median_ms']:.1f} ({tw['n_runs']})"
            if tw.get("mode") != c["mode"]:
                tws += f" [{tw['mode']}]"
            if tw.get("budget_exceeded"):
                tws += " ⏱"
        else:
            tws = "skipped"
        pes = _f(pe.get("median_ms")) if "skipped" not in pe else "skipped"
        if "error" in pe:
            pes = "error"
        agree = "—" if ag is None else ("yes" if ag["agree"] else
                                        f"NO ({ag['pixels_differing']} px)")
        if ag is not None:
            agree += f", Δz {ag['max_depth_diff']:.1g}"
        L.append(f"| {', '.join(c['sweeps'])} | {c['scene']['name']} | {c['triangles']:,} | "
                 f"{c['size'][0]}×{c['size'][1]} | {c['mode']} | "
                 f"{_f(c['opencl']['median_ms'])} | {tws} | {_x(c['speedup_vs_twin'])} | "
                 f"{pes} | {_f(pe.get('ratio_clraster_over_llvmpipe'), '.2f')} | "
                 f"{_si(c['opencl']['triangles_per_s'])} | {_si(c['opencl']['pixels_per_s'])} "
                 f"| {agree} |")
        if "error" in pe:
            notes.append(f"- {c['id']}: llvmpipe error: {pe['error']}")
        if tw.get("skipped"):
            notes.append(f"- {c['id']}: {tw['skipped']}")
    L += ["", "[frustum] after a twin time: the twin has no occlusion culling and rendered the "
          "frustum mode (same image). ⏱: the twin's time budget "
          f"({res['settings']['twin_budget_s']:g} s per configuration) was spent; (runs) is "
          "how many timed frames it made. Occlusion configurations are timed after "
          f"{res['settings']['warmup'] + res['settings']['occlusion_warmup']} warm-up frames "
          "(temporal history warm)."]
    if notes:
        L += [""] + notes
    # stages
    stages: list[str] = []
    for c in res["configs"]:
        stages += [k for k in c["opencl"]["stages_median_ms"] if k not in stages]
    L += ["", "## Per-stage times (OpenCL, median ms)", "",
          "| configuration | " + " | ".join(stages) + " | frame |",
          "|---|" + "---:|" * (len(stages) + 1)]
    for c in res["configs"]:
        s = c["opencl"]["stages_median_ms"]
        L.append(f"| {c['id']} | " + " | ".join(_f(s.get(k), ".2f") for k in stages)
                 + f" | {_f(c['opencl']['median_ms'])} |")
    # funnel
    cul = [c for c in res["configs"] if "culling" in c["sweeps"]]
    if cul:
        L += ["", "## Culling funnel (triangles; last OpenCL frame)", "",
              "| mode | total | frustum culled | cone culled | occlusion culled | to setup | "
              "back-face culled | rasterized | fragments tested | frame ms |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for c in cul:
            k = c["opencl"]["counts"]
            L.append(f"| {c['mode']} | {k['triangles_total']:,} | "
                     f"{k['triangles_frustum_culled']:,} | {k['triangles_cone_culled']:,} | "
                     f"{k['triangles_occlusion_culled']:,} | {k['triangles_in']:,} | "
                     f"{k['backface_culled']:,} | {k['rasterized']:,} | "
                     f"{k['fragments_tested']:,} | {_f(c['opencl']['median_ms'])} |")
    st = res.get("startup")
    if st:
        L += ["", f"## Cold and warm start ({st['scene']}, {st['size'][0]}×{st['size'][1]})",
              "", "| start | import | context | programs | first frame | to first frame | "
              "process wall |", "|---|---:|---:|---:|---:|---:|---:|"]
        for k in ("cold", "warm"):
            s = st[k]
            if "error" in s:
                L.append(f"| {k} | error: {s['error']} ||||||")
                continue
            L.append(f"| {k} | {s['import_s']:.2f} s | {s['context_s']:.2f} s | "
                     f"{s['renderer_programs_s']:.2f} s | {s['first_frame_s']:.2f} s | "
                     f"{s['to_first_frame_s']:.2f} s | {s['process_wall_s']:.2f} s |")
        L += ["", st["method"]]
    mem = res.get("memory")
    if mem:
        L += ["", "## Peak host memory (MiB)", "",
              "| scene | size, mode | path | after imports | scene loaded | peak RSS | "
              "rendering adds |", "|---|---|---|---:|---:|---:|---:|"]
        for m in mem:
            where = f"{m['scene']} | {m['size'][0]}×{m['size'][1]} {m['mode']}"
            for path in ("opencl", "twin"):
                x = m[path]
                if "peak_rss_mib" not in x:
                    why = x.get("error") or x.get("skipped")
                    L.append(f"| {where} | {path} | "
                             f"{why} ||||")
                    continue
                L.append(f"| {where} | {path} | "
                         f"{_f(x['baseline_rss_mib'], '.0f')} | {_f(x['scene_rss_mib'], '.0f')} "
                         f"| {_f(x['peak_rss_mib'], '.0f')} | "
                         f"{_f(x.get('render_extra_mib'), '.0f')} |")
        L += ["", res["memory_method"]]
    if res.get("errors"):
        L += ["", "## Errors", ""] + [f"- {s}" for s in res["errors"]]
    if res["skipped"]:
        L += ["", "## Skipped", ""] + [f"- {s}" for s in res["skipped"]]
    if res.get("plots"):
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in res["plots"]]
    return "\n".join(L) + "\n"


# =======================================================================================
# main
# =======================================================================================

def _default_out() -> Path:
    """bench/results/ of the repository (a checkout or an editable install); from an
    installed package, ./clraster-bench-results."""
    repo = Path(__file__).resolve().parents[2]   # clraster/bench/harness.py -> repository
    if (repo / "pyproject.toml").is_file() and (repo / "bench").is_dir():
        return repo / "bench" / "results"
    return Path.cwd() / "clraster-bench-results"


def _default_meshes() -> Path:
    repo = Path(__file__).resolve().parents[2]
    cands = [repo.parent / "shared" / "meshes", Path.cwd().parent / "shared" / "meshes",
             Path.cwd() / "shared" / "meshes"]
    return next((p for p in cands if p.is_dir()), cands[0])


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clraster bench", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Scenes: NAME (spot, bunny, armadillo, lucy, dragon202k, igea, dragon, or a "
               "file in --meshes), example, grid:MESH:NXxNYxNZ, plant:N[@inside|@overview] "
               "(N like 20K, 10.1M).")
    p.add_argument("--quick", action="store_true",
                   help="smoke mode: tiny scenes, 320x240 and 640x480, repeat 2 (< 1 min); "
                        "checks the harness works, not a speed")
    p.add_argument("--out", type=Path, help="output folder (default bench/results/; with "
                                            "--quick a new temporary folder)")
    p.add_argument("--meshes", type=Path, default=None,
                   help="folder of the shared meshes (default ../shared/meshes)")
    p.add_argument("--sweeps", type=_list, default=["triangles", "pixels", "culling"],
                   help="comma-separated subset of triangles,pixels,culling (default all)")
    p.add_argument("--scenes", type=_list, help="scenes of the triangles sweep (comma-"
                   f"separated; default {','.join(FULL_TRIANGLE_SCENES)})")
    p.add_argument("--size", type=_size, help="image size of the triangles and culling "
                                              "sweeps (default 1920x1080)")
    p.add_argument("--pixels-scene", help="scene of the pixels sweep (default dragon)")
    p.add_argument("--sizes", type=lambda t: [_size(s) for s in _list(t)],
                   help=f"sizes of the pixels sweep (default {','.join(FULL_PIXEL_SIZES)})")
    p.add_argument("--culling-scene", help="scene of the culling sweep (default "
                                           "plant:10.1M@inside, ≥ 10M triangles)")
    p.add_argument("--modes", type=_list, help="culling modes of the culling sweep "
                                               "(default off,frustum,occlusion)")
    p.add_argument("--repeat", type=int, help="timed frames per configuration (default 5; "
                                              "quick 2)")
    p.add_argument("--warmup", type=int, default=1, help="warm-up frames (default 1)")
    p.add_argument("--occlusion-warmup", type=int, default=2,
                   help="extra warm-up frames in occlusion mode (default 2)")
    p.add_argument("--twin-budget", type=float, default=60.0, metavar="S",
                   help="seconds of twin time per configuration after which the twin stops "
                        "(after >= 1 timed frame; default 60)")
    p.add_argument("--twin-max-triangles", type=_limit, default=None, metavar="N",
                   help="skip the twin on scenes with more triangles, recorded as 'twin "
                        "skipped' (default 6M: one twin frame of the 10M plant takes "
                        "minutes; 'none' for no limit; quick: none)")
    p.add_argument("--no-twin", action="store_true", help="time the OpenCL path only")
    p.add_argument("--no-peer", action="store_true", help="do not run the llvmpipe peer")
    p.add_argument("--no-startup", action="store_true", help="skip cold/warm start")
    p.add_argument("--no-memory", action="store_true", help="skip peak memory")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--startup-scene", help="scene of the cold/warm start (default dragon "
                                           "at 1920x1080; quick: spot at 320x240)")
    p.add_argument("--cull", choices=("back", "front", "none"), default="back",
                   help="face culling (default back)")
    p.add_argument("--list", action="store_true", help="print the configurations and exit")
    p.add_argument("--probe", help=argparse.SUPPRESS)
    return p


def _fill_defaults(a: argparse.Namespace) -> None:
    a.meshes = a.meshes or _default_meshes()
    if a.quick:
        small = "spot" if mesh_path("spot", a.meshes) else "example"
        grid = "grid:spot:3x2x1" if small == "spot" else "grid:example:2x1x1"
        a.scenes = a.scenes or [small, grid, "plant:20K@overview"]
        a.size = a.size or (320, 240)
        a.pixels_scene = a.pixels_scene or small
        a.sizes = a.sizes or [(320, 240), (640, 480)]
        a.culling_scene = a.culling_scene or "plant:20K@inside"
        a.repeat = a.repeat or 2
        a.startup_scene = a.startup_scene or small
        a.startup_size = (320, 240)
    else:
        a.scenes = a.scenes or list(FULL_TRIANGLE_SCENES)
        a.size = a.size or (1920, 1080)
        a.pixels_scene = a.pixels_scene or "dragon"
        a.sizes = a.sizes or [_size(s) for s in FULL_PIXEL_SIZES]
        a.culling_scene = a.culling_scene or "plant:10.1M@inside"
        a.repeat = a.repeat or 5
        a.startup_scene = a.startup_scene or (
            "dragon" if mesh_path("dragon", a.meshes) else "example")
        a.startup_size = (1920, 1080)
        if a.twin_max_triangles is None:
            a.twin_max_triangles = FULL_TWIN_MAX_TRIANGLES
    if a.twin_max_triangles is not None and a.twin_max_triangles < 0:
        a.twin_max_triangles = None
    a.modes = a.modes or list(MODES)


def main(argv: list[str] | None = None) -> int:
    """``clraster bench ARGS``: run the benchmark; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    p = _parser()
    try:
        a = p.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if a.probe:
        print("PROBE " + json.dumps(_jsonable(_probe(json.loads(a.probe)))), flush=True)
        return 0
    _fill_defaults(a)
    bad = [s for s in a.sweeps if s not in ("triangles", "pixels", "culling")]
    bad += [m for m in a.modes if m not in MODES]
    if bad or a.repeat < 1 or a.warmup < 0 or a.occlusion_warmup < 0:
        p.print_usage(sys.stderr)
        print(f"clraster bench: error: bad sweep/mode {bad}, or --repeat < 1, or a negative "
              f"warm-up", file=sys.stderr)
        return 2
    try:
        configs = build_matrix(a)
        for s in [a.startup_scene]:
            SceneSpec.parse(s)
    except ValueError as exc:
        print(f"clraster bench: error: {exc}", file=sys.stderr)
        return 2
    if a.list:
        for c in configs:
            print(f"{c.id:<45} sweeps={','.join(c.sweeps)}")
        return 0

    out = a.out or (Path(tempfile.mkdtemp(prefix="clraster-bench-")) if a.quick
                    else _default_out())
    out.mkdir(parents=True, exist_ok=True)
    print(f"clraster bench: {len(configs)} configurations; results in {out}", flush=True)

    from clraster.bench.machine import describe

    t_start = time.perf_counter()
    peer = PeerRunner(not a.no_peer)
    print(f"llvmpipe: {peer.reason}", flush=True)

    skipped: list[str] = []
    # drop the configurations whose scene files are missing, before the ETA is set
    runnable = []
    for c in configs:
        if c.scene.kind in ("mesh", "grid") and c.scene.mesh != "example" \
                and mesh_path(c.scene.mesh, a.meshes) is None:
            msg = (f"{c.id}: mesh {c.scene.mesh!r} not found in {a.meshes} "
                   f"(set --meshes DIR)")
            skipped.append(msg)
            print(f"skipped {msg}", file=sys.stderr)
        else:
            runnable.append(c)
    def weight(c: Config) -> float:   # rough cost, for the ETA only
        n = estimated_triangles(c.scene, a.meshes)
        twin = not a.no_twin and (a.twin_max_triangles is None or n <= a.twin_max_triangles)
        return n * (1 + (0 if not twin else 60 if c.scene.kind == "plant" else 12)) \
            + c.width * c.height * 20 + 2e6

    weights = [weight(c) for c in runnable]
    # peak memory: one probe pair per geometry, on its heaviest configuration (most pixels,
    # frustum mode, a view that sees it all rather than the inside one)
    mem_jobs: list[Config] = []
    if not a.no_memory:
        for geo in dict.fromkeys(c.scene.geometry for c in runnable):
            cs = [c for c in runnable if c.scene.geometry == geo]
            mem_jobs.append(max(cs, key=lambda c: (c.width * c.height, c.mode == "frustum",
                                                   c.scene.view != "inside")))
    avg = sum(weights) / len(weights) if weights else 1.0
    steps = weights + [avg * 0.5] * len(mem_jobs) + ([] if a.no_startup else [avg])
    prog = Progress(steps)

    records: list[dict] = []
    errors: list[str] = []
    loaded: LoadedScene | None = None
    for c in runnable:
        prog.start(c.id)
        try:
            if loaded is None or loaded.spec.geometry != c.scene.geometry:
                loaded = None   # free the previous scene first (10M triangles are large)
                loaded = load_scene(c.scene, a.meshes)
            records.append(_jsonable(run_config(c, loaded, a, peer, prog.log, prog.detail)))
        except SceneMissing as exc:
            skipped.append(f"{c.id}: {exc}")
            prog.log(f"skipped {c.id}: {exc}")
        except Exception as exc:  # keep the other configurations of a long run
            import traceback

            errors.append(f"{c.id}: {type(exc).__name__}: {exc}")
            prog.log(f"ERROR {c.id}: {type(exc).__name__}: {exc}\n"
                     + traceback.format_exc(limit=4))
        prog.finish_step()
        # checkpoint: a long run that dies later still leaves its measurements
        (out / "results.partial.json").write_text(json.dumps(
            {"schema": SCHEMA, "command": ["clraster", "bench", *argv], "configs": records,
             "errors": errors, "skipped": skipped}, indent=1) + "\n")
    loaded = None

    memory = []
    for c in mem_jobs:
        prog.start(f"peak memory {c.id}")
        tri = next((r["triangles"] for r in records if r["scene"]["name"] == c.scene.text),
                   0)
        twin_ok = not a.no_twin and (a.twin_max_triangles is None
                                     or tri <= a.twin_max_triangles)
        memory.append(measure_memory(c.scene.text, (c.width, c.height), c.mode, a, twin_ok))
        prog.finish_step()
    startup = None
    if not a.no_startup:
        prog.start(f"cold/warm start {a.startup_scene}")
        startup = measure_startup(a.startup_scene, a.startup_size, a)
        prog.finish_step()
    prog.close()

    res: dict[str, Any] = {
        "schema": SCHEMA,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": ["clraster", "bench", *argv],
        "quick": bool(a.quick),
        "settings": {"repeat": a.repeat, "warmup": a.warmup,
                     "occlusion_warmup": a.occlusion_warmup, "twin_budget_s": a.twin_budget,
                     "twin_max_triangles": a.twin_max_triangles, "cull": a.cull,
                     "sweeps": a.sweeps, "meshes": str(a.meshes), "no_twin": a.no_twin},
        "machine": describe(peer_renderer=peer.reason if peer.ok else None),
        "peer": peer.status(),
        "configs": records,
        "targets": evaluate_targets(records),
        "startup": startup,
        "memory": memory,
        "memory_method": "A fresh Python process per scene and path imports clraster, "
                         "loads or builds the scene, and renders one frame (two in "
                         "occlusion mode) on one path only (OpenCL or twin). "
                         "peak_rss_mib: the process's peak resident set (VmHWM; ru_maxrss "
                         "is not used because Linux carries it over exec from the parent); "
                         "the PoCL device is the CPU, so device buffers are host memory and "
                         "are included. baseline_rss_mib: RSS after the imports (and the "
                         "OpenCL context, on the OpenCL path); "
                         "scene_rss_mib: RSS with the scene loaded; render_extra_mib: the "
                         "peak during rendering above that (VmHWM reset through "
                         "/proc/self/clear_refs after loading).",
        "skipped": skipped,
        "errors": errors,
    }
    res["elapsed_s"] = time.perf_counter() - t_start
    plots: list[str] = []
    if not a.no_plots:
        from clraster.bench import plots as plots_mod

        plots, why = plots_mod.make_all(res, out)
        if why:
            print(why)
    res["plots"] = plots
    res = _jsonable(res)
    (out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    (out / "results.md").write_text(markdown(res))
    print(_summary_lines(res))
    (out / "results.partial.json").unlink(missing_ok=True)
    print(f"wrote {out / 'results.json'}, {out / 'results.md'}"
          + (f" and {len(plots)} plots" if plots else ""))
    if errors:
        print(f"clraster bench: {len(errors)} configuration(s) failed:\n  "
              + "\n  ".join(errors), file=sys.stderr)
        return 1
    return 0


def _summary_lines(res: dict) -> str:
    lines = []
    for c in res["configs"]:
        pe = c["peer"].get("median_ms")
        lines.append(f"{c['id']:<42} OpenCL {_f(c['opencl']['median_ms']):>8} ms  twin "
                     f"{_f(c['twin'].get('median_ms')):>9} ms  x{_f(c['speedup_vs_twin']):>6}"
                     f"  llvmpipe {_f(pe):>8} ms")
    for t in res["targets"]:
        st = {True: "MET", False: "MISSED", None: "not measured"}[t["met"]]
        v = f"{t['value']:.2f}x" if t["value"] is not None else "—"
        lines.append(f"target {t['name']}: {v} (needs {t['comparison']} {t['threshold']:g}x)"
                     f" {st}" + (f" — {t['note']}" if t["note"] else ""))
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
