"""Hierarchical occlusion culling: frame times per group size, still and walking.

    PYTHONPATH=. python bench/occlusion_groups.py                    # 0 (flat) 8 16 32 64
    PYTHONPATH=. python bench/occlusion_groups.py --groups 0 16 --walk 40

The 10M plant (`plant(10_100_000)`), first person (`plant_inside_camera`), 1920x1080, two-
phase occlusion culling, one `Renderer` per `RasterConfig(occlusion_groups=g)` (0: the
flat schedule, every cluster tested). Still camera: after a warm-up, ``--frames`` rounds
in which every renderer draws one frame, the order alternating per round; per group size
the median and min frame wall time and the clusters a frame culls one by one (frustum
and cone tests: every cluster of the instances in view when flat, those of the groups not
proved hidden and last frame's visible ones when hierarchical). Walk (``--walk N`` > 0): N cameras
stepping 0.25 m down the corridor while the gaze turns 0.02 rad a step, twice over, every
renderer drawing each camera in turn; the median and mean frame. Every frame's triangle ids
are compared across the group sizes (they must be identical: culling is conservative).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from clraster import Camera, RasterConfig, Renderer
from clraster.culling.cull import ViewCull
from clraster.world.generators import plant, plant_inside_camera


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--groups", type=int, nargs="+", default=[0, 8, 16, 32, 64])
    ap.add_argument("--frames", type=int, default=15)
    ap.add_argument("--walk", type=int, default=40)
    ap.add_argument("--triangles", type=int, default=10_100_000)
    a = ap.parse_args(argv)
    w, h = 1920, 1080
    scene = plant(a.triangles)
    cam0 = plant_inside_camera(scene, w, h)
    rs = {g: Renderer(w, h, config=RasterConfig(occlusion_groups=g)) for g in a.groups}
    # clusters culled one by one: the pairs `ViewCull.pairs` gets (hierarchical), or every
    # pair of the instances in view (`ViewCull.all`: the flat schedule)
    tested: dict[int, int] = {}
    seen: list[int] = []
    pairs, full = ViewCull.pairs, ViewCull.all

    def counting_pairs(self, inst, cl):
        seen.append(int(inst.size))
        return pairs(self, inst, cl)

    def counting_all(self):
        dl = full(self)
        seen.append(dl.counts["clusters_total"] - self.outside_totals()[0])
        return dl

    for g, r in rs.items():
        for _ in range(2):
            r.render(scene, cam0, occlusion=True)
        ViewCull.pairs, ViewCull.all = counting_pairs, counting_all
        seen.clear()
        r.render(scene, cam0, occlusion=True)
        ViewCull.pairs, ViewCull.all = pairs, full
        tested[g] = sum(seen)
    times: dict[int, list[float]] = {g: [] for g in rs}

    def round_(cam, k: int) -> None:
        ids = None
        order = list(rs.items()) if k % 2 else list(reversed(rs.items()))
        for g, r in order:
            t0 = time.perf_counter()
            f = r.render(scene, cam, occlusion=True)
            times[g].append((time.perf_counter() - t0) * 1e3)
            if ids is None:
                ids = f.triangle_id
            elif not np.array_equal(ids, f.triangle_id):
                raise SystemExit(f"ids differ with groups of {g}")

    for k in range(a.frames):
        round_(cam0, k)
    print(f"still camera, {a.frames} rounds (frame ms):")
    for g in rs:
        print(f"  groups {g:3d}: median {statistics.median(times[g]):7.2f}  min "
              f"{min(times[g]):7.2f}  clusters tested one by one {tested[g]:,}")
    if a.walk > 0:
        eye0 = np.asarray(cam0.eye, np.float64)

        def cam(k: int) -> Camera:
            e = eye0 + [0.25 * k, 0.0, 0.0]
            t = 0.02 * k
            return Camera.look_at(e, e + [np.cos(t), 0.0, np.sin(t)], (0.0, 1.0, 0.0),
                                  fov_y=cam0.fov_y, near=cam0.near, far=cam0.far)

        cams = [cam(k) for k in range(a.walk)]
        for r in rs.values():
            r.render(scene, cams[0], occlusion=True)
        times = {g: [] for g in rs}
        for rep in range(2):
            for k, c in enumerate(cams):
                round_(c, k + rep)
        print(f"walk, {a.walk} cameras twice (frame ms):")
        for g in rs:
            print(f"  groups {g:3d}: median {statistics.median(times[g]):7.2f}  mean "
                  f"{statistics.mean(times[g]):7.2f}  max {max(times[g]):6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
