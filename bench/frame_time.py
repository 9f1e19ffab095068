"""Frame time of one mesh: OpenCL pipeline vs the NumPy twin, measured in the same run.

    python bench/frame_time.py ../shared/meshes/stanford_dragon_vrip.ply --size 1920x1080

Both are warmed up once (kernel build, buffer allocation), then timed ``--repeat`` times,
interleaved (OpenCL, NumPy, OpenCL, ...), so machine noise hits both alike; medians are
reported with per-stage device times from OpenCL profiling events. The timed closure is
``render()`` only: mesh loading and camera set-up are outside it. It also checks that the
two agree (triangle ids identical).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import numpy as np

import clraster
from clraster import RasterConfig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", help="mesh file, or 'example'")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--tile-log2", type=int, default=RasterConfig().tile_log2)
    ap.add_argument("--cull", default="back")
    ap.add_argument("--no-numpy", action="store_true", help="time the OpenCL path only")
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    if a.mesh == "example":
        from clraster.world.examples import example_mesh
        mesh = example_mesh()
    else:
        mesh = clraster.Mesh.load(a.mesh)
    lo, hi = mesh.bounds()
    cam = clraster.Camera.framing(lo, hi, aspect=w / h)
    cfg = RasterConfig(tile_log2=a.tile_log2)
    r = clraster.Renderer(w, h, config=cfg)

    t0 = time.perf_counter()
    f = r.render(mesh, cam, cull=a.cull)  # warm-up: builds kernels, allocates buffers
    first = time.perf_counter() - t0
    g = None if a.no_numpy else clraster.reference.render(mesh, cam, w, h, cull=a.cull,
                                                         config=cfg)
    cl_t, np_t, stages = [], [], []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        f = r.render(mesh, cam, cull=a.cull)
        cl_t.append(time.perf_counter() - t0)
        stages.append(f.stats.timings_ms)
        if g is not None:
            t0 = time.perf_counter()
            g = clraster.reference.render(mesh, cam, w, h, cull=a.cull, config=cfg)
            np_t.append(time.perf_counter() - t0)
    res = {
        "mesh": a.mesh, "triangles": int(mesh.n_faces), "size": [w, h],
        "tile_log2": a.tile_log2, "repeat": a.repeat, "first_frame_s": first,
        "opencl_median_ms": statistics.median(cl_t) * 1e3,
        "opencl_stage_median_ms": {k: statistics.median(s[k] for s in stages)
                                   for k in stages[0]},
        "device": r.context.devices[0].platform.version,
        "machine": f"{platform.processor() or platform.machine()}, {platform.platform()}",
    }
    if g is not None:
        res["numpy_median_ms"] = statistics.median(np_t) * 1e3
        res["speedup"] = res["numpy_median_ms"] / res["opencl_median_ms"]
        res["ids_identical"] = bool(np.array_equal(f.triangle_id, g.triangle_id))
        res["max_depth_diff"] = float(np.abs(f.depth - g.depth).max())
    print(f.stats)
    print(json.dumps(res, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
