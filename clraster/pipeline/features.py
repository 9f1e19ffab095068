"""Which compiler builtins a device's OpenCL C compiler supports, probed once per device.

The kernels' fast paths use Clang builtins that PoCL's and Intel's compilers (both Clang)
take and that other OpenCL compilers may not (GPU drivers, Oclgrind's interpreter); each
has a portable OpenCL C fallback that gives the same bits (kernels/common.h). A feature is
used only where its probe kernel — the builtin on inputs read from a buffer, so that it is
compiled for the device rather than folded by the front end — both builds and returns the
expected values; otherwise the host passes ``-DCLRASTER_NO_<FEATURE>`` and the kernels
take the fallback. All probes build as one program (one build on a device that has them
all), and one at a time only where that fails.

Forcing fallbacks, for tests: the environment variable ``CLRASTER_FALLBACKS`` names the
features to treat as missing (``rintf,ctz``, `FEATURES`), ``all`` for every one (what a
compiler with none of them gets), or ``portable`` for the build option
``-DCLRASTER_PORTABLE``: every fallback and the kernels' workarounds for Oclgrind, whose
interpreter builds some builtins it cannot run (always there). Fallbacks change speed, never
results: tests/test_portability.py checks the golden hashes with them forced.

Work-group sizes come from the device's limits too (`local_size`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyopencl as cl

from .runtimes import RuntimeSetupError, cache_root

log = logging.getLogger("clraster.device")

__all__ = ["FEATURES", "FallbackError", "WorkGroupError", "compiler_features",
           "feature_options", "forced_fallbacks", "local_size", "precision_options"]

#: probe inputs: floats with ties (x.5 both signs), values near 2^23 and 2^24 where float
#: rounding and int→float conversion round, a negative zero; ints with one bit set, several,
#: the top bit, and 2^24 + 1 (not a float)
_F_IN = np.array([2.5, -2.5, 0.5, 1.5, -0.5, 3.7, -0.0, 8388607.5,
                  -1.25, 7.5, 1e-40, -6.5, 0.49999997, 16777215.0, 1e30, -2.0], np.float32)
_I_IN = np.array([1, 8, -2147483648, 12, 0x10000, 16777217, -16777217, 6], np.int32)


@dataclass(frozen=True)
class Feature:
    """One builtin: the kernel body that exercises it (``fi``/``ii`` in, ``fo``/``io``
    out, one work-item), and the expected ``(fo, io)`` in NumPy."""

    name: str
    body: str
    expect: Callable[[], tuple[np.ndarray, np.ndarray]]

    @property
    def macro(self) -> str:
        return f"CLRASTER_NO_{self.name.upper()}"


def _rint() -> tuple[np.ndarray, np.ndarray]:
    return np.rint(_F_IN[:8]), np.zeros(0, np.int32)


def _ctz() -> tuple[np.ndarray, np.ndarray]:
    u = _I_IN.view(np.uint32).astype(np.int64)
    return np.zeros(0, np.float32), np.array([(int(v) & -int(v)).bit_length() - 1
                                              for v in u], np.int32)


def _sqrt() -> tuple[np.ndarray, np.ndarray]:
    return np.sqrt(np.abs(_F_IN[:8])), np.zeros(0, np.int32)


def _copy_twice() -> tuple[np.ndarray, np.ndarray]:
    return _F_IN[:8] * np.float32(2), np.zeros(0, np.int32)


def _convert() -> tuple[np.ndarray, np.ndarray]:
    return _I_IN.astype(np.float32), -(_I_IN > 0).astype(np.int32)


def _shuffle() -> tuple[np.ndarray, np.ndarray]:
    a, b = _F_IN[:8], _F_IN[8:]
    return np.array([a[0], b[0], a[1], b[1], a[6], b[7], a[7], b[6]], np.float32), \
        np.zeros(0, np.int32)


def _unaligned() -> tuple[np.ndarray, np.ndarray]:
    out = np.zeros(9, np.float32)
    out[1:] = _F_IN[:8]
    return out, np.zeros(0, np.int32)


#: name → the builtin and its probe. The names are CLRASTER_FALLBACKS's, and each one's
#: macro (CLRASTER_NO_<NAME>) selects its fallback in kernels/common.h or at its use.
FEATURES: dict[str, Feature] = {f.name: f for f in (
    Feature("rintf", "for (int k = 0; k < 8; ++k) fo[k] = __builtin_rintf(fi[k]);", _rint),
    Feature("sqrtf", "for (int k = 0; k < 8; ++k) fo[k] = __builtin_sqrtf(fabs(fi[k]));",
            _sqrt),
    Feature("ctz", "for (int k = 0; k < 8; ++k) io[k] = (int)__builtin_ctz((uint)ii[k]);",
            _ctz),
    Feature("nontemporal_store", "for (int k = 0; k < 8; ++k) "
            "__builtin_nontemporal_store(fi[k] * 2.0f, &fo[k]);", _copy_twice),
    Feature("prefetch", "for (int k = 0; k < 8; ++k) { __builtin_prefetch(fi + k + 8); "
            "fo[k] = fi[k] * 2.0f; }", _copy_twice),
    Feature("convertvector", "int8 x = vload8(0, ii); "
            "vstore8(__builtin_convertvector(x, float8), 0, fo); "
            "long8 m = __builtin_convertvector(x > (int8)(0), long8); "
            "vstore8(__builtin_convertvector(m, int8), 0, io);", _convert),
    Feature("shufflevector", "float8 a = vload8(0, fi), b = vload8(1, fi); "
            "vstore8(__builtin_shufflevector(a, b, 0, 8, 1, 9, 6, 15, 7, 14), 0, fo);",
            _shuffle),
    Feature("roundeven", "vstore8(__builtin_elementwise_roundeven(vload8(0, fi)), 0, fo);",
            _rint),
    Feature("ext_vector_type", "typedef float f8u __attribute__((ext_vector_type(8), "
            "aligned(4))); fo[0] = 0.0f; *(__global f8u *)(fo + 1) = vload8(0, fi);",
            _unaligned),
)}


class FallbackError(ValueError):
    """CLRASTER_FALLBACKS names a feature there is not."""


def forced_fallbacks() -> frozenset[str]:
    """The features ``CLRASTER_FALLBACKS`` forces off (``all`` and ``portable``: every one).

    Raises:
        FallbackError: a name that is not in `FEATURES`."""
    text = os.environ.get("CLRASTER_FALLBACKS", "").strip().lower()
    if not text:
        return frozenset()
    if text in ("all", "portable"):
        return frozenset(FEATURES)
    names = {n.strip() for n in text.split(",") if n.strip()}
    unknown = sorted(names - set(FEATURES))
    if unknown:
        raise FallbackError(f"CLRASTER_FALLBACKS={text!r}: unknown feature(s) "
                            f"{', '.join(unknown)}; give 'all', 'portable' or a "
                            f"comma-separated list of "
                            f"{', '.join(FEATURES)}")
    return frozenset(names)


def _kernel_source(features: list[Feature]) -> str:
    return "\n".join(
        f"__kernel void probe_{f.name}(__global const float *fi, __global const int *ii, "
        f"__global float *fo, __global int *io) {{ {f.body} }}" for f in features)


def _run(ctx: cl.Context, features: list[Feature]) -> set[str]:
    """The features of ``features`` that build together and give the expected values on
    ``ctx``'s device. Raises cl.Error when the program does not build."""
    with warnings.catch_warnings():   # a compiler's remarks on success are not ours
        warnings.simplefilter("ignore", cl.CompilerWarning)
        prg = cl.Program(ctx, _kernel_source(features)).build(
            options=list(precision_options(ctx.devices[0])))
    queue = cl.CommandQueue(ctx)
    mf = cl.mem_flags
    fi = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=_F_IN)
    ii = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=_I_IN)
    good = set()
    for f in features:
        fo, io = np.full(16, np.nan, np.float32), np.full(8, -7, np.int32)
        fo_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=fo)
        io_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=io)
        try:   # a kernel the device cannot create (Oclgrind: an unknown intrinsic) or run
            cl.Kernel(prg, f"probe_{f.name}")(queue, (1,), (1,), fi, ii, fo_buf, io_buf)
            cl.enqueue_copy(queue, fo, fo_buf)
            cl.enqueue_copy(queue, io, io_buf)
            queue.finish()
        except cl.Error as exc:
            log.debug("probe %s failed to run: %s", f.name, exc)
            continue
        want_f, want_i = f.expect()
        if (fo[:want_f.size].tobytes() == want_f.tobytes()
                and io[:want_i.size].tobytes() == want_i.tobytes()):
            good.add(f.name)
        else:
            log.debug("probe %s gave %s %s, expected %s %s", f.name, fo, io, want_f, want_i)
    return good


def precision_options(dev: cl.Device) -> tuple[str, ...]:
    """``-cl-fp32-correctly-rounded-divide-sqrt`` where ``dev`` offers it (its
    CL_DEVICE_SINGLE_FP_CONFIG has CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT), else nothing.

    OpenCL lets float ``/`` and ``sqrt`` be 2.5 and 3 ulp off unless a program is built with
    this option; CPU runtimes round them correctly either way, GPU drivers do not (they
    divide by a reciprocal). The twin divides in IEEE float32, so the same bytes on every
    runtime need it asked for. A device without the bit (Oclgrind reports none, and computes
    on the host's IEEE arithmetic) is built as it is."""
    if dev.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT:
        return ("-cl-fp32-correctly-rounded-divide-sqrt",)
    return ()


def _device_key(dev: cl.Device) -> tuple[str, ...]:
    return (dev.platform.name, dev.platform.version, dev.name, dev.driver_version)


def _disk_path(key: tuple[str, ...]) -> Path | None:
    """Where a probe's answer is kept across processes (each new process would otherwise
    build and run the probes again, ~70 ms on the warm pip PoCL), named by a hash of the
    device's names and versions and of the probes themselves; None without a cache."""
    try:
        root = cache_root()
    except RuntimeSetupError:
        return None
    h = hashlib.sha256("\0".join((*key, _kernel_source(list(FEATURES.values())))).encode())
    return root / f"features-{h.hexdigest()[:20]}"


def _read_disk(key: tuple[str, ...]) -> frozenset[str] | None:
    path = _disk_path(key)
    try:
        text = path.read_text() if path is not None else None
    except OSError:
        return None
    if text is None or not text.endswith("\n"):   # absent, or not written whole
        return None
    names = frozenset(n for n in text.strip().split(",") if n)
    return names if names <= set(FEATURES) else None


def _write_disk(key: tuple[str, ...], names: frozenset[str]) -> None:
    path = _disk_path(key)
    if path is None:
        return
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(",".join(sorted(names)) + "\n")
        os.replace(tmp, path)
    except OSError:
        pass


_probed: dict[tuple[str, ...], frozenset[str]] = {}
_probe_lock = threading.Lock()


def compiler_features(ctx: cl.Context) -> frozenset[str]:
    """The `FEATURES` the compiler of ``ctx``'s device supports: probed once per device
    (the answer kept in this process and in the user's cache folder, `_disk_path`); a
    device that builds nothing at all supports none."""
    dev = ctx.devices[0]
    key = _device_key(dev)
    with _probe_lock:
        known = _probed.get(key)
        if known is None:
            known = _read_disk(key)
            if known is not None:
                _probed[key] = known
        if known is None:
            all_features = list(FEATURES.values())
            try:
                good = _run(ctx, all_features)
            except cl.Error:
                good = set()
            if len(good) < len(all_features):   # one at a time: a failed build is local
                for f in all_features:
                    if f.name in good:
                        continue
                    try:
                        good |= _run(ctx, [f])
                    except cl.Error as exc:
                        log.debug("probe %s does not build on %s: %s", f.name, dev.name,
                                  str(exc).strip().splitlines()[-1:] or exc)
            known = _probed[key] = frozenset(good)
            _write_disk(key, known)
            missing = sorted(set(FEATURES) - known)
            if missing:
                log.debug("%s / %s: portable fallbacks for %s", dev.platform.name.strip(),
                          dev.name.strip(), ", ".join(missing))
        return known


def feature_options(ctx: cl.Context) -> tuple[str, ...]:
    """Build options selecting each fallback the device needs or CLRASTER_FALLBACKS forces:
    ``-DCLRASTER_PORTABLE`` alone on Oclgrind (every fallback, and its own workarounds
    in the kernels) or for ``portable``; else ``-DCLRASTER_NO_<FEATURE>`` per feature.

    Raises:
        FallbackError: CLRASTER_FALLBACKS names a feature there is not."""
    dev = ctx.devices[0]
    forced = forced_fallbacks()
    portable = os.environ.get("CLRASTER_FALLBACKS", "").strip().lower() == "portable"
    if "oclgrind" in dev.platform.name.lower() or portable:
        return ("-DCLRASTER_PORTABLE",)
    have = compiler_features(ctx) - forced
    return tuple(f"-D{f.macro}" for f in FEATURES.values() if f.name not in have)


class WorkGroupError(RuntimeError):
    """A kernel needs a work-group size its device cannot run it with."""


def local_size(k: cl.Kernel, dev: cl.Device, wanted: int, *, exact: bool = False) -> int:
    """The work-group size to launch kernel ``k`` with on ``dev``: ``wanted`` where the
    device runs ``k`` with that many work-items (CL_KERNEL_WORK_GROUP_SIZE, which a GPU
    driver lowers for a kernel short of registers, and CL_DEVICE_MAX_WORK_ITEM_SIZES[0]).
    Else, for a size that only sets speed (``exact`` False: the Hi-Z test's, the lines'),
    the largest power of two within the limits; for one the kernel's indexing depends on
    (``exact``: one work-group per draw in the vertex and setup stages), a WorkGroupError
    naming the kernel, the device and both sizes.

    PoCL's and Intel's CPU devices allow 4096 and 8192 work-items; any size a CPU device
    gets here is ``wanted``."""
    limit = min(int(k.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, dev)),
                int(dev.max_work_item_sizes[0]))
    if wanted <= limit:
        return wanted
    if exact:
        raise WorkGroupError(
            f"kernel {k.function_name} needs work-groups of {wanted} work-items (one per "
            f"cluster triangle or lane) and {dev.name.strip()} "
            f"({dev.platform.name.strip()}) runs it with at most {limit}: choose another "
            f"device (`clraster devices`, CLRASTER_DEVICE)")
    return 1 << (limit.bit_length() - 1)
