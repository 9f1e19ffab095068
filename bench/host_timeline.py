"""Where a frame's wall time goes on the host: each step of `render()` (planning, culling,
draw records, the stage plumbing, the launches, the wait, the bookkeeping after it) and
the device's kernels, on one clock, median over the frames.

    PYTHONPATH=. python bench/host_timeline.py quad              # 100 MB evicted per frame
    PYTHONPATH=. python bench/host_timeline.py dragon --evict 0  # warm caches
    PYTHONPATH=. python bench/host_timeline.py spot@close --frames 60

Scenes: the harness's fill scenes quad, empty (the quad behind the camera) and NAME@close
(spot, bunny, dragon seen from close by: `clraster.bench.spec.close_camera`), and spot,
bunny, dragon framed. 1920x1080, default outputs.

Each host step is timed by wrapping its function (start and duration in ms from the call
of `render`; a step called several times a frame is listed once per call, by its first);
each kernel by its profiling event, moved onto the host's clock by a marker enqueued
before the frame (PoCL's profiling clock and ``time.monotonic_ns`` are both the
monotonic clock, so the offset is small). With ``--evict MB`` (default 100) an MB-megabyte
array is read and written before each frame, so the frame starts with cold caches, as in
the benchmark harness (a NumPy twin frame and an llvmpipe frame run between two clraster
frames): Python and NumPy calls then take 2-3 times as long as warm (bench/README.md's
performance log, session 48).
"""

from __future__ import annotations

import argparse
import collections
import functools
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

import clraster.pipeline.drawlist as drawlist
import clraster.pipeline.driver as driver
from clraster import Camera, Mesh, Renderer
from clraster.pipeline import params as params_mod
from clraster.pipeline.stages import bin as bin_stage
from clraster.pipeline.stages import chain, geometry, raster, setup

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel_times import FILES, MESHES, record_launches  # noqa: E402  (bench/ is not a package)

#: (owner, attribute, label) of every host step timed; properties by their getter
STEPS = [
    (drawlist, "plan_frame", "plan_frame"),
    (drawlist.FramePlan, "draw_list", "cull (draw list)"),
    (drawlist.FramePlan, "frame", "draw records"),
    (params_mod.FrameParams, "make", "frame params"),
    (chain.StageChain, "_bin", "setup + bin (host)"),
    (geometry.GeometryStage, "upload_frame", "upload draws"),
    (setup.SetupStage, "run", "setup launch"),
    (bin_stage.BinStage, "run", "bin launches"),
    (raster.RasterStage, "outputs", "frame arrays"),
    (raster.RasterStage, "launch", "raster launch"),
    (raster.RasterStage, "clear", "clear (empty frame)"),
    (raster.RasterStage, "wait", "wait"),
    (setup.SetupStage, "check_unclipped", "clip check"),
    (bin_stage.BinStage, "settle", "bin settle"),
    (raster.RasterStage, "finish", "raster finish"),
    (params_mod.FrameTotals, "settle", "event times"),
    (params_mod.FrameTotals, "stats", "frame stats"),
    (driver, "_frame", "Frame"),
]

_calls: list[tuple[str, float, float]] = []   # (label, start, end) of this frame's steps


def _timed(fn, label):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            _calls.append((label, t0, time.perf_counter()))
    return wrapper


def instrument() -> None:
    """Wrap every step of `STEPS` (the driver's own references to plan_frame too)."""
    for owner, name, label in STEPS:
        attr = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        if isinstance(attr, property):
            setattr(owner, name, property(_timed(attr.fget, label), attr.fset))
        elif isinstance(attr, classmethod):
            setattr(owner, name, classmethod(_timed(attr.__func__, label)))
        else:
            setattr(owner, name, _timed(attr, label))
    driver.plan_frame = drawlist.plan_frame


def scene(name: str, width: int, height: int):
    from clraster.bench.spec import close_camera, quad_mesh

    base = name.split("@")[0]
    if base in ("quad", "empty"):
        target = quad_mesh()
        return target, close_camera(*target.bounds(), width, height, away=base == "empty")
    target = Mesh.load(MESHES / FILES[base])
    if name.endswith("@close"):
        return target, close_camera(*target.bounds(), width, height)
    return target, Camera.framing(*target.bounds(), aspect=width / height)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="quad, empty, spot, bunny, dragon, or NAME@close")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--evict", type=int, default=100, metavar="MB",
                    help="touch this many MB before each frame (0: warm caches)")
    a = ap.parse_args(argv)
    w, h = 1920, 1080
    target, cam = scene(a.scene, w, h)
    launches = record_launches()
    instrument()
    r = Renderer(w, h)
    for _ in range(4):   # kernel builds, buffer growth
        r.render(target, cam)
    junk = np.ones(a.evict << 17) if a.evict else None   # float64: MB << 17 of them
    rows: dict[str, list[tuple[float, float]]] = collections.defaultdict(list)
    walls = []
    for _ in range(a.frames):
        if junk is not None:
            junk += 1.0
        marker = cl.enqueue_marker(r.queue)
        marker.wait()
        # the profiling clock's offset from this process's perf_counter
        off = marker.profile.end * 1e-9 - time.perf_counter()
        _calls.clear()
        launches.clear()
        t0 = time.perf_counter()
        r.render(target, cam)
        t1 = time.perf_counter()
        walls.append((t1 - t0) * 1e3)
        seen = set()
        for label, s, e in _calls:
            if label not in seen:
                seen.add(label)
                rows[label].append(((s - t0) * 1e3, (e - s) * 1e3))
        for name, ev in launches:
            s = ev.profile.start * 1e-9 - off
            rows["kernel " + name].append(((s - t0) * 1e3, (ev.profile.end - ev.profile.start)
                                           * 1e-6))
    print(f"{a.scene} at {w}x{h}, {a.frames} frames, "
          + (f"{a.evict} MB evicted before each" if a.evict else "warm")
          + f"; {r.device_description}")
    print(f"{'step':28s} {'starts at':>10s} {'takes':>8s}  (ms from the call of render)")
    order = sorted(rows, key=lambda k: statistics.median(v[0] for v in rows[k]))
    for k in order:
        v = rows[k]
        print(f"{k:28s} {statistics.median(x[0] for x in v):10.3f} "
              f"{statistics.median(x[1] for x in v):8.3f}"
              + ("" if len(v) == a.frames else f"  ({len(v)} of {a.frames} frames)"))
    print(f"{'render returns':28s} {statistics.median(walls):10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
