"""Host-side costs of driving the device from Python: one kernel launch with its scalar
arguments undeclared vs declared (`clraster.device.kernel`), and how late a wait returns
after the kernel it waits for ends (`clraster.device.wait` vs the polling it replaced).

    PYTHONPATH=. python bench/host_overhead.py

Launch: a kernel of 12 buffers and 10 int scalars, 2000 launches each way, µs per launch.
Wait: a kernel spinning for about the given work, then the wait; lateness = the next
marker's queued time minus the kernel's end (profiling clock), median of 60.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import pyopencl as cl

from clraster.pipeline import device

SRC = ("__kernel void launch(" + ", ".join(f"__global int *a{i}" for i in range(12)) + ", "
       + ", ".join(f"const int s{i}" for i in range(10))
       + ") { if (get_global_id(0) == 0) a0[0] = s0; }\n"
       "__kernel void spin(__global float *a, const int n) { float s = a[get_global_id(0)];"
       " for (int i = 0; i < n; ++i) s = s * 0.999f + 1.0f; a[get_global_id(0)] = s; }\n")


def polled_wait(queue: cl.CommandQueue) -> None:
    """The wait before session 12: status polls with sleeps of 20 µs doubling to 250 µs."""
    ev = cl.enqueue_marker(queue)
    queue.flush()
    delay = 2e-5
    while ev.command_execution_status != cl.command_execution_status.COMPLETE:
        time.sleep(delay)
        delay = min(2.0 * delay, 2.5e-4)


def main() -> None:
    ctx = device.default_context()
    q = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    prg = cl.Program(ctx, SRC).build(options=["-cl-kernel-arg-info"])
    bufs = [cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 64) for _ in range(12)]
    scalars = [np.int32(i) for i in range(10)]
    n = 2000
    for label, k in (("undeclared", cl.Kernel(prg, "launch")),
                     ("declared (device.kernel)", device.kernel(prg, "launch"))):
        for _ in range(50):
            k(q, (16,), (16,), *bufs, *scalars)
        q.finish()
        t0 = time.perf_counter()
        for _ in range(n):
            k(q, (16,), (16,), *bufs, *scalars)
        dt = time.perf_counter() - t0
        q.finish()
        print(f"launch, {label}: {dt / n * 1e6:.1f} µs")
    spin = device.kernel(prg, "spin")
    a = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 4 * 1024)
    for work in (20_000, 200_000, 2_000_000):
        for label, w in (("polled (before)", polled_wait), ("device.wait", device.wait)):
            late = []
            for _ in range(60):
                ev = spin(q, (64,), (32,), a, np.int32(work))
                w(q)
                m = cl.enqueue_marker(q)
                q.finish()
                late.append((m.profile.queued - ev.profile.end) / 1e3)
            kernel_us = (ev.profile.end - ev.profile.start) / 1e3
            print(f"wait after a {kernel_us:7.0f} µs kernel, {label}: "
                  f"{statistics.median(late):.0f} µs late")


if __name__ == "__main__":
    main()
