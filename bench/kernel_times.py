"""Device time per kernel of one scene's warm frames, from each launch's profiling event.

    PYTHONPATH=. python bench/kernel_times.py plant10m      # 10M plant, first person, occlusion
    PYTHONPATH=. python bench/kernel_times.py dragon --frames 20

Scenes: spot, bunny, dragon (framed as the harness does), plant10m (first person, two-phase
occlusion culling). Per kernel: the median over the frames of its summed device time in a
frame, and its launches per frame; then the frame's wall-time median and the kernels' sum
(the rest is host time). 1920x1080 unless --size.

``--evict MB`` writes and reads an MB-megabyte array before each timed frame, so the frame
starts with cold caches, as in the benchmark harness, where a NumPy twin frame and an
llvmpipe frame run between two clraster frames (its stage times were 10-35% above this
script's warm ones on the dragon at 1080p).
"""

from __future__ import annotations

import argparse
import collections
import statistics
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
FILES = {"spot": "spot.ply", "bunny": "stanford_bunny.ply",
         "dragon": "stanford_dragon_vrip.ply"}


def record_launches() -> list[tuple[str, cl.Event]]:
    """From now on, every kernel launch of this process (name, event) is appended to the
    list returned (clear it between frames)."""
    launches: list[tuple[str, cl.Event]] = []
    call = cl.Kernel.__call__

    def recording_call(self, *args, **kw):
        ev = call(self, *args, **kw)
        launches.append((self.function_name, ev))
        return ev

    cl.Kernel.__call__ = recording_call
    return launches


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", choices=[*FILES, "plant10m", "quad", "empty"])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--evict", type=int, default=0, metavar="MB",
                    help="touch this many MB between frames (cold caches)")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    launches = record_launches()
    from clraster import Camera, Mesh, Renderer
    kw = {}
    if a.scene in ("quad", "empty"):   # the harness's fill scenes (clraster.bench.spec)
        from clraster.bench.spec import close_camera, quad_mesh

        target = quad_mesh()
        cam = close_camera(*target.bounds(), w, h, away=a.scene == "empty")
    elif a.scene == "plant10m":
        from clraster.world.generators import plant, plant_inside_camera
        target = plant(10_100_000)
        cam = plant_inside_camera(target, w, h)
        kw = {"occlusion": True}
    else:
        target = Mesh.load(MESHES / FILES[a.scene])
        cam = Camera.framing(*target.bounds(), aspect=w / h)
    r = Renderer(w, h)
    for _ in range(4):   # kernel builds, buffer growth, the occlusion history
        r.render(target, cam, **kw)
    per: dict[str, list[tuple[float, int]]] = collections.defaultdict(list)
    walls = []
    junk = np.ones(a.evict << 17) if a.evict else None   # float64: MB << 17 of them
    for _ in range(a.frames):
        if junk is not None:
            junk += 1.0   # read and write every line: the frame's data leaves the caches
        launches.clear()
        t0 = time.perf_counter()
        r.render(target, cam, **kw)
        walls.append((time.perf_counter() - t0) * 1e3)
        ms: dict[str, float] = collections.defaultdict(float)
        n: collections.Counter = collections.Counter()
        for name, ev in launches:
            ms[name] += (ev.profile.end - ev.profile.start) * 1e-6
            n[name] += 1
        for name in ms:
            per[name].append((ms[name], n[name]))
    med = {k: statistics.median(x[0] for x in v) for k, v in per.items()}
    for k in sorted(med, key=lambda k: -med[k]):
        print(f"  {k:28s} {med[k]:7.2f} ms  x{per[k][0][1]}")
    print(f"frame median {statistics.median(walls):.2f} ms, kernels {sum(med.values()):.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
