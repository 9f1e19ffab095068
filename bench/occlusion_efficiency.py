"""Occlusion-culling efficiency: the share of truly invisible clusters the Hi-Z path culls.

    python bench/occlusion_efficiency.py --triangles 100000 --size 320x240

Builds `clraster.scenes.plant(N)` and takes the first-person corridor view
(`plant_inside_camera`). Among the clusters that survive frustum and normal-cone culling (the
draw list: the only ones occlusion culling can still remove):

* **truly invisible**: none of the cluster's triangle ids appears in the frame rendered
  without occlusion culling (face ids from `clraster.clusters.clusters_of`, offset by
  `scene.face_base`);
* **box-invisible**: the exact occlusion query (`clraster.occlusion.query`) of the cluster's
  world box against that frame's depth passes 0 samples (a stricter notion: no
  box-based test could do better than this; a visible flat cluster lying on a face of its
  own box also has 0 samples, so this set is not a subset of the other);
* **culled**: the clusters ``Renderer.render(..., occlusion=True)`` skips on a *second* frame
  of the same view (steady state: phase 1 is the visible set of the first frame). The count
  is `stats.clusters_occlusion_culled`; the set itself is not in the public API, so it is
  rebuilt from the algorithm: the draws whose world box (`clraster.drawlist.key_boxes`) the
  Hi-Z test (the `hiz` verdicts of the same query) does not call VISIBLE against the final
  depth. `check` verifies that the rebuilt set has exactly the renderer's count and lies
  inside the truly invisible set. The rebuild is the flat two-phase schedule's, so the
  renderer runs it (``RasterConfig(occlusion_groups=0)``); the hierarchical one decides
  hidden groups' clusters without their frustum and cone tests, so its counts are not
  over this draw list.

Prints efficiency = culled / truly invisible (and culled ∩ box-invisible / box-invisible).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clraster import RasterConfig, Renderer
from clraster.culling.clusters import clusters_of
from clraster.pipeline.drawlist import PlanCache, key_boxes, plan_frame
from clraster.pipeline.occlusion import Occlusion, query
from clraster.world.generators import plant, plant_inside_camera


def cluster_face_ids(scene, instance: np.ndarray, cluster: np.ndarray) -> list[np.ndarray]:
    """Scene triangle ids (face_base[instance] + face) of each (instance, cluster) draw."""
    base = np.asarray(scene.face_base, np.int64)
    out = []
    for i, c in zip(instance.tolist(), cluster.tolist(), strict=True):
        cm = clusters_of(scene.instances[i].mesh)
        out.append(cm.face_ids[cm.tri_offset[c]:cm.tri_offset[c + 1]].astype(np.int64)
                   + base[i])
    return out


def measure(scene, camera, width: int, height: int, *, cull: str = "back",
            renderer: Renderer | None = None, reference: Renderer | None = None) -> dict:
    """Render ``scene`` without occlusion culling and twice with it (one renderer, same
    camera), and classify the draw list's clusters. Returns a dict of counts, the boolean
    per-draw sets (keys ``invisible``, ``box_invisible``, ``culled``) and the frames."""
    occ = renderer or Renderer(width, height, config=RasterConfig(occlusion_groups=0))
    ref = reference or Renderer(width, height)
    ref.render(scene, camera, cull=cull)   # warm-up: uploads, buffer growth
    t0 = time.perf_counter()
    off = ref.render(scene, camera, cull=cull)
    t_off = time.perf_counter() - t0
    f1 = occ.render(scene, camera, cull=cull, occlusion=True)
    t0 = time.perf_counter()
    f2 = occ.render(scene, camera, cull=cull, occlusion=True)
    t_on = time.perf_counter() - t0

    plan = plan_frame(scene, camera, width, height, cull=cull, frustum=True, cones=True,
                      cache=PlanCache())
    pool, dl = plan.pool, plan.draw_list
    inst = np.asarray(dl.instance, np.int64)
    clus = np.asarray(dl.cluster, np.int64)
    keys = pool.instance_key_base[inst] + clus
    lo, hi, bounded = (a[keys] for a in key_boxes(pool, scene))

    seen = np.zeros(scene.n_faces, bool)
    seen[off.visible_faces()] = True
    invisible = np.array([not seen[f].any() for f in cluster_face_ids(scene, inst, clus)],
                         bool)
    q = query(ref, off.depth, lo, hi, camera)
    box_invisible = q.samples == 0
    culled = bounded & (q.hiz != Occlusion.VISIBLE)

    n_inv = int(invisible.sum())
    n_box = int(box_invisible.sum())
    return {
        "draws": int(keys.size),
        "truly_invisible": n_inv,
        "box_invisible": n_box,
        "culled_rebuilt": int(culled.sum()),
        "culled_frame2": f2.stats.clusters_occlusion_culled,
        "culled_frame1": f1.stats.clusters_occlusion_culled,
        "phase1_frame2": f2.stats.clusters_phase1,
        "phase2_frame2": f2.stats.clusters_phase2,
        "efficiency": (int((culled & invisible).sum()) / n_inv) if n_inv else 1.0,
        "efficiency_vs_box": (int((culled & box_invisible).sum()) / n_box) if n_box else 1.0,
        "fragments_tested_off": off.stats.fragments_tested,
        "fragments_tested_frame2": f2.stats.fragments_tested,
        "ms_off": t_off * 1e3,
        "ms_frame2": t_on * 1e3,
        "sets": {"invisible": invisible, "box_invisible": box_invisible, "culled": culled},
        "frames": {"off": off, "first": f1, "second": f2},
    }


def check(m: dict) -> None:
    """The invariants the measurement rests on (raises AssertionError)."""
    s = m["sets"]
    off, f2 = m["frames"]["off"], m["frames"]["second"]
    assert np.array_equal(off.triangle_id, f2.triangle_id), "occlusion culling changed ids"
    assert np.array_equal(off.depth, f2.depth), "occlusion culling changed depth"
    assert m["culled_frame2"] == m["culled_rebuilt"], (m["culled_frame2"], m["culled_rebuilt"])
    assert not (s["culled"] & ~s["invisible"]).any(), "a culled cluster has a visible triangle"
    assert 0.0 <= m["efficiency"] <= 1.0 and 0.0 <= m["efficiency_vs_box"] <= 1.0


def report(m: dict) -> str:
    return (f"draw list {m['draws']:,} clusters; truly invisible {m['truly_invisible']:,}, "
            f"box-invisible {m['box_invisible']:,}; culled on frame 2: "
            f"{m['culled_frame2']:,} (first frame {m['culled_frame1']:,}; frame 2 phase 1 "
            f"{m['phase1_frame2']:,}, phase 2 {m['phase2_frame2']:,})\n"
            f"efficiency = culled / truly invisible = {m['efficiency']:.4f}; "
            f"vs box-invisible = {m['efficiency_vs_box']:.4f}\n"
            f"fragments tested {m['fragments_tested_off']:,} -> "
            f"{m['fragments_tested_frame2']:,}; render {m['ms_off']:.1f} ms -> "
            f"{m['ms_frame2']:.1f} ms (wall time of render(), warm)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=100_000)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--storey", type=int, default=0)
    ap.add_argument("--band", type=int, default=0)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    scene = plant(a.triangles)
    cam = plant_inside_camera(scene, w, h, storey=a.storey, band=a.band)
    m = measure(scene, cam, w, h)
    check(m)
    print(f"plant({a.triangles:,}), {w}x{h}, inside camera (storey {a.storey}, band {a.band})")
    print(report(m))
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({k: v for k, v in m.items() if k not in ("sets", "frames")}, fh,
                      indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
