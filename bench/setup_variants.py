"""The setup_triangles kernel alone, on inputs captured from one frame, built from variants
of kernels/setup.cl that stop at a given step: where a dense mesh's setup time goes.

    python bench/setup_variants.py ../shared/meshes/stanford_dragon_vrip.ply 640 480

One frame is rendered to capture the setup stage's inputs (the pool, the draws); then each
variant is built from the working tree's source with one substitution
(timing only: a variant's results are wrong by design, and are never read) and launched
``--rounds`` times in turn with the same arguments; min and median kernel times (OpenCL
profiling events) are printed. Variants: ``base`` (the kernel), ``vertices`` (return once the
work-item has made its draw's vertices), ``indices`` (return once the work-item has its
lanes' vertex indices), ``facing`` (after the lanes' facing), ``lanes``
(after the lanes' fates and stores, before the pieces), ``no_prefetch`` (without the
prefetch of the pieces' record lines), ``no_store`` (each piece's coverage made, nothing of
it stored), ``no_record`` (value_planes8 without its stores of the records' last 64 bytes),
``no_values`` (value_planes8 returns at once: no value planes). bench/README.md's log quotes
a run. (A variant that drops a result lets LLVM drop what computed it too: ``no_record``
also loses the value planes.)
"""

from __future__ import annotations

import argparse
import statistics
import warnings

import numpy as np
import pyopencl as cl

import clraster
import clraster.pipeline.device as dev
import clraster.pipeline.stages.setup as setup_stage
from clraster.base.config import RasterConfig

#: variant → (text of kernels/setup.cl, the same text with an early exit added or a step
#: taken out). The lanes' stores are skipped by the exits: a variant's outputs are never read.
_EXIT = "    if (width > 0) return 0u;\n"   # in batch_fates
VARIANTS = {
    # (a few of the draw's vertices read back at a run-time index, so that none is dropped)
    "vertices": ("    int codes = any_code != 0;\n",
                 "    if (width > 0) {\n        int j_ = nt & (CLUSTER_MAX - 1);\n"
                 "        status[d] = (uchar)(any_code + V.wx[j_] + V.wy[j_] + V.oc[j_]"
                 " + (int)(V.x[j_] + V.y[j_] + V.w[j_]));\n        return;\n    }\n"
                 "    int codes = any_code != 0;\n"),
    "indices": ("#define OUTC(i) V->oc[i]\n", _EXIT + "#define OUTC(i) V->oc[i]\n"),
    "facing": ("    int8 clipped = (", _EXIT + "    int8 clipped = ("),
    "lanes": ("    return left;\n", "    return width > 0 ? 0u : left;\n"),
    "no_prefetch": ("        PREFETCH(rec); PREFETCH(rec + 64);\n",
                    ""),
    "no_store": ("    if (st == ST_RASTER) {\n        /* the record's first 32 bytes",
                 "    if (width > 0) return;\n"
                 "    if (st == ST_RASTER) {\n        /* the record's first 32 bytes"),
    "no_record": ("        d8[1] = r[k];",
                  "        if (n > 0) continue;\n        d8[1] = r[k];"),
    "no_values": ("    int n = q->n;\n    for (int k = n;",
                  "    q->n = 0; return;\n    int n = q->n;\n    for (int k = n;"),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("width", type=int)
    ap.add_argument("height", type=int)
    ap.add_argument("--rounds", type=int, default=30)
    a = ap.parse_args()

    captured = {}
    run = setup_stage.SetupStage.run

    def capture(self, queue, geo, params, max_pieces=None):
        captured["args"] = (self, queue, geo, params)
        return run(self, queue, geo, params, max_pieces)

    setup_stage.SetupStage.run = capture   # type: ignore[method-assign]
    mesh = clraster.Mesh.load(a.mesh)
    lo, hi = mesh.bounds()
    centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    cam = clraster.Camera.look_at(eye=centre + np.array([0.3, 0.2, 1.0]) * size * 0.9,
                                  target=centre, fov_y=45, near=size * 0.05, far=size * 5)
    r = clraster.Renderer(a.width, a.height)
    r.render(mesh, cam)
    setup_stage.SetupStage.run = run   # type: ignore[method-assign]
    stage, queue, geo, params = captured["args"]
    b = stage.buffers
    args = (geo.draws.buf, np.uint32(geo.n_draws), geo.clusters.buf, geo.local_tris.buf,
            geo.face_ids.buf, geo.positions.buf, geo.mvps64.buf, geo.zrows.buf,
            geo.uplanes.buf, np.int32(geo.n_user), np.uint32(geo.uclip), geo.mvps.buf,
            np.int32(params.width), np.int32(params.height), np.int32(params.cull_mode),
            np.float32(params.kx), np.float32(params.ky), np.int32(params.reversed_z),
            b.pieces.buf, b.status.buf, np.int32(params.tiles_x), b.tile1.buf,
            stage.n_clipped.buf, b.clip_count.buf, b.clip_list.buf)
    gsize, lsize = (max(geo.n_draws, 1),), (1,)   # a work-item per draw (kernels/setup.cl)
    source = dev.kernel_source("setup")
    options = [*RasterConfig().build_options(), *dev.feature_options(r.context)]
    kernels = {}
    for name, (old, new) in {"base": ("", ""), **VARIANTS}.items():
        if old and old not in source:
            raise SystemExit(f"variant {name}: kernels/setup.cl no longer has {old!r}")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", cl.CompilerWarning)
            prg = cl.Program(r.context, source.replace(old, new, 1) if old else source)
            kernels[name] = prg.build(options=options).setup_triangles
    times: dict[str, list[float]] = {name: [] for name in kernels}
    for _ in range(a.rounds + 1):
        for name, k in kernels.items():
            ev = k(queue, gsize, lsize, *args)
            ev.wait()
            times[name].append((ev.profile.end - ev.profile.start) * 1e-6)
    print(f"{mesh.n_faces:,} triangles at {a.width}x{a.height}, {geo.n_tris:,} sent to "
          f"setup; setup_triangles alone, {a.rounds} rounds (after one):")
    for name, t in times.items():
        print(f"  {name:10s} min {min(t[1:]):6.2f} ms  median {statistics.median(t[1:]):6.2f} ms")


if __name__ == "__main__":
    main()
