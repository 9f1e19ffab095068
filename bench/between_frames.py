"""Spot's raster time at 1920x1080 with different work between its frames: nothing, a frame
of the NumPy twin, a 200 MB allocation, a sum over an existing 100 MB array, or 20 ms of
sleep.

    PYTHONPATH=. python bench/between_frames.py            # all five, each in a fresh process
    CLRASTER_PIN_THREADS=0 PYTHONPATH=. python bench/between_frames.py   # PoCL's threads free

Why the harness (whose rounds put llvmpipe's and the twin's frames between clraster's)
measures spot's raster at about twice what alternating clraster processes do. Medians of
``--frames`` frames after 3 warm-up ones; the raster's device time (profiling events) and the
minor page faults of a frame, and how many frames' rasters took over 1.5x the fastest one.

What it found (2026-11-24): the slow rasters after other work were not memory effects (no
page faults; huge pages for every buffer changed nothing) but PoCL's two worker threads put
on one core by the scheduler after an idle moment, the kernel then running on one core; with
the workers pinned one per CPU (clraster.device, the default since) every mode gives the
back-to-back time. The printed line says whether this process pinned them.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
MODES = ("nothing", "twin", "alloc", "sweep", "sleep")


def run(mode: str, frames: int) -> str:
    import numpy as np

    from clraster import Camera, Mesh, Renderer
    from clraster.pipeline import device
    from clraster.pipeline import reference as twin

    w, h = 1920, 1080
    mesh = Mesh.load(MESHES / "spot.ply")
    cam = Camera.framing(*mesh.bounds(), aspect=w / h)
    r, tw = Renderer(w, h), twin.Renderer(w, h)
    big = np.ones(100_000_000 // 8) if mode == "sweep" else None
    for _ in range(3):
        r.render(mesh, cam)
    raster, faults = [], []
    for _ in range(frames):
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        f = r.render(mesh, cam)
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
        raster.append(f.stats.timings_ms["raster"])
        if mode == "twin":
            tw.render(mesh, cam)
        elif mode == "alloc":
            a = np.ones(200_000_000 // 8)
            a += 1.0
            del a
        elif mode == "sleep":
            time.sleep(0.02)
        elif big is not None:
            big.sum()
    slow = sum(t > 1.5 * min(raster) for t in raster)
    return (f"{mode:8s} raster {statistics.median(raster):.2f} ms, "
            f"minor faults a frame {statistics.median(faults):.0f}, "
            f"slow rasters {slow}/{len(raster)}, PoCL threads pinned: "
            f"{device.pin_pocl_threads()}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=MODES, help="one mode in this process")
    ap.add_argument("--frames", type=int, default=10)
    a = ap.parse_args(argv)
    if a.mode:
        print(run(a.mode, a.frames), flush=True)
        return 0
    for mode in MODES:
        subprocess.run([sys.executable, __file__, "--mode", mode, "--frames", str(a.frames)],
                       check=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
