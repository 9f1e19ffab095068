"""What the benchmark harness writes: results.json (schema :data:`SCHEMA`), results.md and the
summary it prints. The PNG plots are `clraster.bench.plots`.

The results dict (:func:`results_record`) is the JSON document as written; :func:`markdown`
renders it section by section and reads nothing else, so results.md can be rebuilt from a
results.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
from pathlib import Path
from typing import Any

SCHEMA = "clraster-bench/1"


def jsonable(v: Any) -> Any:
    """Plain JSON values from NumPy scalars/arrays, dicts and lists (NaN/Inf → None)."""
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    if hasattr(v, "tolist") and not isinstance(v, (str, bytes)):
        return jsonable(v.tolist())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def hms(s: float) -> str:
    """A duration in seconds as ``1h02m`` (an hour or more) or ``3m07s``."""
    s = int(round(max(0.0, s)))
    return f"{s // 3600}h{s // 60 % 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


# =======================================================================================
# results.json
# =======================================================================================

def results_record(*, argv: list[str], a: argparse.Namespace, machine: dict,
                   peer: dict, configs: list[dict], targets: list[dict],
                   startup: dict | None, memory: list[dict], memory_method: str,
                   skipped: list[str], errors: list[str],
                   scale: dict | None = None, datasets: dict | None = None) -> dict[str, Any]:
    """The results document of a run, less ``elapsed_s`` and ``plots`` (the caller adds them
    last, in that order, then passes it through :func:`jsonable`). `scale` is the scale
    sweep's summary (`clraster.bench.scale.scale_summary`; None without that sweep),
    `datasets` the datasets sweep's (`clraster.bench.datasets.run_sweep`; None without
    it)."""
    return {
        "schema": SCHEMA,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "command": ["clraster", "bench", *argv],
        "quick": bool(a.quick),
        "settings": {"repeat": a.repeat, "warmup": a.warmup,
                     "occlusion_warmup": a.occlusion_warmup, "twin_budget_s": a.twin_budget,
                     "twin_max_triangles": a.twin_max_triangles, "cull": a.cull,
                     "sweeps": a.sweeps, "meshes": str(a.meshes), "no_twin": a.no_twin,
                     "scale_scenes": getattr(a, "scale_scenes", None),
                     "scale_repeat": getattr(a, "scale_repeat", None),
                     "views": getattr(a, "views", None),
                     "datasets_meshes": getattr(a, "datasets_meshes", None),
                     "datasets_size": getattr(a, "datasets_size", None)},
        "machine": machine,
        "peer": peer,
        "configs": configs,
        "targets": targets,
        "scale": scale,
        "datasets": datasets,
        "startup": startup,
        "memory": memory,
        "memory_method": memory_method,
        "skipped": skipped,
        "errors": errors,
    }


def write_partial(out: Path, argv: list[str], configs: list[dict], errors: list[str],
                  skipped: list[str]) -> None:
    """Checkpoint results.partial.json: a long run that dies later still leaves its
    measurements."""
    (out / "results.partial.json").write_text(json.dumps(
        {"schema": SCHEMA, "command": ["clraster", "bench", *argv], "configs": configs,
         "errors": errors, "skipped": skipped}, indent=1) + "\n")


def write_results(res: dict, out: Path) -> tuple[Path, Path]:
    """Write results.json and results.md of `res` (already :func:`jsonable`) into `out`."""
    js, md = out / "results.json", out / "results.md"
    js.write_text(json.dumps(res, indent=1) + "\n")
    md.write_text(markdown(res))
    return js, md


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
    """results.md of a results dict: one section after another, each a list of lines."""
    L: list[str] = []
    for section in (_md_header, _md_targets, _md_configs, _md_fill, _md_stages, _md_funnel,
                    _md_scale, _md_datasets, _md_startup, _md_memory, _md_lists):
        L += section(res)
    return "\n".join(L) + "\n"


def _md_header(res: dict) -> list[str]:
    from clraster.bench.machine import summary

    return ["# clraster benchmark results", "",
            f"Run {res['created']} ({hms(res['elapsed_s'])}); command: "
            f"`{' '.join(res['command'])}`.", "",
            f"Machine: {summary(res['machine'])}", "",
            "Frame time = wall time of `render()` (host culling and read-back included), "
            f"median of {res['settings']['repeat']} frames after warm-up, OpenCL, the NumPy "
            "twin and llvmpipe interleaved (a frame of each per round). Stage times are "
            "OpenCL profiling-event device times (median). "
            f"llvmpipe: {res['peer']['reason']}.", ""]


def target_value(v: float | None, unit: str = "×") -> str:
    """A target's value or threshold in its unit ("×" ratios unless the target says)."""
    if v is None:
        return "—"
    if unit == "MiB":
        return f"{v:,.0f} MiB"
    if unit == "triangles":
        return f"{v / 1e6:,.1f}M triangles"
    if unit == "fraction":
        return f"{v:.1%}"
    return f"{v:.2f}×" if unit == "×" else f"{v:g} {unit}"


def _md_targets(res: dict) -> list[str]:
    L = ["## Targets", "", "| target | configuration | measured | threshold | status |",
         "|---|---|---:|---:|---|"]
    for t in res["targets"]:
        st = {True: "**met**", False: "**missed**", None: "not measured"}[t["met"]]
        if t["note"]:
            st += f" ({t['note']})"
        unit = t.get("unit", "×")
        thr = (f"{t['threshold']:g}×" if unit == "×"
               else target_value(t["threshold"], unit))
        L.append(f"| {t['description']} | {t['config'] or '—'} | "
                 f"{target_value(t['value'], unit)} | {t['comparison']} {thr} | {st} |")
    return L


def _md_config_row(c: dict) -> str:
    """One row of the configurations table."""
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
    return (f"| {', '.join(c['sweeps'])} | {c['scene']['name']} | {c['triangles']:,} | "
            f"{c['size'][0]}×{c['size'][1]} | {c['mode']} | "
            f"{_f(c['opencl']['median_ms'])} | {tws} | {_x(c['speedup_vs_twin'])} | "
            f"{pes} | {_f(pe.get('ratio_clraster_over_llvmpipe'), '.2f')} | "
            f"{_f((c['opencl'].get('lean') or {}).get('median_ms'))} | "
            f"{_f(pe.get('ratio_lean_over_llvmpipe'), '.2f')} | "
            f"{_si(c['opencl']['triangles_per_s'])} | {_si(c['opencl']['pixels_per_s'])} "
            f"| {agree} |")


def _md_configs(res: dict) -> list[str]:
    if not res["configs"]:   # a run of the datasets sweep alone
        return []
    L = ["", "## Configurations", "",
         "| sweep | scene | triangles | size | mode | OpenCL ms | twin ms (runs) | "
         "speedup | llvmpipe ms | clraster/llvmpipe | depth+ids ms | depth+ids/llvmpipe | "
         "tri/s | px/s | twin agrees |",
         "|---|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    notes = []
    for c in res["configs"]:
        L.append(_md_config_row(c))
        if "error" in c["peer"]:
            notes.append(f"- {c['id']}: llvmpipe error: {c['peer']['error']}")
        if c["twin"].get("skipped"):
            notes.append(f"- {c['id']}: {c['twin']['skipped']}")
    mixed = any(c["twin"].get("mode", c["mode"]) != c["mode"] for c in res["configs"])
    L += ["", ("[frustum] after a twin time: the twin had no occlusion culling and rendered "
               "the frustum mode (same image). " if mixed else "") + "depth+ids: clraster "
          "rendering only what the llvmpipe peer makes (`outputs=(\"depth\", \"ids\")`, no "
          "barycentrics), timed in the same rounds; llvmpipe's time is its draw and "
          "glFinish, without reading its buffers back. ⏱: the twin's time budget "
          f"({res['settings']['twin_budget_s']:g} s per configuration) was spent; (runs) is "
          "how many timed frames it made. Occlusion configurations are timed after "
          f"{res['settings']['warmup'] + res['settings']['occlusion_warmup']} warm-up frames "
          "(temporal history warm)."]
    if notes:
        L += [""] + notes
    return L


def _md_fill(res: dict) -> list[str]:
    """The fill sweep: per-pixel rates of clraster and llvmpipe on the same frames."""
    rows = [c for c in res["configs"] if "fill" in c["sweeps"]]
    if not rows:
        return []
    L = ["", "## Fill rate", "",
         "| scene | size | covered | fragments tested | clraster ms | llvmpipe ms | ratio | "
         "clraster covered px/s | llvmpipe covered px/s | clraster fragments/s | "
         "frame px/s |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for c in rows:
        o, pe = c["opencl"], c["peer"]
        lp = pe.get("median_ms")
        lrate = (o.get("covered_pixels", 0) / (lp / 1e3)) if lp else None
        L.append(f"| {c['scene']['name']} | {c['size'][0]}×{c['size'][1]} | "
                 f"{_f(100 * (o.get('covered_fraction') or 0.0))}% | "
                 f"{o['counts'].get('fragments_tested', 0):,} | {_f(o['median_ms'], '.2f')} | "
                 f"{_f(lp, '.2f')} | {_f(pe.get('ratio_clraster_over_llvmpipe'), '.2f')} | "
                 f"{_si(o.get('covered_pixels_per_s'))} | {_si(lrate)} | "
                 f"{_si(o.get('fragments_per_s'))} | {_si(o['pixels_per_s'])} |")
    L += ["", "covered: pixels with a triangle; covered px/s: those pixels per second of the "
          "whole frame (raster, clear, resolve and read-back for clraster; draw and finish for "
          "llvmpipe); frame px/s: all the frame's pixels per second of clraster's frame."]
    return L


def _md_stages(res: dict) -> list[str]:
    stages: list[str] = []
    for c in res["configs"]:
        stages += [k for k in c["opencl"]["stages_median_ms"] if k not in stages]
    if not stages:
        return []
    L = ["", "## Per-stage times (OpenCL, median ms)", "",
         "| configuration | " + " | ".join(stages) + " | frame |",
         "|---|" + "---:|" * (len(stages) + 1)]
    for c in res["configs"]:
        s = c["opencl"]["stages_median_ms"]
        L.append(f"| {c['id']} | " + " | ".join(_f(s.get(k), ".2f") for k in stages)
                 + f" | {_f(c['opencl']['median_ms'])} |")
    return L


def _md_funnel(res: dict) -> list[str]:
    cul = [c for c in res["configs"] if "culling" in c["sweeps"]]
    if not cul:
        return []
    L = ["", "## Culling funnel (triangles; last OpenCL frame)", "",
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
    return L


def _md_scale(res: dict) -> list[str]:
    sc = res.get("scale")
    if not sc:
        return []
    L = ["", "## Scale sweep", "", sc["method"], "",
         "| configuration | instances | triangles | to setup | rasterized | frame ms "
         "(median) | runs ms | tri/s (scene) | tri/s (to setup) | peak RSS MiB | fit ms | "
         "residual |", "|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|"]
    for r in sc["rows"]:
        rss = _f(r["peak_rss_mib"], ",.0f") if r["peak_rss_mib"] is not None else \
            (r["peak_rss_note"] or "—")
        resid = ("—" if r.get("residual_ms") is None else
                 f"{r['residual_ms']:+.1f} ms ({r['relative_residual']:+.1%})")
        L.append(f"| {r['id']} | {r['instances']:,} | {r['triangles']:,} | "
                 f"{r['triangles_to_setup']:,} | {r['rasterized']:,} | {_f(r['median_ms'])} | "
                 f"{', '.join(f'{t:.0f}' for t in r['runs_ms'])} | "
                 f"{_si(r['scene_triangles_per_s'])} | {_si(r['setup_triangles_per_s'])} | "
                 f"{rss} | {_f(r.get('fit_ms'))} | {resid} |")
    fit = sc.get("fit")
    if fit:
        r2 = f"{fit['r2']:.4f}" if fit["r2"] is not None else "—"
        L += ["", f"Fit over {fit['n_points']} configurations: frame ms ≈ "
                  f"{fit['intercept_ms']:.1f} + {fit['slope_ms_per_mtri']:.2f} × (million "
                  f"triangles sent to setup); R² {r2}, RMS residual "
                  f"{fit['rms_residual_ms']:.1f} ms, largest |residual| "
                  f"{fit['max_abs_relative_residual']:.1%} of the measured frame time."]
    else:
        L += ["", "No fit: fewer than two scale configurations with distinct triangle "
                  "counts were measured."]
    for key, what in (("failed", "failed"), ("not_measured", "not measured")):
        if sc.get(key):
            L += [f"- {what}: {x}" for x in sc[key]]
    return L


def _md_datasets(res: dict) -> list[str]:
    """The datasets sweep: views/s of clraster (cull back, none) and Open3D per mesh."""
    ds = res.get("datasets")
    if not ds:
        return []
    st = ds["settings"]
    L = ["", f"## Datasets sweep ({st['size'][0]}×{st['size'][1]}, {st['views']} views, "
             f"median of {st['repeat']} rounds)", "", ds["method"], "",
         f"Peer: {ds['open3d']['reason']}.", "",
         "| mesh | triangles | clraster cull=back views/s | clraster cull=none views/s | "
         "Open3D views/s | back / Open3D | none / Open3D | ids agree with Open3D (back, "
         "none) | covered |", "|---|---:|---:|---:|---:|---:|---:|---|---:|"]
    for r in ds["rows"]:
        cl, o3d, ratio = r["clraster"], r["open3d"], r["ratio_vs_open3d"]

        def rate(x: dict) -> str:
            if "median_views_per_s" not in x:
                return "skipped"
            runs = ", ".join(f"{v:.1f}" for v in x["runs_views_per_s"])
            return f"**{x['median_views_per_s']:.1f}** ({runs})"

        agree = [cl[c]["ids_agree_open3d"] for c in ("back", "none") if c in cl]
        L.append(f"| {r['mesh']} | {r['triangles']:,} | "
                 + " | ".join(rate(cl[c]) if c in cl else "—" for c in ("back", "none"))
                 + f" | {rate(o3d)} | {_x(ratio.get('back'), '.2f')} | "
                 f"{_x(ratio.get('none'), '.2f')} | "
                 + (", ".join(f"{a:.2%}" for a in agree) if None not in agree else "—")
                 + f" | {next(iter(cl.values()))['covered_fraction']:.0%} |")
    L += ["", "views/s: bold the median, then each round's; covered: the first view's "
              "pixels with a triangle (clraster)."]
    return L


def _md_startup(res: dict) -> list[str]:
    st = res.get("startup")
    if not st:
        return []
    L = ["", f"## Cold and warm start ({st['scene']}, {st['size'][0]}×{st['size'][1]})",
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
    return L + ["", st["method"]]


def _md_memory(res: dict) -> list[str]:
    mem = res.get("memory")
    if not mem:
        return []
    L = ["", "## Peak host memory (MiB)", "",
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
    return L + ["", res["memory_method"]]


def _md_lists(res: dict) -> list[str]:
    """The errors, skipped configurations and plots, each a section when there are any."""
    L: list[str] = []
    if res.get("errors"):
        L += ["", "## Errors", ""] + [f"- {s}" for s in res["errors"]]
    if res["skipped"]:
        L += ["", "## Skipped", ""] + [f"- {s}" for s in res["skipped"]]
    if res.get("plots"):
        L += ["", "## Plots", ""] + [f"![{p}]({p})" for p in res["plots"]]
    return L


# =======================================================================================
# Summary (stdout)
# =======================================================================================

def summary_lines(res: dict) -> str:
    """One line per configuration (OpenCL, twin, speed-up, llvmpipe) and per target."""
    lines = []
    for c in res["configs"]:
        pe = c["peer"].get("median_ms")
        lines.append(f"{c['id']:<42} OpenCL {_f(c['opencl']['median_ms']):>8} ms  twin "
                     f"{_f(c['twin'].get('median_ms')):>9} ms  x{_f(c['speedup_vs_twin']):>6}"
                     f"  llvmpipe {_f(pe):>8} ms")
    for r in (res.get("datasets") or {}).get("rows", []):
        cl, o3d = r["clraster"], r["open3d"].get("median_views_per_s")
        lines.append(f"datasets {r['mesh']:<12} " + "  ".join(
            f"cull={c} {_f(v['median_views_per_s'])} views/s"
            + (f" ({r['ratio_vs_open3d'][c]:.2f}x Open3D)" if c in r["ratio_vs_open3d"]
               else "") for c, v in cl.items())
            + f"  Open3D {_f(o3d)} views/s")
    sc = res.get("scale")
    if sc and sc.get("fit"):
        fit = sc["fit"]
        lines.append(f"scale fit: frame ms ≈ {fit['intercept_ms']:.1f} + "
                     f"{fit['slope_ms_per_mtri']:.2f} per million triangles to setup "
                     f"({fit['n_points']} points, largest |residual| "
                     f"{fit['max_abs_relative_residual']:.1%})")
    for t in res["targets"]:
        st = {True: "MET", False: "MISSED", None: "not measured"}[t["met"]]
        unit = t.get("unit", "×")
        v = target_value(t["value"], unit).replace("×", "x")
        thr = (f"{t['threshold']:g}x" if unit == "×"
               else target_value(t["threshold"], unit))
        lines.append(f"target {t['name']}: {v} (needs {t['comparison']} {thr})"
                     f" {st}" + (f" — {t['note']}" if t["note"] else ""))
    return "\n".join(lines)
