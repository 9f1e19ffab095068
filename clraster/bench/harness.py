"""Benchmark harness: the OpenCL pipeline vs its NumPy twin (and Mesa llvmpipe), one run.

    clraster bench                 # the full matrix (about 10-20 min on 2 cores)
    clraster bench --quick         # the smoke mode CI runs (< 1 min; asserts it works)
    clraster bench --list          # print the configurations and exit

The matrix is four sweeps, each a list of configurations (scene × image size × culling
mode); a configuration that belongs to two sweeps runs once:

* ``triangles`` (time vs triangles): meshes from ``--meshes`` (spot … the 871K dragon), an
  instance grid of the dragon and the procedural plant up to ≥ 10M triangles, at ``--size``;
* ``pixels`` (time vs pixels): ``--pixels-scene`` at each of ``--sizes``;
* ``culling``: ``--culling-scene`` (the ≥ 10M plant seen from inside) at ``--size`` in each
  of ``--modes``: off (no object culling), frustum (BVH frustum + normal cones) and occlusion
  (those + two-phase Hi-Z occlusion culling);
* ``scale`` (only when named: ``--sweeps scale`` or ``all``): instance grids of the dragon
  of 10M to 200M triangles, overview and inside views, with peak RSS per configuration and
  a line fitted to frame time over the triangles sent to setup (`clraster.bench.scale`).

Per configuration: one Renderer, warm-up frames of the OpenCL path (occlusion gets
``--occlusion-warmup`` more, so its visible set from the previous frame is warm) and one of
the twin, then ``--repeat`` rounds interleaved (OpenCL, twin, OpenCL, twin, ...), so machine
noise hits both alike; medians. A frame's time is the wall time of ``render()`` (host
culling and the read-back of depth, ids and barycentrics included); per-stage times are
the device times from OpenCL profiling events (``frame.stats.timings_ms``). The twin gets a
time budget per configuration (``--twin-budget``): once spent, it stops after ≥ 1 timed run
and the JSON says how many it made. The twin renders the same culling mode, occlusion
culling included (it runs the same two-phase schedule, `clraster.pipeline.twophase`). The OpenCL and
twin images are compared (triangle ids identical, largest depth difference). The llvmpipe peer
(`clraster.bench.peer_llvmpipe`) draws the whole scene with back-face culling on the same
view-projection, one frame per round after clraster's (interleaved like the twin); its
coverage is compared with clraster's. Each round also times clraster making only what
llvmpipe makes (depth and ids).

Also measured: cold start (fresh, empty PoCL and pyopencl kernel caches) and warm start of a
fresh process, and the peak memory (VmHWM, not ru_maxrss) of a fresh process rendering one
frame of each scene, the OpenCL path and the twin separately.

Outputs in ``--out``: results.json, results.md, and PNG plots (with matplotlib).

Where the code lives: `clraster.bench.spec` (scenes, configurations, sweeps, targets),
`clraster.bench.measure` (one configuration, the llvmpipe peer, the subprocess probes),
`clraster.bench.scale` (the scale sweep's scenes, inside camera, fit and goals),
`clraster.bench.report` (results.json, results.md), `clraster.bench.plots` (PNG plots) and
`clraster.bench.cli` (arguments, progress bar, :func:`main`). This module is the entry point
``clraster bench`` and ``bench/harness.py`` call, and re-exports the names below.
"""

from clraster.bench.cli import main
from clraster.bench.measure import (
    PeerRunner,
    measure_memory,
    measure_startup,
    run_config,
)
from clraster.bench.report import SCHEMA, markdown
from clraster.bench.spec import (
    MESH_ALIASES,
    MODES,
    TWIN_MODE,
    Config,
    LoadedScene,
    SceneMissing,
    SceneSpec,
    build_matrix,
    evaluate_targets,
    load_scene,
    mesh_path,
)

__all__ = ["MESH_ALIASES", "MODES", "SCHEMA", "TWIN_MODE", "Config", "LoadedScene",
           "PeerRunner", "SceneMissing", "SceneSpec", "build_matrix", "evaluate_targets",
           "load_scene", "main", "markdown", "measure_memory", "measure_startup",
           "mesh_path", "run_config"]

if __name__ == "__main__":
    raise SystemExit(main())
