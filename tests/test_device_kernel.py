"""device.kernel declares each kernel's scalar argument dtypes from its argument info, so a
launch packs scalars in one call (pyopencl's undeclared path took ~9 µs per scalar);
device.wait waits for the device interruptibly."""

import _thread
import threading
import time

import numpy as np
import pyopencl as cl
import pytest

from clraster import device
from clraster.config import ST_CLIPPED, ST_RASTER, RasterConfig


@pytest.fixture(scope="module")
def ctx():
    return device.default_context()


@pytest.fixture(scope="module")
def queue(ctx):
    return cl.CommandQueue(ctx)


def _setup_program(ctx):
    return device.program(ctx, "setup", RasterConfig().build_options())


def test_scalar_dtypes_follow_the_kernel_signature(ctx):
    """scan_partials(__global const uchar *status, __global const int *cnt, const uint m,
    const uint chunks, __global int *partial) in kernels/setup.cl."""
    k = device.kernel(_setup_program(ctx), "scan_partials")
    assert device.scalar_arg_dtypes(k) == [None, None, np.uint32, np.uint32, None]


def test_every_stage_kernel_is_declared(ctx):
    """Every kernel of the stage programs gets argument info (the programs are built with
    -cl-kernel-arg-info; without it PoCL gives none) and its scalars a dtype."""
    opts = RasterConfig().build_options()
    for stage in ("vertex", "setup", "bin", "raster", "pyramid", "query", "lines"):
        prg = device.program(ctx, stage, opts)
        for name in prg.kernel_names.split(";"):
            k = cl.Kernel(prg, name)
            dtypes = device.scalar_arg_dtypes(k)
            assert dtypes is not None, f"{stage}.cl {name}: no argument info"
            for i, dt in enumerate(dtypes):
                type_name = str(k.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME))
                if not type_name.endswith("*"):
                    assert dt is not None, f"{stage}.cl {name} argument {i}: {type_name}"


def test_declared_kernel_runs_with_python_ints(ctx, queue):
    """Declared, a kernel takes plain Python ints for its scalars and computes the same
    sums; undeclared, pyopencl refuses them (so the declaration is what is tested)."""
    prg = _setup_program(ctx)
    cnt = np.arange(1, 11, dtype=np.int32)
    # the scan counts the pieces of clipped triangles only (clip_count is undefined elsewhere)
    status = np.full(10, ST_CLIPPED, np.uint8)
    status[[2, 7]] = ST_RASTER
    mf = cl.mem_flags
    st_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=status)
    cnt_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=cnt)
    part_buf = cl.Buffer(ctx, mf.READ_WRITE, 4 * 2)
    device.kernel(prg, "scan_partials")(queue, (2,), (1,), st_buf, cnt_buf, 10, 2, part_buf)
    part = np.zeros(2, np.int32)
    cl.enqueue_copy(queue, part, part_buf)
    queue.finish()
    kept = np.where(status == ST_CLIPPED, cnt, 0)
    assert part.tolist() == [kept[:5].sum(), kept[5:].sum()] == [12, 32]
    with pytest.raises(cl.LogicError):
        cl.Kernel(prg, "scan_partials")(queue, (2,), (1,), st_buf, cnt_buf, 10, 2, part_buf)


SPIN = """__kernel void spin(__global float *a, const int n)
{
    float s = a[get_global_id(0)];
    for (int i = 0; i < n; ++i) s = s * 0.999f + 1.0f;
    a[get_global_id(0)] = s;
}"""


def test_wait_returns_when_done_and_ctrl_c_ends_it_at_once(ctx, queue):
    """device.wait returns once everything enqueued has run (its helper thread blocks in
    OpenCL's wait); a KeyboardInterrupt during it gets through within a slice (50 ms)
    while the kernel runs on; the next wait returns when that kernel is done."""
    prg = cl.Program(ctx, SPIN).build()
    spin = prg.spin
    a = np.zeros(16, np.float32)
    mf = cl.mem_flags
    buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a)
    n = 200_000
    spin(queue, (16,), (1,), buf, np.int32(n))   # PoCL compiles it for this size here
    queue.finish()
    t0 = time.perf_counter()
    ev = spin(queue, (16,), (1,), buf, np.int32(n))
    device.wait(queue)
    took = time.perf_counter() - t0
    assert ev.command_execution_status == cl.command_execution_status.COMPLETE
    n = min(int(n * 3.0 / max(took, 1e-3)), 2**31 - 1)   # a kernel of about 3 s
    t0 = time.perf_counter()
    ev = spin(queue, (16,), (1,), buf, np.int32(n))
    timer = threading.Timer(0.3, _thread.interrupt_main)
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            device.wait(queue)
    finally:
        timer.cancel()   # (should the wait end first, no interrupt after the test)
    interrupted = time.perf_counter() - t0
    assert interrupted < 0.3 + 0.25, interrupted
    assert ev.command_execution_status != cl.command_execution_status.COMPLETE
    assert device.device_busy()   # the abandoned marker is kept until the kernel is done
    device.wait(queue)
    assert ev.command_execution_status == cl.command_execution_status.COMPLETE
    assert not device.device_busy()
    cl.enqueue_copy(queue, a, buf)
    assert np.all(a > 0)
