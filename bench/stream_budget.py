"""Frame time against the streaming budget (RasterConfig.batch_triangles / batch_entries):
the measurement behind the defaults in clraster/config.py.

    python bench/stream_budget.py                        # dragon + plant(5M), 1920x1080
    python bench/stream_budget.py --plant 2000000 --rounds 3

One renderer per budget, all warmed up, then rendered in turn ``--rounds`` times (the
machine is shared and noisy: compare rows of one run). Every budget's frame must equal the
unbatched one (ids, depth, barycentrics, counts); the script fails otherwise. Prints, per
scene and budget: passes per frame, median frame ms, peak device bytes of the stage chain.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import clraster
from clraster import RasterConfig, Renderer

REPO = Path(__file__).resolve().parents[1]
BUDGETS = ((1 << 16, 1 << 22), (1 << 18, 1 << 22), (1 << 20, 1 << 20), (1 << 20, 1 << 21),
           (1 << 20, 1 << 22), (1 << 22, 1 << 24))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default=str(REPO.parent / "shared/meshes/stanford_dragon_vrip.ply"))
    ap.add_argument("--plant", type=int, default=5_000_000)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    from clraster.world.generators import plant, plant_inside_camera, plant_overview_camera

    mesh = clraster.Mesh.load(a.mesh)
    scene = plant(a.plant)
    cases = [("dragon", mesh, clraster.Camera.framing(*mesh.bounds(), aspect=w / h), {}),
             (f"plant {a.plant / 1e6:g}M outside", scene, plant_overview_camera(scene, w, h),
              {}),
             (f"plant {a.plant / 1e6:g}M inside, occlusion", scene,
              plant_inside_camera(scene, w, h), {"occlusion": True})]
    ok = True
    for name, target, cam, kw in cases:
        rs = {}
        for tris, entries in BUDGETS:
            r = Renderer(w, h, config=RasterConfig(batch_triangles=tris, batch_entries=entries))
            n = [0]
            real = r.chain.draw

            def draw(*args, _real=real, _n=n, **kws):
                _n[0] += 1
                return _real(*args, **kws)

            r.chain.draw = draw
            for _ in range(2):
                r.render(target, cam, **kw)
            rs[(tris, entries)] = (r, n)
        times = {k: [] for k in rs}
        frames = {}
        for _ in range(a.rounds):
            for k, (r, n) in rs.items():
                n[0] = 0
                t0 = time.perf_counter()
                frames[k] = r.render(target, cam, **kw)
                times[k].append((time.perf_counter() - t0) * 1e3)
        ref = frames[BUDGETS[-1]]
        print(f"\n{name}: {ref.stats.triangles_in:,} triangles to setup, "
              f"{ref.stats.binned_entries:,} bin entries")
        print("| batch_triangles | batch_entries | passes | frame ms (median) | min | "
              "chain device MiB |")
        print("|---:|---:|---:|---:|---:|---:|")
        for k, (r, n) in rs.items():
            f = frames[k]
            same = (np.array_equal(f.triangle_id, ref.triangle_id)
                    and np.array_equal(f.depth, ref.depth)
                    and np.array_equal(f.barycentrics, ref.barycentrics)
                    and f.stats.counts() == ref.stats.counts())
            ok &= same
            print(f"| 2^{k[0].bit_length() - 1} | 2^{k[1].bit_length() - 1} | {n[0]} | "
                  f"{statistics.median(times[k]):.1f} | {min(times[k]):.1f} | "
                  f"{r.chain.device_bytes() / 2**20:.0f} |" + ("" if same else " DIFFERS"))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
