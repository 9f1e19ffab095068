"""Views per second of many views of one mesh: a plain loop of ``Renderer.render`` calls vs
``Renderer.render_many``, measured in the same run.

    python bench/views.py ../shared/meshes/stanford_dragon_vrip.ply --views 1000 --size 640x480

The cameras orbit the mesh (framing its bounding box, varying height). Each method uses its
own Renderer, warmed up once on the first camera (kernel build, buffers, the mesh's clusters
and geometry pool), so the timed part is the views only. The two are run ``--repeat`` times
interleaved in ABBA order (loop, many, many, loop, ...), so machine noise and drift hit both
alike; the medians are reported. The frames are checked equal (triangle ids) on the first camera.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from clraster import Camera, Mesh, Renderer


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
    r_loop, r_many = Renderer(w, h), Renderer(w, h)
    f0 = r_loop.render(mesh, cams[0], cull=a.cull)
    f1 = next(iter(r_many.render_many(mesh, cams[:1], cull=a.cull)))
    assert np.array_equal(f0.triangle_id, f1.triangle_id)

    def loop() -> None:
        for cam in cams:
            r_loop.render(mesh, cam, cull=a.cull)

    def many() -> None:
        for _ in r_many.render_many(mesh, cams, cull=a.cull):
            pass

    rates: dict[str, list[float]] = {"loop of render": [], "render_many": []}
    for rep in range(a.repeat):
        # ABBA order: on a machine whose load drifts, the method run second in every pair
        # would gain (18% on a first try with the same order throughout)
        pair = [("loop of render", loop), ("render_many", many)]
        for name, fn in pair if rep % 2 == 0 else pair[::-1]:
            t0 = time.perf_counter()
            fn()
            rate = len(cams) / (time.perf_counter() - t0)
            rates[name].append(rate)
            print(f"run {rep + 1}: {name:<15} {rate:7.2f} views/s", flush=True)
    med = {k: statistics.median(v) for k, v in rates.items()}
    print(f"{a.views} views of {a.mesh} ({mesh.n_faces:,} triangles) at {w}x{h}, median of "
          f"{a.repeat}: loop of render {med['loop of render']:.2f} views/s, render_many "
          f"{med['render_many']:.2f} views/s ({med['render_many'] / med['loop of render']:.2f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
