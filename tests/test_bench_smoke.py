"""Smoke test of the benchmark harness: `clraster bench --quick` runs end to end.

It checks that the harness works and writes what it promises (JSON schema, markdown, plots,
peer present or skipped with a reason), never a speed. A second run does the scale sweep
alone (`--quick --sweeps scale`: instance grids of ~1M and ~2M triangles) and checks its
rows, peak RSS and fit; a third the datasets sweep alone (`--quick --sweeps datasets`: a few
views of spot, clraster and, where it imports, Open3D).
"""

from __future__ import annotations

import importlib.util
import json
import math
import statistics
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
            {"setup", "bin", "raster"} <= set(cl["stages_median_ms"]))
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
                            "scale_200m_renders", "scale_200m_peak_rss", "scale_linear",
                            "datasets_dragon_back_vs_open3d", "datasets_dragon_none_vs_open3d",
                            "datasets_small_vs_open3d", *every}
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
            assert t["met"] is None and t["note"]   # scale and datasets sweeps run only
    assert res["scale"] is None and res["datasets"] is None   # when named
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


# =======================================================================================
# The datasets sweep (clraster.bench.datasets)
# =======================================================================================

def _open3d_importable() -> bool:
    from clraster.bench.datasets import open3d_status

    return open3d_status()[0]


@pytest.fixture(scope="module")
def quick_datasets(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_datasets")
    rc = main(["bench", "--quick", "--sweeps", "datasets", "--no-startup", "--out", str(out)])
    return rc, out


def test_datasets_sweep_alone(quick_datasets):
    """`--sweeps datasets` alone: one row (a tiny mesh, a few views at 640x480), views/s of
    each round and their median for cull back and none, the first view's coverage; no
    frame-time configuration, no llvmpipe; its section, plot and targets."""
    from clraster.bench.datasets import DATASETS_SIZE, QUICK_VIEWS

    rc, out = quick_datasets
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["errors"] == [] and res["configs"] == [] and res["memory"] == []
    assert res["peer"]["available"] is False   # llvmpipe has nothing to draw here
    ds = res["datasets"]
    assert ds["failed"] == [] and ds["skipped"] == [] and len(ds["rows"]) == 1
    assert ds["settings"]["views"] == res["settings"]["views"] == QUICK_VIEWS
    row = ds["rows"][0]
    assert row["mesh"] in ("spot", "example") and row["triangles"] > 0
    assert row["size"] == list(DATASETS_SIZE) and row["views"] == QUICK_VIEWS
    assert set(row["clraster"]) == {"back", "none"}
    for c in row["clraster"].values():
        assert len(c["runs_views_per_s"]) == res["settings"]["repeat"] == row["repeat"]
        assert all(_positive(v) for v in c["runs_views_per_s"])
        assert c["median_views_per_s"] == statistics.median(c["runs_views_per_s"])
        assert 0.0 < c["covered_fraction"] < 1.0   # the mesh is framed, with margin
    # both culling modes see the same closed-ish mesh: nearly the same pixels covered
    back, none = (row["clraster"][k]["covered_fraction"] for k in ("back", "none"))
    assert abs(back - none) < 0.01
    o3d = row["open3d"]
    t = {t["name"]: t for t in res["targets"]}
    if ds["open3d"]["available"]:
        assert _positive(o3d["median_views_per_s"])
        for cull, ratio in row["ratio_vs_open3d"].items():
            assert ratio == (row["clraster"][cull]["median_views_per_s"]
                             / o3d["median_views_per_s"])
        small = t["datasets_small_vs_open3d"]
        assert small["value"] == min(row["ratio_vs_open3d"].values())
        assert small["met"] is (small["value"] >= 2.0)
    else:
        assert o3d["skipped"].startswith("Open3D skipped") and row["ratio_vs_open3d"] == {}
        assert all(c["ids_agree_open3d"] is None for c in row["clraster"].values())
        assert t["datasets_small_vs_open3d"]["met"] is None
        assert "Open3D" in t["datasets_small_vs_open3d"]["note"]
    for name in ("datasets_dragon_back_vs_open3d", "datasets_dragon_none_vs_open3d"):
        assert t[name]["met"] is None and t[name]["note"]   # no dragon in quick mode
    md = (out / "results.md").read_text()
    assert "## Datasets sweep" in md and f"| {row['mesh']} |" in md
    assert "## Configurations" not in md   # no frame-time configuration was run
    if importlib.util.find_spec("matplotlib") is not None:
        assert res["plots"] == ["datasets.png"]
        assert (out / "datasets.png").stat().st_size > 1000


def test_datasets_open3d_agrees(quick_datasets):
    """Where Open3D imports: its views/s and the first view's ids, which agree with
    clraster's on almost every pixel once the pixel centres are matched."""
    if not _open3d_importable():
        pytest.skip("open3d is not importable here (pip install 'clraster[open3d]', which "
                    "needs the system's libusb-1.0)")
    _, out = quick_datasets
    row = json.loads((out / "results.json").read_text())["datasets"]["rows"][0]
    o3d = row["open3d"]
    assert len(o3d["runs_views_per_s"]) == row["repeat"]
    assert all(_positive(v) for v in o3d["runs_views_per_s"])
    assert abs(o3d["covered_fraction"] - row["clraster"]["none"]["covered_fraction"]) < 0.01
    for c in row["clraster"].values():
        assert c["ids_agree_open3d"] > 0.99


def test_datasets_sphere_poses():
    """The cameras: rotations (orthonormal, det +1, OpenCV axes) on a sphere around the
    mesh's box centre, each looking at it, spread evenly (directions average to ~0); K with
    the principal point at the image centre (OpenCV pixel centres)."""
    import numpy as np

    from clraster import Mesh
    from clraster.bench.datasets import near_far, sphere_poses

    v = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 4]], np.float32)
    mesh = Mesh(v, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int32))
    k, poses = sphere_poses(mesh, 50, 64, 48)
    assert k[0, 2] == 31.5 and k[1, 2] == 23.5 and k[0, 0] == k[1, 1] > 0
    centre = np.array([1.0, 0.5, 2.0])
    dists = []
    dirs = []
    for p in poses:
        r, eye = p[:3, :3], p[:3, 3]
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        d = centre - eye
        dists.append(np.linalg.norm(d))
        assert np.allclose(r[:, 2], d / np.linalg.norm(d))   # +z looks at the centre
        dirs.append(-d / np.linalg.norm(d))
    assert np.ptp(dists) < 1e-9
    assert np.linalg.norm(np.mean(dirs, axis=0)) < 0.05
    near, far = near_far(mesh, poses)
    radius = np.linalg.norm([2.0, 1.0, 4.0]) / 2
    assert 0 < near < dists[0] - radius and far > dists[0] + radius


def test_datasets_rounds_abba():
    """The jobs alternate order each round (A B C, C B A, A B C), each timed once a round."""
    from clraster.bench.datasets import time_rounds

    calls: list[str] = []
    jobs = {n: (lambda n=n: calls.append(n)) for n in "ABC"}
    rates = time_rounds(jobs, 10, 3)
    assert calls == list("ABCCBAABC")
    assert all(len(v) == 3 and all(_positive(x) for x in v) for v in rates.values())


def test_datasets_targets():
    """Issue 32's targets from a hand-made summary: the dragon's ratios per culling mode,
    the smallest ratio over meshes under 100K triangles; nothing timed → not measured."""
    from clraster.bench.datasets import datasets_targets

    def row(mesh, tri, back, none):
        return {"mesh": mesh, "source": f"/m/{mesh}.ply", "triangles": tri,
                "ratio_vs_open3d": {"back": back, "none": none}}

    summary = {"open3d": {"available": True, "reason": "Open3D 0.20"},
               "rows": [row("dragon", 871_414, 1.6, 0.9), row("armadillo", 86_482, 2.4, 2.1),
                        row("spot", 5_856, 3.0, 1.9), row("lucy", 100_000, 0.5, 0.5)]}
    t = {x["name"]: x for x in datasets_targets(summary)}
    assert t["datasets_dragon_back_vs_open3d"]["value"] == 1.6
    assert t["datasets_dragon_back_vs_open3d"]["met"] is True
    assert t["datasets_dragon_none_vs_open3d"]["met"] is False
    small = t["datasets_small_vs_open3d"]   # lucy has 100K: not "under 100K"
    assert small["value"] == 1.9 and small["met"] is False
    assert small["config"] == "datasets spot cull=none"
    for summ, needle in ((None, "--sweeps datasets"),
                         ({"open3d": {"available": False, "reason": "Open3D skipped: x"},
                           "rows": [{**row("spot", 5_856, 0, 0), "ratio_vs_open3d": {}}]},
                          "Open3D skipped")):
        for x in datasets_targets(summ):
            assert x["met"] is None and needle in x["note"], x


@pytest.mark.parametrize("name", ["grid:spot:2x1x1", "spot@close", "plant:many"])
def test_datasets_bad_mesh_is_a_usage_error(tmp_path, capsys, name):
    """The datasets sweep times meshes seen from its sphere of cameras: a grid, a view
    suffix or a name that does not parse is refused before anything runs (exit 2, the
    name and the reason on stderr)."""
    rc = main(["bench", "--quick", "--sweeps", "datasets", "--datasets-meshes", name,
               "--out", str(tmp_path / "out")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "datasets mesh" in err and name in err
    assert not (tmp_path / "out").exists()
