#!/usr/bin/env bash
# One-step set-up on a fresh machine: a virtual environment in .venv with clraster installed
# (pass "test" to add the test extras), then a check that an OpenCL CPU device can compile a
# kernel. PoCL comes from PyPI; its LLVM 14 cannot target CPUs newer than it knows (e.g.
# AMD Zen 5 reports "unknown target CPU 'generic'"). On such a machine, and only there, this
# installs Debian/Ubuntu's PoCL (pocl-opencl-icd), which clraster then picks automatically;
# where that cannot compile either (or there is no apt-get), Intel's OpenCL CPU runtime from
# PyPI (the intel extra, which runs on AMD CPUs too and which clraster picks next).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
extras=${1:-}

python3 -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip >/dev/null || true
python -m pip install ".${extras:+[$extras]}"
if [[ ",$extras," == *",test,"* ]]; then bash scripts/install_browser.sh; fi   # viewer tests

probe() { python -c "from clraster.pipeline.device import default_context; print(default_context().devices[0].platform.version)"; }
if ! probe 2>/dev/null; then
    echo "setup: the pip PoCL cannot compile kernels on this CPU; installing the system PoCL" >&2
    if command -v apt-get >/dev/null 2>&1; then
        sudo_cmd=""
        [ "$(id -u)" = 0 ] || sudo_cmd="sudo"
        { $sudo_cmd apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
              $sudo_cmd apt-get install -y -qq pocl-opencl-icd >/dev/null; } \
            || echo "setup: installing the system PoCL failed" >&2
    else
        echo "setup: no apt-get here for a PoCL built with LLVM >= 15" >&2
    fi
    if ! probe 2>/dev/null; then
        echo "setup: no PoCL compiles kernels here; installing Intel's OpenCL CPU runtime" >&2
        python -m pip install -q ".[intel]"
    fi
    probe
fi
