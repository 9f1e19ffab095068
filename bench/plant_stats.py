"""Build the procedural power plant at the given sizes and report what came out.

    python bench/plant_stats.py 1000000 10000000 --seed 0

Per size: triangles (and the error against the request), instances, unique meshes, the
largest mesh, the instanced share, the building's size (storeys, rooms), the build time
(median of ``--repeat`` builds; the timed closure is ``plant(n, seed=seed)`` only) and
the memory it holds (bytes of its unique meshes' arrays). Peak resident memory of the
process is printed at the end (it includes Python and NumPy themselves).
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import time

from clraster.world import generators as scenes


def stats(n: int, seed: int, repeat: int) -> dict[str, object]:
    times = []
    scene = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        scene = scenes.plant(n, seed=seed)
        times.append(time.perf_counter() - t0)
    assert scene is not None
    meshes: dict[int, object] = {}
    uses: dict[int, int] = {}
    for inst in scene.instances:
        meshes.setdefault(id(inst.mesh), inst.mesh)
        uses[id(inst.mesh)] = uses.get(id(inst.mesh), 0) + 1
    unique_faces = sum(m.n_faces for m in meshes.values())
    instanced = sum(m.n_faces * uses[k] for k, m in meshes.items() if uses[k] > 1)
    lo, hi = scene.bounds()
    storeys = round((hi[1] - lo[1] - scenes.SLAB) / scenes.STOREY)
    rooms = 2 * round((hi[0] - lo[0]) / scenes.ROOM_X) * round((hi[2] - lo[2]) / scenes.BAND)
    return {
        "requested": n,
        "triangles": scene.n_faces,
        "error_pct": 100.0 * (scene.n_faces - n) / n,
        "instances": scene.n_instances,
        "unique_meshes": len(meshes),
        "unique_triangles": unique_faces,
        "largest_mesh": max(m.n_faces for m in meshes.values()),
        "instanced_share_pct": 100.0 * instanced / scene.n_faces,
        "storeys": storeys,
        "rooms": storeys * rooms,
        "size_m": [round(float(v), 2) for v in hi - lo],
        "build_s": statistics.median(times),
        "mesh_mb": sum(m.vertices.nbytes + m.faces.nbytes for m in meshes.values()) / 2**20,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sizes", nargs="+", type=int, help="requested triangle counts")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=1, help="builds per size (median time)")
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args(argv)
    rows = []
    for n in a.sizes:
        r = stats(n, a.seed, max(1, a.repeat))
        rows.append(r)
        print(f"plant({n:,}): {r['triangles']:,} triangles ({r['error_pct']:+.2f}%), "
              f"{r['instances']:,} instances of {r['unique_meshes']} meshes "
              f"({r['unique_triangles']:,} unique triangles, largest {r['largest_mesh']:,}, "
              f"{r['instanced_share_pct']:.0f}% of the triangles in shared meshes), "
              f"{r['storeys']} storeys × {r['rooms'] // max(1, r['storeys'])} rooms, "
              f"{r['size_m'][0]:g} × {r['size_m'][1]:g} × {r['size_m'][2]:g} m; "
              f"built in {r['build_s']:.2f} s, meshes hold {r['mesh_mb']:.0f} MiB")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_mb = peak / 2**20 if sys.platform == "darwin" else peak / 2**10
    print(f"peak resident memory of this process: {peak_mb:.0f} MiB")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"results": rows, "peak_rss_mb": peak_mb}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
