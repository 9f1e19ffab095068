"""PNG plots of a harness run (results.json as a dict): matplotlib, imported lazily.

`make_all(results, out)` writes time_vs_triangles.png, time_vs_pixels.png, stages.png,
funnel.png, scale.png (frame time vs triangles sent to setup, with the scale sweep's fit)
and datasets.png (the datasets sweep's views/s, clraster beside Open3D; each only when the
run has the data) and returns (file names, message); without
matplotlib it writes nothing and says how to install it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["make_all"]

SKIPPED = "plots skipped: pip install 'clraster[bench]'"

_C = {"opencl": "#1f77b4", "twin": "#ff7f0e", "peer": "#2ca02c"}
_STAGE_COLORS = ["#9467bd", "#1f77b4", "#17becf", "#2ca02c", "#bcbd22", "#ff7f0e",
                 "#d62728", "#e377c2", "#8c564b", "#7f7f7f"]


def make_all(res: dict[str, Any], out: Path) -> tuple[list[str], str | None]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return [], SKIPPED
    out = Path(out)
    written = []
    for name, fn in (("time_vs_triangles.png", _vs_triangles), ("time_vs_pixels.png",
                                                               _vs_pixels),
                     ("stages.png", _stages), ("funnel.png", _funnel),
                     ("fill_rate.png", _fill_rate),
                     ("scale.png", _scale), ("datasets.png", _datasets)):
        fig = fn(res, plt)
        if fig is None:
            continue
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        written.append(name)
    return written, None


def _title(res: dict, text: str) -> str:
    m = res.get("machine") or {}
    cpu = (m.get("cpu") or "").replace("(R)", "").replace("(TM)", "")
    return f"{text}\n{cpu}, {m.get('cores_usable')} cores"


_LABELS = {"opencl": "clraster OpenCL (PoCL)", "twin": "NumPy twin",
           "peer": "Mesa llvmpipe (draws all)"}
_MARK = {"mesh": ("o", "mesh"), "example": ("o", "mesh"), "grid": ("s", "instance grid"),
         "plant": ("^", "plant")}


def _value(c: dict, k: str) -> float | None:
    return (c["opencl"] if k == "opencl" else c["twin"] if k == "twin" else c["peer"]
            ).get("median_ms")


def _line_plot(res, plt, configs, xkey, xlabel, title, label_of):
    """Medians vs `xkey`: colour = renderer, marker = scene kind; lines join the points
    of one renderer and one scene kind only (different scenes are not a curve)."""
    if not configs:
        return None
    from matplotlib.lines import Line2D

    configs = sorted(configs, key=lambda c: c[xkey])
    fig, ax = plt.subplots(figsize=(9, 5.5))
    kinds = list(dict.fromkeys(_MARK[c["scene"]["kind"]][1] for c in configs))
    used = []
    for k in ("twin", "peer", "opencl"):
        for kind in kinds:
            pts = [(c[xkey], _value(c, k)) for c in configs
                   if _MARK[c["scene"]["kind"]][1] == kind and _value(c, k)]
            if not pts:
                continue
            marker = next(m for m, n in _MARK.values() if n == kind)
            ax.plot(*zip(*pts, strict=True), marker=marker, ls="-", color=_C[k], lw=1.8,
                    ms=7, alpha=0.9)
            if k not in used:
                used.append(k)
    for c in configs:
        v = _value(c, "opencl")
        if v:
            ax.annotate(label_of(c), (c[xkey], v), textcoords="offset points", xytext=(5, -13),
                        fontsize=7.5, color="#333")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("frame time, ms (median, log)")
    ax.set_title(_title(res, title), fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    handles = [Line2D([], [], color=_C[k], lw=2, label=_LABELS[k]) for k in used]
    if len(kinds) > 1:
        handles += [Line2D([], [], color="#555", ls="", marker=next(
            m for m, n in _MARK.values() if n == kind), label=kind) for kind in kinds]
    ax.legend(handles=handles, loc="upper left", fontsize=9)
    fig.tight_layout()
    return fig


def _vs_triangles(res, plt):
    cs = [c for c in res["configs"] if "triangles" in c["sweeps"]]
    size = f"{cs[0]['size'][0]}×{cs[0]['size'][1]}" if cs else ""
    return _line_plot(res, plt, cs, "triangles", "input triangles (log)",
                      f"Frame time vs triangles at {size}", lambda c: c["scene"]["name"])


def _vs_pixels(res, plt):
    cs = [c for c in res["configs"] if "pixels" in c["sweeps"]]
    name = cs[0]["scene"]["name"] if cs else ""
    return _line_plot(res, plt, cs, "pixels", "pixels per frame (log)",
                      f"Frame time vs pixels: {name}",
                      lambda c: f"{c['size'][0]}×{c['size'][1]}")


def _fill_rate(res, plt):
    """Covered pixels per second of frame time, clraster beside llvmpipe, per fill scene."""
    cs = [c for c in res["configs"] if "fill" in c["sweeps"]
          and (c["opencl"].get("covered_pixels") or 0) > 0]
    if not cs:
        return None
    import numpy as np

    names = [f"{c['scene']['name']}\n{100 * c['opencl']['covered_fraction']:.0f}% covered"
             for c in cs]
    ours = [c["opencl"]["covered_pixels_per_s"] or 0.0 for c in cs]
    peer = [c["opencl"]["covered_pixels"] / (c["peer"]["median_ms"] / 1e3)
            if c["peer"].get("median_ms") else 0.0 for c in cs]
    x = np.arange(len(cs))
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.bar(x - 0.2, np.array(ours) / 1e6, 0.4, label="clraster")
    if any(peer):
        ax.bar(x + 0.2, np.array(peer) / 1e6, 0.4, label="llvmpipe")
    ax.set_xticks(x, names)
    ax.set_ylabel("covered pixels per second of frame time (M/s)")
    ax.set_title(_title(res, f"Fill rate at {cs[0]['size'][0]}×{cs[0]['size'][1]}"))
    ax.legend()
    fig.tight_layout()
    return fig


def _stages(res, plt):
    cs = [c for c in res["configs"] if c["opencl"].get("stages_median_ms")]
    if not cs:
        return None
    stages: list[str] = []
    for c in cs:
        stages += [k for k in c["opencl"]["stages_median_ms"] if k not in stages]
    fig, ax = plt.subplots(figsize=(10, 0.42 * len(cs) + 2.2))
    labels = [c["id"] for c in cs]
    left = [0.0] * len(cs)
    for i, s in enumerate(stages):
        vals = [c["opencl"]["stages_median_ms"].get(s, 0.0) for c in cs]
        ax.barh(labels, vals, left=left, color=_STAGE_COLORS[i % len(_STAGE_COLORS)], label=s)
        left = [a + b for a, b in zip(left, vals, strict=True)]
    frame = [c["opencl"].get("median_ms") or 0.0 for c in cs]
    ax.scatter(frame, labels, marker="|", s=200, color="k", zorder=3,
               label="frame (wall, render())")
    ax.invert_yaxis()
    ax.set_xlabel("ms (median per stage; device times from profiling events, host culling "
                  "wall time)")
    ax.set_title(_title(res, "OpenCL per-stage times"), fontsize=10)
    ax.tick_params(axis="y", labelsize=7.5)
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


_FUNNEL = [("in scene", "triangles_total", None),
           ("after frustum", None, ("triangles_frustum_culled",)),
           ("after cones", None, ("triangles_frustum_culled", "triangles_cone_culled")),
           ("after occlusion", None, ("triangles_frustum_culled", "triangles_cone_culled",
                                      "triangles_occlusion_culled")),
           ("sent to setup", "triangles_in", None),
           ("rasterized", "rasterized", None)]


def _funnel(res, plt):
    cs = [c for c in res["configs"] if "culling" in c["sweeps"]]
    if not cs:
        return None
    import numpy as np

    fig, ax = plt.subplots(figsize=(10, 5.5))
    n = len(cs)
    width = 0.8 / n
    x = np.arange(len(_FUNNEL))
    colors = {"off": "#7f7f7f", "frustum": "#1f77b4", "occlusion": "#2ca02c"}
    all_vals: list[int] = []
    for j, c in enumerate(cs):
        k = c["opencl"]["counts"]
        vals = []
        for _, key, minus in _FUNNEL:
            vals.append(k[key] if key else k["triangles_total"] - sum(k[m] for m in minus or ()))
        all_vals += vals
        ms = c["opencl"].get("median_ms")
        bars = ax.bar(x + (j - (n - 1) / 2) * width, vals, width,
                      color=colors.get(c["mode"], None),
                      label=f"{c['mode']} ({ms:.1f} ms/frame)" if ms else c["mode"])
        for b, v in zip(bars, vals, strict=True):
            ax.annotate(f"{v / 1e6:.2f}M" if v >= 1e5 else f"{v:,}",
                        (b.get_x() + b.get_width() / 2, max(v, 1)), ha="center",
                        va="bottom", fontsize=6.5, rotation=90, xytext=(0, 2),
                        textcoords="offset points")
    ax.set_yscale("log")
    lo = min(max(v, 1) for v in all_vals)
    ax.set_ylim(lo / 4, max(all_vals) * 12)
    ax.set_xticks(x, [f[0] for f in _FUNNEL])
    ax.set_ylabel("triangles (log)")
    c0 = cs[0]
    ax.set_title(_title(res, f"Culling funnel: {c0['scene']['name']} "
                             f"({c0['triangles']:,} triangles), {c0['size'][0]}×"
                             f"{c0['size'][1]}"), fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=9, loc="upper right")
    fig.tight_layout()
    return fig


def _scale(res, plt):
    """The scale sweep: frame time vs triangles sent to setup (marker = view), the fitted
    line, and the residuals below it."""
    sc = res.get("scale") or {}
    rows = sc.get("rows") or []
    if not rows:
        return None
    fig, (ax, axr) = plt.subplots(2, 1, figsize=(9, 7), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1]})
    marks = {"overview": ("o", "#1f77b4"), "inside": ("^", "#d62728")}
    for view in dict.fromkeys(r["view"] for r in rows):
        m, col = marks.get(view, ("s", "#555"))
        pts = [r for r in rows if r["view"] == view]
        ax.plot([r["triangles_to_setup"] / 1e6 for r in pts], [r["median_ms"] for r in pts],
                ls="", marker=m, ms=8, color=col, label=f"{view} view")
        if all(r.get("residual_ms") is not None for r in pts):
            axr.plot([r["triangles_to_setup"] / 1e6 for r in pts],
                     [r["residual_ms"] for r in pts], ls="", marker=m, ms=7, color=col)
    for r in rows:
        ax.annotate(f"{r['triangles'] / 1e6:.0f}M", (r["triangles_to_setup"] / 1e6,
                                                     r["median_ms"]),
                    textcoords="offset points", xytext=(6, -12), fontsize=7.5, color="#333")
    fit = sc.get("fit")
    if fit:
        xmax = max(r["triangles_to_setup"] for r in rows) / 1e6 * 1.05
        b0, b1 = fit["intercept_ms"], fit["slope_ms_per_mtri"]
        ax.plot([0, xmax], [b0, b0 + b1 * xmax], color="k", lw=1.2, ls="--",
                label=f"fit: {b0:.0f} ms + {b1:.1f} ms per million"
                      + (f" (R² {fit['r2']:.3f})" if fit["r2"] is not None else ""))
    axr.axhline(0.0, color="k", lw=0.8)
    ax.set_ylabel("frame time, ms (median)")
    axr.set_ylabel("residual, ms")
    axr.set_xlabel("triangles sent to setup (after frustum + cone culling), millions")
    size = rows and next((c["size"] for c in res["configs"] if c["id"] == rows[0]["id"]),
                         None)
    where = f" at {size[0]}×{size[1]}" if size else ""
    ax.set_title(_title(res, f"Scale sweep{where}: frame time vs surviving triangles"),
                 fontsize=10)
    for a in (ax, axr):
        a.grid(True, alpha=0.3)
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=9, loc="upper left")
    fig.tight_layout()
    return fig


def _datasets(res, plt):
    """The datasets sweep: views/s bars per mesh (clraster cull back, cull none, Open3D),
    each clraster bar labelled with its ratio to Open3D."""
    ds = res.get("datasets") or {}
    rows = ds.get("rows") or []
    if not rows:
        return None
    import numpy as np

    series = [("clraster cull=back", "#1f77b4", lambda r: r["clraster"].get("back"), "back"),
              ("clraster cull=none", "#17becf", lambda r: r["clraster"].get("none"), "none"),
              ("Open3D RaycastingScene", "#2ca02c", lambda r: r["open3d"], None)]
    x = np.arange(len(rows))
    width = 0.27
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for j, (label, color, get, cull) in enumerate(series):
        vals = [(get(r) or {}).get("median_views_per_s") or 0.0 for r in rows]
        if not any(vals):
            continue
        bars = ax.bar(x + (j - 1) * width, vals, width, color=color, label=label)
        for b, r, v in zip(bars, rows, vals, strict=True):
            ratio = r["ratio_vs_open3d"].get(cull) if cull else None
            if v and ratio is not None:
                ax.annotate(f"{ratio:.2f}×", (b.get_x() + b.get_width() / 2, v),
                            ha="center", va="bottom", fontsize=7.5, xytext=(0, 2),
                            textcoords="offset points")
    ax.set_xticks(x, [f"{r['mesh']}\n{r['triangles']:,} tri" for r in rows])
    ax.set_ylabel("views per second (median of rounds)")
    st = ds["settings"]
    ax.set_title(_title(res, f"Dataset job (depth + ids + normals) at {st['size'][0]}×"
                             f"{st['size'][1]}, {st['views']} views: clraster vs Open3D"),
                 fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8.5)
    fig.tight_layout()
    return fig
