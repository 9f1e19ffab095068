"""OpenCL context selection and the program cache.

Device choice: ``PYOPENCL_CTX`` is honoured when set (pyopencl's own syntax, e.g. ``0`` or
``"Portable"``); otherwise the first PoCL CPU device. We never call
``create_some_context()`` blindly: with Oclgrind installed it may pick the *simulator*
first, which is ~1000× slower.

Programs are built once per (context, stage, build options) and cached here; PoCL also keeps
compiled binaries on disk, so a second process skips the LLVM compile (cold vs warm start).
"""

from __future__ import annotations

import functools
import logging
import os
import re
import threading
from pathlib import Path

import pyopencl as cl

log = logging.getLogger(__name__)

_INSTALL_HINT = (
    "clraster needs an OpenCL CPU platform. `pip install pocl-binary-distribution` gives one "
    "with no system packages (it is a dependency of clraster). Its LLVM 14 cannot compile for "
    "CPUs newer than it knows (e.g. AMD Zen 5: 'unknown target CPU generic'); there, install "
    "a newer PoCL, e.g. Debian/Ubuntu `apt-get install pocl-opencl-icd`, which clraster picks "
    "up automatically. Or set PYOPENCL_CTX to choose a platform yourself."
)

_PROBE_SRC = "__kernel void probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"


class NoDeviceError(RuntimeError):
    """No usable OpenCL platform/device could be found."""


def kernel_dir() -> Path:
    """Directory holding the OpenCL sources (installed wheel: clraster/kernels)."""
    here = Path(__file__).resolve().parent
    for cand in (here / "kernels", here.parent / "kernels"):
        if (cand / "common.h").is_file():
            return cand
    raise FileNotFoundError(f"OpenCL kernels not found next to {here}; reinstall clraster")


@functools.cache
def kernel_source(stage: str) -> str:
    """Source of ``kernels/<stage>.cl`` with ``#include "common.h"`` inlined.

    Inlining (rather than ``-I``) keeps every cache keyed on the full text, so an edited
    header can never be served from a stale binary.
    """
    kdir = kernel_dir()
    text = (kdir / f"{stage}.cl").read_text()
    header = (kdir / "common.h").read_text()
    return re.sub(r'^#include "common\.h"\s*$', lambda _m: header, text, flags=re.M)


@functools.lru_cache(maxsize=1)
def default_context() -> cl.Context:
    """The context clraster uses when none is given (see module docstring); made once."""
    if os.environ.get("PYOPENCL_CTX"):
        try:
            return cl.create_some_context(interactive=False)
        except Exception as exc:  # pyopencl raises several types here
            raise NoDeviceError(f"PYOPENCL_CTX={os.environ['PYOPENCL_CTX']!r} did not select "
                                f"a device ({exc}). {_INSTALL_HINT}") from exc
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        raise NoDeviceError(f"no OpenCL platform found ({exc}). {_INSTALL_HINT}") from exc
    # PoCL first; never the Oclgrind simulator. A platform is used only if it can actually
    # compile a kernel: several PoCLs may be installed side by side and an old one may be
    # unable to target this CPU.
    ordered = sorted(platforms, key=lambda p: "portable computing" not in p.name.lower())
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
        try:
            cl.Program(ctx, _PROBE_SRC).build()
        except cl.Error as exc:
            first = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
            failures.append(f"{plat.version}: {first}")
            continue
        log.debug("clraster: using %s / %s", plat.version, devs[0].name)
        return ctx
    names = ", ".join(p.name for p in platforms) or "none"
    why = ("; platforms that failed to compile a probe kernel: " + " | ".join(failures)
           if failures else "")
    raise NoDeviceError(f"no usable OpenCL CPU device (platforms: {names}){why}. "
                        f"{_INSTALL_HINT}")


_programs: dict[tuple[int, str, tuple[str, ...]], cl.Program] = {}
_lock = threading.Lock()


def program(ctx: cl.Context, stage: str, options: tuple[str, ...]) -> cl.Program:
    """Built program for ``kernels/<stage>.cl``, cached per (context, stage, options)."""
    if "portable computing language" not in ctx.devices[0].platform.name.lower():
        # kernels/common.h: Clang builtins only where PoCL compiles them (not Oclgrind)
        options = (*options, "-DCLRASTER_PORTABLE")
    key = (ctx.int_ptr, stage, tuple(options))
    with _lock:
        prg = _programs.get(key)
        if prg is None:
            prg = cl.Program(ctx, kernel_source(stage)).build(options=list(options))
            _programs[key] = prg
        return prg
