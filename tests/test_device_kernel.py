"""device.kernel declares each kernel's scalar argument dtypes from its argument info, so a
launch packs scalars in one call (pyopencl's undeclared path took ~9 µs per scalar);
device.wait waits for the device interruptibly."""

import _thread
import contextlib
import threading
import time

import numpy as np
import pyopencl as cl
import pytest

from clraster.base.config import RasterConfig
from clraster.base.layout import ST_CLIPPED, ST_RASTER
from clraster.pipeline import device


@pytest.fixture(scope="module")
def ctx():
    return device.default_context()


@pytest.fixture(scope="module")
def queue(ctx):
    return cl.CommandQueue(ctx)


@contextlib.contextmanager
def _interrupt_while_held(gate: cl.UserEvent):
    """Ctrl-C (``_thread.interrupt_main``) 0.2 s from now, while ``gate`` holds a queue's
    work back; a fallback opens the gate after 60 s, so a wait that cannot be interrupted
    fails (the fallback is no longer alive) instead of hanging. Yields (the list that gets
    the interrupt's time, the fallback timer); on exit both timers stop and the gate opens,
    so the held work runs."""
    sent: list[float] = []

    def interrupt() -> None:
        sent.append(time.perf_counter())
        _thread.interrupt_main()

    timer = threading.Timer(0.2, interrupt)
    fallback = threading.Timer(60.0, gate.set_status, (cl.command_execution_status.COMPLETE,))
    timer.start()
    fallback.start()
    try:
        yield sent, fallback
    finally:
        timer.cancel()   # (should the wait end first, no interrupt after the test)
        fallback.cancel()
        if gate.command_execution_status != cl.command_execution_status.COMPLETE:
            gate.set_status(cl.command_execution_status.COMPLETE)   # the work runs now


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
    for stage in ("setup", "bin", "raster", "pyramid", "query", "lines"):
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
    OpenCL's wait); a KeyboardInterrupt during it gets through within a slice (50 ms) while
    the work is unfinished, and the work goes on; the next wait returns when it is done.

    The work is held back by a user event that the test completes only after the interrupt
    (a fallback opens it after 60 s, so a wait that cannot be interrupted fails instead of
    hanging): the wait cannot end because the work ended, on any machine or runtime. (It
    used to be a kernel sized from one timed run to last ~3 s: a slow first run, e.g. behind
    another test's work on the device, made it end before the interrupt, "DID NOT RAISE".)"""
    prg = cl.Program(ctx, SPIN).build()
    spin = prg.spin
    a = np.zeros(16, np.float32)
    mf = cl.mem_flags
    buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=a)
    ev = spin(queue, (16,), (1,), buf, np.int32(1000))
    device.wait(queue)
    assert ev.command_execution_status == cl.command_execution_status.COMPLETE

    gate = cl.UserEvent(ctx)
    cl.enqueue_barrier(queue, wait_for=[gate])   # nothing after it runs before the gate
    ev = spin(queue, (16,), (1,), buf, np.int32(100_000))
    with _interrupt_while_held(gate) as (sent, fallback):
        try:
            device.wait(queue)
        except KeyboardInterrupt:
            pass
        else:
            pytest.fail("device.wait returned while its work was held back, uninterrupted "
                        f"(gate {gate.command_execution_status}, work "
                        f"{ev.command_execution_status}, interrupt sent: {bool(sent)})")
        latency = time.perf_counter() - sent[0]
        assert fallback.is_alive(), "the wait ended only when its work could run"
        # the slice is 50 ms; the bound leaves room for a loaded machine
        assert latency < 2.0, f"the interrupt took {latency:.2f} s to get through"
        assert ev.command_execution_status != cl.command_execution_status.COMPLETE
        assert device.device_busy()   # the abandoned marker is kept until the work is done
    device.wait(queue)
    assert ev.command_execution_status == cl.command_execution_status.COMPLETE
    assert not device.device_busy()
    cl.enqueue_copy(queue, a, buf)
    assert np.all(a > 0)


def test_empty_frame_behind_abandoned_work_is_interruptible():
    """A frame with nothing in view is cleared with one uninterruptible wait, which is
    short, unless an interrupted frame's work still runs ahead of it on the renderer's
    queue (`device.device_busy`): then Ctrl-C must still get through at once, as in any
    other frame. The abandoned work is held back by a user event (the test's own stand-in
    for an interrupted frame's kernels)."""
    from clraster import Camera, Mesh, Renderer

    mesh = Mesh(np.array([[0, 0, -2], [1, 0, -2], [0, 1, -2]], np.float32),
                np.array([[0, 1, 2]], np.int32))
    away = Camera.look_at(eye=(0, 0, 0), target=(0, 0, 1), up=(0, 1, 0))
    r = Renderer(64, 48)
    assert (r.render(mesh, away).triangle_id == -1).all()   # nothing in view
    gate = cl.UserEvent(r.context)
    cl.enqueue_barrier(r.queue, wait_for=[gate])   # nothing after it runs before the gate
    device.abandon(r.queue, None)                  # as an interrupted frame leaves it
    with _interrupt_while_held(gate) as (sent, fallback):
        with pytest.raises(KeyboardInterrupt):
            r.render(mesh, away)
        assert fallback.is_alive(), "the clear's wait ended only when the work could run"
        assert time.perf_counter() - sent[0] < 2.0
    device.wait(r.queue)
    assert (r.render(mesh, away).depth == 1.0).all()


@pytest.mark.parametrize("size", [(64, 48), (203, 77), (9, 7), (1, 1)])
def test_cleared_frame_overwrites_every_pixel_of_reused_arrays(size):
    """A frame with nothing in view (`RasterStage.clear`: kernel clear_frame, contiguous
    shares of blocks of eight pixels, the last block partial where width · height is not a
    multiple of 8) is depth 1.0, id −1, barycentrics and overdraw 0 at every pixel, also
    in arrays a dropped frame that drew everywhere leaves to the frame pool."""
    from clraster import Camera, Mesh, Renderer

    w, h = size
    quad = Mesh(np.array([[-9, -9, -2], [9, -9, -2], [9, 9, -2], [-9, 9, -2]], np.float32),
                np.array([[0, 1, 2], [0, 2, 3]], np.int32))
    ahead = Camera.look_at(eye=(0, 0, 0), target=(0, 0, -1), up=(0, 1, 0))
    away = Camera.look_at(eye=(0, 0, 0), target=(0, 0, 1), up=(0, 1, 0))
    r = Renderer(w, h)
    for _ in range(2):
        drawn = r.render(quad, ahead, overdraw=True)
        assert (drawn.triangle_id >= 0).all() and (drawn.overdraw == 1).all()
        del drawn   # its arrays go back to the pool
        for overdraw in (True, False):
            f = r.render(quad, away, overdraw=overdraw)
            assert (f.depth == 1.0).all() and (f.triangle_id == -1).all()
            assert (f.barycentrics == 0.0).all()
            assert not overdraw or (f.overdraw == 0).all()
            del f
