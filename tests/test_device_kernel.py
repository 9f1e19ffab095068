"""device.kernel declares each kernel's scalar argument dtypes from its argument info, so a
launch packs scalars in one call (pyopencl's undeclared path took ~9 µs per scalar)."""

import numpy as np
import pyopencl as cl
import pytest

from clraster import device
from clraster.config import RasterConfig


@pytest.fixture(scope="module")
def ctx():
    return device.default_context()


@pytest.fixture(scope="module")
def queue(ctx):
    return cl.CommandQueue(ctx)


def _setup_program(ctx):
    return device.program(ctx, "setup", RasterConfig().build_options())


def test_scalar_dtypes_follow_the_kernel_signature(ctx):
    """scan_partials(__global const int *cnt, const uint m, const uint chunks,
    __global int *partial) in kernels/setup.cl."""
    k = device.kernel(_setup_program(ctx), "scan_partials")
    assert device.scalar_arg_dtypes(k) == [None, np.uint32, np.uint32, None]


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
    mf = cl.mem_flags
    cnt_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=cnt)
    part_buf = cl.Buffer(ctx, mf.READ_WRITE, 4 * 2)
    device.kernel(prg, "scan_partials")(queue, (2,), (1,), cnt_buf, 10, 2, part_buf)
    part = np.zeros(2, np.int32)
    cl.enqueue_copy(queue, part, part_buf)
    queue.finish()
    assert part.tolist() == [cnt[:5].sum(), cnt[5:].sum()]
    with pytest.raises(cl.LogicError):
        cl.Kernel(prg, "scan_partials")(queue, (2,), (1,), cnt_buf, 10, 2, part_buf)
