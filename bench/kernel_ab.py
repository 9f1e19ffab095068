"""A/B of kernel sources: the working tree's kernels/ against a git revision's, in one
process, interleaved, on the same scene. The tool behind bench/README.md's performance log.

    python bench/kernel_ab.py HEAD~1                      # dragon at 1920x1080
    python bench/kernel_ab.py HEAD~1 --plant 10000000     # plant, first person, occlusion

Two renderers are built, one from each set of sources (kernel files taken with
``git show REV:kernels/...``; PoCL caches both), warmed up, then rendered alternately
``--rounds`` times; per-stage min / median (ms) are printed. The machine is shared and
noisy, so compare the two rows of one run, never across runs. It also checks that both
give identical ids, depth and barycentrics: a kernel change must never change the image.
The host code is the working tree's for both, so REV's kernels must take the same
arguments, launch sizes and buffer sizes (across a change of those, e.g. d19f502's
bin_scatter and raster_tiles, d40dce6's vertex work-items, or f62e4a4's rnum buffer, sized
only for reversed-Z frames since — an older vertex kernel writes it in full, out of bounds —
compare whole trees with proc_ab.py).
"""

from __future__ import annotations

import argparse
import collections
import re
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

import clraster
import clraster.pipeline.device as dev
from clraster.base import layout

REPO = Path(__file__).resolve().parents[1]


def revision_source(rev: str):
    """kernel_source for the kernels of git revision `rev` (common.h inlined likewise)."""
    def show(name: str) -> str:
        return subprocess.run(["git", "show", f"{rev}:kernels/{name}"], cwd=REPO, check=True,
                              capture_output=True, text=True).stdout

    header = show("common.h")
    if layout.LAYOUT_INCLUDE.search(header):
        # its generated constants and records, from this working tree's clraster/layout.py
        header = layout.inline_layout(header)

    def source(stage: str) -> str:
        return re.sub(r'^#include "common\.h"\s*$', lambda _m: header, show(f"{stage}.cl"),
                      flags=re.M)
    return source


def warm_renderers(sources, w: int, h: int, target, cam, kw: dict) -> dict:
    """A Renderer (w × h) per (name, kernel_source function) in ``sources``, each built from
    its source (the program cache is cleared first; PoCL's on-disk cache keeps both) and
    warmed up with 3 frames of ``target`` from ``cam`` (``kw``: render keywords; the
    frames also fill an occlusion history). Returns {name: Renderer}."""
    current = dev.kernel_source
    renderers = {}
    for name, source in sources:
        dev.clear_program_cache(dev.default_context())   # rebuild from `source`
        dev.kernel_source = source
        try:
            renderers[name] = clraster.Renderer(w, h)
        finally:
            dev.kernel_source = current
        for _ in range(3):
            renderers[name].render(target, cam, **kw)
    return renderers


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", help="git revision whose kernels/ is the baseline (A)")
    ap.add_argument("--mesh", default=str(REPO.parent / "shared/meshes/stanford_dragon_vrip.ply"))
    ap.add_argument("--plant", type=int, help="use scenes.plant(N), first person, occlusion")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--rounds", type=int, default=8)
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    if a.plant:
        from clraster.world.generators import plant, plant_inside_camera
        target = plant(a.plant)
        cam = plant_inside_camera(target, w, h)
        kw = {"occlusion": True}
    else:
        target = clraster.Mesh.load(a.mesh)
        cam = clraster.Camera.framing(*target.bounds(), aspect=w / h)
        kw = {}
    renderers = warm_renderers(((a.rev, revision_source(a.rev)),
                                ("working tree", dev.kernel_source)), w, h, target, cam, kw)
    times = collections.defaultdict(lambda: collections.defaultdict(list))
    frames = {}
    for _ in range(a.rounds):
        for name, r in renderers.items():
            t0 = time.perf_counter()
            frames[name] = r.render(target, cam, **kw)
            times[name]["frame"].append((time.perf_counter() - t0) * 1e3)
            for k, v in frames[name].stats.timings_ms.items():
                times[name][k].append(v)
    fa, fb = frames.values()
    same = (np.array_equal(fa.triangle_id, fb.triangle_id) and np.array_equal(fa.depth, fb.depth)
            and np.array_equal(fa.barycentrics, fb.barycentrics))
    print(f"outputs identical: {same}")
    for name, t in times.items():
        print(f"{name:>14}: " + "  ".join(f"{k} {min(v):.1f}/{statistics.median(v):.1f}"
                                          for k, v in t.items()))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
