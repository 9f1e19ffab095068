"""OpenCL context selection and the program cache.

Device choice, first match wins (`choose_context`, `list_devices`, ``clraster devices``):

1. ``device=`` (a `Renderer`'s argument): a name (below) or a ``pyopencl.Device``;
2. ``CLRASTER_DEVICE``: ``pocl``, ``intel``, ``oclgrind``, or any other case-insensitive
   substring of a platform or device name; the first matching device that compiles a
   probe kernel is used, and a name that matches none is a `NoDeviceError` listing the
   devices there are;
3. ``PYOPENCL_CTX`` (pyopencl's own syntax, e.g. ``0`` or ``"Portable"``);
4. default: the first CPU device that compiles a probe kernel, PoCL platforms first, never
   the Oclgrind simulator.

Runtimes installed as wheels (Intel's CPU runtime: ``pip install clraster[intel]``) are made
visible to pyopencl's ICD loader when this module is imported, before any OpenCL call
(`clraster.pipeline.runtimes`).

We never call ``create_some_context()`` blindly: with Oclgrind installed it may pick the
*simulator* first, which is ~1000× slower (choosing it on purpose warns, `SimulatorWarning`).
Every choice keeps its reason (e.g. ``"CLRASTER_DEVICE=pocl"``): `describe_choice`.

Programs are built once per (context, stage, build options) and cached here; PoCL also keeps
compiled binaries on disk, so a second process skips the LLVM compile (cold vs warm start).

Worker threads: PoCL's CPU device runs kernels on one worker thread per core. Left to the
Linux scheduler, the workers of this 2-core VM were often both placed on one core after the
process had been idle for a few milliseconds (a Python pause, another library's frame): a
kernel then ran on one core, twice as long (bench/README.md's performance log has the
measurement). So `platforms` asks PoCL to pin worker i to CPU i (``POCL_AFFINITY=1``)
when that is safe: on Linux, the process may run on every CPU, and no PoCL thread count
other than the CPU count is set (with fewer, the process shares the machine, e.g. one of
several Dask workers, and would pin its threads onto the same first CPUs as the others;
with more, PoCL would pin a worker to a CPU that is not there and abort). ``POCL_AFFINITY``
set in the environment is honoured as it is; ``CLRASTER_PIN_THREADS=0`` turns the choice
off. The variables are set only while PoCL starts, so child processes do not inherit them.
"""

from __future__ import annotations

import atexit
import dataclasses
import functools
import logging
import os
import queue as queue_mod
import re
import threading
import time
import warnings
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyopencl as cl

from .arraypool import page_aligned  # plain NumPy, imports nothing of clraster
from .features import feature_options, precision_options
from .runtimes import hint as _runtime_hint
from .runtimes import register_wheel_runtimes

# Before any OpenCL call: the ICD loader reads its environment once, at the first
# (clraster.pipeline.runtimes: Intel's CPU runtime from `pip install clraster[intel]`).
register_wheel_runtimes()
# pyopencl (2026.1) reads this variable without a default when its binary cache fails, so
# the failure became a KeyError that hid the cache's error and failed the build (seen once
# on Intel's runtime under load); unset means "not fatal": pyopencl then warns and builds.
os.environ.setdefault("PYOPENCL_CACHE_FAILURE_FATAL", "")

#: named by the module's public path (users' logging settings name it)
log = logging.getLogger("clraster.device")

_INSTALL_HINT = (
    "clraster needs an OpenCL CPU platform. `pip install pocl-binary-distribution` gives one "
    "with no system packages (it is a dependency of clraster). Its LLVM 14 cannot compile for "
    "CPUs newer than it knows (e.g. AMD Zen 5: 'unknown target CPU generic'); there, install "
    "a newer PoCL, e.g. Debian/Ubuntu `apt-get install pocl-opencl-icd`, which clraster picks "
    "up automatically. Or set PYOPENCL_CTX to choose a platform yourself."
)

_PROBE_SRC = "__kernel void probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"


#: Environment variables that bound PoCL's CPU worker threads: PoCL 3.x reads the first,
#: PoCL 4+ the second (an unknown one is ignored, so both are set).
POCL_THREAD_VARS = ("POCL_MAX_PTHREAD_COUNT", "POCL_CPU_MAX_CU_COUNT")


#: PoCL's lower bounds on its worker count (3.x, 4+): with one above the CPU count PoCL
#: would pin a worker to a CPU that does not exist, and abort
_POCL_MIN_THREAD_VARS = ("POCL_PTHREAD_MIN_THREADS", "POCL_CPU_MIN_CU_COUNT")

#: held while the environment carries POCL_AFFINITY (`platforms`)
_platforms_lock = threading.Lock()


def pin_pocl_threads() -> bool:
    """Whether `platforms` asks PoCL to pin its worker threads, one per CPU (module
    docstring): Linux, no ``POCL_AFFINITY`` or ``CLRASTER_PIN_THREADS=0`` in the
    environment, every CPU in this process's affinity mask, and no PoCL thread count set
    other than the CPU count (PoCL pins worker i to CPU i and aborts the process if that
    CPU is not there, so the worker count must be the CPU count exactly)."""
    env = os.environ
    if env.get("CLRASTER_PIN_THREADS", "1") == "0" or "POCL_AFFINITY" in env:
        return False
    try:
        allowed = os.sched_getaffinity(0)
    except AttributeError:   # not Linux: PoCL pins only there anyway
        return False
    n = os.cpu_count() or 0
    if n < 2 or allowed != set(range(n)):
        return False
    return all(env.get(k) in (None, str(n)) for k in POCL_THREAD_VARS + _POCL_MIN_THREAD_VARS)


def platforms() -> list:
    """``cl.get_platforms()``, with PoCL's workers pinned where `pin_pocl_threads` says so.

    PoCL reads these variables and starts its worker threads when its devices are first
    listed in a process, so this call lists them; a later call changes nothing. (Listing
    the platforms alone was not enough: pyopencl's ICD loader queried the platforms'
    devices itself only where there were several, so Debian's PoCL 3.1 as the only ICD
    started its workers at the context's first device query, after the environment was
    restored, and they ran unpinned.) While pinning, the environment also bounds PoCL's
    worker count to the CPU count from both sides (PoCL falls back to a fixed count where it
    cannot read the machine's topology, and a worker beyond the CPUs would abort the
    process); all of it is restored when PoCL has started. A process started by another
    thread during that call inherits those variables."""
    with _platforms_lock:
        saved = {}
        if pin_pocl_threads():
            n = str(os.cpu_count())
            pinned = {"POCL_AFFINITY": "1",
                      **{k: n for k in POCL_THREAD_VARS + _POCL_MIN_THREAD_VARS}}
            saved = {k: os.environ.get(k) for k in pinned}
            os.environ.update(pinned)
        try:
            found = cl.get_platforms()
            if saved:
                for plat in found:
                    if "portable computing" in plat.name.lower():
                        try:
                            plat.get_devices()   # PoCL starts its workers here
                        except cl.Error:   # none here: _default_context skips it
                            pass
            return found
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


class NoDeviceError(RuntimeError):
    """No usable OpenCL platform/device could be found."""


def kernel_dir() -> Path:
    """Directory holding the OpenCL sources (installed wheel: clraster/kernels; a checkout:
    kernels/ beside the package)."""
    package = Path(__file__).resolve().parent.parent   # clraster/ (this is pipeline/device.py)
    for cand in (package / "kernels", package.parent / "kernels"):
        if (cand / "common.h").is_file():
            return cand
    raise FileNotFoundError(f"OpenCL kernels not found next to {package}; reinstall clraster")


@functools.cache
def kernel_source(stage: str) -> str:
    """Source of ``kernels/<stage>.cl`` with ``#include "common.h"`` inlined, and in it the
    constants and records generated from clraster/layout.py (`clraster.base.layout.inline_layout`).

    Inlining (rather than ``-I``) keeps every cache keyed on the full text, so an edited
    header can never be served from a stale binary.
    """
    from ..base.layout import inline_layout

    kdir = kernel_dir()
    text = (kdir / f"{stage}.cl").read_text()
    header = inline_layout((kdir / "common.h").read_text())
    return re.sub(r'^#include "common\.h"\s*$', lambda _m: header, text, flags=re.M)


class ForkedProcessError(RuntimeError):
    """OpenCL was used in a parent process and this process is a fork() child of it.

    PoCL's worker threads exist only in the process that started them: after fork() the
    child's first OpenCL call (even a new context's first kernel) waits for them forever.
    Measured here: a child forked after one render hung in its first ``queue.finish()``
    both with the inherited context and with a fresh one, so no context can be built in the
    child; clraster refuses instead of hanging.
    """


#: pid of the process in which clraster first touched OpenCL (None: not yet).
_opencl_pid: int | None = None


def mark_opencl_use() -> None:
    """Record that this process uses OpenCL (see `check_process`)."""
    global _opencl_pid
    if _opencl_pid is None:
        _opencl_pid = os.getpid()


def check_process(owner_pid: int | None = None) -> None:
    """Raise `ForkedProcessError` if OpenCL was started in another process than this one.

    Args:
        owner_pid: pid that created the object about to use OpenCL (a Renderer's); by
            default the process in which clraster first used OpenCL.
    """
    pid = _opencl_pid if owner_pid is None else owner_pid
    if pid is not None and pid != os.getpid():
        raise ForkedProcessError(
            f"OpenCL was started in process {pid} and this is process {os.getpid()}, a "
            f"fork() of it: PoCL's worker threads do not survive fork(), so any OpenCL call "
            f"here would hang. Start worker processes with the 'spawn' or 'forkserver' "
            f"method (multiprocessing.get_context('spawn'), or "
            f"concurrent.futures.ProcessPoolExecutor(mp_context=...)), or create renderers "
            f"only in the children, never in the parent before forking")


class SimulatorWarning(UserWarning):
    """The selected OpenCL device is a simulator (Oclgrind): correct but ~1000× slower."""


def _warn_if_simulator(ctx: cl.Context, reason: str | None = None) -> cl.Context:
    """Warn (`SimulatorWarning`) when ``ctx``'s device is Oclgrind; ``reason`` says what
    chose it (default: PYOPENCL_CTX, the only way before CLRASTER_DEVICE)."""
    plat = ctx.devices[0].platform.name
    if "oclgrind" in plat.lower():
        if reason is None:
            reason = f"PYOPENCL_CTX={os.environ.get('PYOPENCL_CTX')!r}"
        warnings.warn(
            f"{reason} selected the {plat.strip()} "
            f"simulator, which checks memory accesses and runs ~1000x slower than PoCL; "
            f"unset it to let clraster pick PoCL, or select the PoCL platform "
            f"(`clraster devices` lists them)",
            SimulatorWarning, stacklevel=3)
    return ctx


def _platform_list() -> str:
    try:
        rows = []
        for i, p in enumerate(platforms()):
            devs = ", ".join(f"{j}: {d.name.strip()}" for j, d in enumerate(p.get_devices()))
            rows.append(f"{i}: {p.name.strip()} [{devs}]")
        return "; ".join(rows) or "none"
    except cl.Error as exc:
        return f"none ({exc})"


def default_context() -> cl.Context:
    """The context clraster uses when none is given (see module docstring: CLRASTER_DEVICE,
    else PYOPENCL_CTX, else the first CPU device that compiles); made once per process.

    Raises:
        NoDeviceError: no usable OpenCL CPU device, or CLRASTER_DEVICE / PYOPENCL_CTX
            selects none.
        ForkedProcessError: OpenCL was started in the parent of this fork() child.
    """
    check_process()
    ctx = _default_choice()[0]
    mark_opencl_use()
    return ctx


#: why the default context has the device it has (the reason `default_context` chose it)
_DEFAULT_REASON = "default: first CPU runtime that compiles the kernels"


@functools.lru_cache(maxsize=1)
def _default_choice() -> tuple[cl.Context, str]:
    spec = os.environ.get("CLRASTER_DEVICE", "").strip()
    if spec:
        dev = find_device(spec, source="CLRASTER_DEVICE")
        reason = f"CLRASTER_DEVICE={spec}"
        return _warn_if_simulator(cl.Context([dev]), reason), reason
    return _default_context(), (f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']}"
                                if os.environ.get("PYOPENCL_CTX") else _DEFAULT_REASON)


def _default_context() -> cl.Context:
    if os.environ.get("PYOPENCL_CTX"):
        try:
            platforms()   # PoCL's threads start here, pinned or not (module docstring)
            return _warn_if_simulator(cl.create_some_context(interactive=False))
        except Exception as exc:  # pyopencl raises several types here
            raise NoDeviceError(
                f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} did not select a device "
                f"({exc}). It takes pyopencl's syntax 'PLATFORM[:DEVICE]', by index or by a "
                f"part of the name; the platforms here are: {_platform_list()}. Unset it to "
                f"let clraster choose PoCL") from exc
    try:
        found = platforms()
    except cl.Error as exc:
        raise NoDeviceError(f"no OpenCL platform found ({exc}). {_INSTALL_HINT}") from exc
    # PoCL first; never the Oclgrind simulator. A platform is used only if it can actually
    # compile a kernel: several PoCLs may be installed side by side and an old one may be
    # unable to target this CPU.
    ordered = sorted(found, key=lambda p: "portable computing" not in p.name.lower())
    failures = []
    for plat in ordered:
        if "oclgrind" in plat.name.lower():
            continue
        try:
            devs = plat.get_devices(device_type=cl.device_type.CPU)
        except cl.Error:
            continue
        if not devs:
            continue
        ctx = cl.Context([devs[0]])
        error = _probe_error(ctx)
        if error is not None:
            failures.append(f"{plat.version}: {error}")
            continue
        log.debug("clraster: using %s / %s", plat.version, devs[0].name)
        return ctx
    names = ", ".join(p.name for p in found) or "none"
    why = ("; platforms that failed to compile a probe kernel: " + " | ".join(failures)
           if failures else "")
    raise NoDeviceError(f"no usable OpenCL CPU device (platforms: {names}){why}. "
                        f"{_INSTALL_HINT}{_other_devices_hint()}")


def _other_devices_hint() -> str:
    """How to choose a device that is not a CPU (never the default), naming those there
    are; empty where there are none."""
    # (Oclgrind, a simulator that calls itself a GPU, is never suggested)
    others = [r.name for r in _unprobed_devices()
              if not r.device.type & cl.device_type.CPU and "oclgrind" not in r.platform.lower()]
    if not others:
        return ""
    return (f" Devices that are not CPUs ({', '.join(others)}) are used only when chosen: "
            f"CLRASTER_DEVICE={others[0]!r} (any part of a platform or device name); they "
            f"give the same bytes, untuned for speed.")


def _probe_error(ctx: cl.Context) -> str | None:
    """None if ``ctx``'s device compiles the probe kernel, else the last line of the error
    (several PoCLs may be installed side by side, and an old one may be unable to target
    this CPU)."""
    try:
        with warnings.catch_warnings():   # a compiler's remarks on success are not ours
            warnings.simplefilter("ignore", cl.CompilerWarning)
            cl.Program(ctx, _PROBE_SRC).build()
    except cl.Error as exc:
        return str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
    return None


#: CLRASTER_DEVICE / ``device=`` short names → the platform-name substring they stand for
DEVICE_ALIASES = {"pocl": "portable computing language", "intel": "intel",
                  "oclgrind": "oclgrind"}


@dataclass(frozen=True)
class DeviceInfo:
    """One OpenCL device as `list_devices` sees it."""

    platform: str           #: platform name, e.g. "Portable Computing Language"
    platform_version: str   #: e.g. "OpenCL 3.0 PoCL 3.0-rc2 ... LLVM 14.0.6 ..."
    name: str               #: device name, e.g. "pthread-AMD EPYC"
    kind: str               #: "CPU", "GPU", "ACCELERATOR" or "OTHER"
    compile_error: str | None   #: None when the device compiled the probe kernel
    device: cl.Device       #: the pyopencl device itself (for ``Renderer(device=...)``)

    @property
    def compiles(self) -> bool:
        return self.compile_error is None

    @property
    def label(self) -> str:
        return f"{self.platform} / {self.name}"


def _kind(dev: cl.Device) -> str:
    t = dev.type
    for name in ("GPU", "CPU", "ACCELERATOR"):
        if t & getattr(cl.device_type, name):
            return name
    return "OTHER"


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device of every platform, in the ICD loader's order, each with whether
    it compiles a probe kernel (one small build per device; a broken device is listed with
    its error, never raised). Empty when there is no OpenCL platform at all."""
    check_process()
    rows = _unprobed_devices()
    if rows:
        mark_opencl_use()
    for k, r in enumerate(rows):
        try:
            error = _probe_error(cl.Context([r.device]))
        except cl.Error as exc:   # not even a context
            error = str(exc).strip() or repr(exc)
        rows[k] = dataclasses.replace(r, compile_error=error)
    return rows


def _unprobed_devices() -> list[DeviceInfo]:
    """Every device of every platform, named but not yet probed (``compile_error`` None
    until `list_devices` fills it in)."""
    try:
        found = platforms()
    except cl.Error:
        return []
    rows: list[DeviceInfo] = []
    for plat in found:
        try:
            devs = plat.get_devices()
        except cl.Error:
            continue
        rows.extend(DeviceInfo(plat.name.strip(), plat.version.strip(), dev.name.strip(),
                               _kind(dev), None, dev) for dev in devs)
    return rows


def _matches(spec: str, info: DeviceInfo) -> bool:
    s = spec.strip().lower()
    alias = DEVICE_ALIASES.get(s)
    if alias is not None:
        return alias in info.platform.lower()
    return s in info.platform.lower() or s in info.name.lower()


def find_device(spec: str, source: str = "device") -> cl.Device:
    """The first device (ICD order) whose platform or device name contains ``spec``
    (case-insensitive; ``pocl``, ``intel`` and ``oclgrind`` name their platforms) and that
    compiles a probe kernel.

    Raises:
        NoDeviceError: nothing matches, or nothing that matches compiles; the message lists
            every device there is (``source`` names where ``spec`` came from).
    """
    # only the devices that match are probed (a context and a build each): a runtime the
    # user did not ask for is never started (Oclgrind's LLVM, say, beside another LLVM
    # already in this process)
    hits = [r for r in _unprobed_devices() if _matches(spec, r)]
    for r in hits:
        try:
            if _probe_error(cl.Context([r.device])) is None:
                return r.device
        except cl.Error:
            continue
    rows = list_devices()   # the error lists everything, probed
    hits = [r for r in rows if _matches(spec, r)]
    listing = "; ".join(f"{r.label} ({r.kind}"
                        + ("" if r.compiles else f", does not compile: {r.compile_error}")
                        + ")" for r in rows) or "none"
    if hits:
        raise NoDeviceError(f"{source}={spec!r}: no matching device compiles the probe "
                            f"kernel; devices here: {listing}")
    why = _runtime_hint(spec)   # e.g. Intel's wheel installed without its dependencies
    raise NoDeviceError(f"{source}={spec!r} matches no OpenCL device (give 'pocl', 'intel', "
                        f"'oclgrind' or a part of a platform or device name); devices here: "
                        f"{listing}. {why + '. ' if why else ''}"
                        f"{_INSTALL_HINT if not rows else ''}".rstrip())


#: contexts made for ``device=`` choices, one per device: a Renderer made with the same
#: device again reuses its context and so its built programs (bounded by the devices there are)
_device_contexts: dict[int, cl.Context] = {}


def choose_context(device: str | cl.Device | None = None) -> tuple[cl.Context, str]:
    """(context, reason) for a renderer: ``device`` if given (a `find_device` name or a
    ``pyopencl.Device``), else `default_context`'s choice (CLRASTER_DEVICE, PYOPENCL_CTX,
    default), the reason saying which (module docstring).

    Raises:
        NoDeviceError: the choice matches no usable device.
        ForkedProcessError: OpenCL was started in the parent of this fork() child.
    """
    if device is None:
        ctx = default_context()
        return ctx, _default_choice()[1]
    check_process()
    if isinstance(device, cl.Device):
        dev, reason = device, "device=<pyopencl.Device>"
    elif isinstance(device, str) and device.strip():
        dev, reason = find_device(device, source="device"), f"device={device.strip()}"
    else:
        raise TypeError(f"device must be a device name or a pyopencl.Device, got {device!r}")
    mark_opencl_use()
    # a context this device already has (its programs are built): an earlier device=
    # choice's, else the default context when it exists and has this device
    default = _default_choice()[0] if _default_choice.cache_info().currsize else None
    with _lock:
        known = _device_contexts.get(dev.int_ptr)
        if known is None:
            known = (default if default is not None and default.devices[0] == dev
                     else cl.Context([dev]))
            _device_contexts[dev.int_ptr] = known
    return _warn_if_simulator(known, reason), reason


def describe_choice(ctx: cl.Context, reason: str) -> str:
    """One line: ``"<platform> / <device> (<reason>)"``."""
    dev = ctx.devices[0]
    return f"{dev.platform.name.strip()} / {dev.name.strip()} ({reason})"


#: Whether a context's device works in the memory of CL_MEM_USE_HOST_PTR buffers itself
#: (`shares_host_memory`), kept on the context object like its programs.
_SHARED_ATTR = "_clraster_shares_host_memory"


def shares_host_memory(ctx: cl.Context) -> bool:
    """True when the device of ``ctx`` keeps a CL_MEM_USE_HOST_PTR buffer in the host
    array itself, so that once a wait has seen the commands that wrote it complete, the
    array holds what they wrote, with no map or read command.

    PoCL's CPU drivers do (lib/CL/devices/common_driver.c: ``alloc_mem_obj`` makes the
    host pointer the device's pointer, and map/unmap copy nothing when the two are the
    same); OpenCL in general does not promise it, so it is probed once per context, both
    ways: a fill enqueued on such a buffer must show in its array without a map, and what
    the host then writes into the array must be what a copy command reads. Only a CPU
    device is asked: a GPU driver may work in the host array through the bus for one
    command and in a copy of its own for the next (NVIDIA's OpenCL on an H200 failed the
    host-memory tests with the path forced). Every map, unmap or
    read is a command of its own that PoCL's threads pick up one after another: the reads
    after a frame (the raster's counts, its three output maps, the bin summary, setup's
    flag) came back a measurable share of a small frame after the raster ended."""
    cached = getattr(ctx, _SHARED_ATTR, None)
    if cached is None:
        cached = _probe_shared(ctx)
        setattr(ctx, _SHARED_ATTR, cached)
    return bool(cached)


def _probe_shared(ctx: cl.Context) -> bool:
    if not ctx.devices[0].type & cl.device_type.CPU:
        return False
    arr = page_aligned(4096).view(np.uint32)
    arr[:] = 0
    mf = cl.mem_flags
    try:
        buf = cl.Buffer(ctx, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=arr)
        queue = cl.CommandQueue(ctx)
        cl.enqueue_fill_buffer(queue, buf, np.uint32(0xA5A5A5A5), 0, arr.nbytes)
        queue.finish()
        shared = bool(np.all(arr == 0xA5A5A5A5))
        # and the other way: the host's write is what the device reads next
        arr[:] = 0x5A5A5A5A
        seen = np.zeros_like(arr)
        other = cl.Buffer(ctx, mf.READ_WRITE, arr.nbytes)
        cl.enqueue_copy(queue, other, buf)
        cl.enqueue_copy(queue, seen, other)
        queue.finish()
        shared = shared and bool(np.all(seen == 0x5A5A5A5A))
        # the formal way too, so the implementation's own bookkeeping ends consistent
        mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, arr.shape,
                                          arr.dtype)
        mapped.base.release(queue)
        queue.finish()
    except cl.Error:
        return False
    return shared


#: Built programs live on their context object, per (stage, options): a pyopencl Program
#: keeps a reference to its Context, so any cache outside the context (a dict keyed by the
#: context, even weakly) kept every context alive — ~9 MB per Renderer made with its own
#: context (40 of them grew RSS by 360 MB). As an attribute, context → programs → context is
#: an ordinary reference cycle that the garbage collector frees with the context.
_CACHE_ATTR = "_clraster_programs"
_lock = threading.Lock()


def program(ctx: cl.Context, stage: str, options: tuple[str, ...]) -> cl.Program:
    """Built program for ``kernels/<stage>.cl``, cached per (context, stage, options) for as
    long as the context object lives."""
    check_process()
    mark_opencl_use()
    # argument info: `kernel` declares the scalar arguments' dtypes from it (PoCL gives
    # none for these programs without the option)
    # kernels/common.h: the Clang builtins the device's compiler lacks (or that
    # CLRASTER_FALLBACKS forces) take their portable fallbacks (clraster.pipeline.features)
    options = (*options, "-cl-kernel-arg-info", *feature_options(ctx),
               *precision_options(ctx.devices[0]))
    key = (stage, tuple(options))
    with _lock:
        per_ctx = getattr(ctx, _CACHE_ATTR, None)
        if per_ctx is None:
            per_ctx = {}
            setattr(ctx, _CACHE_ATTR, per_ctx)
        prg = per_ctx.get(key)
        if prg is None:
            prg = _build(ctx, stage, options)
            per_ctx[key] = prg
        return prg


def _build(ctx: cl.Context, stage: str, options: tuple[str, ...]) -> cl.Program:
    """Build ``kernels/<stage>.cl``; the compiler's log of a successful build goes to this
    module's logger (DEBUG), not to the user's stderr.

    A successful build's log is a compiler's business, not the user's: some compilers warn
    where nothing is wrong (LLVM 14 on CPUs it does not know warns that a double8 argument
    "changes the ABI" of a function that is always inlined), and pyopencl turns any log into
    a CompilerWarning, which a CLI or a notebook prints as noise. A failed build still raises
    with its full log."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", cl.CompilerWarning)
        prg = cl.Program(ctx, kernel_source(stage)).build(options=list(options))
    for w in caught:
        if issubclass(w.category, cl.CompilerWarning):
            logs = [prg.get_build_info(d, cl.program_build_info.LOG).strip()
                    for d in ctx.devices]
            log.debug("building %s.cl %s: %s", stage, " ".join(options),
                      "\n".join(x for x in logs if x) or w.message)
        else:   # anything else is not ours to hide
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return prg


#: OpenCL scalar type names (clGetKernelArgInfo) → the NumPy dtype pyopencl packs them as.
_SCALAR_DTYPES = {
    "char": np.int8, "uchar": np.uint8, "unsigned char": np.uint8,
    "short": np.int16, "ushort": np.uint16, "unsigned short": np.uint16,
    "int": np.int32, "uint": np.uint32, "unsigned int": np.uint32,
    "long": np.int64, "ulong": np.uint64, "unsigned long": np.uint64,
    "float": np.float32, "double": np.float64,
}


def kernel(prg: cl.Program, name: str) -> cl.Kernel:
    """Kernel ``name`` of ``prg``, with its scalar arguments' dtypes declared.

    pyopencl sets an undeclared scalar argument (a NumPy scalar) through a generic path that
    costs ~20 times a buffer argument's, and a frame launches kernels of up to a dozen
    scalars 7 or more times. With the dtypes declared (``set_scalar_arg_dtypes``, read here
    from the kernel's argument info so they cannot drift from the source) pyopencl packs
    them in one generated call, an order of magnitude cheaper (bench/host_overhead.py).
    Where the platform gives no argument info, the kernel is returned undeclared (slower,
    same results). Callers pass scalars as NumPy scalars of the kernel's types, as before.
    """
    k = cl.Kernel(prg, name)
    dtypes = scalar_arg_dtypes(k)
    if dtypes is not None:
        try:
            # what set_scalar_arg_dtypes does, with the generated functions kept per
            # signature in this process: pyopencl looks them up in its on-disk cache for
            # every kernel object (no in-memory cache), and a process making a renderer
            # with its own context 40 times grew by 46 MB (tests/test_processes.py)
            k._set_enqueue_and_set_args(  # type: ignore[attr-defined]  # pyopencl's, private
                *_invoker(k.function_name, k.num_args, tuple(dtypes)))
        except (AttributeError, ImportError, TypeError):   # another pyopencl's internals
            k.set_scalar_arg_dtypes(dtypes)
    return k


@functools.cache
def _invoker(function_name: str, num_args: int, dtypes: tuple) -> tuple:
    """pyopencl's generated (enqueue, set_args) pair for a kernel signature (`kernel`)."""
    from pyopencl.invoker import generate_enqueue_and_set_args

    return generate_enqueue_and_set_args(function_name, num_args, num_args, dtypes,
                                         work_around_arg_count_bug=False,
                                         warn_about_arg_count_bug=False, devs=())


def scalar_arg_dtypes(k: cl.Kernel) -> list | None:
    """Per argument of ``k``: the NumPy dtype of a scalar argument, None for a pointer or a
    by-value type not listed in _SCALAR_DTYPES (pyopencl's generic path, as undeclared);
    None altogether when the platform gives no argument info (e.g. a program built from a
    binary)."""
    try:
        dtypes = []
        for i in range(k.num_args):
            type_name = str(k.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME)).strip()
            pointer = type_name.endswith("*") or (
                k.get_arg_info(i, cl.kernel_arg_info.ADDRESS_QUALIFIER)
                != cl.kernel_arg_address_qualifier.PRIVATE)
            dtypes.append(None if pointer else _SCALAR_DTYPES.get(type_name))
    except cl.Error:
        return None
    return dtypes


def clear_program_cache(ctx: cl.Context) -> None:
    """Forget the programs built for ``ctx`` (the next `program` call rebuilds them)."""
    with _lock:
        if hasattr(ctx, _CACHE_ATTR):
            delattr(ctx, _CACHE_ATTR)


#: (marker event, objects the device may still write) of waits that were interrupted: OpenCL
#: cannot cancel a running kernel, so host memory it writes (USE_HOST_PTR frame arrays) must
#: outlive it — freeing it as the exception unwinds let the kernel write into freed memory
#: (a segfault after Ctrl-C). Pruned as the events complete.
_in_flight: list[tuple[cl.Event, object]] = []


def abandon(queue: cl.CommandQueue, keep: object) -> None:
    """After an exception that left work enqueued on ``queue`` (an interrupted wait, an
    error between two launches): keep ``keep`` — the objects owning host memory that work
    may still read or write (host-mode buffers, frame arrays) — alive until everything
    enqueued so far has run (a marker in the in-flight list, `device_busy`)."""
    try:
        ev = cl.enqueue_marker(queue)
        queue.flush()
    except cl.Error:   # a broken queue: nothing more will run on it
        return
    _in_flight.append((ev, keep))


def device_busy() -> bool:
    """True while work abandoned by an interrupted `wait` may still be running."""
    _in_flight[:] = [(ev, keep) for ev, keep in _in_flight
                     if ev.command_execution_status > 0]   # queued/submitted/running
    return bool(_in_flight)


#: Sleeps (s) between the first status polls of `wait`, before it hands the wait over to
#: the calling thread's waiter (`_Waiter`).
_SHORT_POLLS = (2e-5, 4e-5, 4e-5)


class _Waiter:
    """A helper thread of one calling thread that blocks in OpenCL's own wait
    (``Event.wait``: clWaitForEvents, GIL released) on the markers `wait` gives it and sets
    each marker's `threading.Event` when it returns, so that the calling thread can wait in
    interruptible slices and still wake as soon as the device is done.

    One per calling thread (`_waiter`): a waiter shared by two renderers in two threads
    would keep one's wait behind the other's frame. It ends with its thread (`__del__`,
    when the thread's locals go) and is made again in a forked child (a thread does not
    survive fork)."""

    def __init__(self) -> None:
        self.pid = os.getpid()
        self.jobs: queue_mod.SimpleQueue = queue_mod.SimpleQueue()
        self.last: threading.Event | None = None   # the Event of the last marker given
        threading.Thread(target=self._run, args=(self.jobs,), daemon=True,
                         name="clraster-wait").start()
        _all_waiters.add(self)

    @property
    def busy(self) -> bool:
        """Still waiting for a marker: one whose wait was interrupted (the device goes on
        with the abandoned work)."""
        return self.last is not None and not self.last.is_set()

    def submit(self, ev: cl.Event, done: threading.Event) -> None:
        self.last = done
        self.jobs.put((ev, done))

    @staticmethod
    def _run(jobs: queue_mod.SimpleQueue) -> None:
        while True:
            job = jobs.get()
            if job is None:
                return
            ev, done = job
            try:
                ev.wait()
            except Exception:   # a failed command: the calling thread raises (`wait`)
                pass
            done.set()

    def __del__(self) -> None:
        if self.pid == os.getpid():
            self.jobs.put(None)


_waiters = threading.local()
#: Every `_Waiter` of this process, for `_drain_waiters` at exit.
_all_waiters: weakref.WeakSet = weakref.WeakSet()


def _drain_waiters() -> None:
    """At interpreter exit (atexit): wait until no waiter thread is inside OpenCL's wait.

    A daemon thread that wakes from ``Event.wait`` (clWaitForEvents, in pyopencl's C++
    with the GIL released) while the interpreter is finalizing is stopped as it takes the
    GIL back, from inside a C++ destructor that may not throw, and the process aborts
    ("terminate called without an active exception"): seen when Ctrl-C ended `clraster
    render` just as a frame's wait was ending (tests/test_processes.py), and whenever a
    script exited while the device still ran work a waiter was waiting for. Here the
    interpreter is still whole: the waiters finish their waits (the device runs what it
    was given) and go back to their queue, where finalization stops them harmlessly.
    `clraster.cli` leaves with os._exit while work is in flight, so it does not wait."""
    for w in list(_all_waiters):
        if w.pid == os.getpid() and w.last is not None:
            w.last.wait()


atexit.register(_drain_waiters)


def _waiter() -> _Waiter:
    """The calling thread's `_Waiter`: made on first use, again after a fork, and again when
    the last one is still blocked on an abandoned marker (a wait on another queue would
    otherwise wait behind it; the old one ends once that marker is done). Raises
    RuntimeError where no thread can be started (interpreter shutdown)."""
    w = getattr(_waiters, "waiter", None)
    if w is None or w.pid != os.getpid() or w.busy:
        if w is not None and w.pid == os.getpid():
            w.jobs.put(None)
        w = _waiters.waiter = _Waiter()
    return w


def wait(queue: cl.CommandQueue, keep: object = None) -> None:
    """Block until everything enqueued on ``queue`` has run, interruptibly.

    ``keep``: host memory the enqueued commands use (e.g. the frame's arrays); if the wait
    is interrupted, it is kept alive until the device is done with it.

    ``queue.finish()`` waits inside one C call: the GIL is released, but Python runs its
    signal handlers only when the call returns, so Ctrl-C during a long frame took effect
    only at the frame's end (16 s late in a 19 s frame). Instead: a few status polls
    over the first ~100 µs (`_SHORT_POLLS`), then this thread's `_Waiter` blocks in
    OpenCL's wait on a marker and sets a `threading.Event` that this thread waits on in
    50 ms slices: a lock wait sleeps with the GIL free, takes no core from PoCL's threads
    and is interrupted by signals, so KeyboardInterrupt gets through at once (the waiter
    goes on waiting for the abandoned marker).

    Why not the alternatives: polling the status with sleeps wakes up on the kernels' cores
    and returns up to a sleep late; a marker's completion callback (pyopencl runs callbacks
    through a thread of its own) returned later than this waiter. The measurements are in
    bench/README.md's performance log.
    """
    ev = cl.enqueue_marker(queue)
    queue.flush()
    complete = cl.command_execution_status.COMPLETE
    try:
        for delay in _SHORT_POLLS:   # a short wait is cheaper polled than handed over
            if ev.command_execution_status == complete:
                return
            time.sleep(delay)
        done = threading.Event()
        try:
            _waiter().submit(ev, done)   # done is set when the marker completes or fails
            slice_s = 0.05
        except RuntimeError:   # no thread can start (interpreter shutdown): poll
            slice_s = 0.001
        while not done.wait(slice_s):
            # a safety net: should the waiter never return, the status is polled every 50 ms
            if ev.command_execution_status <= complete:   # complete (0) or failed (< 0)
                break
        if ev.command_execution_status > complete:
            # should the runtime's wait return (or fail) with the marker neither complete
            # nor failed, returning would hand the caller buffers the device still writes:
            # poll instead, in short sleeps that a signal interrupts
            log.debug("device wait returned before its marker completed; polling")
            while ev.command_execution_status > complete:
                time.sleep(0.002)
        if ev.command_execution_status < 0:   # the command failed: let pyopencl raise
            ev.wait()
    except BaseException:   # KeyboardInterrupt: the device goes on regardless
        _in_flight.append((ev, keep))
        raise


_START, _END = cl.profiling_info.START, cl.profiling_info.END


def event_ms(events) -> float:
    """Sum of the device execution times of profiling ``events`` (None entries skipped), in
    milliseconds; the queue must have been made with PROFILING_ENABLE. (Read with
    ``get_profiling_info``: pyopencl's ``event.profile.end`` goes through a Python
    attribute lookup that took ~7 µs an event with the caches cold, ~0.1 ms a frame.)"""
    return sum(e.get_profiling_info(_END) - e.get_profiling_info(_START)
               for e in events if e is not None) * 1e-6
