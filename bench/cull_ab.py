"""Host object culling (`cull.build_draw_list`) of the 10M plant's first-person view, with a
culling switch off (A) and on (B), interleaved in one process; checks that both give the
same draw list and counts.

    PYTHONPATH=. python bench/cull_ab.py threads     # culling paths on threads (THREAD_PAIRS)
    PYTHONPATH=. python bench/cull_ab.py dense       # instances classified densely
    PYTHONPATH=. python bench/cull_ab.py threads --triangles 1000000 --calls 60

Medians of ``--calls`` calls each, after 3 warm-up calls.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import clraster.culling.cull as cull
from clraster.base.checks import view_projection
from clraster.pipeline.drawlist import PlanCache
from clraster.world.generators import plant, plant_inside_camera

#: switch → (module constant, value for A (off), value for B (on))
SWITCHES = {"threads": ("THREAD_PAIRS", 1 << 62, cull.THREAD_PAIRS),
            "dense": ("DENSE_INSTANCES", 0, cull.DENSE_INSTANCES)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("switch", choices=sorted(SWITCHES))
    ap.add_argument("--triangles", type=int, default=10_100_000)
    ap.add_argument("--calls", type=int, default=40)
    a = ap.parse_args(argv)
    scene = plant(a.triangles)
    w, h = 1920, 1080
    vp = view_projection(plant_inside_camera(scene, w, h), w, h)
    PlanCache().scene_and_pool(scene)
    name, off, on = SWITCHES[a.switch]
    times: dict[bool, list[float]] = {False: [], True: []}
    lists = {}
    for k in range(3 + a.calls):
        for b in (False, True) if k % 2 else (True, False):
            setattr(cull, name, on if b else off)
            t0 = time.perf_counter()
            lists[b] = cull.build_draw_list(scene, vp)
            if k >= 3:
                times[b].append((time.perf_counter() - t0) * 1e3)
    setattr(cull, name, on)
    x, y = lists[False], lists[True]
    same = (np.array_equal(x.instance, y.instance) and np.array_equal(x.cluster, y.cluster)
            and np.array_equal(x.inside, y.inside) and x.counts == y.counts)
    ma, mb = statistics.median(times[False]), statistics.median(times[True])
    print(f"{a.switch}: off {ma:.2f} ms, on {mb:.2f} ms ({mb / ma:.3f}x), "
          f"{len(y):,} draws, lists {'same' if same else 'DIFFER'}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
