"""Sort-last rendering on Dask: compositing time as a share of frame time.

    python bench/sort_last.py --mesh ../shared/meshes/stanford_dragon_vrip.ply \\
        --size 1920x1080 --parts 2 4 8 --workers 2 --repeat 5

Starts a LocalCluster (`clraster.distributed.local_cluster`: ``--workers`` processes, one
task thread each, PoCL threads = cores // workers), scatters the parts of the scene once per
part count (`scatter_parts`, outside the timed part), warms every worker up with two frames,
then times ``--repeat`` frames of `submit_sort_last` per part count, measuring on the client:

* ``parts``: submit → every part frame rendered (on the workers);
* ``tree``: → the root of the reduction tree computed (on the workers). tree − parts is
  the compositing the frame waits for (transfers between workers + the NumPy operator; a
  level that can start before the last part is done overlaps with rendering);
* ``frame``: → the composited frame on the client (adds the gather of the root's crop and
  `uncrop` to the full frame).

Part frames travel cropped to the rectangle they cover (`clraster.composite.Crop`).

Also the NumPy operator alone (`clraster.composite.composite` of two frames, in this process)
and the one-machine frame (`Renderer.render` in this process, PoCL on every core). Medians.
``--plant N`` renders `clraster.scenes.plant(N)` from inside instead of a mesh. Every
composited frame is checked against the one-machine frame (ids and depth bit for bit).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

import clraster
from clraster.scale.composite import composite, uncrop
from clraster.scale.distributed import local_cluster, scatter_parts, submit_sort_last


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="../shared/meshes/stanford_dragon_vrip.ply")
    ap.add_argument("--plant", type=int, default=0, help="use plant(N) from inside instead")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--parts", type=int, nargs="+", default=[2, 4, 8])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    if a.plant:
        from clraster.world.generators import plant, plant_inside_camera

        target = plant(a.plant)
        cam = plant_inside_camera(target, w, h)
        name = f"plant({a.plant:,}) inside"
    else:
        target = clraster.Mesh.load(a.mesh)
        lo, hi = target.bounds()
        cam = clraster.Camera.framing(lo, hi, fov_y=45.0, aspect=w / h)
        name = a.mesh.rsplit("/", 1)[-1]

    # one machine (this process, all cores), for reference
    r = clraster.Renderer(w, h)
    ref = r.render(target, cam)
    one = []
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        r.render(target, cam)
        one.append((time.perf_counter() - t0) * 1e3)
    op = []
    f2 = r.render(target, cam)
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        composite(ref, f2)
        op.append((time.perf_counter() - t0) * 1e3)
    del r

    from dask.distributed import Client, wait

    rows = []
    with local_cluster(a.workers) as cluster, Client(cluster) as client:
        for n in a.parts:
            held = scatter_parts(client, target, n)
            for _ in range(2):   # warm-up: programs, buffers, plan caches on every worker
                submit_sort_last(held, cam, client, width=w, height=h).frame.result()
            t_parts, t_tree, t_frame, t_ops = [], [], [], []
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                futs = submit_sort_last(held, cam, client, width=w, height=h)
                wait(list(futs.parts))
                t1 = time.perf_counter()
                wait([futs.frame])
                t2 = time.perf_counter()
                root = futs.frame.result()
                out = uncrop(root)
                t3 = time.perf_counter()
                if not (np.array_equal(out.triangle_id, ref.triangle_id)
                        and np.array_equal(out.depth, ref.depth)):
                    raise SystemExit(f"{n} parts: the composited frame differs")
                t_parts.append((t1 - t0) * 1e3)
                t_tree.append((t2 - t0) * 1e3)
                t_frame.append((t3 - t0) * 1e3)
                t_ops.append(root.frame.stats.timings_ms.get("composite", 0.0))
                del futs
            med = {k: statistics.median(v) for k, v in (
                ("parts_ms", t_parts), ("tree_ms", t_tree), ("frame_ms", t_frame),
                ("composite_ops_ms", t_ops))}
            med["composite_wait_ms"] = med["tree_ms"] - med["parts_ms"]
            med["share"] = med["composite_wait_ms"] / med["frame_ms"]
            med["share_with_gather"] = (med["frame_ms"] - med["parts_ms"]) / med["frame_ms"]
            rows.append({"parts": n, **med})
            del held
    result = {"scene": name, "size": f"{w}x{h}", "workers": a.workers,
              "one_machine_ms": statistics.median(one), "operator_ms": statistics.median(op),
              "rows": rows}
    print(f"{name} at {w}x{h}, {a.workers} workers; one machine {result['one_machine_ms']:.0f}"
          f" ms/frame; the NumPy operator on two frames {result['operator_ms']:.1f} ms")
    print(f"{'parts':>5} {'parts ms':>9} {'tree ms':>8} {'frame ms':>9} {'composite wait':>15}"
          f" {'share':>6} {'+gather':>8} {'ops (sum)':>10}")
    for row in rows:
        print(f"{row['parts']:>5} {row['parts_ms']:>9.0f} {row['tree_ms']:>8.0f} "
              f"{row['frame_ms']:>9.0f} {row['composite_wait_ms']:>12.0f} ms {row['share']:>6.1%}"
              f" {row['share_with_gather']:>8.1%} {row['composite_ops_ms']:>7.0f} ms")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
