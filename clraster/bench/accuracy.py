"""Accuracy of the values written at covered pixels against a float64 ray caster, and
against Mesa llvmpipe on the same pixels (where a headless llvmpipe is available).

    PYTHONPATH=. python -m clraster.bench.accuracy [--size 320 240]

The oracle, per covered pixel: the ray through the pixel centre meets the plane of the
triangle clraster shows there; window depth (z/w + 1)/2 and barycentrics relative to the
triangle's three vertices are solved in float64 from a view-projection given in float64
("f64": the camera's own matrix) or as the float32 matrix both renderers draw with
("f32": what the rasterizer itself adds). Rows: real meshes from ../shared/meshes at two
ordinary cameras and one whose near plane cuts the mesh. Columns: max |window depth −
oracle| (f32, f64 matrix) over pixels whose centre lies in the triangle; llvmpipe's on the
pixels where both show the same triangle (and ours on those, in the f64 column, when the
peer runs); the 99.9th percentile of the max barycentric error over pixels of triangles
covering >= 1 px²; the share of covered pixels whose centre lies just outside the unsnapped
triangle (<= 1/512 px, where values extrapolate). tests/test_accuracy.py holds the bars;
this prints the numbers behind them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..world.camera import Camera
from ..world.mesh import Mesh

MESHES = ("spot.ply", "stanford_bunny.ply", "stanford_dragon_res2.ply")


def ray_oracle(mesh: Mesh, vp: np.ndarray, ids: np.ndarray):
    """Float64 ray–plane oracle at the pixel centres of ``ids`` >= 0 (int32 (H, W) face
    indices of ``mesh``) for the float64 view-projection ``vp`` (4, 4) (column vectors).

    Returns (mask bool (H, W), depth float64 (K,), barycentrics float64 (K, 3), screen area
    of the pixel's triangle in px² float64 (K,), nearest vertex window depth float64 (K,))
    for the K pixels of the mask, row-major.
    """
    h, w = ids.shape
    mask = ids >= 0
    ys, xs = np.nonzero(mask)
    tri = mesh.faces[ids[mask]]
    p = mesh.vertices[tri].astype(np.float64)                       # (K, 3, 3)
    c = np.einsum("ij,kvj->kvi", vp[:, :3], p) + vp[:, 3]            # (K, 3, 4)
    xn = 2.0 * (xs + 0.5) / w - 1.0
    yn = 1.0 - 2.0 * (ys + 0.5) / h
    # b with sum 1 whose clip point projects to (xn, yn): a 3x3 solve per pixel
    a = np.empty((xs.size, 3, 3))
    a[:, 0] = c[:, :, 0] - xn[:, None] * c[:, :, 3]
    a[:, 1] = c[:, :, 1] - yn[:, None] * c[:, :, 3]
    a[:, 2] = 1.0
    rhs = np.zeros((xs.size, 3, 1))
    rhs[:, 2] = 1.0
    b = np.linalg.solve(a, rhs)[:, :, 0]
    q = np.einsum("kv,kvi->ki", b, c)
    depth = (q[:, 2] / q[:, 3]) * 0.5 + 0.5
    sx = (c[..., 0] / c[..., 3] + 1.0) * (w / 2)
    sy = (1.0 - c[..., 1] / c[..., 3]) * (h / 2)
    area = 0.5 * np.abs((sx[:, 1] - sx[:, 0]) * (sy[:, 2] - sy[:, 0])
                        - (sy[:, 1] - sy[:, 0]) * (sx[:, 2] - sx[:, 0]))
    zmin = ((c[..., 2] / c[..., 3]) * 0.5 + 0.5).min(axis=1)
    return mask, depth, b, area, zmin


def cameras(mesh: Mesh, aspect: float) -> list[tuple[str, Camera, str]]:
    """(name, camera, cull): two ordinary cameras framing the mesh and one whose near plane
    cuts through it (many clipped triangles; drawn with cull "none")."""
    lo, hi = mesh.bounds()
    out = [(f"ordinary {k}", Camera.framing(lo, hi, direction=d, aspect=aspect), "back")
           for k, d in enumerate(((0.7, 0.4, 1.0), (-1.0, 0.2, -0.3)))]
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    eye = centre + size * np.array([0.35, 0.2, 0.6])
    dist = float(np.linalg.norm(eye - centre))
    out.append(("near cut", Camera.look_at(eye, centre, fov_y=50.0,
                                           near=0.8 * dist, far=3.0 * dist), "none"))
    return out


def main(argv: list[str] | None = None) -> int:
    from .. import Renderer
    from .peer_llvmpipe import LlvmpipePeer, probe

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, nargs=2, default=(320, 240), metavar=("W", "H"))
    ap.add_argument("--meshes", type=Path,
                    default=Path(__file__).resolve().parents[2].parent / "shared" / "meshes")
    args = ap.parse_args(argv)
    w, h = args.size
    r = Renderer(w, h)
    ok, why = probe()
    peer = LlvmpipePeer(w, h) if ok else None
    print(f"{w}x{h}; llvmpipe: {'yes' if ok else why}")
    print(f"{'mesh':<26}{'camera':<12}{'depth f32':>11}{'depth f64':>11}{'llvmpipe':>11}"
          f"{'bary f32':>12}{'bary f64':>12}{'outside':>9}")
    try:
        for name in MESHES:
            mesh = Mesh.load(args.meshes / name)
            if peer is not None:
                peer.upload(mesh)
            for cname, cam, cull in cameras(mesh, w / h):
                f = r.render(mesh, cam, cull=cull)
                vp64 = np.asarray(cam.view_projection(w, h), np.float64)
                mask, dz, b, area, _ = ray_oracle(mesh, vp64.astype(np.float32)
                                                  .astype(np.float64), f.triangle_id)
                inside = b.min(axis=1) >= 0.0
                d32 = np.abs(f.depth[mask].astype(np.float64) - dz)[inside].max()
                berr = np.abs(f.need_barycentrics()[mask] - b).max(axis=1)
                p999 = np.quantile(berr[(area >= 1.0) & inside], 0.999)
                mask, dz, b, _, _ = ray_oracle(mesh, vp64, f.triangle_id)
                inside = b.min(axis=1) >= 0.0
                berr = np.abs(f.need_barycentrics()[mask] - b).max(axis=1)
                p999_64 = np.quantile(berr[(area >= 1.0) & inside], 0.999)
                derr = np.abs(f.depth[mask].astype(np.float64) - dz)
                ours, theirs = f"{derr[inside].max():.2e}", "-"
                if peer is not None:
                    # both on the pixels where they show the same triangle (centre inside it)
                    pf = peer.render(vp64, cull=cull, repeat=1, ids=True)
                    assert pf.triangle_id is not None   # asked for with ids=True
                    same = (pf.triangle_id[mask] == f.triangle_id[mask]) & inside
                    perr = np.abs(pf.depth[mask].astype(np.float64) - dz)[same]
                    ours, theirs = f"{derr[same].max():.2e}", f"{perr.max():.2e}"
                print(f"{name:<26}{cname:<12}{d32:>11.2e}{ours:>11}{theirs:>11}"
                      f"{p999:>12.2e}{p999_64:>12.2e}{1.0 - inside.mean():>9.2%}")
    finally:
        if peer is not None:
            peer.release()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
