"""Views per second of a dataset job — metric depth, triangle ids and face normals of many
views of one mesh — with clraster and with Open3D's RaycastingScene (Embree), in one run.

    python bench/datasets.py ../shared/meshes/stanford_dragon_vrip.ply --views 200

One mesh file, printed; the measurement (cameras, jobs, ABBA rounds, medians) is the
harness's datasets sweep, `clraster.bench.datasets` (its docstring says what is timed), which
``clraster bench --sweeps datasets`` runs over several meshes into results.json. Open3D is
used where it imports (``pip install 'clraster[open3d]'``; it needs the system's
libusb-1.0); without it only clraster is timed.
"""

from __future__ import annotations

import argparse

from clraster import Mesh
from clraster.base.checks import parse_size
from clraster.bench.datasets import DATASETS_CULLS, measure_mesh


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--size", type=parse_size, default=(640, 480))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cull", choices=("back", "none", "both"), default="both")
    a = ap.parse_args(argv)
    mesh = Mesh.load(a.mesh)
    culls = DATASETS_CULLS if a.cull == "both" else (a.cull,)
    row = measure_mesh(mesh, a.mesh, views=a.views, size=a.size, repeat=a.repeat,
                       culls=culls, source=a.mesh, log=print)
    o3d = row["open3d"]
    if "skipped" in o3d:
        print(o3d["skipped"])
    for cull, c in row["clraster"].items():
        if c["ids_agree_open3d"] is not None:
            print(f"first view: clraster cull={cull} ids agree with Open3D's on "
                  f"{100 * c['ids_agree_open3d']:.2f}% of pixels")
    w, h = row["size"]
    print(f"{a.views} views of {a.mesh} ({row['triangles']:,} triangles) at {w}x{h}, depth "
          f"+ ids + normals, median of {a.repeat}:")
    for cull, c in row["clraster"].items():
        ratio = row["ratio_vs_open3d"].get(cull)
        print(f"  clraster cull={cull:<5} {c['median_views_per_s']:7.2f} views/s"
              + (f" ({ratio:.2f}x Open3D)" if ratio is not None else ""))
    if "median_views_per_s" in o3d:
        print(f"  open3d raycast     {o3d['median_views_per_s']:7.2f} views/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
