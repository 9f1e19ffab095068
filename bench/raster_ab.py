"""A/B of the raster kernel alone: a git revision's kernels/ against the working tree's, on
the same bins, in one process, interleaved.

    python bench/raster_ab.py HEAD                          # dragon at 1920x1080
    python bench/raster_ab.py HEAD --mesh spot.ply --n 40
    python bench/raster_ab.py HEAD --plant 10100000         # plant, first person, occlusion
    python bench/raster_ab.py HEAD --mesh quad --close --evict 100   # the fill sweep's quad

Two renderers are built, one from each set of sources (as `kernel_ab.py` does), each
renders the scene a few times; then only `RasterStage.run` is repeated on the bins of each
renderer's last pass (fresh outputs: the last pass of a two-phase frame is rasterized as a
whole frame here), A and B taking turns, and the profiling event of each launch is timed.
Prints min / median device ms per tree, B/A of the medians, and whether the outputs (ids,
depth, barycentrics) are identical. Whole frames are noisier than one kernel on fixed
inputs; this is how the raster figures of bench/README.md's performance log were taken.
As with `kernel_ab.py`, REV's kernels must take the working tree's arguments.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

import clraster
import clraster.pipeline.device as dev
from clraster.pipeline.stages import chain as chain_mod

sys.path.insert(0, str(Path(__file__).resolve().parent))
from kernel_ab import REPO, revision_source, warm_renderers  # noqa: E402  (bench/ is not a package)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", help="git revision whose kernels/ is the baseline (A)")
    ap.add_argument("--mesh", default="stanford_dragon_vrip.ply",
                    help="a file in ../shared/meshes (default the dragon), or quad (the "
                         "fill sweep's large quad)")
    ap.add_argument("--close", action="store_true",
                    help="seen from close by, as the fill sweep's scenes (spec.close_camera)")
    ap.add_argument("--evict", type=int, default=0, metavar="MB",
                    help="touch this many MB before each launch (cold caches, as in the "
                         "harness)")
    ap.add_argument("--plant", type=int, help="use scenes.plant(N), first person, occlusion")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--n", type=int, default=30, help="launches per tree")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    kw: dict = {}
    if a.plant:
        from clraster.world.generators import plant, plant_inside_camera
        target = plant(a.plant)
        cam = plant_inside_camera(target, w, h)
        kw["occlusion"] = True
    else:
        from clraster.bench.spec import close_camera, quad_mesh
        target = (quad_mesh() if a.mesh == "quad"
                  else clraster.Mesh.load(str(REPO.parent / "shared" / "meshes" / a.mesh)))
        cam = (close_camera(*target.bounds(), w, h) if a.close or a.mesh == "quad"
               else clraster.Camera.framing(*target.bounds(), aspect=w / h))

    # the (queue, params, keywords) of each chain's last pass
    last: dict[int, tuple] = {}
    draw = chain_mod.StageChain.draw

    def recording_draw(self, queue, pool, fd, params, totals, **k):
        last[id(self)] = (queue, params, k)
        return draw(self, queue, pool, fd, params, totals, **k)

    chain_mod.StageChain.draw = recording_draw   # type: ignore[method-assign]
    renderers = warm_renderers((("A", revision_source(a.rev)), ("B", dev.kernel_source)),
                               w, h, target, cam, kw)
    chain_mod.StageChain.draw = draw   # type: ignore[method-assign]

    times: dict[str, list[float]] = {name: [] for name in renderers}
    outs = {}
    junk = np.ones(a.evict << 17) if a.evict else None   # float64: MB << 17 of them
    for i in range(a.n):
        for name in (list(renderers) if i % 2 == 0 else list(renderers)[::-1]):
            if junk is not None:
                junk += 1.0   # read and write every line: the caches hold none of the frame
            ch = renderers[name].chain
            queue, params, k = last[id(ch)]
            out, _, ev = ch.raster.run(queue, ch.setup.buffers, ch.binning.buffers, params,
                                       overdraw=k.get("overdraw", False),
                                       bary=k.get("bary", True))
            times[name].append((ev.profile.end - ev.profile.start) * 1e-6)
            outs[name] = out
    oa, ob = outs["A"], outs["B"]
    same = (np.array_equal(oa.ids, ob.ids) and np.array_equal(oa.depth, ob.depth)
            and (oa.bary is None or np.array_equal(oa.bary, ob.bary)))
    print(f"outputs identical: {same}")
    for name, t in times.items():
        print(f"{name} ({a.rev if name == 'A' else 'working tree'}): raster min {min(t):.2f} "
              f"median {statistics.median(t):.2f} ms")
    print(f"B/A median {statistics.median(times['B']) / statistics.median(times['A']):.3f}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
