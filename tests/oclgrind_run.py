"""Run small differential cases on the Oclgrind simulator (a helper of test_oclgrind.py).

Run as a subprocess so that Oclgrind's reports, which it prints on the process's stderr,
can be captured. Prints one JSON line on stdout: the cases run, their mismatches against the
NumPy twin, and (exit status 3) why the Oclgrind platform could not be used.

    python tests/oclgrind_run.py [--quick]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from random_scenes import Lens, random_soup  # noqa: E402


def main() -> int:
    import pyopencl as cl

    try:
        plats = [p for p in cl.get_platforms() if "oclgrind" in p.name.lower()]
        if not plats:
            print(json.dumps({"unavailable": "no OpenCL platform named Oclgrind; platforms: "
                              + ", ".join(p.name for p in cl.get_platforms())}))
            return 3
        ctx = cl.Context(plats[0].get_devices())
    except Exception as exc:  # the ICD may be missing or broken
        print(json.dumps({"unavailable": f"{type(exc).__name__}: {exc}"}))
        return 3

    from clraster import Mesh, RasterConfig, Renderer
    from clraster.pipeline import reference

    class Cam:
        def __init__(self, m):
            self.m = m

        def view_projection(self, w, h):
            return self.m

    quick = "--quick" in sys.argv
    w, h = 33, 17
    lens = Lens(80.0, 0.4, 60.0)
    cam = Cam(lens.projection(w / h))
    v, f, _ = random_soup(np.random.default_rng(2024), 150 if quick else 1500, w, h, lens)
    v = v.copy()
    v[5] = np.nan  # a few invalid triangles too
    meshes = {"soup": Mesh(v, f), "empty": Mesh([], []),
              "one": Mesh([[-0.5, -0.5, -1.0], [0.5, -0.5, -1.0], [0.0, 0.5, -1.0]],
                          [[0, 1, 2]]),
              # two triangles past the image's edges, slanted
              "quad": Mesh([[-3.0, -2.0, -1.0], [3.0, -2.0, -2.0], [3.0, 2.0, -3.0],
                            [-3.0, 2.0, -1.5]], [[0, 1, 2], [0, 2, 3]])}
    def compared(case, a, b):
        """The comparison record of OpenCL frame ``a`` against the twin's ``b``."""
        return {
            "case": case,
            "id_mismatch": int((a.triangle_id != b.triangle_id).sum()),
            "depth_mismatch": int((a.depth != b.depth).sum()),
            "bary_max_diff": float(np.abs(a.barycentrics - b.barycentrics).max()),
            "counts_equal": a.stats.counts() == b.stats.counts(),
            # fragments tested per pixel (the raster's overdraw paths) add up
            "overdraw_ok": (a.overdraw is None
                            or int(a.overdraw.sum()) == a.stats.fragments_tested),
            "covered": int(a.mask.sum()),
            "clipped": a.stats.clipped,
        }

    results = []
    for tile_log2 in ((3,) if quick else (3, 4, 6)):
        config = RasterConfig(tile_log2=tile_log2, bin_chunks=7)
        r = Renderer(w, h, config=config, context=ctx)
        for name, mesh in meshes.items():
            for cull in (("none",) if quick else ("none", "back")):
                case = f"{name} tile_log2={tile_log2} cull={cull}"
                b = reference.render(mesh, cam, w, h, cull=cull, config=config)
                results.append(compared(case, r.render(mesh, cam, cull=cull, overdraw=True),
                                        b))
                if name in ("one", "quad"):
                    # without overdraw: a tile whose list is one wide piece takes the
                    # raster's sole-piece path (raster.cl sole_piece_tile)
                    results.append(compared(case + " no overdraw",
                                            r.render(mesh, cam, cull=cull), b))
    # the depth pyramid against its twin, at sizes whose rows are not 32-byte aligned and
    # whose blocks take both the float8 first level and the clamped one (pyramid.cl)
    from clraster.pipeline.reference import pyramid as ref_pyramid
    from clraster.pipeline.stages.pyramid import PyramidStage
    queue = cl.CommandQueue(ctx)
    stage = PyramidStage(ctx)
    rng = np.random.default_rng(7)
    pyramids = []
    for ph, pw in ((37, 130), (70, 97)):
        depth = rng.random((ph, pw), dtype=np.float32)
        buf = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                        hostbuf=depth)
        got = stage.build(queue, buf, pw, ph).read(queue)
        want = ref_pyramid.build(depth)
        pyramids.append({"size": f"{pw}x{ph}", "equal": len(got) == len(want) and all(
            np.array_equal(g, t) for g, t in zip(got, want, strict=False))})
    print(json.dumps({"device": ctx.devices[0].name, "results": results,
                      "pyramids": pyramids}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
