"""Portability: the compiler-feature probes and their fallbacks (clraster.pipeline.features),
work-group sizes from device limits, and the wheel runtimes' set-up
(clraster.pipeline.runtimes: Intel's CPU runtime from ``pip install clraster[intel]``).

The golden hashes with fallbacks forced are in tests/test_golden.py. The Intel tests that
need the wheel skip, saying so, where it is not installed; CI installs it (.ci/run).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from clraster.pipeline import features, runtimes
from clraster.pipeline.device import default_context

ROOT = Path(__file__).resolve().parent.parent


def _python(code: str, env: dict[str, str] | None = None, timeout: float = 120
            ) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter (the ICD loader reads its environment once per
    process, so registration is tested where no OpenCL call came first)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)


# -- compiler features ------------------------------------------------------------------------

@pytest.fixture
def fresh_probes(monkeypatch, tmp_path):
    """An empty in-process probe cache and a cache folder of this test's own."""
    monkeypatch.setattr(features, "_probed", {})
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))


def test_probe_rejects_a_feature_that_computes_wrong(fresh_probes, monkeypatch):
    """A builtin that builds but gives other values than expected is not used: here
    `rintf`'s probe expects truncation, which rint on 2.5, 3.7... does not give."""
    wrong = features.Feature("rintf", features.FEATURES["rintf"].body,
                             lambda: (np.trunc(features._F_IN[:8]), np.zeros(0, np.int32)))
    monkeypatch.setitem(features.FEATURES, "rintf", wrong)
    have = features.compiler_features(default_context())
    assert "rintf" not in have
    # the rest were probed one by one after the combined program disagreed
    assert "-DCLRASTER_NO_RINTF" in features.feature_options(default_context())


def test_probe_survives_a_feature_that_does_not_build(fresh_probes, monkeypatch):
    bad = features.Feature("ctz", "io[0] = __builtin_no_such_thing_at_all(ii[0]);",
                           features.FEATURES["ctz"].expect)
    monkeypatch.setitem(features.FEATURES, "ctz", bad)
    ctx = default_context()
    have = features.compiler_features(ctx)
    assert "ctz" not in have
    # the others are judged on their own (a device that has rint gets it)
    monkeypatch.setattr(features, "_probed", {})
    monkeypatch.setitem(features.FEATURES, "ctz", features.Feature(
        "ctz", "io[0] = ii[0];", lambda: (np.zeros(0, np.float32), features._I_IN[:1])))
    assert "ctz" in features.compiler_features(ctx)


def test_probe_answer_is_kept_on_disk(fresh_probes, tmp_path):
    ctx = default_context()
    first = features.compiler_features(ctx)
    files = list((tmp_path / "clraster" / "opencl").glob("features-*"))
    assert len(files) == 1
    assert set(files[0].read_text().strip().split(",")) - {""} == set(first)
    files[0].write_text("rintf\n")   # a later process believes the file
    features._probed.clear()
    assert features.compiler_features(ctx) == {"rintf"}
    files[0].write_text("rintf,no_such_feature\n")   # a file it cannot trust is probed anew
    features._probed.clear()
    assert features.compiler_features(ctx) == first


def test_forced_fallbacks_parse(monkeypatch):
    monkeypatch.setenv("CLRASTER_FALLBACKS", "rintf, CTZ")
    assert features.forced_fallbacks() == {"rintf", "ctz"}
    monkeypatch.setenv("CLRASTER_FALLBACKS", "all")
    assert features.forced_fallbacks() == set(features.FEATURES)
    monkeypatch.setenv("CLRASTER_FALLBACKS", "rint")
    with pytest.raises(features.FallbackError, match="unknown feature.*rint.*rintf"):
        features.forced_fallbacks()


def test_feature_options_follow_the_forced_set(monkeypatch):
    ctx = default_context()
    if "oclgrind" in ctx.devices[0].platform.name.lower():
        pytest.skip("the default device is Oclgrind, which always builds CLRASTER_PORTABLE")
    monkeypatch.setenv("CLRASTER_FALLBACKS", "all")
    assert set(features.feature_options(ctx)) == {f"-D{f.macro}"
                                                 for f in features.FEATURES.values()}
    monkeypatch.setenv("CLRASTER_FALLBACKS", "portable")
    assert features.feature_options(ctx) == ("-DCLRASTER_PORTABLE",)
    monkeypatch.setenv("CLRASTER_FALLBACKS", "prefetch")
    assert "-DCLRASTER_NO_PREFETCH" in features.feature_options(ctx)


def test_oclgrind_always_builds_portable():
    """In a fresh process, as the other tests that start every runtime: Oclgrind's LLVM
    started in a process that has loaded Mesa's llvmpipe (the benchmark peer's tests)
    aborted it."""
    code = ("import pyopencl as cl\n"
            "from clraster.pipeline import features\n"
            "from clraster.pipeline.device import list_devices\n"
            "rows = [r for r in list_devices() if 'oclgrind' in r.platform.lower()]\n"
            "print(features.feature_options(cl.Context([rows[0].device])) if rows else 'none')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    if out.stdout.strip().splitlines()[-1] == "none":
        pytest.skip("Oclgrind is not installed")
    assert out.stdout.strip().splitlines()[-1] == "('-DCLRASTER_PORTABLE',)"


def test_kernels_name_every_feature_macro():
    """Every probed feature's macro is used by the kernels (a probe for nothing would be
    dead weight), and every Clang builtin the kernels call sits behind one."""
    kdir = ROOT / "kernels"
    text = "\n".join(p.read_text() for p in sorted(kdir.glob("*.cl")) + [kdir / "common.h"])
    for f in features.FEATURES.values():
        assert f.macro in text, f.macro
    common = (kdir / "common.h").read_text()
    for f in features.FEATURES.values():   # CLRASTER_PORTABLE turns every one on
        assert f"#define {f.macro}\n" in common, f.macro


# -- float division and square root -----------------------------------------------------------

_DIV_SRC = """
#pragma OPENCL FP_CONTRACT OFF
__kernel void div_sqrt(__global const float *a, __global const float *b,
                       __global float *q, __global float *r) {
    size_t i = get_global_id(0);
    q[i] = a[i] / b[i];
    r[i] = sqrt(a[i]);
}
"""


def _div_sqrt_inputs() -> tuple[np.ndarray, np.ndarray]:
    """Positive floats over the exponents the kernels meet (2^-40..2^40) with random
    mantissas, denominators alike, plus 1..64 over 3 (repeating binary fractions)."""
    rng = np.random.default_rng(11)
    n = 1 << 16
    a = (rng.uniform(1.0, 2.0, n) * 2.0 ** rng.integers(-40, 40, n)).astype(np.float32)
    b = (rng.uniform(1.0, 2.0, n) * 2.0 ** rng.integers(-40, 40, n)).astype(np.float32)
    b[:64] = np.float32(3.0)                        # 1/3, 2/3...: repeating binary fractions
    a[:64] = np.arange(1, 65, dtype=np.float32)
    return a, b


def test_kernels_are_built_for_correctly_rounded_division():
    """Every kernel program is built with the device's correctly rounded float ``/`` and
    ``sqrt`` where it offers them (OpenCL allows 2.5 and 3 ulp without the option; the
    NVIDIA H200's OpenCL gave other barycentrics in 13 of the golden cases so)."""
    from clraster.base.config import RasterConfig
    from clraster.pipeline.device import program

    ctx = default_context()
    dev = ctx.devices[0]
    opts = program(ctx, "raster", RasterConfig().build_options()).get_build_info(
        dev, cl.program_build_info.OPTIONS)
    offered = bool(dev.single_fp_config & cl.device_fp_config.CORRECTLY_ROUNDED_DIVIDE_SQRT)
    assert ("-cl-fp32-correctly-rounded-divide-sqrt" in opts) == offered


def test_division_and_sqrt_round_as_the_twin_does():
    """Built as clraster builds its kernels, the device's float ``/`` and ``sqrt`` give
    NumPy's (IEEE, correctly rounded) bits: what the barycentrics' equality with the twin
    and across runtimes rests on."""
    ctx = default_context()
    prg = cl.Program(ctx, _DIV_SRC).build(
        options=list(features.precision_options(ctx.devices[0])))
    a, b = _div_sqrt_inputs()
    q, r = np.empty_like(a), np.empty_like(a)
    mf = cl.mem_flags
    queue = cl.CommandQueue(ctx)
    bufs = [cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=x) for x in (a, b)]
    outs = [cl.Buffer(ctx, mf.WRITE_ONLY, a.nbytes) for _ in range(2)]
    prg.div_sqrt(queue, a.shape, None, *bufs, *outs)
    cl.enqueue_copy(queue, q, outs[0])
    cl.enqueue_copy(queue, r, outs[1])
    queue.finish()
    np.testing.assert_array_equal(q.view(np.uint32), (a / b).view(np.uint32))
    np.testing.assert_array_equal(r.view(np.uint32), np.sqrt(a).view(np.uint32))


# -- work-group sizes -------------------------------------------------------------------------

@pytest.mark.filterwarnings("ignore::pyopencl.CompilerWarning")   # a compiler's remarks
def test_local_size_from_device_limits():
    ctx = default_context()
    dev = ctx.devices[0]
    k = cl.Kernel(cl.Program(ctx, "__kernel void f(__global int *a) { a[0] = 1; }").build(),
                  "f")
    limit = min(k.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, dev),
                dev.max_work_item_sizes[0])
    assert features.local_size(k, dev, 16) == min(16, 1 << (limit.bit_length() - 1))
    over = 2 * limit + 3
    got = features.local_size(k, dev, over)
    assert got <= limit and got & (got - 1) == 0 and 2 * got > limit
    with pytest.raises(features.WorkGroupError, match=f"at most {limit}"):
        features.local_size(k, dev, over, exact=True)


# -- wheel runtimes: the mechanism, with stand-ins ----------------------------------------------

def _fake_wheel(root: Path, deps_beside: bool) -> Path:
    """A site folder holding a dist-info of ``intel-opencl-rt`` whose RECORD lists a
    ``lib/libintelocl.so`` (an empty file: nothing is loaded, only found), with the
    compiler runtime's files beside it or not. Returns the site folder."""
    site = root / "lib" / "site"
    info = site / "intel_opencl_rt-2026.2.0.dist-info"
    info.mkdir(parents=True)
    lib = root / "lib"
    (lib / "libintelocl.so").write_bytes(b"")
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: intel-opencl-rt\n"
                                   "Version: 2026.2.0\n")
    (info / "RECORD").write_text("../libintelocl.so,,\n")
    if deps_beside:
        for soname, _ in runtimes.INTEL_NEEDS:
            (lib / soname).write_bytes(b"")
    return site


_REGISTER = """
import json, os, sys
from importlib import metadata
_all = metadata.distributions   # only the stand-in site's wheels, not this venv's
metadata.distributions = lambda **kw: _all(path=[sys.path[1]], **kw)
from clraster.pipeline import runtimes
(rt,) = runtimes.register_wheel_runtimes()
print(json.dumps({"registered": rt.registered, "problem": rt.problem,
                  "library": str(rt.library), "vendors": os.environ.get("OCL_ICD_VENDORS")}))
"""


def _register(site: Path, tmp_path: Path, **env: str) -> dict:
    full = {k: v for k, v in os.environ.items() if k not in ("OCL_ICD_VENDORS",
                                                            "OPENCL_VENDOR_PATH")}
    full.update(PYTHONPATH=os.pathsep.join([str(site), str(ROOT)]),
                XDG_CACHE_HOME=str(tmp_path / "cache"), **env)
    p = _python(_REGISTER, full)   # sys.path: "" (-c), then the stand-in site
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_registration_keeps_the_other_icds_visible(tmp_path):
    site = _fake_wheel(tmp_path / "prefix", deps_beside=True)
    vendors = tmp_path / "vendors"
    vendors.mkdir()
    (vendors / "pocl.icd").write_text("libpocl.so.2\n")
    (vendors / "other.icd").write_text("/opt/x/libother.so\n")
    got = _register(site, tmp_path, OCL_ICD_VENDORS=str(vendors))
    assert got["registered"], got["problem"]
    folder = Path(got["vendors"])
    assert folder != vendors and str(folder).startswith(str(tmp_path / "cache"))
    icds = {p.name: p.read_text() for p in folder.glob("*.icd")}
    lib = str((tmp_path / "prefix" / "lib" / "libintelocl.so").resolve())
    assert icds == {"pocl.icd": "libpocl.so.2\n", "other.icd": "/opt/x/libother.so\n",
                    runtimes.ICD_NAME: lib + "\n"}
    # a child process inheriting OCL_ICD_VENDORS gets the same folder, not a copy of a copy
    again = _register(site, tmp_path, OCL_ICD_VENDORS=got["vendors"])
    assert again["vendors"] == got["vendors"]


def test_registration_respects_a_single_icd_file(tmp_path):
    site = _fake_wheel(tmp_path / "prefix", deps_beside=True)
    one = tmp_path / "pocl.icd"
    one.write_text("libpocl.so.2\n")
    got = _register(site, tmp_path, OCL_ICD_VENDORS=str(one))
    assert not got["registered"]
    assert got["vendors"] == str(one)
    assert "names one ICD" in got["problem"] and "unset it" in got["problem"]


def test_registration_names_missing_dependencies(tmp_path):
    site = _fake_wheel(tmp_path / "prefix", deps_beside=False)
    got = _register(site, tmp_path, OCL_ICD_VENDORS=str(tmp_path))
    assert not got["registered"]
    for soname, dist in runtimes.INTEL_NEEDS:
        assert soname in got["problem"] and dist in got["problem"]
    assert "clraster[intel]" in got["problem"]
    assert got["vendors"] == str(tmp_path)   # the loader's view is left as it was


def test_registration_off_switch(tmp_path):
    site = _fake_wheel(tmp_path / "prefix", deps_beside=True)
    # the environment's own PYTHONPATH after the fake wheel's site (packages put there)
    paths = [str(site), str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    full = dict(os.environ, PYTHONPATH=os.pathsep.join(paths),
                XDG_CACHE_HOME=str(tmp_path / "cache"), CLRASTER_WHEEL_RUNTIMES="0")
    full.pop("OCL_ICD_VENDORS", None)
    p = _python("from clraster.pipeline import runtimes, device\n"
                "import os; print(runtimes.wheel_runtimes(), os.environ.get('OCL_ICD_VENDORS'))",
                full)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split() == ["()", "None"]


@pytest.mark.skipif(shutil.which("cc") is None, reason="needs a C compiler to build the two "
                    "stand-in shared libraries")
def test_dependency_from_another_prefix_is_preloaded(tmp_path):
    """A library whose dependency lies in another folder (no RUNPATH reaches it) loads once
    `_dependencies` has loaded that dependency from where its wheel put it; without, the
    dynamic linker does not find it (LD_LIBRARY_PATH is read only at process start)."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (tmp_path / "dep.c").write_text("int clr_dep_value(void) { return 42; }\n")
    (tmp_path / "main.c").write_text("int clr_dep_value(void);\n"
                                     "int clr_main_value(void) { return clr_dep_value() + 1; }\n")
    subprocess.run(["cc", "-shared", "-fPIC", "-o", str(b / "libclrdep.so"),
                    "-Wl,-soname,libclrdep.so", str(tmp_path / "dep.c")], check=True)
    subprocess.run(["cc", "-shared", "-fPIC", "-o", str(a / "libclrmain.so"),
                    "-Wl,-rpath,$ORIGIN", str(tmp_path / "main.c"), "-L", str(b),
                    "-lclrdep"], check=True)
    code = f"""
        import ctypes, sys
        from pathlib import Path
        from clraster.pipeline import runtimes
        try:
            ctypes.CDLL("{a}/libclrmain.so")
            sys.exit("loaded without the dependency: the test proves nothing")
        except OSError as exc:
            assert "libclrdep.so" in str(exc), exc
        runtimes._distribution_file = lambda dist, name: Path("{b}") / name
        print(runtimes._dependencies(Path("{a}"), (("libclrdep.so", "stand-in"),)))
        print(ctypes.CDLL("{a}/libclrmain.so").clr_main_value())
        """
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    p = _python(code, env)
    assert p.returncode == 0, p.stderr[-2000:] + p.stdout
    lines = p.stdout.split("\n")
    assert f"{b}/libclrdep.so" in lines[0]
    assert lines[1] == "43"


# -- the real Intel runtime, where the wheel is installed -----------------------------------

def _intel_installed() -> bool:
    return any(rt.installed for rt in runtimes.wheel_runtimes() if rt.name == "intel")


needs_intel = pytest.mark.skipif(
    not _intel_installed(), reason="Intel's OpenCL runtime wheel is not installed "
    "(pip install 'clraster[intel]'; CI installs it for its second runtime)")


@needs_intel
def test_intel_wheel_is_listed_and_chosen_by_name():
    env = {k: v for k, v in os.environ.items() if k not in ("OCL_ICD_VENDORS",
                                                            "PYOPENCL_CTX")}
    env["CLRASTER_DEVICE"] = "intel"
    p = _python("""
        from clraster.pipeline.device import choose_context, describe_choice, list_devices
        rows = list_devices()
        print([r.platform for r in rows if r.compiles])
        ctx, reason = choose_context()
        print(describe_choice(ctx, reason))
        """, env)
    assert p.returncode == 0, p.stderr[-2000:]
    listed, chosen = p.stdout.strip().splitlines()[-2:]
    assert "Intel(R) OpenCL" in listed
    assert "Portable Computing Language" in listed   # the pip PoCL is still there
    assert chosen.startswith("Intel(R) OpenCL") and "CLRASTER_DEVICE=intel" in chosen
