"""Batch views on Dask: views per second with 1 vs 2 worker processes on one machine.

    python bench/distributed_views.py --mesh ../shared/meshes/stanford_dragon_vrip.ply \\
        --size 640x480 --views 200 --workers 1 2 --repeat 3

For each worker count a LocalCluster (`clraster.distributed.local_cluster`: that many worker
processes, one task thread each, PoCL threads per worker = cores // workers, so workers ×
threads <= cores) is started once and warmed up (every worker renders a few views: kernel
build, buffers, the mesh's clusters and geometry pool — outside the timed part). Then each
repeat times one whole `clraster.distributed.render_views` call — scatter of the mesh,
``--views`` orbit cameras in chunks, every view's files written on the workers (``--outputs``),
the records gathered — into a fresh folder, deleted afterwards. The clusters stay up side by
side (idle workers cost no CPU) and the repeats are interleaved in ABBA order (1, 2, 2, 1,
...), so machine noise and drift hit every worker count alike; medians are reported, with
the speed-up over the first worker count and the views/s of each worker (views per busy
second, from the summary's per-worker records). Every run must render every view; the
files of the first run of each worker count are checked equal (bytes) to the first's.

A timed call is a whole batch, so it includes what a batch pays once: the mesh scattered to
every worker, and each worker preparing it (clusters, geometry pool: the scattered copy is
a new object, so the plan cache starts cold) — amortized by ``--views``; with few views it
weighs on views/s.

Measure on an otherwise idle machine: another process on the cores changes views/s.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import statistics
import tempfile
from pathlib import Path

import clraster
from clraster.scale.distributed import local_cluster, render_views, usable_cores


def orbit(mesh: clraster.Mesh, n: int, width: int, height: int) -> list[clraster.Camera]:
    """``n`` cameras around the mesh, framing its bounding box, at varying heights (as
    bench/views.py)."""
    lo, hi = mesh.bounds()
    cams = []
    for k in range(n):
        a = 2.0 * math.pi * k / n
        direction = (math.sin(a), 0.2 + 0.4 * math.sin(3.0 * a) ** 2, math.cos(a))
        cams.append(clraster.Camera.framing(lo, hi, direction=direction, aspect=width / height))
    return cams


def _warm(mesh: clraster.Mesh, cam: clraster.Camera, width: int, height: int,
          cull: str) -> int:
    """Worker task: one frame with this worker's Renderer (kernel builds, buffers)."""
    from clraster.scale.distributed import worker_renderer

    worker_renderer(width, height).render(mesh, cam, cull=cull)
    return os.getpid()


def warm_up(client, mesh: clraster.Mesh, cam: clraster.Camera, width: int, height: int,
            cull: str) -> None:
    """One frame on every worker of ``client``, outside the timed part."""
    held = client.scatter(mesh, broadcast=True, hash=False)
    futs = [client.submit(_warm, held, cam, width, height, cull, workers=[addr], pure=False)
            for addr in client.nthreads()]
    pids = client.gather(futs)
    assert len(set(pids)) == len(futs), "every worker warms up its own Renderer"


def abba(keys: list[int], repeat: int) -> list[int]:
    """Run order: keys, reversed keys, keys, ... ``repeat`` rounds."""
    out: list[int] = []
    for r in range(repeat):
        out += keys if r % 2 == 0 else keys[::-1]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default="../shared/meshes/stanford_dragon_vrip.ply")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--chunk", type=int, default=None,
                    help="cameras per task (default: render_views's)")
    ap.add_argument("--outputs", default="depth,ids")
    ap.add_argument("--cull", default="back")
    ap.add_argument("--tmp", default=None, help="folder for the output folders (default: "
                                                "the system's temporary folder)")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    outputs = tuple(o.strip() for o in a.outputs.split(",") if o.strip())
    mesh = clraster.Mesh.load(a.mesh)
    cams = orbit(mesh, a.views, w, h)
    cores = usable_cores()

    from dask.distributed import Client

    runs: dict[int, list[dict]] = {n: [] for n in a.workers}
    first_files: dict[int, dict[str, bytes]] = {}
    clusters, clients = {}, {}
    try:
        for n in a.workers:
            clusters[n] = local_cluster(n)
            clients[n] = Client(clusters[n])
            warm_up(clients[n], mesh, cams[0], w, h, a.cull)
        for n in abba(list(a.workers), a.repeat):
            tmp = Path(tempfile.mkdtemp(dir=a.tmp))
            try:
                s = render_views(mesh, cams, clients[n], tmp / "views", outputs, chunk=a.chunk,
                                 size=(w, h), progress=False, cull=a.cull)
                if s.rendered != a.views or s.failures:
                    raise SystemExit(f"{n} workers: {s}")
                if n not in first_files:
                    first_files[n] = {p.name: p.read_bytes()
                                      for p in sorted((tmp / "views").iterdir())[:20]}
                    if first_files[n] != first_files[a.workers[0]]:
                        raise SystemExit(f"{n} workers: files differ from "
                                         f"{a.workers[0]} workers'")
                runs[n].append({"seconds": s.seconds, "views_per_s": a.views / s.seconds,
                                "per_worker": [w_.views_per_s for w_ in s.per_worker],
                                "chunks": len(s.chunks)})
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
    finally:
        for n in clients:
            clients[n].close()
            clusters[n].close()

    base = statistics.median(r["views_per_s"] for r in runs[a.workers[0]])
    rows = []
    for n in a.workers:
        vps = statistics.median(r["views_per_s"] for r in runs[n])
        per = statistics.median(v for r in runs[n] for v in r["per_worker"])
        rows.append({"workers": n, "pocl_threads": max(1, cores // n), "views_per_s": vps,
                     "speedup": vps / base, "per_worker_views_per_s": per,
                     "seconds": statistics.median(r["seconds"] for r in runs[n]),
                     "chunks": runs[n][0]["chunks"], "runs": runs[n]})
    result = {"mesh": a.mesh.rsplit("/", 1)[-1], "triangles": mesh.n_faces, "size": f"{w}x{h}",
              "views": a.views, "outputs": list(outputs), "cores": cores, "repeat": a.repeat,
              "rows": rows}
    print(f"{result['mesh']} ({mesh.n_faces:,} triangles) at {w}x{h}, {a.views} views, "
          f"outputs {','.join(outputs)}, {cores} cores; medians of {a.repeat}")
    print(f"{'workers':>7} {'PoCL thr':>8} {'chunks':>6} {'seconds':>8} {'views/s':>8} "
          f"{'speed-up':>8} {'views/s per worker':>19}")
    for row in rows:
        print(f"{row['workers']:>7} {row['pocl_threads']:>8} {row['chunks']:>6} "
              f"{row['seconds']:>8.2f} {row['views_per_s']:>8.2f} {row['speedup']:>7.2f}x "
              f"{row['per_worker_views_per_s']:>19.2f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
