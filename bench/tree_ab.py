"""A/B of whole source trees: a git revision's clraster (host code and kernels) against
another's (default: the working tree), each frame timed in a fresh process, interleaved.

    python bench/tree_ab.py 096ae39                  # dragon, spot, plant 1M (occlusion)
    python bench/tree_ab.py 096ae39 --rounds 4 --scenes spot

Where `kernel_ab.py` swaps only kernels/ under today's host code, this compares what a user
gets from each revision: `Renderer.render` wall time at 1920x1080 (3 warm-up frames, then
the median and min of 9), one process per (round, scene, tree), alternating trees. The
machine is shared and noisy: compare the two columns of one run. It also saves each
tree's triangle ids and reports how many pixels differ.
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
MESHES = REPO.parent / "shared" / "meshes"

ONE = r"""
import json, statistics, sys, time
import numpy as np
tree, scene, ids_out = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, tree)
from clraster import Camera, Mesh, Renderer
W, H = 1920, 1080
kw = {}
if scene == "plant":
    from clraster.world.generators import plant, plant_inside_camera
    target = plant(1_000_000); cam = plant_inside_camera(target, W, H); kw = {"occlusion": True}
else:
    target = Mesh.load(scene); cam = Camera.framing(*target.bounds(), aspect=W / H)
r = Renderer(W, H)
for _ in range(3):
    f = r.render(target, cam, **kw)
np.save(ids_out, f.triangle_id)
ts = []
for _ in range(9):
    t0 = time.perf_counter(); r.render(target, cam, **kw)
    ts.append((time.perf_counter() - t0) * 1e3)
print(json.dumps({"median": statistics.median(ts), "min": min(ts)}))
"""


def export(rev: str, dest: Path) -> Path:
    """The tree of ``rev``: the checkout ("WORKTREE"), a folder as it is, or a git
    revision's tracked files exported under ``dest``. (bench/proc_ab.py uses it too.)"""
    if rev == "WORKTREE":
        return REPO
    if os.path.isdir(rev):
        return Path(rev)
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="git revision A")
    ap.add_argument("after", nargs="?", default="WORKTREE", help="git revision B (default: "
                    "the working tree)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--scenes", nargs="+", default=["stanford_dragon_vrip", "spot", "plant"],
                    help="shared mesh names (../shared/meshes/NAME.ply) or 'plant'")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {a.before: export(a.before, Path(tmp) / "a"),
                 a.after: export(a.after, Path(tmp) / "b")}
        script = Path(tmp) / "one.py"
        script.write_text(ONE)
        res: dict[tuple[str, str], list[dict]] = {(t, s): [] for t in trees for s in a.scenes}
        for _ in range(a.rounds):
            for s in a.scenes:
                scene = s if s == "plant" else str(MESHES / f"{s}.ply")
                for t, path in trees.items():
                    ids = Path(tmp) / f"{abs(hash((t, s)))}.npy"
                    out = subprocess.run([sys.executable, str(script), str(path), scene,
                                          str(ids)], capture_output=True, text=True,
                                         cwd=tmp, check=True)
                    res[(t, s)].append(json.loads(out.stdout.strip().splitlines()[-1]))
        import numpy as np

        for s in a.scenes:
            ids = [np.load(Path(tmp) / f"{abs(hash((t, s)))}.npy") for t in trees]
            cols = []
            for t in trees:
                meds = [r["median"] for r in res[(t, s)]]
                mins = [r["min"] for r in res[(t, s)]]
                cols.append(f"{t}: median {statistics.median(meds):.1f} ms, "
                            f"min {min(mins):.1f} ms")
            diff = int((ids[0] != ids[1]).sum())
            print(f"{s}: " + " | ".join(cols) + f" | ids differ at {diff} of "
                  f"{int((ids[0] >= 0).sum())} covered pixels")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
