"""A/B of whole source trees with one persistent worker process per tree, interleaved.

    python bench/proc_ab.py 23d0dc1                   # spot, dragon, empty at 1920x1080
    python bench/proc_ab.py 23d0dc1 HEAD --scenes spot bunny dragon plant10m plant10m:off
    python bench/proc_ab.py HEAD HEAD --kwb '{"outputs": ["depth", "ids"]}'   # same tree, lean
    python bench/proc_ab.py HEAD HEAD --env-b '{"POCL_WORK_GROUP_METHOD": "loops"}'   # PoCL option
    python bench/proc_ab.py 23d0dc1 --size 3840x2160 --rounds 9
    python bench/proc_ab.py HEAD WORKTREE --scenes dragon --evict 2000   # cold caches
    python bench/proc_ab.py HEAD HEAD --config-a '{"tile_log2": 4}'       # RasterConfig

Where `tree_ab.py` starts a process per frame, each tree here keeps one process (one
Renderer per scene, warmed up) and renders one frame per request, the two trees taking
turns (their order alternating per round), so a round costs two frames and rounds can be
many. Per scene and tree: the median and min frame wall time, the median process CPU time
of a frame (user + system over all threads, PoCL's included: less sensitive than wall time
to other jobs on a shared machine) and the median device time per stage; B/A ratios of the
medians; and whether the last frames' ids agree. A revision may be a git revision,
WORKTREE (the checkout) or a folder holding a tree. Scenes: spot, bunny, armadillo, lucy,
dragon202k, dragon (framed as the harness does), empty (spot behind the camera), plant1m,
plant5m, plant10m (first person, occlusion culling; ":off" no object culling), and the
harness's fill scenes quad, quad@away (its empty frame), spot@close, bunny@close.
``--evict MB``: before each timed frame the worker reads and writes an MB-megabyte array,
so the frame starts with cold caches and TLBs, as in the benchmark harness (where a NumPy
twin frame and an llvmpipe frame run between two clraster frames).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))
from tree_ab import export  # noqa: E402  (bench/ is not a package)

MESHES = REPO.parent / "shared" / "meshes"
WORKER = r'''
import json, resource, sys, time
tree, W, H, M = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] + "/"
CONFIG = json.loads(sys.argv[5])
sys.path.insert(0, tree)
import numpy as np
from clraster import Camera, Mesh, RasterConfig, Renderer
FILES = {"spot": "spot.ply", "dragon": "stanford_dragon_vrip.ply",
         "bunny": "stanford_bunny.ply", "lucy": "stanford_lucy_100k.ply",
         "armadillo": "armadillo_86k.ply", "dragon202k": "stanford_dragon_res2.ply"}
PLANTS = {"plant1m": 1_000_000, "plant5m": 5_000_000, "plant10m": 10_100_000}
renderers, scenes = {}, {}
junk = {}


def scene(name):
    if name not in scenes:
        kw = {}
        if name.startswith("plant"):
            from clraster.world.generators import plant, plant_inside_camera
            t = plant(PLANTS[name.split(":")[0]])
            cam = plant_inside_camera(t, W, H)
            kw = ({"frustum": False, "cones": False} if name.endswith(":off")
                  else {"occlusion": True})
        elif name == "empty":   # spot behind the camera: nothing in view
            t = Mesh.load(M + "spot.ply")
            cam = Camera.look_at(eye=(0, 0, 10), target=(0, 0, 20), up=(0, 1, 0))
        elif name in ("quad", "quad@away") or name.endswith("@close"):
            # the harness's fill scenes (clraster.bench.spec)
            from clraster.bench.spec import close_camera, quad_mesh
            base = name.split("@")[0]
            t = quad_mesh() if base == "quad" else Mesh.load(M + FILES[base])
            cam = close_camera(*t.bounds(), W, H, away=name.endswith("@away"))
        else:
            t = Mesh.load(M + FILES[name])
            cam = Camera.framing(*t.bounds(), aspect=W / H)
        scenes[name] = (t, cam, kw)
        renderers[name] = Renderer(W, H, config=RasterConfig(**CONFIG))
    return scenes[name] + (renderers[name],)


def cpu_ms():
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return (ru.ru_utime + ru.ru_stime) * 1e3


for line in sys.stdin:
    req = json.loads(line)
    t, cam, kw, r = scene(req["scene"])
    kw = dict(kw, **req.get("kw", {}))
    for _ in range(req.get("warm", 0)):
        r.render(t, cam, **kw)
    if req.get("evict"):   # cold caches, as after the harness's twin and llvmpipe frames
        if "a" not in junk:   # made once (setdefault would fill a new one each time)
            junk["a"] = np.ones(req["evict"] << 17)
        junk["a"] += 1.0
    c0, t0 = cpu_ms(), time.perf_counter()
    f = r.render(t, cam, **kw)
    ms, cpu = (time.perf_counter() - t0) * 1e3, cpu_ms() - c0
    ids = f.triangle_id
    print(json.dumps({"ms": ms, "cpu": cpu, "st": f.stats.timings_ms,
                      "ids": int(np.count_nonzero(ids >= 0)),
                      "idsum": int(ids.astype(np.int64).sum())}), flush=True)
'''


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", help="tree A: git revision, WORKTREE or a folder")
    ap.add_argument("b", nargs="?", default="WORKTREE", help="tree B (default: WORKTREE)")
    ap.add_argument("--scenes", nargs="+", default=["spot", "dragon", "empty"])
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--kwa", default="{}", help="render keywords of A, JSON")
    ap.add_argument("--kwb", default="{}", help="render keywords of B, JSON")
    ap.add_argument("--env-a", default="{}", help="extra environment of A's worker, JSON "
                    '(e.g. \'{"POCL_WORK_GROUP_METHOD": "loops"}\')')
    ap.add_argument("--env-b", default="{}", help="extra environment of B's worker, JSON")
    ap.add_argument("--config-a", default="{}", help="RasterConfig keywords of A's "
                    'renderers, JSON (e.g. \'{"tile_log2": 4}\')')
    ap.add_argument("--config-b", default="{}", help="RasterConfig keywords of B's renderers")
    ap.add_argument("--evict", type=int, default=0, metavar="MB",
                    help="touch this many MB before each timed frame (cold caches)")
    a = ap.parse_args(argv)
    w, h = a.size.lower().split("x")
    tmp = Path(tempfile.mkdtemp())
    (tmp / "worker.py").write_text(WORKER)
    procs = {}
    for tag, rev, kw, env, cfg in (("A", a.a, a.kwa, a.env_a, a.config_a),
                                   ("B", a.b, a.kwb, a.env_b, a.config_b)):
        tree = export(rev, tmp / tag)
        p = subprocess.Popen([sys.executable, str(tmp / "worker.py"), str(tree), w, h,
                              str(MESHES), json.dumps(json.loads(cfg))],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True, cwd=tmp, env={**os.environ, **json.loads(env)})
        procs[tag] = (p, json.loads(kw))

    def ask(tag: str, scene: str, warm: int = 0) -> dict:
        p, kw = procs[tag]
        assert p.stdin is not None and p.stdout is not None
        p.stdin.write(json.dumps({"scene": scene, "warm": warm, "kw": kw,
                                  "evict": a.evict}) + "\n")
        p.stdin.flush()
        return json.loads(p.stdout.readline())

    res: dict[tuple[str, str], list[dict]] = {}
    for s in a.scenes:
        for tag in procs:
            ask(tag, s, warm=3)
    for rnd in range(a.rounds):
        for s in a.scenes:
            for tag in (list(procs) if rnd % 2 == 0 else list(procs)[::-1]):
                res.setdefault((s, tag), []).append(ask(tag, s))
    for s in a.scenes:
        line = []
        for tag in procs:
            rs = res[(s, tag)]
            med = statistics.median(r["ms"] for r in rs)
            mn = min(r["ms"] for r in rs)
            cpu = statistics.median(r["cpu"] for r in rs)
            st = {k: statistics.median(r["st"].get(k, 0) for r in rs) for k in rs[0]["st"]}
            line.append(f"{tag} {med:7.2f} (min {mn:6.2f}, cpu {cpu:6.2f}) ms ["
                        + " ".join(f"{k.split(' ')[0]} {v:.2f}" for k, v in st.items()) + "]")
        ra, rb = res[(s, "A")], res[(s, "B")]
        r_ms = statistics.median(r["ms"] for r in rb) / statistics.median(r["ms"] for r in ra)
        r_cpu = (statistics.median(r["cpu"] for r in rb)
                 / statistics.median(r["cpu"] for r in ra))
        same = ra[-1]["idsum"] == rb[-1]["idsum"] and ra[-1]["ids"] == rb[-1]["ids"]
        print(f"{s:>10}: " + " | ".join(line) + f" | B/A {r_ms:.3f} cpu B/A {r_cpu:.3f} ids "
              + ("same" if same else "DIFFER"))
    for p, _ in procs.values():
        assert p.stdin is not None
        p.stdin.close()
        p.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
