"""Smoke test of the benchmark harness: `clraster bench --quick` runs end to end.

It checks that the harness works and writes what it promises (JSON schema, markdown, plots,
peer present or skipped with a reason), never a speed. A second run does the scale sweep
alone (`--quick --sweeps scale`: instance grids of ~1M and ~2M triangles) and checks its
rows, peak RSS and fit.
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
    assert {"triangles", "pixels", "culling", "fill"} <= {s for c in configs
                                                           for s in c["sweeps"]}
    # the fill sweep: a quad framed close covers much of the frame, the empty one none
    fill = {c["scene"]["name"]: c["opencl"] for c in configs if "fill" in c["sweeps"]}
    assert fill["quad"]["covered_fraction"] > 0.25 and fill["empty"]["covered_pixels"] == 0
    assert fill["quad"]["fragments_per_s"] > 0
    assert {"off", "frustum", "occlusion"} <= {c["mode"] for c in configs}
    assert len({tuple(c["size"]) for c in configs}) >= 2
    for c in configs:
        cl, tw = c["opencl"], c["twin"]
        assert c["triangles"] > 0 and c["pixels"] == c["size"][0] * c["size"][1]
        assert len(cl["runs_ms"]) == res["settings"]["repeat"]
        assert all(_positive(t) for t in cl["runs_ms"]) and _positive(cl["median_ms"])
        assert _positive(cl["triangles_per_s"]) and _positive(cl["pixels_per_s"])
        # (an empty frame draws nothing: no stage runs)
        assert c["scene"]["name"] == "empty" or (
            {"vertex", "setup", "bin", "raster"} <= set(cl["stages_median_ms"]))
        assert 0.0 <= cl["covered_fraction"] <= 1.0
        assert cl["covered_pixels"] == round(cl["covered_fraction"] * c["pixels"])
        assert cl["counts"]["triangles_total"] == c["triangles"]
        lean = cl["lean"]   # the same frames with depth and ids only (llvmpipe's outputs)
        assert lean["outputs"] == ["depth", "ids"]
        assert len(lean["runs_ms"]) == res["settings"]["repeat"]
        assert all(_positive(t) for t in lean["runs_ms"]) and _positive(lean["median_ms"])
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
            assert pe["ratio_lean_over_llvmpipe"] == lean["median_ms"] / pe["median_ms"]
            # a llvmpipe frame in each round, with clraster's
            assert pe["interleaved"] is True
            assert len(pe["runs_ms"]) == res["settings"]["repeat"]
        else:
            assert pe["skipped"].startswith("peer skipped") and res["peer"]["reason"]

    targets = {t["name"]: t for t in res["targets"]}
    every = {"every_config_vs_llvmpipe": 1.0, "every_config_vs_llvmpipe_lean": 1.0,
             "every_config_vs_llvmpipe_0.8": 0.8}
    assert set(targets) == {"dragon_vs_twin", "dragon_vs_llvmpipe",
                            "plant10m_occlusion_vs_llvmpipe", "dragon_vs_llvmpipe_0.2",
                            "plant10m_occlusion_vs_llvmpipe_20", "plant10m_occlusion_vs_off",
                            "dragon_vs_llvmpipe_0.15", "plant10m_occlusion_vs_llvmpipe_30",
                            "fill_vs_llvmpipe", "empty_frame_ms",
                            "scale_200m_renders", "scale_200m_peak_rss", "scale_linear", *every}
    fills = [c for c in configs if "fill" in c["sweeps"] and c["peer"].get("median_ms")
             and c["opencl"]["covered_fraction"] >= 0.25]
    for name, t in targets.items():
        if name in every and res["peer"]["available"]:
            # the largest ratio over the configurations, and which one it is
            key = "ratio_lean_over_llvmpipe" if name.endswith("_lean") \
                else "ratio_clraster_over_llvmpipe"
            assert t["value"] == max(c["peer"][key] for c in configs)
            assert t["met"] is (t["value"] <= every[name]) and t["config"]
        elif name == "fill_vs_llvmpipe" and fills:
            # the largest ratio over the fill frames at least a quarter covered
            worst = max(fills, key=lambda c: c["peer"]["ratio_clraster_over_llvmpipe"])
            assert t["config"] == worst["id"] and t["met"] is (t["value"] <= 0.8)
        else:   # quick mode has neither the dragon at 1080p nor a 10M plant, and the
            assert t["met"] is None and t["note"]   # scale sweep runs only when named
    assert res["scale"] is None
    assert all("scale" not in c["sweeps"] for c in configs)

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


@pytest.fixture(scope="module")
def quick_scale(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_scale")
    rc = main(["bench", "--quick", "--sweeps", "scale", "--no-startup", "--no-peer",
               "--out", str(out)])
    return rc, out


def test_scale_sweep_alone(quick_scale):
    """`--sweeps scale` runs the scale sweep alone: two grid scenes × (overview, inside),
    frame times, triangles/s, a peak RSS per row, and the least-squares fit with its
    residuals; the twin and peer sit out; the scale goals are reported."""
    rc, out = quick_scale
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["errors"] == [] and res["startup"] is None
    configs = res["configs"]
    assert len(configs) == 4 and all(c["sweeps"] == ["scale"] for c in configs)
    assert {c["scene"]["view"] for c in configs} == {"overview", "inside"}
    assert len({c["triangles"] for c in configs}) == 2
    assert min(c["triangles"] for c in configs) >= 900_000
    for c in configs:
        assert c["twin"]["skipped"].startswith("twin skipped: scale sweep")
        assert len(c["opencl"]["runs_ms"]) == res["settings"]["scale_repeat"]
        assert _positive(c["opencl"]["setup_triangles_per_s"])

    sc = res["scale"]
    assert [p["id"] for p in sc["planned"]] == [c["id"] for c in configs]
    assert sc["failed"] == [] and sc["not_measured"] == []
    for r in sc["rows"]:
        assert _positive(r["median_ms"]) and _positive(r["peak_rss_mib"])
        assert _positive(r["scene_triangles_per_s"]) and _positive(r["setup_triangles_per_s"])
        assert 0 < r["triangles_to_setup"] <= r["triangles"]
        # residual = measured − fit, also relative to the measurement
        assert math.isclose(r["median_ms"] - r["fit_ms"], r["residual_ms"], abs_tol=1e-6)
        assert math.isclose(r["residual_ms"] / r["median_ms"], r["relative_residual"],
                            abs_tol=1e-9)
    # inside the grid, object culling leaves fewer triangles than the overview
    by = {(r["triangles"], r["view"]): r["triangles_to_setup"] for r in sc["rows"]}
    for n in {c["triangles"] for c in configs}:
        assert by[(n, "inside")] < by[(n, "overview")]
    fit = sc["fit"]
    assert fit["n_points"] == 4
    for k in ("slope_ms_per_mtri", "intercept_ms", "r2", "rms_residual_ms",
              "max_abs_relative_residual"):
        assert isinstance(fit[k], float) and math.isfinite(fit[k]), k
    assert fit["max_abs_relative_residual"] == pytest.approx(
        max(abs(r["relative_residual"]) for r in sc["rows"]))
    assert all(m["twin"]["skipped"] for m in res["memory"])

    t = {t["name"]: t for t in res["targets"]}
    for name in ("scale_200m_renders", "scale_200m_peak_rss"):   # no 200M scene here
        assert t[name]["met"] is None and t[name]["note"], t[name]
    lin = t["scale_linear"]
    assert lin["value"] == pytest.approx(fit["max_abs_relative_residual"])
    assert lin["met"] is (lin["value"] <= lin["threshold"])
    md = (out / "results.md").read_text()
    assert "## Scale sweep" in md and "Fit over 4 configurations" in md
    if importlib.util.find_spec("matplotlib") is not None:
        assert (out / "scale.png").stat().st_size > 1000


def test_scale_targets_failed_200m():
    """A 200M configuration that failed is a missed goal (not "not measured"), and so is
    its peak RSS; a sweep without one says so."""
    from clraster.bench.scale import scale_summary, scale_targets

    planned = [{"id": "grid:dragon:8x5x6@overview/1920x1080/frustum",
                "scene": "grid:dragon:8x5x6@overview", "triangles": 209_139_360}]
    errors = [f"{planned[0]['id']}: MemoryError: out of memory"]
    sc = scale_summary(planned, [], [], errors, 3)
    t = {t["name"]: t for t in scale_targets(sc)}
    assert t["scale_200m_renders"]["met"] is False
    assert "MemoryError" in t["scale_200m_renders"]["note"]
    assert t["scale_200m_peak_rss"]["met"] is False
    assert t["scale_linear"]["met"] is None
    t = {t["name"]: t for t in scale_targets(None)}
    assert all(x["met"] is None and "--sweeps scale" in x["note"] for x in t.values())


def _nothing_args(tmp_path: Path, *extra: str) -> list[str]:
    return ["bench", "--sweeps", "triangles", "--scenes", "spot", "--no-startup",
            "--no-memory", "--no-peer", "--no-plots", "--out", str(tmp_path / "out"), *extra]


def test_nothing_to_measure_fails_loudly(tmp_path, capsys, monkeypatch):
    """Every mesh missing: exit 1 and a message naming where the meshes were looked for,
    not "0/0 done" and exit 0."""
    empty = tmp_path / "no-meshes"
    empty.mkdir()
    assert main(_nothing_args(tmp_path, "--meshes", str(empty))) == 1
    err = capsys.readouterr().err
    assert "nothing to measure" in err and str(empty) in err and "--meshes" in err

    monkeypatch.setenv("CLRASTER_MESHES", str(tmp_path / "typo"))   # named, so used alone
    assert main(_nothing_args(tmp_path)) == 1
    err = capsys.readouterr().err
    assert str(tmp_path / "typo") in err and "missing" in err and "CLRASTER_MESHES" in err


def test_meshes_found_from_the_current_folder(tmp_path, monkeypatch):
    """Without --meshes or $CLRASTER_MESHES: ../shared/meshes from the current folder
    (what an installed package run from a checkout's sibling folder needs)."""
    from clraster.bench.cli import _default_meshes

    monkeypatch.delenv("CLRASTER_MESHES", raising=False)
    meshes = tmp_path / "shared" / "meshes"
    meshes.mkdir(parents=True)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert _default_meshes() == meshes.resolve()
    monkeypatch.setenv("CLRASTER_MESHES", str(tmp_path))
    assert _default_meshes() == tmp_path
