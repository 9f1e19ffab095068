"""Object culling on the procedural plant: counts per stage and frame time, culling on vs off.

    python bench/culling.py --triangles 5000000 --size 1920x1080

Builds `clraster.scenes.plant(N)`, renders the first-person corridor view
(`plant_inside_camera`) with frustum + normal-cone culling on and off, interleaved, a warm-up
each, then the median of ``--repeat`` frames per mode (wall time of ``render()``; the host
culling time is inside it). Also checks that both images are identical.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

import clraster
from clraster.scenes import plant, plant_inside_camera


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
    r = clraster.Renderer(w, h)
    modes = {"on": dict(frustum=True, cones=True), "off": dict(frustum=False, cones=False)}
    t0 = time.perf_counter()
    frames = {k: r.render(scene, cam, **kw) for k, kw in modes.items()}  # warm-up
    t_first = time.perf_counter() - t0
    times: dict[str, list[float]] = {k: [] for k in modes}
    stages: dict[str, list[dict]] = {k: [] for k in modes}
    for _ in range(a.repeat):
        for k, kw in modes.items():
            t = time.perf_counter()
            frames[k] = r.render(scene, cam, **kw)
            times[k].append(time.perf_counter() - t)
            stages[k].append(frames[k].stats.timings_ms)
    same = (np.array_equal(frames["on"].triangle_id, frames["off"].triangle_id)
            and np.array_equal(frames["on"].depth, frames["off"].depth))
    res = {
        "triangles": scene.n_faces, "instances": scene.n_instances, "size": [w, h],
        "scene_build_s": t_build, "first_frames_s": t_first, "identical": bool(same),
        "median_ms": {k: statistics.median(v) * 1e3 for k, v in times.items()},
        "stage_median_ms": {k: {s: statistics.median(d[s] for d in v) for s in v[0]}
                            for k, v in stages.items()},
        "counts": {k: f.stats.counts() for k, f in frames.items()},
    }
    res["speedup"] = res["median_ms"]["off"] / res["median_ms"]["on"]
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
