"""What the benchmark harness measures: scenes, configurations, sweeps and targets.

Nothing here renders or times anything. A scene is named on the command line
(:class:`SceneSpec`) and loaded once per geometry (:func:`load_scene`); a configuration
(:class:`Config`) is scene × image size × culling mode (:data:`MODES`); :func:`build_matrix`
turns the requested sweeps into the list of configurations; :func:`evaluate_targets` says,
from the JSON records of a run, whether the issue's targets were met. The scale sweep's
scenes, views, fit and goals are `clraster.bench.scale`; the datasets sweep (views/s of many
views against Open3D, not a scene × size × mode configuration) is `clraster.bench.datasets`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clraster.bench.scale import SCALE_VIEWS, scale_targets

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
MODES: dict[str, dict[str, Any]] = {
    "off": {"frustum": False, "cones": False},
    "frustum": {"frustum": True, "cones": True},
    "occlusion": {"frustum": True, "cones": True, "occlusion": True},
}
#: The culling mode the twin renders in each configuration: the same one. The twin runs the
#: OpenCL renderer's two-phase occlusion schedule (`clraster.pipeline.twophase`, with its
#: own pyramid and Hi-Z test), so occlusion rows time the twin's occlusion culling too.
#: (Results made before it had one show "[frustum]" where the twin rendered the frustum mode
#: instead.)
TWIN_MODE = {"off": "off", "frustum": "frustum", "occlusion": "occlusion"}

#: The sweeps `--sweeps` may name (see :func:`build_matrix`); ``all`` names every one.
SWEEPS = ("triangles", "pixels", "culling", "fill", "scale", "datasets")
#: The sweeps of a run without `--sweeps`: the scale sweep (10M-200M triangles, ~4.5 min on
#: its own with its memory probes on 2 cores, see bench/README.md) runs only when named, and
#: so does the datasets sweep (a few minutes of 200-view rounds; its peer, Open3D, is
#: usually installed in another environment than llvmpipe's, see bench/README.md).
DEFAULT_SWEEPS = ("triangles", "pixels", "culling", "fill")

#: Scenes of the fill sweep: frames a few large triangles fill (per-pixel work: raster,
#: clear, resolve), each mesh seen from close by (`close_camera`; the record keeps the
#: fraction of the frame covered), and an empty frame (a quad behind the camera: the fixed
#: cost of a frame).
FULL_FILL_SCENES = ["spot@close", "bunny@close", "quad", "empty"]
#: A frame at least this much covered counts as "filling the screen" (issue 34's targets).
FILL_COVERAGE = 0.25

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
    ``.ply``, or a path), ``example`` (the built-in example mesh),
    ``grid:MESH:NXxNYxNZ[@overview|@inside]`` (`clraster.scenes.instance_grid`; the camera
    is `grid_camera` (no suffix: view "grid", or "overview") or
    `clraster.bench.scale.grid_inside_camera`), ``plant:N[@inside|@overview]``
    (`clraster.scenes.plant`, N may end in K or M; the camera is `plant_inside_camera`
    (default) or `plant_overview_camera`), ``NAME@close`` (a mesh seen from close by:
    `close_camera`), ``quad`` (one large quad, two triangles, seen from close by) and
    ``empty`` (the same quad behind the camera: nothing drawn).
    """

    text: str
    kind: str                     # mesh | example | grid | plant | quad
    mesh: str = ""                # mesh name (mesh, grid)
    count: int = 0                # plant triangles
    grid: tuple[int, int, int] = (1, 1, 1)
    view: str = "framing"         # framing | grid | inside | overview | close | away

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
        if t in ("quad", "empty"):
            return SceneSpec(t, "quad", view="close" if t == "quad" else "away")
        if t.startswith("plant:"):
            body, _, view = t[6:].partition("@")
            view = view or "inside"
            if view not in ("inside", "overview"):
                raise ValueError(f"plant view must be inside or overview, got {view!r}")
            return SceneSpec(t, "plant", count=parse_count(body), view=view)
        if t.startswith("grid:"):
            body, at, view = t.partition("@")
            if at and view not in ("inside", "overview"):
                raise ValueError(f"grid view must be inside or overview, got {view!r}")
            parts = body.split(":")
            if len(parts) != 3:
                raise ValueError(f"expected grid:MESH:NXxNYxNZ, got {t!r}")
            dims = tuple(int(v) for v in parts[2].lower().split("x"))
            if len(dims) != 3 or min(dims) < 1:
                raise ValueError(f"expected three positive counts NXxNYxNZ, got {parts[2]!r}")
            return SceneSpec(t, "grid", mesh=parts[1], grid=dims, view=view or "grid")
        if not t:
            raise ValueError("empty scene name")
        name, at, view = t.partition("@")
        if at:
            if view != "close":
                raise ValueError(f"a mesh's view must be close (NAME@close), got {view!r}")
            return SceneSpec(t, "example" if name == "example" else "mesh", mesh=name,
                             view="close")
        return SceneSpec(t, "mesh", mesh=t)


def parse_count(text: str) -> int:
    """A triangle count like ``20000``, ``20K`` or ``10.1M`` (ValueError otherwise)."""
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
    if spec.kind == "quad":
        return 2
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
        from clraster.world import generators as sc

        v = view or self.spec.view
        if v in ("close", "away"):
            lo, hi = self.target.bounds()
            return close_camera(lo, hi, width, height, away=v == "away")
        if self.spec.kind == "grid":
            if v == "inside":
                from clraster.bench.scale import grid_inside_camera

                return grid_inside_camera(self.target, self.spec.grid, width, height)
            return sc.grid_camera(self.target, width, height)
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


def close_camera(lo, hi, width: int, height: int, away: bool = False):
    """A camera close to the box [lo, hi]: it looks at the box centre, slightly from above
    and the side, from 0.6 of the distance at which the box's bounding sphere would just
    fit the vertical field of view (45°), so the object fills much of the frame (the record
    keeps how much). ``away``: the same camera turned round, seeing nothing of it."""
    import numpy as np

    from clraster import Camera

    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre, radius = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    d = np.array([0.25, 0.2, 1.0]) / np.linalg.norm([0.25, 0.2, 1.0])
    dist = 0.6 * radius / math.tan(math.radians(45.0) / 2.0)
    eye = centre + dist * d
    target = eye + (eye - centre) if away else centre
    return Camera.look_at(eye=eye, target=target, fov_y=45.0,
                          near=max(dist - radius, 0.02 * radius) * 0.5, far=dist + 2 * radius)


def quad_mesh():
    """One large quad: the square [-1, 1]² at z = 0, two counter-clockwise triangles seen
    from +z (the fill sweep's "quad" and "empty" scenes)."""
    import numpy as np

    import clraster

    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    return clraster.Mesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32))


def _load_mesh(name: str, meshes: Path):
    import clraster

    if name == "example":
        from clraster.world.examples import example_mesh

        return example_mesh(), "clraster.world.examples.example_mesh()"
    p = mesh_path(name, meshes)
    if p is None:
        raise SceneMissing(f"mesh {name!r} not found (looked for "
                           f"{meshes / MESH_ALIASES.get(name, name)}; set --meshes DIR)")
    return clraster.Mesh.load(p), str(p)


def load_scene(spec: SceneSpec, meshes: Path) -> LoadedScene:
    """Load or build `spec` (SceneMissing when its file is not there)."""
    from clraster.world import generators as sc

    t0 = time.perf_counter()
    if spec.kind == "quad":
        target, source = quad_mesh(), "clraster.bench.spec.quad_mesh()"
    elif spec.kind == "plant":
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
    if "fill" in a.sweeps:
        for s in getattr(a, "fill_scenes", None) or []:
            add(s, a.size, "frustum", "fill")
    if "scale" in a.sweeps:
        for s in getattr(a, "scale_scenes", None) or []:
            for view in SCALE_VIEWS:
                add(f"{s}@{view}", a.size, "frustum", "scale")
    # the datasets sweep is not a configuration of this matrix: it times views/s of many
    # views per mesh (`clraster.bench.datasets.run_sweep`, called by the command line)
    order: dict[tuple, int] = {}
    for c in out.values():
        order.setdefault(c.scene.geometry, len(order))
    mode_rank = {m: i for i, m in enumerate(MODES)}
    return sorted(out.values(), key=lambda c: (order[c.scene.geometry], c.scene.view,
                                               c.width * c.height, mode_rank[c.mode]))


# =======================================================================================
# Targets
# =======================================================================================

def _find(configs: list[dict], pred) -> dict | None:
    found = [c for c in configs if pred(c)]
    return max(found, key=lambda c: c["triangles"]) if found else None


def evaluate_targets(configs: list[dict], scale: dict | None = None) -> list[dict]:
    """The issue's targets, each met / missed / not measured (met None) with the figures;
    the scale sweep's goals come from its summary `scale` (`clraster.bench.scale`). The
    datasets sweep's are its own (`clraster.bench.datasets.datasets_targets`, which reads
    this module's scenes: the caller adds them)."""
    out = []

    def target(name, desc, cfg, value, threshold, ok_if, why_none, unit="×"):
        met = None if value is None else bool(value >= threshold if ok_if == ">=" else
                                               value <= threshold)
        out.append({"name": name, "description": desc, "config": cfg["id"] if cfg else None,
                    "value": value, "threshold": threshold, "comparison": ok_if, "met": met,
                    "unit": unit, "note": None if value is not None else why_none})

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
    # issue 15 ("ahead of llvmpipe on every configuration, and far ahead on big meshes")
    timed = [c for c in configs if (c.get("peer") or {}).get("ratio_clraster_over_llvmpipe")]
    none_timed = "no configuration with an llvmpipe time in this run"
    for key, what in (("ratio_clraster_over_llvmpipe", "all outputs"),
                      ("ratio_lean_over_llvmpipe", "depth and ids, as llvmpipe")):
        worst = max((c for c in timed if c["peer"].get(key)), default=None,
                    key=lambda c: c["peer"][key])
        target(f"every_config_vs_llvmpipe{'' if what == 'all outputs' else '_lean'}",
               f"every configuration ({what}): largest clraster time / llvmpipe time",
               worst, worst["peer"][key] if worst else None, 1.0, "<=", none_timed)
    # issue 34 (performance on every CPU)
    target("dragon_vs_llvmpipe_0.15", "dragon at 1920x1080: clraster time / llvmpipe time "
           "(issue 34)", dragon, pr, 0.15, "<=", nodragon if not dragon else
           (dragon.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    worst = max((c for c in timed if c["peer"].get("ratio_clraster_over_llvmpipe")),
                default=None, key=lambda c: c["peer"]["ratio_clraster_over_llvmpipe"])
    target("every_config_vs_llvmpipe_0.8", "every configuration: largest clraster time / "
           "llvmpipe time (issue 34)", worst,
           worst["peer"]["ratio_clraster_over_llvmpipe"] if worst else None, 0.8, "<=",
           none_timed)
    fills = [c for c in timed if "fill" in c["sweeps"]
             and (c["opencl"].get("covered_fraction") or 0.0) >= FILL_COVERAGE]
    wf = max(fills, default=None, key=lambda c: c["peer"]["ratio_clraster_over_llvmpipe"])
    target("fill_vs_llvmpipe", f"frames ≥ {FILL_COVERAGE:.0%} covered (fill sweep): largest "
           "clraster time / llvmpipe time (issue 34)", wf,
           wf["peer"]["ratio_clraster_over_llvmpipe"] if wf else None, 0.8, "<=",
           "no fill configuration with an llvmpipe time in this run")
    target("plant10m_occlusion_vs_llvmpipe_30",
           "plant ≥ 10M triangles, occlusion culling: llvmpipe time / clraster time "
           "(issue 34)", plant, ps, 30.0, ">=",
           "no plant ≥ 10M triangles with occlusion mode in this run" if not plant else
           (plant.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    empty = _find(configs, lambda c: c["scene"]["name"] == "empty"
                  and c["size"] == [1920, 1080])
    target("empty_frame_ms", "empty frame at 1920x1080: clraster median time, ms (issue 34)",
           empty, empty["opencl"]["median_ms"] if empty else None, 1.0, "<=",
           "no empty configuration at 1920x1080 in this run", unit="ms")
    target("dragon_vs_llvmpipe_0.2", "dragon at 1920x1080: clraster time / llvmpipe time "
           "(issue 15)", dragon, pr, 0.2, "<=", nodragon if not dragon else
           (dragon.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    target("plant10m_occlusion_vs_llvmpipe_20",
           "plant ≥ 10M triangles, occlusion culling: llvmpipe time / clraster time "
           "(issue 15)", plant, ps, 20.0, ">=",
           "no plant ≥ 10M triangles with occlusion mode in this run" if not plant else
           (plant.get("peer") or {}).get("skipped") or "llvmpipe not measured")
    off = plant and _find(configs, lambda c: c["scene"]["name"] == plant["scene"]["name"]
                          and c["size"] == plant["size"] and c["mode"] == "off")
    own = (off["opencl"]["median_ms"] / plant["opencl"]["median_ms"]
           if off and plant and plant["opencl"]["median_ms"] else None)
    target("plant10m_occlusion_vs_off",
           "plant ≥ 10M triangles: clraster without object culling / with occlusion culling",
           plant, own, 6.0, ">=", "no plant ≥ 10M triangles in both occlusion and off modes "
           "in this run")
    return out + scale_targets(scale)
