"""Object culling on the procedural plant: counts per stage and frame time per culling mode.

    python bench/culling.py --triangles 5000000 --size 1920x1080

Builds `clraster.scenes.plant(N)`, renders the first-person corridor view
(`plant_inside_camera`) in three modes — "off" (no object culling), "frustum" (BVH frustum
+ normal cones) and "occlusion" (those + two-phase Hi-Z occlusion culling) — one renderer
per mode, interleaved, two warm-up frames each (the occlusion mode's first frame has no
history), then the median of ``--repeat`` frames per mode (wall time of ``render()``, host
culling included). Checks that all images are identical.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

import clraster
from clraster.world.generators import plant, plant_inside_camera


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=5_000_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    t0 = time.perf_counter()
    scene = plant(a.triangles)
    t_build = time.perf_counter() - t0
    cam = plant_inside_camera(scene, w, h)
    modes = {"off": dict(frustum=False, cones=False), "frustum": dict(),
             "occlusion": dict(occlusion=True)}
    rs = {k: clraster.Renderer(w, h) for k in modes}
    t0 = time.perf_counter()
    frames = {k: rs[k].render(scene, cam, **kw) for k, kw in modes.items()}  # warm-up
    t_first = time.perf_counter() - t0
    frames = {k: rs[k].render(scene, cam, **kw) for k, kw in modes.items()}
    times: dict[str, list[float]] = {k: [] for k in modes}
    stages: dict[str, list[dict]] = {k: [] for k in modes}
    for _ in range(a.repeat):
        for k, kw in modes.items():
            t = time.perf_counter()
            frames[k] = rs[k].render(scene, cam, **kw)
            times[k].append(time.perf_counter() - t)
            stages[k].append(frames[k].stats.timings_ms)
    same = all(np.array_equal(f.triangle_id, frames["off"].triangle_id)
               and np.array_equal(f.depth, frames["off"].depth) for f in frames.values())
    res = {
        "triangles": scene.n_faces, "instances": scene.n_instances, "size": [w, h],
        "scene_build_s": t_build, "first_frames_s": t_first, "identical": bool(same),
        "median_ms": {k: statistics.median(v) * 1e3 for k, v in times.items()},
        "stage_median_ms": {k: {s: statistics.median(d[s] for d in v) for s in v[0]}
                            for k, v in stages.items()},
        "counts": {k: f.stats.counts() for k, f in frames.items()},
    }
    res["speedup_vs_off"] = {k: res["median_ms"]["off"] / v
                             for k, v in res["median_ms"].items()}
    for k, f in frames.items():
        print(f"--- culling {k}: median {res['median_ms'][k]:.1f} ms")
        print(f.stats)
    print(json.dumps({k: v for k, v in res.items() if k != "counts"}, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
