"""Time `clraster.shade.shade` on a finished frame (issue 35 item 1): the dragon at 1920x1080
(flat and smooth) and the 10M plant's 1280x720 occlusion frame, wall time per call as a user
pays it (checks, tables, launch and read-back), and the kernel's own time from profiling
events.

    python bench/shade_device.py                    # median of 9 after 3 warm-ups, ms
    python bench/shade_device.py --rounds 15 --plant 0 --modes flat,smooth,tints,colors

Modes: flat, smooth, tints (a per-instance colour) run in the kernel's 8-pixel lanes;
colors (vertex colours) and texture in its per-pixel path.

The machine is shared: compare rows of one run, or interleave runs of two checkouts.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

import clraster
from clraster.output.shade import render_shaded, shade

REPO = Path(__file__).resolve().parent.parent


def timed(fn, rounds: int, warm: int = 3) -> tuple[float, float]:
    for _ in range(warm):
        fn()
    ts = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return min(ts), statistics.median(ts)


def modes(target, mesh) -> dict[str, dict]:
    n = mesh.n_vertices
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (256, 256, 3), np.uint8)
    uv = rng.random((n, 2))
    return {"flat": {}, "smooth": {"smooth": True},
            "tints": {"per_instance_colors": rng.random((1, 3))},
            "colors": {"colors": rng.random((n, 3))},
            "texture": {"texture": (uv, img)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--mesh", default=str(REPO.parent / "shared/meshes/stanford_dragon_vrip.ply"))
    ap.add_argument("--plant", type=int, default=10_100_000, help="0: no plant")
    ap.add_argument("--modes", default="flat,smooth")
    ap.add_argument("--ssaa", action="store_true", help="also render_shaded(ssaa=2) dragon")
    a = ap.parse_args()
    wanted = a.modes.split(",")
    w, h = 1920, 1080
    dragon = clraster.Mesh.load(a.mesh)
    cam = clraster.Camera.framing(*dragon.bounds(), aspect=w / h)
    r = clraster.Renderer(w, h)
    frame = r.render(dragon, cam)
    for name, kw in modes(dragon, dragon).items():
        if name in wanted:
            lo, med = timed(lambda kw=kw: shade(frame, dragon, **kw), a.rounds)
            print(f"dragon {w}x{h} {name:>8}: min {lo:6.2f}  median {med:6.2f} ms")
    if a.ssaa:
        r2 = clraster.Renderer(w // 2, h // 2)
        lo, med = timed(lambda: render_shaded(r2, dragon, cam, ssaa=2), a.rounds)
        print(f"dragon render_shaded ssaa=2 {w // 2}x{h // 2} (render included): "
              f"min {lo:6.2f}  median {med:6.2f} ms")
    if a.plant:
        from clraster.world.generators import plant, plant_inside_camera
        pw, ph = 1280, 720
        scene = plant(a.plant)
        pcam = plant_inside_camera(scene, pw, ph)
        pr = clraster.Renderer(pw, ph)
        pframe = pr.render(scene, pcam, occlusion=True)
        pframe = pr.render(scene, pcam, occlusion=True)
        for name in ("flat", "smooth"):
            if name in wanted:
                kw = {"smooth": True} if name == "smooth" else {}
                lo, med = timed(lambda kw=kw: shade(pframe, scene, **kw), a.rounds)
                print(f"plant {a.plant:,} {pw}x{ph} occlusion {name:>8}: min {lo:6.2f}  "
                      f"median {med:6.2f} ms")


if __name__ == "__main__":
    main()
