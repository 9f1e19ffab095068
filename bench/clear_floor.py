"""What an empty frame cannot go below on this machine: the bytes its clear must write at
the memory's store bandwidth, plus one kernel launch, against `render()` of an empty frame.

    PYTHONPATH=. python bench/clear_floor.py                 # 1920x1080, 31 rounds
    PYTHONPATH=. python bench/clear_floor.py --evict 0       # warm caches

An empty frame (the harness's `empty` scene: the quad behind the camera) still returns
float32 depth 1.0 and int32 id −1 for every pixel: 8 bytes a pixel (16.6 MB at 1080p) that
the `clear_frame` kernel writes (`RasterStage.clear`; the barycentrics are fresh zero
pages, written by nobody). So its time has a floor set by the machine, not
by clraster: those bytes at the device's store bandwidth, plus the launch of one kernel
and the wait for it. Measured here, in turn, each round (medians):

* ``fill nt`` / ``fill plain``: a kernel writing the same 8 bytes a pixel (1.0 and −1 as
  `float8` / `int8` stores, non-temporal as `clear_frame`'s (`common.h NT_STORE`), or
  ordinary), one contiguous share per compute unit: its device time (profiling
  event);
* ``launch``: a kernel that does nothing, from the enqueue to the return of the wait (the
  runtime's wake-up and completion: what every frame pays at least once);
* ``numpy fill``: the same bytes written by NumPy on the calling thread (one core);
* ``render``: `Renderer.render` of the empty frame (wall), and its clear kernel's device
  time.

floor = fill nt + launch. ``--evict MB`` (default 100) reads and writes an MB-megabyte array
before each measurement, as the harness's twin and llvmpipe frames do between clraster's.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parent))
from host_timeline import scene  # noqa: E402  (bench/ is not a package)
from kernel_times import record_launches  # noqa: E402

# The fill as the raster's clear writes: float8 / int8 rows, non-temporal where the compiler
# has the builtin (clang's: PoCL, Intel's CPU runtime), else ordinary stores.
SOURCE = r"""
#if defined(__has_builtin)
#if __has_builtin(__builtin_nontemporal_store)
#define HAVE_NT 1
#endif
#endif
#if defined(HAVE_NT) && defined(NT)
#define STORE(v, p) __builtin_nontemporal_store((v), (p))
#else
#define STORE(v, p) (*(p) = (v))
#endif
__kernel void fill(__global float8 *restrict depth, __global int8 *restrict ids,
                   const int n8)
{
    int per = (n8 + (int)get_global_size(0) - 1) / (int)get_global_size(0);
    int a = (int)get_global_id(0) * per, b = min(n8, a + per);
    for (int i = a; i < b; ++i) {
        STORE((float8)(1.0f), depth + i);
        STORE((int8)(-1), ids + i);
    }
}
__kernel void nothing(__global int *unused) { }
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--rounds", type=int, default=31)
    ap.add_argument("--evict", type=int, default=100, metavar="MB",
                    help="touch this many MB before each measurement (0: warm caches)")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    launches = record_launches()
    from clraster import Renderer

    r = Renderer(w, h)
    ctx, queue = r.context, r.queue
    dev = ctx.devices[0]
    units = dev.max_compute_units
    prog_nt = cl.Program(ctx, SOURCE).build(options=["-DNT"])
    prog_plain = cl.Program(ctx, SOURCE).build()
    fills = {"fill nt": cl.Kernel(prog_nt, "fill"), "fill plain": cl.Kernel(prog_plain, "fill")}
    nothing = cl.Kernel(prog_nt, "nothing")
    n = w * h
    n8 = n // 8
    mf = cl.mem_flags
    depth = cl.Buffer(ctx, mf.READ_WRITE, 4 * n)
    ids = cl.Buffer(ctx, mf.READ_WRITE, 4 * n)
    scratch = cl.Buffer(ctx, mf.READ_WRITE, 4)
    target, cam = scene("empty", w, h)   # the harness's empty frame
    host = np.empty(2 * n, np.float32)
    junk = np.ones(a.evict << 17) if a.evict else None   # float64: MB << 17 of them

    def evict() -> None:
        if junk is not None:
            np.add(junk, 1.0, out=junk)

    for _ in range(3):   # builds, PoCL's per-size specializations, the frame pool
        for k in fills.values():
            k(queue, (units,), (1,), depth, ids, np.int32(n8)).wait()
        nothing(queue, (1,), (1,), scratch).wait()
        r.render(target, cam)
    rows: dict[str, list[float]] = {k: [] for k in
                                    ("fill nt", "fill plain", "launch", "numpy fill",
                                     "render", "render's clear kernel")}
    for _ in range(a.rounds):
        for name, k in fills.items():
            evict()
            ev = k(queue, (units,), (1,), depth, ids, np.int32(n8))
            ev.wait()
            rows[name].append((ev.profile.end - ev.profile.start) * 1e-6)
        evict()
        t0 = time.perf_counter()
        nothing(queue, (1,), (1,), scratch).wait()
        rows["launch"].append((time.perf_counter() - t0) * 1e3)
        evict()
        t0 = time.perf_counter()
        host.fill(1.0)
        rows["numpy fill"].append((time.perf_counter() - t0) * 1e3)
        evict()
        launches.clear()
        t0 = time.perf_counter()
        f = r.render(target, cam)
        rows["render"].append((time.perf_counter() - t0) * 1e3)
        del f
        rows["render's clear kernel"].append(
            sum((e.profile.end - e.profile.start) * 1e-6 for _, e in launches))
    med = {k: statistics.median(v) for k, v in rows.items()}
    mb = 8 * n / 1e6
    print(f"empty frame {w}x{h}: {mb:.1f} MB of depth and ids; {a.rounds} rounds, "
          f"{a.evict} MB evicted before each measurement; {r.device_description}; "
          f"{units} compute units")
    for k, v in med.items():
        rate = f"  {mb / v:6.1f} GB/s" if k.startswith(("fill", "numpy")) else ""
        print(f"  {k:<24}{v:8.3f} ms{rate}")
    floor = med["fill nt"] + med["launch"]
    print(f"  {'floor (fill nt + launch)':<24}{floor:8.3f} ms")
    print(f"  render − floor          {med['render'] - floor:8.3f} ms (host work of the frame)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
