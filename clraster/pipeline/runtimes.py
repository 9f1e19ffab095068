"""OpenCL runtimes installed as Python wheels, made visible to pyopencl's ICD loader.

``pip install clraster[intel]`` installs Intel's OpenCL CPU runtime (``intel-opencl-rt``,
with ``intel-cmplr-lib-rt`` for libimf, libsvml, libirng and libintlc, and ``tbb``); it runs
on AMD CPUs too. The wheels put their libraries in ``<prefix>/lib`` and an ICD file in
``<prefix>/etc/OpenCL/vendors`` whose path is the package build's (``/opt/anaconda1...``), so
no loader would find it as installed. `register_wheel_runtimes` does that set-up, once per
process, before clraster's first OpenCL call (`clraster.pipeline.device` calls it on import):

1. find ``libintelocl.so`` through the wheel's file list (``importlib.metadata``), in a
   virtual environment, a user or a system install alike;
2. make its dependencies loadable: the wheels' libraries carry ``RUNPATH $ORIGIN``, so
   those beside it need nothing; one found only in another prefix (the compiler runtime
   installed elsewhere, say) is loaded first with ctypes (`_preload`): the dynamic linker
   matches a library already in the process by its soname, which ``LD_LIBRARY_PATH`` cannot
   do once the process runs;
3. make an ICD visible: pyopencl's bundled ICD loader (ocl-icd) reads the ``.icd`` files of
   one folder — ``OCL_ICD_VENDORS`` if set, else ``OPENCL_VENDOR_PATH``, else
   ``/etc/OpenCL/vendors`` — plus, in pyopencl's wheels, its own ``pyopencl/.libs`` (where
   the pip PoCL and Oclgrind put theirs). System files are never edited: a folder in the
   user's cache (`cache_root`) gets a copy of every ``.icd`` file of the folder the loader
   would have read and one naming ``libintelocl.so`` by its absolute path, and
   ``OCL_ICD_VENDORS`` is pointed at it. The pip PoCL, Oclgrind and a distribution's
   PoCL stay visible; child processes inherit the same list.

``OCL_ICD_VENDORS`` naming a single ``.icd`` file means "load only that one" (e.g. the
distribution's PoCL alone); it is respected and nothing is added. ``CLRASTER_WHEEL_RUNTIMES=0``
turns the registration off (Intel's runtime costs ~60 ms and ~100 MB of mappings in every
process that lists the OpenCL platforms). The loader reads its environment at the first
OpenCL call of the process: a program that lists platforms before it imports
clraster.pipeline.device does not see the runtime. `wheel_runtimes` says what was found,
registered or missing, and why (``clraster devices`` and a failed ``CLRASTER_DEVICE=intel``
print it).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger("clraster.device")

__all__ = ["WheelRuntime", "cache_root", "register_wheel_runtimes", "wheel_runtimes"]

#: the extra that installs the runtimes, for messages
INSTALL = "pip install 'clraster[intel]'"

#: Intel's runtime: its library, and the libraries it needs from other wheels, in an order
#: in which each one's own dependencies come first (libintlc is needed by the other three)
#: with the distribution that provides each.
INTEL_LIBRARY = "libintelocl.so"
INTEL_DISTRIBUTION = "intel-opencl-rt"
INTEL_NEEDS = (("libintlc.so.5", "intel-cmplr-lib-rt"), ("libimf.so", "intel-cmplr-lib-rt"),
               ("libsvml.so", "intel-cmplr-lib-rt"), ("libirng.so", "intel-cmplr-lib-rt"),
               ("libtbb.so.12", "tbb"))

#: the ICD file clraster writes for Intel's runtime in its vendors folder
ICD_NAME = "clraster-intel-cpu.icd"
#: where a folder made by clraster records the folder it copied (for a child process that
#: inherits OCL_ICD_VENDORS pointing at it)
_SOURCE_NAME = "SOURCE"
_SYSTEM_VENDORS = "/etc/OpenCL/vendors"


class RuntimeSetupError(RuntimeError):
    """An installed wheel runtime could not be made usable (its message says what is
    missing); `register_wheel_runtimes` records it instead of raising."""


@dataclass(frozen=True)
class WheelRuntime:
    """What `register_wheel_runtimes` found for one wheel runtime."""

    name: str                     #: the CLRASTER_DEVICE alias, e.g. "intel"
    distribution: str             #: the wheel, e.g. "intel-opencl-rt"
    installed: bool               #: the wheel's metadata is there
    library: Path | None          #: the ICD library (libintelocl.so), when found
    registered: bool              #: the ICD loader will see it (this process and children)
    problem: str | None = None    #: why not, and what to do
    preloaded: tuple[str, ...] = ()   #: dependencies loaded from another prefix first
    vendors: str | None = None    #: the folder OCL_ICD_VENDORS names for it (None: unchanged)

    def describe(self) -> str:
        """One line for ``clraster devices`` and errors."""
        if self.registered:
            return f"{self.name}: {self.library} ({self.distribution}) registered"
        return f"{self.name} ({self.distribution}): {self.problem}"


def cache_root() -> Path:
    """The folder of clraster's generated ICD folders: ``$XDG_CACHE_HOME/clraster/opencl``
    (``~/.cache/clraster/opencl``), or one in the temporary folder where that cannot be
    written."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    for root in (Path(base) / "clraster" / "opencl",
                 Path(tempfile.gettempdir()) / f"clraster-{os.getuid()}" / "opencl"):
        try:
            root.mkdir(parents=True, exist_ok=True)
            if os.access(root, os.W_OK):
                return root
        except OSError:
            continue
    raise RuntimeSetupError("no writable cache folder for the generated ICD file (tried "
                            f"{base}/clraster/opencl and the temporary folder)")


def _distribution_file(distribution: str, name: str) -> Path | None:
    """The installed file ``name`` (a file name, or a prefix ending in ``*``) of
    ``distribution``, from its file list; None when either is not there."""
    from importlib import metadata

    # every copy on sys.path in order (a stray unpacked wheel may shadow the installed one)
    for dist in metadata.distributions(name=distribution):
        for f in dist.files or []:
            fname = Path(str(f)).name
            if fname == name or (name.endswith("*") and fname.startswith(name[:-1])):
                path = Path(str(dist.locate_file(f))).resolve()
                if path.is_file():
                    return path
    return None


def _installed(distribution: str) -> bool:
    from importlib import metadata

    try:
        metadata.distribution(distribution)
    except metadata.PackageNotFoundError:
        return False
    return True


def _preload(path: Path) -> None:
    """Load a shared library into the process (RTLD_LOCAL: its symbols serve only the
    libraries that name it, never interpose on libm's for anyone else), so that a later
    dlopen of a library that needs it by soname finds it loaded. Raises OSError."""
    ctypes.CDLL(str(path), mode=os.RTLD_LAZY | os.RTLD_LOCAL)


def _dependencies(lib_dir: Path, needs: tuple[tuple[str, str], ...]) -> tuple[str, ...]:
    """Make each of ``needs`` (soname, distribution) loadable for a library in ``lib_dir``
    (RUNPATH $ORIGIN): nothing where it lies beside it; else the distribution's copy, or
    the system's (ld.so.conf), loaded now. Returns what was loaded. Raises
    RuntimeSetupError naming every library that is nowhere, with the wheel it comes from."""
    loaded, missing = [], []
    for soname, dist in needs:
        if (lib_dir / soname).is_file():
            continue
        path = _distribution_file(dist, soname)
        try:
            _preload(path if path is not None else Path(soname))
        except OSError as exc:
            missing.append((soname, dist, str(exc)))
            continue
        loaded.append(str(path) if path is not None else soname)
    if missing:
        names = ", ".join(s for s, _, _ in missing)
        dists = sorted({d for _, d, _ in missing})
        raise RuntimeSetupError(
            f"{names} not found (neither beside {lib_dir} nor installed elsewhere; they come "
            f"from the {' and '.join(dists)} wheel{'s' if len(dists) > 1 else ''}): "
            f"{INSTALL}, or pip install {' '.join(dists)}")
    return tuple(loaded)


def _icd_files(folder: Path) -> dict[str, str]:
    """The ``.icd`` files of ``folder`` (name → text); empty when it is not a folder."""
    try:
        return {p.name: p.read_text(errors="replace") for p in sorted(folder.glob("*.icd"))
                if p.is_file()}
    except OSError:
        return {}


def _loader_source() -> Path:
    """The folder of .icd files pyopencl's loader would read now (module docstring); for a
    folder clraster made, the folder that one copied."""
    env = os.environ.get("OCL_ICD_VENDORS") or os.environ.get("OPENCL_VENDOR_PATH")
    folder = Path(env) if env else Path(_SYSTEM_VENDORS)
    src = folder / _SOURCE_NAME
    if src.is_file():
        try:
            return Path(src.read_text().strip())
        except OSError:
            pass
    try:
        root = cache_root()
    except RuntimeSetupError:
        return folder
    if folder.parent == root and not folder.is_dir():   # ours, since removed
        return Path(_SYSTEM_VENDORS)
    return folder


def _write_vendors(source: Path, icds: dict[str, str]) -> Path:
    """A folder under `cache_root` holding ``icds``, named by a hash of its contents (so
    concurrent processes agree on it and never see it half written: each file is renamed
    into place)."""
    h = hashlib.sha256(str(source).encode())
    for name in sorted(icds):
        h.update(f"\0{name}\0{icds[name]}".encode())
    folder = cache_root() / h.hexdigest()[:20]
    want = {**icds, _SOURCE_NAME: f"{source}\n"}
    if folder.is_dir() and all((folder / n).is_file() for n in want):
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in want.items():
        tmp = folder / f".{name}.{os.getpid()}.tmp"
        tmp.write_text(text)
        os.replace(tmp, folder / name)
    return folder


def _intel(**fields: Any) -> WheelRuntime:
    return WheelRuntime("intel", INTEL_DISTRIBUTION, **fields)


def _register_intel() -> WheelRuntime:
    if not _installed(INTEL_DISTRIBUTION):
        return _intel(installed=False, library=None, registered=False,
                      problem=f"not installed ({INSTALL})")
    lib = _distribution_file(INTEL_DISTRIBUTION, INTEL_LIBRARY)
    if lib is None:
        return _intel(installed=True, library=None, registered=False,
                      problem=f"the wheel is installed but its {INTEL_LIBRARY} is not there "
                              f"(reinstall: pip install --force-reinstall "
                              f"{INTEL_DISTRIBUTION})")
    vendors = os.environ.get("OCL_ICD_VENDORS", "")
    if vendors and not Path(vendors).is_dir() and Path(vendors).exists():
        return _intel(installed=True, library=lib, registered=False,
                      problem=f"OCL_ICD_VENDORS={vendors} names one ICD, and the loader then "
                              f"loads only that one: unset it (or name a folder) to let "
                              f"clraster add Intel's runtime")
    try:
        preloaded = _dependencies(lib.parent, INTEL_NEEDS)
        source = _loader_source()
        icds = _icd_files(source)
        if any(text.strip() == str(lib) for text in icds.values()):   # listed there already
            return _intel(installed=True, library=lib, registered=True, preloaded=preloaded)
        folder = _write_vendors(source, {**icds, ICD_NAME: f"{lib}\n"})
    except (RuntimeSetupError, OSError) as exc:
        return _intel(installed=True, library=lib, registered=False, problem=str(exc))
    os.environ["OCL_ICD_VENDORS"] = str(folder)
    log.debug("Intel's OpenCL runtime %s: OCL_ICD_VENDORS=%s (copied from %s)%s", lib,
              folder, source, f"; preloaded {', '.join(preloaded)}" if preloaded else "")
    return _intel(installed=True, library=lib, registered=True, preloaded=preloaded,
                  vendors=str(folder))


@functools.cache
def register_wheel_runtimes() -> tuple[WheelRuntime, ...]:
    """Make the wheel runtimes visible to the ICD loader (module docstring), once per
    process; never raises (a runtime that cannot be set up is returned with its problem)."""
    if os.environ.get("CLRASTER_WHEEL_RUNTIMES", "1") == "0":
        return ()
    try:
        return (_register_intel(),)
    except Exception as exc:   # never break clraster's other runtimes over this one
        log.debug("setting up Intel's OpenCL runtime failed", exc_info=True)
        return (WheelRuntime("intel", INTEL_DISTRIBUTION, True, None, False,
                             f"set-up failed: {type(exc).__name__}: {exc}"),)


def wheel_runtimes() -> tuple[WheelRuntime, ...]:
    """The wheel runtimes' state (registering them first if that has not happened)."""
    return register_wheel_runtimes()


def hint(spec: str) -> str | None:
    """Why a device name that names a wheel runtime (``intel``) finds no device: the
    runtime's problem, or None."""
    s = spec.strip().lower()
    for rt in wheel_runtimes():
        if s == rt.name and not rt.registered:
            return f"Intel's OpenCL CPU runtime: {rt.problem}"
        if s == rt.name and rt.library is not None:
            try:   # registered, yet the loader lists no such platform: say why it fails
                _preload(rt.library)
            except OSError as exc:
                return f"Intel's OpenCL CPU runtime {rt.library} does not load: {exc}"
    return None
