"""clraster vs Mesa llvmpipe (the peer renderer) on the dragon and the procedural plant.

    python bench/peer_check.py [--dragon PATH] [--plant 10000000] [--size 1920x1080]

Dragon: the camera of bench/frame_time.py (Camera.framing of the mesh bounds), cull back.
Plant: `scenes.plant(N)` seen from `plant_inside_camera`; clraster renders with
``occlusion=True`` (three warm-up frames so its occlusion history settles), llvmpipe draws
every instance (one instanced draw per distinct mesh; no culling but back faces).

Both are warmed up, then timed ``--repeat`` times interleaved (clraster frame, llvmpipe
frame, ...), so machine noise hits both alike. clraster's time is the wall time of
``render()`` (host culling and read-back included); llvmpipe's is clear + draws + glFinish
(its depth read-back is reported apart). Coverage agreement and triangle-id agreement come
from the last frames. Without llvmpipe it prints why the peer is skipped and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

import clraster
from clraster.bench.peer_llvmpipe import LlvmpipePeer, coverage_agreement, probe

DRAGON = Path(__file__).resolve().parents[2] / "shared" / "meshes" / "stanford_dragon_vrip.ply"


def compare(target, cam, w: int, h: int, repeat: int, cl_warmup: int,
            cl_kw: dict) -> dict:
    r = clraster.Renderer(w, h)
    for _ in range(cl_warmup):
        f = r.render(target, cam, **cl_kw)
    vp = cam.view_projection(w, h)
    with LlvmpipePeer(w, h) as peer:
        t0 = time.perf_counter()
        peer.upload(target)
        upload_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        peer.render(vp, repeat=1, warmup=0)   # first frame: shader JIT
        peer_first_s = time.perf_counter() - t0
        cl_t, gl_t, reads = [], [], []
        for _ in range(repeat):
            t0 = time.perf_counter()
            f = r.render(target, cam, **cl_kw)
            cl_t.append((time.perf_counter() - t0) * 1e3)
            pf = peer.render(vp, repeat=1, warmup=0)
            gl_t += pf.times_ms
            reads.append(pf.readback_ms)
        pf = peer.render(vp, repeat=1, warmup=0, ids=True)
        draws = peer.n_draws
    agree = coverage_agreement(f.depth, pf.depth)
    both = (f.triangle_id >= 0) & (pf.triangle_id >= 0)
    cl_ms, gl_ms = statistics.median(cl_t), statistics.median(gl_t)
    return {
        "triangles": int(target.n_faces), "size": [w, h], "repeat": repeat,
        "clraster_options": cl_kw, "clraster_median_ms": cl_ms, "clraster_ms": cl_t,
        "llvmpipe_median_ms": gl_ms, "llvmpipe_ms": gl_t,
        "llvmpipe_readback_median_ms": statistics.median(reads),
        "llvmpipe_over_clraster": gl_ms / cl_ms, "llvmpipe_upload_s": upload_s,
        "llvmpipe_first_frame_s": peer_first_s, "llvmpipe_draw_calls": draws,
        "llvmpipe_depth_format": pf.depth_format,
        "coverage": agree,
        "ids_agree_where_both_cover": float(np.mean(f.triangle_id[both]
                                                    == pf.triangle_id[both]))
        if both.any() else None,
    }


def _summary(r: dict) -> dict:
    return {k: v for k, v in r.items() if k not in ("clraster_ms", "llvmpipe_ms")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dragon", default=str(DRAGON), help="mesh file ('' to skip)")
    ap.add_argument("--plant", type=int, default=10_000_000, help="triangles (0 to skip)")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", help="write the results here")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    ok, why = probe()
    if not ok:
        print(f"peer skipped: {why}")
        return 0
    res: dict = {"peer": why, "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
                 "cpus": os.cpu_count()}
    if a.dragon:
        mesh = clraster.Mesh.load(a.dragon)
        lo, hi = mesh.bounds()
        cam = clraster.Camera.framing(lo, hi, aspect=w / h)
        res["dragon"] = compare(mesh, cam, w, h, a.repeat, 1, {"cull": "back"})
        print("dragon", json.dumps(_summary(res["dragon"]), indent=1), flush=True)
    if a.plant:
        from clraster.world.generators import plant, plant_inside_camera
        scene = plant(a.plant)
        cam = plant_inside_camera(scene, w, h)
        res["plant"] = compare(scene, cam, w, h, a.repeat, 3, {"occlusion": True})
        res["plant"]["instances"] = scene.n_instances
        print("plant", json.dumps(_summary(res["plant"]), indent=1), flush=True)
    print(json.dumps(res, indent=1))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
