"""How the benchmark harness measures: one configuration (OpenCL vs the NumPy twin,
interleaved, and the llvmpipe peer), and the subprocess probes (cold/warm start, peak memory).

Per configuration (:func:`run_config`): one Renderer, warm-up frames of the OpenCL path
(occlusion gets ``--occlusion-warmup`` more, so its visible set from the previous frame is
warm) and one of the twin, then ``--repeat`` rounds, each a frame of every renderer, each
round starting with the next one, so machine noise and what a frame follows hit all alike;
medians. The renderers: OpenCL; OpenCL with only the outputs the llvmpipe peer makes
(:data:`LEAN_OUTPUTS`, depth and triangle ids; not in the scale sweep: the like-for-like
comparison); llvmpipe (:class:`PeerRunner`, :class:`PeerSession`: the same scene, camera and
size, uploaded once per scene and size); the twin, with a time budget per configuration
(``--twin-budget``), rendering the same culling mode (:data:`~clraster.bench.spec.TWIN_MODE`)
through a `clraster.reference.Renderer` of its own, whose occlusion history its warm-up
frame makes warm.

The probes (:func:`measure_startup`, :func:`measure_memory`) each run a fresh Python process,
``python -m clraster.bench.cli --probe JSON``, whose body is :func:`probe`; it prints one
line :data:`PROBE_PREFIX` + JSON, which :func:`run_probe` reads back.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, cast

from clraster.bench.report import jsonable
from clraster.bench.scale import SCALE_SKIP_PEER, SCALE_SKIP_TWIN, scale_only
from clraster.bench.spec import MODES, TWIN_MODE, Config, LoadedScene, SceneSpec, load_scene

#: The module a probe subprocess runs (``-m``); its ``--probe JSON`` option calls `probe`.
PROBE_MODULE = "clraster.bench.cli"
#: Start of the probe's result line on its stdout (the rest is JSON).
PROBE_PREFIX = "PROBE "

#: How the peak memory is measured (results.json "memory_method").
MEMORY_METHOD = (
    "A fresh Python process per scene and path imports clraster, "
    "loads or builds the scene, and renders one frame (two in "
    "occlusion mode) on one path only (OpenCL or twin). "
    "peak_rss_mib: the process's peak resident set (VmHWM; ru_maxrss "
    "is not used because Linux carries it over exec from the parent); "
    "the PoCL device is the CPU, so device buffers are host memory and "
    "are included. baseline_rss_mib: RSS after the imports (and the "
    "OpenCL context, on the OpenCL path); "
    "scene_rss_mib: RSS with the scene loaded; render_extra_mib: the "
    "peak during rendering above that (VmHWM reset through "
    "/proc/self/clear_refs after loading).")


# =======================================================================================
# Measuring one configuration
# =======================================================================================

#: What the llvmpipe peer makes (depth and triangle ids, `peer_llvmpipe`): the outputs of
#: the second clraster timing of every configuration, the like-for-like comparison.
LEAN_OUTPUTS = ("depth", "ids")


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
    # The twin's culling mode for this configuration (spec.TWIN_MODE: the same one)
    twin_mode = TWIN_MODE[cfg.mode]
    twin_kw = MODES[twin_mode]
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
    elif scale_only(cfg.sweeps):
        twin_skip = SCALE_SKIP_TWIN
    elif a.twin_max_triangles is not None and sc.triangles > a.twin_max_triangles:
        twin_skip = (f"twin skipped: {sc.triangles:,} triangles > --twin-max-triangles "
                     f"{a.twin_max_triangles:,}")
    g = None
    twin_warm_ms: list[float] = []
    twin_spent = 0.0
    if twin_skip is None:
        note("twin warm-up")
        # one twin Renderer per configuration, as on the OpenCL side: it keeps the scene's
        # geometry pool and, in occlusion rows, last frame's visible set (warm after this
        # warm-up frame; one is enough, as the camera does not move)
        tw = clraster.reference.Renderer(w, h)
        t0 = time.perf_counter()
        g = tw.render(sc.target, cam, cull=a.cull, **twin_kw)
        twin_spent = time.perf_counter() - t0
        twin_warm_ms.append(twin_spent * 1e3)

    # the llvmpipe peer, timed in the same rounds (None: unavailable, or the scale sweep)
    session = None if scale_only(cfg.sweeps) else peer.session(cfg, sc, cam, a)
    cl_ms: list[float] = []
    lean_ms: list[float] = []
    tw_ms: list[float] = []
    cl_stages: list[dict] = []
    tw_stages: list[dict] = []
    budget_hit = False
    order = ["opencl"] + (["lean"] if not scale_only(cfg.sweeps) else [])
    order += (["llvmpipe"] if session is not None else []) + (["twin"] if g is not None else [])
    for i in range(a.repeat):
        note(f"round {i + 1}/{a.repeat}")
        # each round starts with the next renderer: what a frame follows (the twin's
        # memory churn, llvmpipe's framebuffer) changes its time on this machine, and a
        # fixed order gave a renderer the same neighbour every round
        k = i % len(order)
        for what in order[k:] + order[:k]:
            if what == "opencl":
                t0 = time.perf_counter()
                f = r.render(sc.target, cam, cull=a.cull, **kw)
                cl_ms.append((time.perf_counter() - t0) * 1e3)
                cl_stages.append(dict(f.stats.timings_ms))
            elif what == "lean":
                # the job the llvmpipe peer does: depth and triangle ids, no barycentrics
                # (same renderer and camera: an occlusion history stays the same)
                t0 = time.perf_counter()
                r.render(sc.target, cam, cull=a.cull, outputs=LEAN_OUTPUTS, **kw)
                lean_ms.append((time.perf_counter() - t0) * 1e3)
            elif what == "llvmpipe":
                cast(PeerSession, session).frame()
            elif not budget_hit:   # the twin, within its time budget
                if tw_ms and twin_spent > a.twin_budget:
                    budget_hit = True
                    continue
                t0 = time.perf_counter()
                g = tw.render(sc.target, cam, cull=a.cull, **twin_kw)
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
        # the triangles that survived object culling, per second (what the stages process)
        "setup_triangles_per_s": _rate(counts["triangles_in"], cl_med),
        "counts": counts,
        # fill rate: pixels the frame covers, and fragments depth-tested, per second
        "covered_pixels": int(np.count_nonzero(f.triangle_id >= 0)),
        "covered_fraction": float(np.count_nonzero(f.triangle_id >= 0)) / (w * h),
        "covered_pixels_per_s": _rate(int(np.count_nonzero(f.triangle_id >= 0)), cl_med),
        "fragments_per_s": _rate(counts.get("fragments_tested", 0), cl_med),
        "lean": {"outputs": list(LEAN_OUTPUTS), "runs_ms": lean_ms,
                 "median_ms": _median(lean_ms)},
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
    rec["peer"] = ({"skipped": SCALE_SKIP_PEER} if scale_only(cfg.sweeps) and peer.ok
                   else peer.result(session, f.depth, cl_med, _median(lean_ms)))
    del r, f, g
    return rec


# =======================================================================================
# The llvmpipe peer
# =======================================================================================

class PeerRunner:
    """The llvmpipe peer (`clraster.bench.peer_llvmpipe`), timed in the rounds of each
    configuration (`session`): one llvmpipe frame per round, after clraster's, so a drift of
    the shared machine's speed hits both alike. (It used to be timed apart, once per scene
    and size: a run then put spot at 0.81× llvmpipe while frames taken in turn gave 1.26×,
    `bench/peer_check.py`.) The uploaded scene is kept while consecutive configurations
    draw it (the modes of one scene and size)."""

    def __init__(self, enabled: bool, disabled_reason: str = "--no-peer") -> None:
        self.mod: Any = None
        self.renderer: str | None = None
        self._live: tuple[tuple, Any, float] | None = None   # (key, LlvmpipePeer, upload s)
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

    def session(self, cfg: Config, sc: LoadedScene, cam, a) -> PeerSession | None:
        """A peer session for one configuration (its scene uploaded, one warm-up frame
        drawn), or None when the peer is unavailable. A failure is kept in the session and
        reported by `result`, never raised: the peer is a comparison, not the thing under
        test."""
        if not self.ok:
            return None
        import numpy as np

        key = (cfg.scene.text, cfg.width, cfg.height)
        try:
            if self._live is None or self._live[0] != key:
                self.close()
                t0 = time.perf_counter()
                p = self.mod.LlvmpipePeer(cfg.width, cfg.height)
                self._live = (key, p, 0.0)
                p.upload(sc.target)
                self._live = (key, p, time.perf_counter() - t0)
            _, p, t_up = self._live
            vp = np.asarray(cam.view_projection(cfg.width, cfg.height), np.float64)
            p.render(vp, cull=a.cull, repeat=1, warmup=0)   # the shader JIT: not kept
            return PeerSession(self, p, vp, a.cull, t_up)
        except Exception as exc:
            self.close()
            return PeerSession(self, None, None, a.cull, 0.0, f"{type(exc).__name__}: {exc}")

    def result(self, session: PeerSession | None, cl_depth, cl_med: float | None,
               lean_med: float | None = None) -> dict:
        """The configuration's peer record: llvmpipe's frame times from the session's
        rounds, coverage agreement with clraster's depth, and the ratios."""
        if session is None:
            return {"skipped": self.reason}
        rec = session.record(cl_depth)
        if rec.get("median_ms") and cl_med:
            rec["ratio_clraster_over_llvmpipe"] = cl_med / rec["median_ms"]
            rec["speedup_vs_llvmpipe"] = rec["median_ms"] / cl_med
        if rec.get("median_ms") and lean_med:
            # clraster making what llvmpipe makes (depth and ids) over llvmpipe's time
            rec["ratio_lean_over_llvmpipe"] = lean_med / rec["median_ms"]
        return rec

    def close(self) -> None:
        """Release the uploaded scene's llvmpipe context (the next session makes one)."""
        if self._live is not None:
            _, p, _ = self._live
            self._live = None
            try:
                p.release()
            except Exception:
                pass


class PeerSession:
    """llvmpipe frames of one configuration, one per `frame` call."""

    def __init__(self, runner: PeerRunner, peer, vp, cull: str, upload_s: float,
                 error: str | None = None) -> None:
        self.runner, self.peer, self.vp, self.cull = runner, peer, vp, cull
        self.upload_s, self.error = upload_s, error
        self.times: list[float] = []
        self.reads: list[float] = []
        self.last = None

    def frame(self) -> None:
        """One timed llvmpipe frame (clear, draws, glFinish; its depth read back apart)."""
        if self.error is not None:
            return
        try:
            pf = self.peer.render(self.vp, cull=self.cull, repeat=1, warmup=0)
        except Exception as exc:
            self.error = f"{type(exc).__name__}: {exc}"
            self.runner.close()
            return
        self.times.append(float(pf.times_ms[0]))
        self.reads.append(float(pf.readback_ms))
        self.last = pf

    def record(self, cl_depth) -> dict:
        if self.error is not None:
            return {"error": self.error}
        if self.last is None:
            return {"error": "no llvmpipe frame was drawn (--repeat 0?)"}
        pf = self.last
        self.runner.renderer = str(pf.renderer)
        cov = jsonable(self.runner.mod.coverage_agreement(cl_depth, pf.depth))
        return {"runs_ms": self.times, "median_ms": _median(self.times),
                "readback_ms": _median(self.reads), "renderer": str(pf.renderer),
                "threads": jsonable(pf.threads), "upload_s": self.upload_s,
                "interleaved": True,
                "draws": f"everything (no object culling), back-face culling {self.cull}",
                "coverage": cov}


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


def probe(task: dict) -> dict:
    """Body of a probe subprocess (``--probe JSON``); returns what it measured."""
    if task["task"] == "startup":
        return _probe_startup(task)
    return _probe_memory(task)


def _probe_startup(task: dict) -> dict:
    """Times of a fresh process: imports, context, programs, scene, first frames."""
    meshes = Path(task["meshes"])
    w, h = task["size"]
    spec = SceneSpec.parse(task["scene"])
    t0 = time.perf_counter()
    import numpy  # noqa: F401
    import pyopencl  # noqa: F401

    import clraster
    from clraster.pipeline.device import default_context
    from clraster.pipeline.renderer import Renderer
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


def _probe_memory(task: dict) -> dict:
    """Resident memory of a fresh process that renders one frame on one path."""
    meshes = Path(task["meshes"])
    w, h = task["size"]
    spec = SceneSpec.parse(task["scene"])
    # memory: the path's modules (and, for OpenCL, the context) before the baseline, so
    # that "rendering adds" is the rendering itself
    import clraster

    if task["path"] == "opencl":
        from clraster.pipeline.device import default_context
        from clraster.pipeline.renderer import Renderer

        default_context()
    else:
        from clraster.pipeline import reference  # noqa: F401
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
        # the twin's mode, as in run_config (two frames in occlusion mode, as above)
        tkw = MODES[TWIN_MODE[task["mode"]]]
        tw = clraster.reference.Renderer(w, h)
        for _ in range(2 if tkw.get("occlusion") else 1):
            tw.render(sc.target, cam, cull=task["cull"], **tkw)
    peak_render = _peak_rss_mib()
    peak = max(v for v in (peak_load, peak_render) if v is not None) \
        if (peak_load or peak_render) else None
    return {"baseline_rss_mib": base, "scene_rss_mib": after_scene, "peak_rss_mib": peak,
            "render_peak_rss_mib": peak_render if reset else None,
            "render_extra_mib": (peak_render - after_scene) if reset and peak_render
            and after_scene else None, "triangles": sc.triangles}


def run_probe(task: dict, env: dict[str, str] | None = None, timeout: float = 900) -> dict:
    """Run :func:`probe` on `task` in a fresh Python process; its result plus
    ``process_wall_s``, or ``{"error": ...}``."""
    cmd = [sys.executable, "-m", PROBE_MODULE, "--probe", json.dumps(task)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"probe timed out after {timeout:g} s"}
    wall = time.perf_counter() - t0
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith(PROBE_PREFIX)]
    if p.returncode != 0 or not lines:
        tail = (p.stderr or p.stdout).strip().splitlines()[-3:]
        return {"error": f"probe exited {p.returncode}: {' | '.join(tail)}"}
    out = json.loads(lines[-1][len(PROBE_PREFIX):])
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
        cold = run_probe(task, env)
        warm = run_probe(task, env)
        return {"scene": scene, "size": list(size), "cold": cold, "warm": warm,
                "method": "a fresh Python process each; cold: POCL_CACHE_DIR and "
                          "PYOPENCL_CACHE_DIR point to new empty directories; warm: the "
                          "same directories, filled by the cold run. first_frame_s includes "
                          "PoCL's per-local-size kernel specialization; to_first_frame_s = "
                          "import + context + programs + first frame (scene load excluded)."}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def memory_jobs(configs: list[Config]) -> list[Config]:
    """The configurations whose peak memory is probed: one probe pair per geometry, on its
    heaviest configuration (most pixels, frustum mode, a view that sees it all rather than
    the inside one), and every configuration of the scale sweep (its rows report their
    own peak RSS)."""
    jobs: list[Config] = []
    for geo in dict.fromkeys(c.scene.geometry for c in configs):
        cs = [c for c in configs if c.scene.geometry == geo]
        jobs.append(max(cs, key=lambda c: (c.width * c.height, c.mode == "frustum",
                                           c.scene.view != "inside")))
    jobs += [c for c in configs if "scale" in c.sweeps and c not in jobs]
    return jobs


def measure_memory(scene: str, size: tuple[int, int], mode: str,
                   a: argparse.Namespace, twin_ok: bool,
                   twin_why: str = "twin skipped (--no-twin or --twin-max-triangles)") -> dict:
    """Peak memory of a fresh process rendering `scene` on the OpenCL path, then (when
    `twin_ok`) on the twin; `twin_why` is recorded when not."""
    base = {"task": "memory", "scene": scene, "size": list(size), "mode": mode,
            "meshes": str(a.meshes), "cull": a.cull}
    rec: dict[str, Any] = {"scene": scene, "size": list(size), "mode": mode,
                           "opencl": run_probe({**base, "path": "opencl"})}
    rec["twin"] = (run_probe({**base, "path": "twin"}) if twin_ok
                   else {"skipped": twin_why})
    return rec
