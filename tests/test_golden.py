"""Golden hashes: the same inputs give the same bytes on every conformant OpenCL runtime.

Each case below renders fixed inputs (shared meshes, a clipped near plane, user clip planes,
reversed-Z, a polygon window, an occlusion camera path through a plant, tiny streaming
budgets, line segments, mirrored instances) at a small size, and reduces every output to a
sha256: triangle ids, depth, barycentrics, overdraw (bytes with dtype and shape) and the
stats counts (sorted JSON). tests/golden/frames.json holds the expected hashes; they were
generated on the pip PoCL and checked, before being committed, to be the same on the
distribution's PoCL (``OCL_ICD_VENDORS=/etc/OpenCL/vendors-distro/pocl.icd``), on Oclgrind,
and — for what the twin computes exactly — against the NumPy twin (docs/ARCHITECTURE.md says
what pins them). Cases of the shared meshes skip where the mesh folder is absent.

* the device clraster picks (``CLRASTER_DEVICE`` chooses another) reproduces every hash;
* the NumPy twin reproduces the ids, depth and counts of every triangle case (what the
  differential tests compare exactly; its barycentrics are promised to 1e-5 only, though they
  matched bit for bit when the file was made; it draws no overdraw) and every hash of the
  line case;
* Oclgrind (a subprocess with ``CLRASTER_DEVICE=oclgrind``) reproduces `OCLGRIND_CASES`, and
  every case with ``-m slow``;
* the device reproduces `FALLBACK_CASES` with every compiler builtin's portable fallback
  forced (``CLRASTER_FALLBACKS``, clraster.pipeline.features), and every case with one
  fallback at a time with ``-m slow``.

CI runs this file on the pip PoCL and on Intel's CPU runtime (``CLRASTER_DEVICE=intel``,
.ci/run).

Regenerate (only after a change that is meant to change outputs; then re-check the other
runtimes)::

    python tests/test_golden.py --regenerate        # writes tests/golden/frames.json
    python tests/test_golden.py --print [CASE ...]  # prints this device's hashes as JSON
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from conftest import MESH_DIR, MatrixCamera  # noqa: E402
from random_scenes import Lens, random_soup  # noqa: E402

from clraster import Camera, Mesh, RasterConfig, Renderer  # noqa: E402
from clraster.pipeline import reference  # noqa: E402
from clraster.pipeline.reference import lines as ref_lines  # noqa: E402
from clraster.world.scene import Scene  # noqa: E402

GOLDEN = HERE / "golden" / "frames.json"

#: the cases Oclgrind reproduces in the default run (all of them: the slow test)
OCLGRIND_CASES = ("soup_near_clip", "soup_reversed_z", "mirrored_instances")


def digest(a: np.ndarray) -> str:
    """sha256 of an array's dtype, shape and C-order bytes."""
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def digest_counts(counts: dict[str, int]) -> str:
    return hashlib.sha256(json.dumps(counts, sort_keys=True).encode()).hexdigest()


def frame_hashes(f: Any) -> dict[str, str]:
    """The hashes of one `Frame` (overdraw only where it was asked for)."""
    out = {"ids": digest(f.triangle_id), "depth": digest(f.depth),
           "bary": digest(f.barycentrics), "counts": digest_counts(f.stats.counts())}
    if f.overdraw is not None:
        out["overdraw"] = digest(f.overdraw)
    return out


def line_hashes(f: Any) -> dict[str, str]:
    return {"ids": digest(f.line_id), "depth": digest(f.depth),
            "counts": digest_counts(dict(f.stats))}


@dataclass
class Case:
    """Frames of one target seen along ``cameras`` by one renderer (its history kept)."""

    target: Any
    cameras: list
    size: tuple[int, int]
    kwargs: dict = field(default_factory=dict)
    config: RasterConfig | None = None


def _mesh(name: str) -> Mesh:
    path = MESH_DIR / name
    if not path.is_file():
        pytest.skip(f"shared mesh {name} not found in {MESH_DIR}")
    return Mesh.load(path)


def _framed(name: str, w: int, h: int, direction=(1.0, 0.6, 1.6)) -> tuple[Mesh, Camera]:
    m = _mesh(name)
    lo, hi = m.bounds()
    return m, Camera.framing(lo, hi, direction=direction, aspect=w / h)


def _soup(w: int, h: int) -> tuple[Mesh, MatrixCamera]:
    """Random triangles in eye space, many crossing the near plane (Lens near = 0.4)."""
    lens = Lens(80.0, 0.4, 60.0)
    v, f, _ = random_soup(np.random.default_rng(2024), 600, w, h, lens)
    return Mesh(v, f), MatrixCamera(lens.projection(w / h))


def _planes(m: Mesh) -> np.ndarray:
    lo, hi = m.bounds()
    c = (lo + hi) / 2
    n = np.array([[1.0, 0.3, 0.2], [-0.2, 1.0, 0.5]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.concatenate([n, -(n @ c)[:, None] + [[0.0], [0.02 * float(np.ptp(hi - lo))]]],
                          axis=1)


def case_bunny_back() -> Case:
    m, cam = _framed("stanford_bunny.ply", 96, 72)
    return Case(m, [cam], (96, 72), {"cull": "back", "overdraw": True})


def case_spot_none() -> Case:
    m, cam = _framed("spot.ply", 80, 64, direction=(-1.0, 0.3, 1.2))
    return Case(m, [cam], (80, 64), {"cull": "none", "overdraw": True})


def case_teapot_front_tile8() -> Case:
    m, cam = _framed("utah_teapot.ply", 72, 56)
    return Case(m, [cam], (72, 56), {"cull": "front"}, RasterConfig(tile_log2=3))


def case_dragon_tile64() -> Case:
    m, cam = _framed("stanford_dragon_res3.ply", 100, 75, direction=(0.2, 0.3, 1.0))
    return Case(m, [cam], (100, 75), {"overdraw": True}, RasterConfig(tile_log2=6))


def case_soup_near_clip() -> Case:
    m, cam = _soup(48, 32)
    return Case(m, [cam], (48, 32), {"cull": "none", "frustum": False, "cones": False})


def case_soup_reversed_z() -> Case:
    m, cam = _soup(48, 32)
    return Case(m, [cam], (48, 32), {"cull": "back", "frustum": False, "cones": False,
                                     "reversed_z": True})


def case_armadillo_near_clip() -> Case:
    """The near plane through the middle of the armadillo: it cuts hundreds of triangles."""
    m, framing = _framed("armadillo_86k.ply", 80, 60, direction=(0.3, 0.2, 1.0))
    lo, hi = m.bounds()
    c = (lo + hi) / 2
    dist = float(np.linalg.norm(framing.eye - c))
    cam = Camera.look_at(framing.eye, c, fov_y=45.0, near=dist, far=4.0 * dist)
    return Case(m, [cam], (80, 60), {"cull": "none"})


def case_cow_clip_planes() -> Case:
    m, cam = _framed("cow.ply", 80, 60)
    return Case(m, [cam], (80, 60), {"cull": "none", "clip_planes": _planes(m)})


def case_bunny_clip_planes_reversed_z() -> Case:
    m, cam = _framed("stanford_bunny.ply", 64, 64, direction=(-0.5, 0.2, 1.0))
    return Case(m, [cam], (64, 64), {"clip_planes": _planes(m)[:1], "reversed_z": True})


def case_spot_window() -> Case:
    m, cam = _framed("spot.ply", 96, 72)
    outer = [(10.3, 5.2), (30.7, 5.2), (30.7, 50.1), (60.2, 50.1), (60.2, 5.2), (85.9, 5.2),
             (85.9, 66.6), (10.3, 66.6)]
    hole = [(40.5, 55.25), (50.0, 60.0), (44.0, 64.5)]
    return Case(m, [cam], (96, 72), {"window": (outer, [hole])})


def case_bunny_tiny_budget() -> Case:
    from clraster.base.layout import CLUSTER_MAX

    m, cam = _framed("stanford_bunny.ply", 96, 72)
    return Case(m, [cam], (96, 72), {"overdraw": True},
                RasterConfig(batch_triangles=CLUSTER_MAX, batch_entries=97))


def case_plant_occlusion_path() -> Case:
    from clraster.world.generators import plant, plant_inside_camera

    scene = plant(20_000, seed=1)
    w, h = 80, 60
    c0 = plant_inside_camera(scene, w, h)
    eye, fwd = np.asarray(c0.eye, float), np.array([1.0, 0.0, 0.0])
    cams = [Camera.look_at(eye + fwd * (1.5 * k), eye + fwd * (1.5 * k + 1.0)
                           + [0.0, 0.0, 0.15 * k], fov_y=60.0, near=0.1, far=c0.far)
            for k in range(3)]
    return Case(scene, cams, (w, h), {"occlusion": True})


def case_mirrored_instances() -> Case:
    import trimesh

    rng = np.random.default_rng(5)
    tms = [trimesh.creation.icosphere(subdivisions=2),
           trimesh.creation.capsule(height=1.0, radius=0.4),
           trimesh.creation.box(extents=(1.2, 0.6, 0.9))]
    scene = Scene()
    for k in range(6):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        if (np.linalg.det(q) > 0) == bool(k % 2):   # odd instances mirror
            q[:, 0] = -q[:, 0]
        t = np.eye(4)
        t[:3, :3] = q @ np.diag(rng.uniform(0.6, 1.4, 3))
        t[:3, 3] = rng.uniform(-2.5, 2.5, 3)
        tm = tms[k % 3]
        scene.add(Mesh(tm.vertices, tm.faces), t)
    cam = Camera.look_at((0.5, 1.5, 9.0), (0.0, 0.0, 0.0), fov_y=50.0, near=0.5, far=30.0)
    return Case(scene, [cam], (80, 64), {"cull": "back", "overdraw": True})


CASES: dict[str, Callable[[], Case]] = {
    name[len("case_"):]: fn for name, fn in globals().items() if name.startswith("case_")}

LINE_SIZE = (64, 48)


def _line_inputs() -> tuple[np.ndarray, Camera, np.ndarray]:
    """spot's edges, depth-tested against its rendered depth (so lines hide behind it)."""
    m, cam = _framed("spot.ply", *LINE_SIZE)
    f = np.asarray(m.faces)
    e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1),
                  axis=0)
    seg = np.asarray(m.vertices, np.float64)[e[::7]]
    depth = reference.render(m, cam, *LINE_SIZE).depth
    return seg, cam, depth


def device_hashes(names: list[str] | None = None) -> dict[str, list[dict[str, str]]]:
    """This process's device (the default choice: CLRASTER_DEVICE etc.) on the cases."""
    from clraster.pipeline.lines import LineRenderer

    out: dict[str, list[dict[str, str]]] = {}
    for name in names or [*CASES, "lines_spot"]:
        if name == "lines_spot":
            seg, cam, depth = _line_inputs()
            fr = LineRenderer(*LINE_SIZE).render(seg, cam, depth=depth, depth_bias=1e-4)
            out[name] = [line_hashes(fr)]
            continue
        c = CASES[name]()
        r = Renderer(*c.size, config=c.config)
        out[name] = [frame_hashes(r.render(c.target, cam, **c.kwargs)) for cam in c.cameras]
    return out


@pytest.fixture(scope="module")
def golden() -> dict[str, list[dict[str, str]]]:
    return json.loads(GOLDEN.read_text())


def test_golden_covers_the_cases(golden):
    assert set(golden) == {*CASES, "lines_spot"}
    assert len(golden) >= 12


@pytest.mark.parametrize("name", sorted(CASES))
def test_device_reproduces_golden(golden, name):
    c = CASES[name]()
    r = Renderer(*c.size, config=c.config)
    got = [frame_hashes(r.render(c.target, cam, **c.kwargs)) for cam in c.cameras]
    assert got == golden[name], f"{name} on {r.device_description}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_twin_reproduces_golden_ids_depth_counts(golden, name):
    c = CASES[name]()
    r = reference.Renderer(*c.size, config=c.config)
    kw = {k: v for k, v in c.kwargs.items() if k != "overdraw"}
    got = [frame_hashes(r.render(c.target, cam, **kw)) for cam in c.cameras]
    for k, (g, want) in enumerate(zip(got, golden[name], strict=True)):
        for key in ("ids", "depth", "counts"):
            assert g[key] == want[key], f"{name} frame {k}: the twin's {key} differ"


def test_lines_reproduce_golden(golden):
    from clraster.pipeline.lines import LineRenderer

    seg, cam, depth = _line_inputs()
    dev = LineRenderer(*LINE_SIZE).render(seg, cam, depth=depth, depth_bias=1e-4)
    twin = ref_lines.render_lines(seg, cam, *LINE_SIZE, depth=depth, depth_bias=1e-4)
    assert (dev.line_id >= 0).sum() > 50   # not a vacuous case
    assert [line_hashes(dev)] == golden["lines_spot"]
    assert [line_hashes(twin)] == golden["lines_spot"]


def _on_oclgrind(names: list[str]) -> dict[str, list[dict[str, str]]]:
    """`device_hashes` in a subprocess whose device is Oclgrind (CLRASTER_DEVICE)."""
    import pyopencl as cl

    if not any("oclgrind" in p.name.lower() for p in cl.get_platforms()):
        pytest.skip("Oclgrind is not installed")
    env = dict(os.environ, CLRASTER_DEVICE="oclgrind")
    env.pop("PYOPENCL_CTX", None)
    # the subprocess must import the same clraster as this process (a script's own folder,
    # not the working directory, heads its path: it would take an installed copy)
    import clraster

    pkg_root = str(Path(clraster.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = os.pathsep.join([pkg_root, env.get("PYTHONPATH", "")]).rstrip(
        os.pathsep)
    proc = subprocess.run([sys.executable, "-W", "ignore", str(Path(__file__)), "--print",
                           *names], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_oclgrind_reproduces_golden_subset(golden):
    assert _on_oclgrind(list(OCLGRIND_CASES)) == {k: golden[k] for k in OCLGRIND_CASES}


@pytest.mark.slow
def test_oclgrind_reproduces_golden_all(golden):
    """Every case on Oclgrind (~20 s here)."""
    if not MESH_DIR.is_dir():
        pytest.skip(f"shared meshes not found in {MESH_DIR}")
    assert _on_oclgrind(sorted(golden)) == golden


#: the cases rendered with fallbacks forced: every kernel file's fallbacks run (vertex, setup
#: with clipping, bin, raster with overdraw, the pyramid and Hi-Z test on the occlusion path,
#: lines where the spot mesh is there), and none needs the shared meshes
FALLBACK_CASES = ("soup_near_clip", "mirrored_instances", "plant_occlusion_path")


def _with_fallbacks(monkeypatch, mode: str, names: list[str]) -> dict[str, Any]:
    """`device_hashes` of ``names`` with ``CLRASTER_FALLBACKS=mode``, after checking that
    the kernels were built with that mode's options."""
    from clraster.pipeline.device import default_context
    from clraster.pipeline.features import FEATURES, feature_options

    monkeypatch.setenv("CLRASTER_FALLBACKS", mode)
    want = ({"-DCLRASTER_PORTABLE"} if mode == "portable" else
            {f"-D{FEATURES[n].macro}" for n in
             (FEATURES if mode == "all" else mode.split(","))})
    assert want <= set(feature_options(default_context()))
    if (MESH_DIR / "spot.ply").is_file():
        names = [*names, "lines_spot"]
    return device_hashes(names)


@pytest.mark.parametrize("mode", ["all", "portable"])
def test_fallbacks_reproduce_golden(golden, monkeypatch, mode):
    """Every builtin's portable fallback on (``all``: what a compiler with none of them
    builds; ``portable``: CLRASTER_PORTABLE, Oclgrind's build) gives the same bytes."""
    got = _with_fallbacks(monkeypatch, mode, list(FALLBACK_CASES))
    assert got == {k: golden[k] for k in got}


@pytest.mark.slow
@pytest.mark.parametrize("feature", ["rintf", "ctz", "nontemporal_store", "prefetch",
                                     "convertvector", "shufflevector", "roundeven",
                                     "ext_vector_type"])
def test_each_fallback_reproduces_golden(golden, monkeypatch, feature):
    """One fallback at a time (a compiler missing just that builtin), on every case."""
    got = _with_fallbacks(monkeypatch, feature, sorted(CASES))
    assert got == {k: golden[k] for k in got}


def main(argv: list[str]) -> int:
    if argv[:1] == ["--regenerate"]:
        GOLDEN.parent.mkdir(exist_ok=True)
        GOLDEN.write_text(json.dumps(device_hashes(), indent=1, sort_keys=True) + "\n")
        print(f"wrote {GOLDEN}")
        return 0
    if argv[:1] == ["--print"]:
        print(json.dumps(device_hashes(argv[1:] or None), sort_keys=True))
        return 0
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
