"""Device choice, explicit and listed (clraster.pipeline.device, ``clraster devices``).

Precedence: ``Renderer(device=...)`` > ``CLRASTER_DEVICE`` > ``PYOPENCL_CTX`` > the default
(the first CPU device that compiles a probe kernel, PoCL first, never Oclgrind). A name
that matches nothing is one `NoDeviceError` listing the devices there are; every choice
keeps its reason (`Renderer.device_description`, the bench machine description). The
environment-variable cases run in subprocesses: the default choice is made once per process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from clraster import Mesh, Renderer
from clraster.pipeline import device

ROOT = Path(__file__).resolve().parents[1]

TRI = Mesh([[-0.5, -0.5, -1.0], [0.6, -0.4, -1.0], [0.1, 0.7, -1.5]], [[0, 1, 2]])


class _Cam:
    def view_projection(self, w, h):
        m = np.eye(4)
        m[3, 2], m[3, 3] = -1.0, 0.0   # w = −z: a perspective divide, z kept in range
        m[2, 2], m[2, 3] = -1.2, -2.2
        return m


def _have(name: str) -> bool:
    return any(name in p.name.lower() for p in cl.get_platforms())


def _run(code: str, **env_set: str | None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    for k in ("CLRASTER_DEVICE", "PYOPENCL_CTX"):
        env.pop(k, None)
    env.update({k: v for k, v in env_set.items() if v is not None})
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=300, cwd=ROOT)


_CHOICE = ("import json, warnings\n"
           "warnings.simplefilter('ignore')\n"
           "from clraster import Renderer\n"
           "from clraster.pipeline.device import NoDeviceError\n"
           "try:\n"
           "    r = Renderer(8, 8, device={device!r})\n"
           "    print(json.dumps([r.context.devices[0].platform.name, r.device_description]))\n"
           "except NoDeviceError as e:\n"
           "    print(json.dumps(['NoDeviceError', str(e)]))\n")


def _choice(device_arg=None, **env) -> tuple[str, str]:
    res = _run(_CHOICE.format(device=device_arg), **env)
    assert res.returncode == 0, res.stderr[-3000:]
    plat, text = json.loads(res.stdout.strip().splitlines()[-1])
    return plat, text


@pytest.mark.parametrize("spec", ["pocl", "POCL", "Portable", "portable computing"])
def test_find_device_by_alias_and_substring(spec):
    d = device.find_device(spec)
    assert "portable computing language" in d.platform.name.lower()


def test_renderer_device_argument_names_the_choice():
    r = Renderer(16, 16, device="pocl")
    assert r.device_description.endswith("(device=pocl)")
    assert "Portable Computing Language" in r.device_description
    default = Renderer(16, 16)
    a, b = r.render(TRI, _Cam(), cull="none"), default.render(TRI, _Cam(), cull="none")
    assert (a.triangle_id >= 0).sum() > 10
    np.testing.assert_array_equal(a.triangle_id, b.triangle_id)
    np.testing.assert_array_equal(a.depth, b.depth)
    # the same device again: the same context (programs built once)
    assert Renderer(16, 16, device="POCL").context is r.context


def test_renderer_takes_a_pyopencl_device():
    dev = device.find_device("pocl")
    r = Renderer(16, 16, device=dev)
    assert r.context.devices[0] == dev
    assert "device=<pyopencl.Device>" in r.device_description


def test_renderer_context_and_device_conflict():
    ctx = device.default_context()
    with pytest.raises(ValueError, match="not both"):
        Renderer(8, 8, context=ctx, device="pocl")
    assert "(context= given)" in Renderer(8, 8, context=ctx).device_description


def test_default_reason():
    plat, text = _choice()
    assert "portable computing language" in plat.lower()
    assert text.endswith("(default: first CPU runtime that compiles the kernels)")


def test_clraster_device_env_chooses():
    plat, text = _choice(CLRASTER_DEVICE="pocl")
    assert "portable computing language" in plat.lower() and "(CLRASTER_DEVICE=pocl)" in text


def test_clraster_device_env_unknown_lists_devices():
    plat, text = _choice(CLRASTER_DEVICE="no-such-runtime")
    assert plat == "NoDeviceError"
    assert "CLRASTER_DEVICE='no-such-runtime'" in text and "devices here:" in text


def _pocl_index() -> int:
    return next(i for i, p in enumerate(cl.get_platforms())
                if "portable computing language" in p.name.lower())


def test_pyopencl_ctx_still_honoured():
    plat, text = _choice(PYOPENCL_CTX=str(_pocl_index()))
    assert "portable computing language" in plat.lower()
    assert text.endswith(f"(PYOPENCL_CTX={_pocl_index()})")


def test_precedence_device_over_env_over_pyopencl_ctx():
    if not _have("oclgrind"):
        pytest.skip("Oclgrind is not installed: no second device to tell the rules apart")
    # CLRASTER_DEVICE beats PYOPENCL_CTX
    plat, text = _choice(CLRASTER_DEVICE="oclgrind", PYOPENCL_CTX=str(_pocl_index()))
    assert "oclgrind" in plat.lower() and "(CLRASTER_DEVICE=oclgrind)" in text
    # device= beats both
    plat, text = _choice("pocl", CLRASTER_DEVICE="oclgrind", PYOPENCL_CTX="0")
    assert "portable computing language" in plat.lower() and text.endswith("(device=pocl)")


def test_cli_devices_lists_and_marks_the_choice():
    res = _run("from clraster.cli import main; raise SystemExit(main(['devices']))")
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert any(ln.startswith("* ") and "Portable Computing Language" in ln for ln in lines)
    assert lines[-1].startswith("clraster uses: ") and "default:" in lines[-1]
    if _have("oclgrind"):
        assert any("Oclgrind" in ln and "simulator" in ln for ln in lines)


def test_cli_devices_unknown_choice_exits_1():
    res = _run("from clraster.cli import main; raise SystemExit(main(['devices']))",
               CLRASTER_DEVICE="no-such-runtime")
    assert res.returncode == 1
    assert "no-such-runtime" in res.stderr and "devices here:" in res.stderr
    # the table is printed before the error, with no device marked: it is what the user
    # chooses from (a machine whose only OpenCL device is a GPU ends here too)
    lines = res.stdout.splitlines()
    assert lines[0] == "OpenCL devices (* the one clraster uses):"
    assert any("Portable Computing Language" in ln for ln in lines[1:])
    assert not any(ln.startswith("* ") for ln in lines)


def test_bench_machine_records_the_choice():
    from clraster.bench.machine import describe

    info = describe()["opencl"]
    assert info["device_choice"] in (
        "default: first CPU runtime that compiles the kernels",
        f"CLRASTER_DEVICE={os.environ.get('CLRASTER_DEVICE', '').strip()}",
        f"PYOPENCL_CTX={os.environ.get('PYOPENCL_CTX')}")


# Listing every device, or an error that lists them, starts every runtime installed: these
# run in a fresh process, as `clraster devices` does. In this test process Mesa's llvmpipe
# (the benchmark peer's tests) may already be loaded, and another LLVM starting beside it
# (Oclgrind's) aborts the process.

def _fresh(code: str) -> None:
    res = _run("import warnings\nwarnings.simplefilter('ignore')\n"
               "from clraster.pipeline import device\n"
               "from clraster.pipeline.device import NoDeviceError\n" + code)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]


def test_list_devices_marks_pocl_as_compiling():
    _fresh("rows = device.list_devices()\n"
           "pocl = [r for r in rows if 'portable computing language' in r.platform.lower()]\n"
           "assert pocl and all(r.compiles for r in pocl), rows\n"
           "assert all(r.kind in ('CPU', 'GPU', 'ACCELERATOR', 'OTHER') for r in rows)\n")


def test_find_device_by_device_name():
    _fresh("row = next(r for r in device.list_devices() if r.compiles)\n"
           "tail = row.name.upper()[-6:]\n"
           "assert device.find_device(tail).name.strip().upper().endswith(tail)\n")


def test_unknown_device_is_one_error_listing_what_exists():
    _fresh("try:\n"
           "    device.find_device('no-such-device-xyz')\n"
           "    raise SystemExit('no error')\n"
           "except NoDeviceError as e:\n"
           "    msg = str(e)\n"
           "assert 'no-such-device-xyz' in msg and 'devices here:' in msg, msg\n"
           "for r in device.list_devices():\n"
           "    assert r.label in msg, (r.label, msg)\n")


def test_renderer_device_unknown_raises():
    _fresh("from clraster import Renderer\n"
           "try:\n"
           "    Renderer(8, 8, device='nope-nope')\n"
           "    raise SystemExit('no error')\n"
           "except NoDeviceError as e:\n"
           "    assert \"device='nope-nope'\" in str(e), str(e)\n"
           "try:\n"
           "    Renderer(8, 8, device=3)\n"
           "    raise SystemExit('no error')\n"
           "except TypeError:\n"
           "    pass\n")


def test_renderer_device_oclgrind_warns():
    if not _have("oclgrind"):
        pytest.skip("Oclgrind is not installed")
    _fresh("import warnings\n"
           "from clraster import Renderer\n"
           "from clraster.pipeline.device import SimulatorWarning\n"
           "with warnings.catch_warnings(record=True) as caught:\n"
           "    warnings.simplefilter('always')\n"
           "    r = Renderer(8, 8, device='oclgrind')\n"
           "assert any(issubclass(w.category, SimulatorWarning)\n"
           "           and 'device=oclgrind' in str(w.message) for w in caught), caught\n"
           "assert 'Oclgrind' in r.device_description\n")
