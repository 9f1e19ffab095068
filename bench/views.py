"""Views per second of many views of one mesh: a plain loop of ``Renderer.render`` calls,
``Renderer.render_many`` one view at a time (``RasterConfig(views_in_flight=1)``) and
``render_many`` with two views in flight (the default), measured in the same run.

    python bench/views.py ../shared/meshes/stanford_dragon_vrip.ply --views 1000 --size 640x480

The cameras orbit the mesh (framing its bounding box, varying height). Each method uses its
own Renderer, warmed up on the first cameras (kernel build, buffers, the mesh's clusters and
geometry pool, the second renderer of the views in flight), so the timed part is the views
only. The methods are run ``--repeat`` times, each round in another order (A B C, C B A,
...), so machine noise and drift hit all alike; the medians are reported. The frames are
checked equal (triangle ids) on the first cameras.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from clraster import Camera, Mesh, RasterConfig, Renderer


def orbit(mesh: Mesh, n: int, width: int, height: int) -> list[Camera]:
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2.0
    cams = []
    for k in range(n):
        a = 2.0 * math.pi * k / n
        direction = (math.sin(a), 0.2 + 0.4 * math.sin(3.0 * a) ** 2, math.cos(a))
        cams.append(Camera.framing(lo, hi, direction=direction, aspect=width / height))
    assert np.all(np.isfinite(centre))
    return cams


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("--views", type=int, default=1000)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cull", default="back")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    mesh = Mesh.load(a.mesh)
    cams = orbit(mesh, a.views, w, h)
    r_loop, r_one = Renderer(w, h), Renderer(w, h, config=RasterConfig(views_in_flight=1))
    r_two = Renderer(w, h)
    ids = [r_loop.render(mesh, c, cull=a.cull).triangle_id for c in cams[:3]]
    for r in (r_one, r_two):
        for k, f in enumerate(r.render_many(mesh, cams[:3], cull=a.cull)):
            assert np.array_equal(f.triangle_id, ids[k])

    def loop() -> None:
        for cam in cams:
            r_loop.render(mesh, cam, cull=a.cull)

    def many(r: Renderer) -> None:
        for _ in r.render_many(mesh, cams, cull=a.cull):
            pass

    methods = [("loop of render", loop), ("render_many, 1 in flight", lambda: many(r_one)),
               ("render_many, 2 in flight", lambda: many(r_two))]
    rates: dict[str, list[float]] = {name: [] for name, _ in methods}
    for rep in range(a.repeat):
        # each round in another order: on a machine whose load drifts, the method run last
        # in every round would gain (18% on a first try with the same order throughout)
        for name, fn in methods if rep % 2 == 0 else methods[::-1]:
            t0 = time.perf_counter()
            fn()
            rate = len(cams) / (time.perf_counter() - t0)
            rates[name].append(rate)
            print(f"run {rep + 1}: {name:<26} {rate:7.2f} views/s", flush=True)
    med = {k: statistics.median(v) for k, v in rates.items()}
    base = med["loop of render"]
    print(f"{a.views} views of {a.mesh} ({mesh.n_faces:,} triangles) at {w}x{h}, median of "
          f"{a.repeat}:")
    for name, rate in med.items():
        print(f"  {name:<26} {rate:7.2f} views/s ({rate / base:.2f}x the loop)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
