"""Description of the machine a benchmark ran on (recorded in every results.json).

`describe()` never raises: a part it cannot find is recorded as None (or with the error),
because a benchmark must still run on a machine that lacks, say, git or /proc.
"""

from __future__ import annotations

import os
import platform
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["describe", "summary"]


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text(errors="replace")
    except OSError:
        return None


def _cpu_model() -> str | None:
    text = _read("/proc/cpuinfo")
    if text:
        for key in ("model name", "Hardware", "cpu model"):
            m = re.search(rf"^{key}\s*:\s*(.+)$", text, re.M)
            if m:
                return m.group(1).strip()
    return platform.processor() or platform.machine() or None


def _ram_gib() -> float | None:
    text = _read("/proc/meminfo")
    if text:
        m = re.search(r"^MemTotal:\s*(\d+)\s*kB", text, re.M)
        if m:
            return round(int(m.group(1)) / 2**20, 1)
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        return None


def _os_release() -> str | None:
    text = _read("/etc/os-release")
    if text:
        m = re.search(r'^PRETTY_NAME="?([^"\n]+)"?', text, re.M)
        if m:
            return m.group(1)
    return None


def _version(module: str) -> str | None:
    try:
        from importlib.metadata import version

        return version(module)
    except Exception:  # not installed, or no metadata
        return None


def _git(repo: Path) -> dict[str, Any]:
    def run(*args: str) -> str | None:
        try:
            p = subprocess.run(["git", "-C", str(repo), *args], capture_output=True,
                               text=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return p.stdout.strip() if p.returncode == 0 else None

    commit = run("rev-parse", "HEAD")
    if commit is None:
        return {"commit": None, "dirty": None, "branch": None}
    status = run("status", "--porcelain", "--untracked-files=no")
    return {"commit": commit, "dirty": bool(status), "branch": run("rev-parse",
                                                                   "--abbrev-ref", "HEAD")}


def _opencl() -> dict[str, Any]:
    try:
        from clraster.pipeline.device import choose_context

        ctx, reason = choose_context()
        dev = ctx.devices[0]
        plat = dev.platform
    except Exception as exc:  # no device: the benchmark will fail later with the reason
        return {"error": f"{type(exc).__name__}: {exc}"}
    info: dict[str, Any] = {
        "platform": plat.name.strip(), "platform_version": plat.version.strip(),
        "device": dev.name.strip(), "device_version": dev.version.strip(),
        "driver_version": dev.driver_version.strip(),
        "compute_units": int(dev.max_compute_units),
        "global_mem_gib": round(dev.global_mem_size / 2**30, 1),
        # why this device (clraster bench --device, CLRASTER_DEVICE, PYOPENCL_CTX or the
        # default rule)
        "device_choice": reason,
        # the compiler builtins whose portable fallbacks this device's kernels use
        # (clraster.pipeline.features; same results, maybe slower)
        "kernel_fallbacks": _fallbacks(ctx),
    }
    # PoCL names its LLVM in the platform version ("... LLVM 15.0.6, RELOC, ...").
    m = re.search(r"LLVM\s+([\d.]+)", plat.version)
    info["pocl_llvm"] = m.group(1) if m else None
    return info


def _fallbacks(ctx: Any) -> list[str] | str:
    try:
        from clraster.pipeline.features import feature_options

        return [o.removeprefix("-D") for o in feature_options(ctx)]
    except Exception as exc:  # recorded, never raised (module docstring)
        return f"{type(exc).__name__}: {exc}"


def describe(repo: str | Path | None = None, peer_renderer: str | None = None
             ) -> dict[str, Any]:
    """The machine and software stack as a JSON-ready dict.

    Args:
        repo: git working tree whose commit (and dirty flag) to record; default the
            repository this file lives in.
        peer_renderer: the GL renderer string the llvmpipe peer reported (e.g.
            "llvmpipe (LLVM 15.0.6, 256 bits)"), when it ran.
    """
    repo = Path(repo) if repo is not None else Path(__file__).resolve().parents[2]
    uname = platform.uname()
    return {
        "cpu": _cpu_model(),
        "cores_logical": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
        else os.cpu_count(),
        "ram_gib": _ram_gib(),
        "os": _os_release() or f"{uname.system} {uname.release}",
        "kernel": f"{uname.system} {uname.release}",
        "arch": uname.machine,
        "python": sys.version.split()[0],
        "numpy": _version("numpy"),
        "pyopencl": _version("pyopencl"),
        "moderngl": _version("moderngl"),
        "matplotlib": _version("matplotlib"),
        "clraster": _version("clraster"),
        "opencl": _opencl(),
        "llvmpipe": peer_renderer,
        "git": _git(repo),
    }


def summary(d: dict[str, Any]) -> str:
    """One paragraph for the top of results.md."""
    cl = d.get("opencl") or {}
    git = d.get("git") or {}
    commit = (git.get("commit") or "unknown")[:12] + (" (dirty)" if git.get("dirty") else "")
    dev = (f"{cl.get('platform_version')} / {cl.get('device')} "
           f"(chosen by {cl.get('device_choice')})" if "device" in cl
           else f"no OpenCL device ({cl.get('error')})")
    return (f"{d.get('cpu')} ({d.get('cores_usable')} usable of {d.get('cores_logical')} "
            f"logical cores), {d.get('ram_gib')} GiB RAM; {d.get('os')}, {d.get('kernel')}; "
            f"Python {d.get('python')}, NumPy {d.get('numpy')}, pyopencl {d.get('pyopencl')}; "
            f"OpenCL: {dev}; llvmpipe: {d.get('llvmpipe') or 'not run'}; "
            f"clraster commit {commit}.")
