"""``clraster bench``: the benchmark harness's command line (see `clraster.bench.harness` for
what a run measures and how).

:func:`main` parses and checks the arguments, then runs the named steps in order: prepare the
output folder, drop the configurations whose meshes are missing, measure each configuration
(with a checkpoint after each), probe peak memory and cold/warm start, then write
results.json, results.md and the plots. A progress bar with an ETA goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

from clraster.base.checks import parse_size
from clraster.bench import report
from clraster.bench.datasets import (
    DATASETS_MESHES,
    DATASETS_SIZE,
    DATASETS_VIEWS,
    QUICK_VIEWS,
    datasets_targets,
    open3d_status,
    run_sweep,
)
from clraster.bench.measure import (
    MEMORY_METHOD,
    PROBE_PREFIX,
    PeerRunner,
    measure_memory,
    measure_startup,
    memory_jobs,
    probe,
    run_config,
)
from clraster.bench.scale import (
    FULL_SCALE_REPEAT,
    FULL_SCALE_SCENES,
    SCALE_SKIP_TWIN,
    quick_scale_scenes,
    scale_only,
    scale_summary,
)
from clraster.bench.spec import (
    DEFAULT_SWEEPS,
    FULL_FILL_SCENES,
    FULL_PIXEL_SIZES,
    FULL_TRIANGLE_SCENES,
    FULL_TWIN_MAX_TRIANGLES,
    MODES,
    SWEEPS,
    Config,
    LoadedScene,
    SceneMissing,
    SceneSpec,
    build_matrix,
    estimated_triangles,
    evaluate_targets,
    load_scene,
    mesh_path,
    parse_count,
)

#: First line of ``clraster bench --help``.
DESCRIPTION = ("Benchmark harness: the OpenCL pipeline vs its NumPy twin (and Mesa llvmpipe), "
               "one run.")


class OutputError(Exception):
    """The output folder cannot be created or written (exit 1, before anything is run)."""


# =======================================================================================
# Progress bar (stderr)
# =======================================================================================

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
        line = (f"[{bar:<20}] {self.k + 1}/{n} {label} | {report.hms(el)} elapsed, ETA "
                f"{report.hms(eta) if eta is not None else '?'}"
                + (f" | {detail}" if detail else ""))
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
        line = (f"[{'#' * 20}] {len(self.weights)}/{len(self.weights)} done in "
                f"{report.hms(el)}")
        self.stream.write(("\r\x1b[2K" if self.tty else "") + line + "\n")
        self.stream.flush()

    def log(self, text: str) -> None:
        """A message that does not break the bar."""
        self.stream.write(("\r\x1b[2K" if self.tty else "") + text + "\n")
        self.stream.flush()


# =======================================================================================
# Arguments
# =======================================================================================

def _limit(text: str) -> int:
    """--twin-max-triangles: a count (20K, 6M) or 'none' (-1: no limit)."""
    if text.strip().lower() == "none":
        return -1
    try:
        return parse_count(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _list(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _sweeps(text: str) -> list[str]:
    """--sweeps: a comma-separated list, ``all`` for every sweep (the scale one included)."""
    names = _list(text)
    return list(SWEEPS) if names == ["all"] else names


def _default_out() -> Path:
    """bench/results/ of the repository (a checkout or an editable install); from an
    installed package, ./clraster-bench-results."""
    repo = Path(__file__).resolve().parents[2]   # clraster/bench/cli.py -> repository
    if (repo / "pyproject.toml").is_file() and (repo / "bench").is_dir():
        return repo / "bench" / "results"
    return Path.cwd() / "clraster-bench-results"


#: Environment variable naming the folder of the shared meshes (used when --meshes is not
#: given; a folder named there is used even if it is missing, so a typo is reported).
MESHES_ENV = "CLRASTER_MESHES"


def _mesh_dirs() -> list[Path]:
    """Where the shared meshes are looked for when --meshes is not given, in order:
    $CLRASTER_MESHES alone if set; else ../shared/meshes and ./shared/meshes from the
    current folder, then ../shared/meshes next to the repository (a checkout or an editable
    install; an installed package has no repository, so it is not looked for under the
    virtualenv)."""
    env = os.environ.get(MESHES_ENV, "").strip()
    if env:
        return [Path(env).expanduser()]
    cwd = Path.cwd()
    cands = [cwd.parent / "shared" / "meshes", cwd / "shared" / "meshes"]
    repo = Path(__file__).resolve().parents[2]   # clraster/bench/cli.py -> repository
    if (repo / "pyproject.toml").is_file():
        cands.append(repo.parent / "shared" / "meshes")
    return list(dict.fromkeys(p.resolve() for p in cands))


def _default_meshes() -> Path:
    cands = _mesh_dirs()
    return next((p for p in cands if p.is_dir()), cands[0])


def _where_looked(a: argparse.Namespace) -> str:
    """The mesh folder(s) searched, for messages."""
    dirs = a.meshes_looked or [a.meshes]
    return ", ".join(f"{d}{'' if d.is_dir() else ' (missing)'}" for d in dirs)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="clraster bench", description=DESCRIPTION,
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
                   help=f"folder of the shared meshes (default ${MESHES_ENV} if set, else "
                        "the first of ../shared/meshes and ./shared/meshes from the current "
                        "folder and ../shared/meshes next to a checkout that exists)")
    p.add_argument("--sweeps", type=_sweeps, default=list(DEFAULT_SWEEPS),
                   help="comma-separated subset of triangles,pixels,culling,fill,scale,"
                        f"datasets, or all (default {','.join(DEFAULT_SWEEPS)}: the scale "
                        "sweep, 10M-200M triangles, and the datasets sweep, views/s against "
                        "Open3D, run only when named)")
    p.add_argument("--scenes", type=_list, help="scenes of the triangles sweep (comma-"
                   f"separated; default {','.join(FULL_TRIANGLE_SCENES)})")
    p.add_argument("--size", type=parse_size, help="image size of the triangles and culling "
                                              "sweeps (default 1920x1080)")
    p.add_argument("--pixels-scene", help="scene of the pixels sweep (default dragon)")
    p.add_argument("--sizes", type=lambda t: [parse_size(s) for s in _list(t)],
                   help=f"sizes of the pixels sweep (default {','.join(FULL_PIXEL_SIZES)})")
    p.add_argument("--culling-scene", help="scene of the culling sweep (default "
                                           "plant:10.1M@inside, ≥ 10M triangles)")
    p.add_argument("--fill-scenes", type=_list,
                   help="scenes of the fill sweep, at --size (comma-separated; default "
                        f"{','.join(FULL_FILL_SCENES)}: meshes seen from close by, one large "
                        "quad, an empty frame)")
    p.add_argument("--modes", type=_list, help="culling modes of the culling sweep "
                                               "(default off,frustum,occlusion)")
    p.add_argument("--scale-scenes", type=_list,
                   help="grid scenes of the scale sweep, each seen @overview and @inside "
                        f"(comma-separated; default {','.join(FULL_SCALE_SCENES)}: 10.5M, "
                        "52.3M, 104.6M, 209.1M triangles; quick: ~1M and ~2M)")
    p.add_argument("--scale-repeat", type=int,
                   help=f"timed frames per scale configuration (default {FULL_SCALE_REPEAT}: "
                        "a 200M frame takes 10-20 s; quick: --repeat)")
    p.add_argument("--datasets-meshes", type=_list,
                   help="meshes of the datasets sweep (comma-separated; default "
                        f"{','.join(DATASETS_MESHES)}; quick: spot or example)")
    p.add_argument("--views", type=int,
                   help=f"views per round of the datasets sweep (default {DATASETS_VIEWS}; "
                        f"quick {QUICK_VIEWS})")
    p.add_argument("--datasets-size", type=parse_size,
                   help="image size of the datasets sweep (default "
                        f"{DATASETS_SIZE[0]}x{DATASETS_SIZE[1]})")
    p.add_argument("--repeat", type=int, help="timed frames per configuration, and rounds "
                                              "of the datasets sweep (default 5; quick 2)")
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
    p.add_argument("--no-peer", action="store_true", help="do not run the peers (llvmpipe; "
                                                          "Open3D in the datasets sweep)")
    p.add_argument("--no-startup", action="store_true", help="skip cold/warm start")
    p.add_argument("--no-memory", action="store_true", help="skip peak memory")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--startup-scene", help="scene of the cold/warm start (default dragon "
                                           "at 1920x1080; quick: spot at 320x240)")
    p.add_argument("--cull", choices=("back", "front", "none"), default="back",
                   help="face culling (default back)")
    p.add_argument("--device", help="OpenCL device to measure: pocl, intel, oclgrind or a "
                                    "part of a platform or device name (sets CLRASTER_DEVICE "
                                    "for this run and its subprocesses; `clraster devices` "
                                    "lists them; default: CLRASTER_DEVICE, else clraster's "
                                    "choice); recorded in results.json")
    p.add_argument("--list", action="store_true", help="print the configurations and exit")
    p.add_argument("--probe", help=argparse.SUPPRESS)
    return p


def _choose_device(name: str) -> str | None:
    """Make ``name`` the device of this run and of the subprocesses it starts (memory and
    start-up probes) through CLRASTER_DEVICE; None when a device matches, else why not."""
    from clraster.pipeline.device import NoDeviceError, find_device

    os.environ["CLRASTER_DEVICE"] = name.strip()
    try:
        find_device(name, source="--device")
    except NoDeviceError as exc:
        return str(exc)
    return None


def _fill_defaults(a: argparse.Namespace) -> None:
    a.meshes_looked = None if a.meshes else _mesh_dirs()
    a.meshes = a.meshes or _default_meshes()
    if a.quick:
        small = "spot" if mesh_path("spot", a.meshes) else "example"
        grid = "grid:spot:3x2x1" if small == "spot" else "grid:example:2x1x1"
        a.scenes = a.scenes or [small, grid, "plant:20K@overview"]
        a.size = a.size or (320, 240)
        a.pixels_scene = a.pixels_scene or small
        a.sizes = a.sizes or [(320, 240), (640, 480)]
        a.culling_scene = a.culling_scene or "plant:20K@inside"
        a.fill_scenes = a.fill_scenes or [f"{small}@close", "quad", "empty"]
        a.repeat = a.repeat or 2
        a.scale_scenes = a.scale_scenes or quick_scale_scenes(
            lambda m: mesh_path(m, a.meshes) is not None)
        a.scale_repeat = a.scale_repeat or a.repeat
        a.startup_scene = a.startup_scene or small
        a.startup_size = (320, 240)
        a.datasets_meshes = a.datasets_meshes or [small]
        a.views = a.views or QUICK_VIEWS
    else:
        a.scenes = a.scenes or list(FULL_TRIANGLE_SCENES)
        a.size = a.size or (1920, 1080)
        a.pixels_scene = a.pixels_scene or "dragon"
        a.sizes = a.sizes or [parse_size(s) for s in FULL_PIXEL_SIZES]
        a.culling_scene = a.culling_scene or "plant:10.1M@inside"
        a.fill_scenes = a.fill_scenes or list(FULL_FILL_SCENES)
        a.repeat = a.repeat or 5
        a.scale_scenes = a.scale_scenes or list(FULL_SCALE_SCENES)
        a.scale_repeat = a.scale_repeat or FULL_SCALE_REPEAT
        a.startup_scene = a.startup_scene or (
            "dragon" if mesh_path("dragon", a.meshes) else "example")
        a.startup_size = (1920, 1080)
        if a.twin_max_triangles is None:
            a.twin_max_triangles = FULL_TWIN_MAX_TRIANGLES
        a.datasets_meshes = a.datasets_meshes or list(DATASETS_MESHES)
        a.views = a.views or DATASETS_VIEWS
    a.datasets_size = a.datasets_size or DATASETS_SIZE
    if a.twin_max_triangles is not None and a.twin_max_triangles < 0:
        a.twin_max_triangles = None
    a.modes = a.modes or list(MODES)


def _a_mesh(name: str) -> bool:
    """Whether a scene name names a plain mesh (what the datasets sweep times)."""
    try:
        spec = SceneSpec.parse(name)
    except ValueError:
        return False
    return spec.kind in ("mesh", "example") and spec.view == "framing"


def _bad_settings(a: argparse.Namespace) -> str | None:
    """Why the settings are unusable (a usage error), or None."""
    bad = [s for s in a.sweeps if s not in SWEEPS]
    bad += [m for m in a.modes if m not in MODES]
    bad += [s for s in a.scale_scenes
            if "scale" in a.sweeps and (not s.startswith("grid:") or "@" in s)]
    bad += [s for s in a.datasets_meshes if "datasets" in a.sweeps and not _a_mesh(s)]
    if bad or a.repeat < 1 or a.scale_repeat < 1 or a.warmup < 0 or a.occlusion_warmup < 0 \
            or a.views < 1:
        return (f"bad sweep/mode/scale scene/datasets mesh {bad} (scale scenes are "
                f"grid:MESH:NXxNYxNZ, without @VIEW: both views run; datasets meshes are "
                f"meshes, not grids or plants), or --repeat / --scale-repeat / --views < 1, "
                f"or a negative warm-up")
    return None


def _matrix(a: argparse.Namespace) -> list[Config]:
    """The configurations to run; ValueError for a scene name that does not parse."""
    configs = build_matrix(a)
    for s in [a.startup_scene]:
        SceneSpec.parse(s)
    return configs


# =======================================================================================
# The steps of a run
# =======================================================================================

def _print_probe(task_json: str) -> int:
    """``--probe JSON``: the body of a probe subprocess (`clraster.bench.measure.run_probe`
    reads the line it prints)."""
    print(PROBE_PREFIX + json.dumps(report.jsonable(probe(json.loads(task_json)))),
          flush=True)
    return 0


def _print_list(configs: list[Config], a: argparse.Namespace) -> None:
    for c in configs:
        print(f"{c.id:<45} sweeps={','.join(c.sweeps)}")
    if "datasets" in a.sweeps:
        w, h = a.datasets_size
        for m in a.datasets_meshes:
            print(f"{f'datasets {m}/{w}x{h}/cull back,none + Open3D':<45} sweeps=datasets "
                  f"({a.views} views x {a.repeat} rounds)")


def _prepare_out(a: argparse.Namespace) -> Path:
    """The output folder, created and checked writable now, so that a bad ``--out`` fails
    at once rather than after the measurements (OutputError says which path and why)."""
    if a.out is None and a.quick:
        try:
            return Path(tempfile.mkdtemp(prefix="clraster-bench-"))
        except OSError as exc:
            raise OutputError(f"cannot create a temporary output folder in "
                              f"{tempfile.gettempdir()}: {exc.strerror or exc}") from None
    out = a.out or _default_out()
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):   # writable? (a folder can exist read-only)
            pass
    except FileExistsError:   # mkdir(exist_ok=True) raises it only for a non-folder
        raise OutputError(f"cannot write results to --out {out}: it exists and is not a "
                          f"folder") from None
    except OSError as exc:
        raise OutputError(f"cannot write results to --out {out}: "
                          f"{exc.strerror or exc}") from None
    return out


def _drop_missing(configs: list[Config], meshes: Path) -> tuple[list[Config], list[str]]:
    """The configurations whose mesh files are there, and a message for each of the others
    (dropped before the ETA is set)."""
    runnable, skipped = [], []
    for c in configs:
        if c.scene.kind in ("mesh", "grid") and c.scene.mesh != "example" \
                and mesh_path(c.scene.mesh, meshes) is None:
            msg = (f"{c.id}: mesh {c.scene.mesh!r} not found in {meshes} "
                   f"(set --meshes DIR or ${MESHES_ENV})")
            skipped.append(msg)
            print(f"skipped {msg}", file=sys.stderr)
        else:
            runnable.append(c)
    return runnable, skipped


def _weight(c: Config, a: argparse.Namespace) -> float:
    """Rough cost of a configuration, for the ETA only."""
    n = estimated_triangles(c.scene, a.meshes)
    twin = not a.no_twin and (a.twin_max_triangles is None or n <= a.twin_max_triangles)
    return n * (1 + (0 if not twin else 60 if c.scene.kind == "plant" else 12)) \
        + c.width * c.height * 20 + 2e6


def _datasets_weights(a: argparse.Namespace) -> list[float]:
    """Rough cost of each mesh of the datasets sweep (three jobs, `repeat` rounds of
    `views` frames at about 30 ms per million triangles), in `_weight`'s units (roughly
    5e6 per second), for the ETA only."""
    if "datasets" not in a.sweeps:
        return []
    n = [estimated_triangles(SceneSpec.parse(m), a.meshes) for m in a.datasets_meshes]
    return [3 * (a.repeat + 1) * a.views * (5e-3 + 30e-3 * t / 1e6) * 5e6 for t in n]


def _progress(runnable: list[Config], mem_jobs: list[Config],
              a: argparse.Namespace) -> Progress:
    """The progress bar: the configurations, the datasets sweep's meshes, then the memory
    probes and the start-up probe (weighed against an average configuration)."""
    weights = [_weight(c, a) for c in runnable]
    avg = sum(weights) / len(weights) if weights else 1.0
    weights += _datasets_weights(a)
    steps = weights + [avg * 0.5] * len(mem_jobs) + ([] if a.no_startup else [avg])
    return Progress(steps)


def _settings_for(c: Config, a: argparse.Namespace) -> argparse.Namespace:
    """The settings a configuration is measured with: a scale-only one has its own repeat
    count (its frames take seconds)."""
    if scale_only(c.sweeps):
        return argparse.Namespace(**{**vars(a), "repeat": a.scale_repeat})
    return a


def _measure_configs(runnable: list[Config], a: argparse.Namespace, argv: list[str],
                     peer: PeerRunner, prog: Progress, out: Path,
                     skipped: list[str]) -> tuple[list[dict], list[str]]:
    """Measure each configuration (records, errors); a scene found missing while loading
    goes to `skipped`. One loaded scene at a time, shared by consecutive configurations of
    the same geometry; a checkpoint after each configuration."""
    records: list[dict] = []
    errors: list[str] = []
    loaded: LoadedScene | None = None
    for c in runnable:
        prog.start(c.id)
        try:
            if loaded is None or loaded.spec.geometry != c.scene.geometry:
                loaded = None   # free the previous scene first (10M triangles are large)
                loaded = load_scene(c.scene, a.meshes)
            records.append(report.jsonable(run_config(c, loaded, _settings_for(c, a), peer,
                                                      prog.log, prog.detail)))
        except SceneMissing as exc:
            skipped.append(f"{c.id}: {exc}")
            prog.log(f"skipped {c.id}: {exc}")
        except Exception as exc:  # keep the other configurations of a long run
            errors.append(f"{c.id}: {type(exc).__name__}: {exc}")
            prog.log(f"ERROR {c.id}: {type(exc).__name__}: {exc}\n"
                     + traceback.format_exc(limit=4))
        prog.finish_step()
        # checkpoint: a long run that dies later still leaves its measurements
        report.write_partial(out, argv, records, errors, skipped)
    return records, errors


def _measure_memory(mem_jobs: list[Config], records: list[dict], a: argparse.Namespace,
                    prog: Progress) -> list[dict]:
    memory = []
    for c in mem_jobs:
        prog.start(f"peak memory {c.id}")
        tri = next((r["triangles"] for r in records if r["scene"]["name"] == c.scene.text),
                   0)
        twin_ok = not a.no_twin and (a.twin_max_triangles is None
                                     or tri <= a.twin_max_triangles)
        if scale_only(c.sweeps):
            memory.append(measure_memory(c.scene.text, (c.width, c.height), c.mode, a,
                                         False, SCALE_SKIP_TWIN))
        else:
            memory.append(measure_memory(c.scene.text, (c.width, c.height), c.mode, a,
                                         twin_ok))
        prog.finish_step()
    return memory


def _measure_datasets(a: argparse.Namespace, prog: Progress) -> dict:
    """The datasets sweep (`clraster.bench.datasets.run_sweep`): one progress step per
    mesh, each round's views/s shown on a terminal."""
    prog.log("Open3D skipped: --no-peer" if a.no_peer else open3d_status()[1])
    return run_sweep(a.datasets_meshes, a.meshes, views=a.views, size=a.datasets_size,
                     repeat=a.repeat, use_open3d=not a.no_peer, log=prog.detail,
                     start=prog.start, done=prog.finish_step)


def _measure_startup(a: argparse.Namespace, prog: Progress) -> dict | None:
    if a.no_startup:
        return None
    prog.start(f"cold/warm start {a.startup_scene}")
    startup = measure_startup(a.startup_scene, a.startup_size, a)
    prog.finish_step()
    return startup


def _plots(res: dict[str, Any], a: argparse.Namespace, out: Path) -> list[str]:
    if a.no_plots:
        return []
    from clraster.bench import plots as plots_mod

    plots, why = plots_mod.make_all(res, out)
    if why:
        print(why)
    return plots


def _run(a: argparse.Namespace, argv: list[str], configs: list[Config], out: Path) -> int:
    """Measure `configs` and write the results into `out`; returns the exit code."""
    from clraster.bench.machine import describe

    t_start = time.perf_counter()
    runnable, skipped = _drop_missing(configs, a.meshes)
    datasets_on = "datasets" in a.sweeps
    if not runnable and not datasets_on:
        # a run that skips everything must not look like a successful one (exit 0)
        why = (f"the {len(configs)} configuration(s) need mesh files that are not there; "
               f"looked in {_where_looked(a)}. Give the folder with --meshes DIR or "
               f"${MESHES_ENV}" if configs else "no configuration (see --sweeps, --list)")
        print(f"clraster bench: error: nothing to measure: {why}", file=sys.stderr)
        return 1
    peer = PeerRunner(not a.no_peer and bool(runnable),
                      "--no-peer" if a.no_peer else "no configuration for it in this run")
    print(f"llvmpipe: {peer.reason}", flush=True)
    mem_jobs = [] if a.no_memory else memory_jobs(runnable)
    prog = _progress(runnable, mem_jobs, a)
    records, errors = _measure_configs(runnable, a, argv, peer, prog, out, skipped)
    peer.close()
    datasets = _measure_datasets(a, prog) if datasets_on else None
    if datasets:
        errors += datasets["failed"]
        skipped += datasets["skipped"]
    memory = _measure_memory(mem_jobs, records, a, prog)
    startup = _measure_startup(a, prog)
    prog.close()

    planned = [{"id": c.id, "scene": c.scene.text,
                "triangles": estimated_triangles(c.scene, a.meshes)}
               for c in runnable if "scale" in c.sweeps]
    scale = scale_summary(planned, records, memory, errors, a.scale_repeat)
    targets = evaluate_targets(records, scale) + datasets_targets(datasets)
    res = report.results_record(
        argv=argv, a=a, machine=describe(peer_renderer=peer.reason if peer.ok else None),
        peer=peer.status(), configs=records, targets=targets,
        startup=startup, memory=memory, memory_method=MEMORY_METHOD, skipped=skipped,
        errors=errors, scale=scale, datasets=datasets)
    res["elapsed_s"] = time.perf_counter() - t_start
    plots = _plots(res, a, out)
    res["plots"] = plots
    res = report.jsonable(res)
    js, md = report.write_results(res, out)
    print(report.summary_lines(res))
    (out / "results.partial.json").unlink(missing_ok=True)
    print(f"wrote {js}, {md}" + (f" and {len(plots)} plots" if plots else ""))
    if errors:
        print(f"clraster bench: {len(errors)} configuration(s) failed:\n  "
              + "\n  ".join(errors), file=sys.stderr)
        return 1
    if not records and not (datasets and datasets["rows"]):
        print(f"clraster bench: error: nothing was measured: every configuration was "
              f"skipped (meshes looked for in {_where_looked(a)}; see 'skipped' above)",
              file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    """``clraster bench ARGS``: run the benchmark; returns the exit code (0 done, 1 a
    configuration failed or ``--out`` is not writable, 2 a usage error)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    p = _parser()
    try:
        a = p.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    if a.probe:
        return _print_probe(a.probe)
    _fill_defaults(a)
    why = _bad_settings(a)
    if why:
        p.print_usage(sys.stderr)
        print(f"clraster bench: error: {why}", file=sys.stderr)
        return 2
    try:
        configs = _matrix(a)
    except ValueError as exc:
        print(f"clraster bench: error: {exc}", file=sys.stderr)
        return 2
    if a.list:
        _print_list(configs, a)
        return 0
    if a.device:
        why = _choose_device(a.device)
        if why:
            print(f"clraster bench: error: {why}", file=sys.stderr)
            return 2
    try:
        out = _prepare_out(a)
    except OutputError as exc:
        print(f"clraster bench: error: {exc}", file=sys.stderr)
        return 1
    ds = (f" and the datasets sweep ({len(a.datasets_meshes)} meshes)"
          if "datasets" in a.sweeps else "")
    print(f"clraster bench: {len(configs)} configurations{ds}; results in {out}", flush=True)
    return _run(a, argv, configs, out)


if __name__ == "__main__":
    raise SystemExit(main())
