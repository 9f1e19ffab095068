"""Smoke test of the benchmark harness: `clraster bench --quick` runs end to end.

It checks that the harness works and writes what it promises (JSON schema, markdown, plots,
peer present or skipped with a reason), never a speed.
"""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

from clraster.cli import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = main(["bench", "--quick", "--out", str(out)])
    return rc, out


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v) and v > 0


def test_exit_code_and_files(quick):
    rc, out = quick
    assert rc == 0
    assert (out / "results.json").is_file()
    md = (out / "results.md").read_text()
    assert "## Targets" in md and "## Configurations" in md
    if importlib.util.find_spec("matplotlib") is not None:
        for name in ("time_vs_triangles.png", "time_vs_pixels.png", "stages.png",
                     "funnel.png"):
            assert (out / name).stat().st_size > 1000, name


def test_json_schema(quick):
    _, out = quick
    res = json.loads((out / "results.json").read_text())
    assert res["schema"] == "clraster-bench/1"
    assert res["quick"] is True and res["errors"] == []
    for key in ("created", "command", "settings", "machine", "peer", "configs", "targets",
                "startup", "memory", "skipped", "errors", "elapsed_s", "plots"):
        assert key in res, key
    m = res["machine"]
    assert isinstance(m["cpu"], str) and m["cores_logical"] >= 1
    assert "device" in m["opencl"], m["opencl"]
    assert "commit" in m["git"]

    configs = res["configs"]
    assert {"triangles", "pixels", "culling"} <= {s for c in configs for s in c["sweeps"]}
    assert {"off", "frustum", "occlusion"} <= {c["mode"] for c in configs}
    assert len({tuple(c["size"]) for c in configs}) >= 2
    for c in configs:
        cl, tw = c["opencl"], c["twin"]
        assert c["triangles"] > 0 and c["pixels"] == c["size"][0] * c["size"][1]
        assert len(cl["runs_ms"]) == res["settings"]["repeat"]
        assert all(_positive(t) for t in cl["runs_ms"]) and _positive(cl["median_ms"])
        assert _positive(cl["triangles_per_s"]) and _positive(cl["pixels_per_s"])
        assert {"vertex", "setup", "bin", "raster"} <= set(cl["stages_median_ms"])
        assert cl["counts"]["triangles_total"] == c["triangles"]
        assert tw["n_runs"] == len(tw["runs_ms"]) >= 1
        assert all(_positive(t) for t in tw["runs_ms"]) and _positive(tw["median_ms"])
        assert _positive(c["speedup_vs_twin"])
        assert c["agreement"]["agree"] is True and c["agreement"]["ids_equal"] is True
        if c["mode"] == "occlusion":
            # the twin runs the same two-phase occlusion schedule (clraster.twophase)
            assert tw["mode"] == "occlusion" and "note_mode" not in tw
            assert "occlusion (host)" in tw["stages_median_ms"]
            assert cl["warmup_frames"] >= 2
        pe = c["peer"]
        if res["peer"]["available"]:
            assert "error" not in pe, pe
            assert _positive(pe["median_ms"]) and isinstance(pe["coverage"], dict)
            assert _positive(pe["ratio_clraster_over_llvmpipe"])
        else:
            assert pe["skipped"].startswith("peer skipped") and res["peer"]["reason"]

    names = {t["name"] for t in res["targets"]}
    assert names == {"dragon_vs_twin", "dragon_vs_llvmpipe", "plant10m_occlusion_vs_llvmpipe"}
    for t in res["targets"]:   # quick mode has neither the dragon at 1080p nor a 10M plant
        assert t["met"] is None and t["note"]

    for k in ("cold", "warm"):
        s = res["startup"][k]
        assert "error" not in s, s
        assert _positive(s["first_frame_s"]) and _positive(s["to_first_frame_s"])
    assert res["memory"]
    for m in res["memory"]:
        for path in ("opencl", "twin"):
            assert "error" not in m[path], m[path]
            assert _positive(m[path]["peak_rss_mib"])


@pytest.mark.parametrize("where", ["parent_is_file", "is_file", "read_only"])
def test_unwritable_out_is_one_error_line(tmp_path, capsys, where):
    """A bad --out fails at once (before any measurement) with one line naming the path and
    the reason, exit code 1, not a traceback."""
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    if where == "parent_is_file":
        out, reason = blocker / "results", "Not a directory"
    elif where == "is_file":
        out, reason = blocker, "not a folder"
    else:
        if not Path("/proc/self").is_dir():
            pytest.skip("needs Linux /proc (read-only even for root)")
        out, reason = Path("/proc/clraster-bench-results"), ""
    rc = main(["bench", "--quick", "--no-peer", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1, err
    assert err[0].startswith("clraster bench: error: ") and str(out) in err[0], err
    assert reason in err[0], err
    assert not out.is_dir() and blocker.read_text() == "not a folder"
