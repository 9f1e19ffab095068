"""Views per second of a dataset job — metric depth, triangle ids and face normals of many
views of one mesh — with clraster and with Open3D's RaycastingScene (Embree), in one run.

    python bench/datasets.py ../shared/meshes/stanford_dragon_vrip.ply --views 200

The job per view, as a user writes it: clraster renders (``cull`` back or none) with
``outputs=("ids", "linear_depth", "normals")`` — made on the device — and takes
``Frame.linear_depth(camera)`` and ``Frame.normals(mesh)``; Open3D casts one ray per pixel
(``create_rays_pinhole``, whose rays have z = 1 in the camera frame, so ``t_hit`` is the
linear depth) and returns ``t_hit``, ``primitive_ids`` and ``primitive_normals``. The same
K for both, with Open3D's pixel centres at (u + ½, v + ½) against OpenCV's (u, v) (clraster's
K is Open3D's with cx, cy − ½), so the two agree on the ids of almost every pixel (checked on
the first view and printed).

The cameras sit on a sphere around the mesh (a Fibonacci lattice), looking at its centre,
framing it. Each method is warmed up on the first view (kernel build, BVH), then the methods
run ``--repeat`` times in ABBA order (so drift on a shared machine hits both alike);
medians are reported, and their ratio. Open3D is used where it imports (``pip install
open3d-cpu``; it needs the system's libusb-1.0); without it only clraster is timed.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable

import numpy as np

from clraster import Camera, Mesh, Renderer


def sphere_poses(mesh: Mesh, n: int, width: int, height: int, fov_y: float = 40.0
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
    """K (OpenCV, (3, 3)) and ``n`` camera → world poses (OpenCV axes) on a Fibonacci sphere
    around the mesh's bounding box, each looking at its centre from a distance that frames
    its bounding sphere."""
    lo, hi = mesh.bounds()
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    f = 0.5 * height / math.tan(math.radians(fov_y) / 2.0)
    k = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0, 0, 1.0]])
    dist = radius / math.sin(math.radians(fov_y) / 2.0) * 1.05
    poses = []
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for i in range(n):
        y = 1.0 - 2.0 * (i + 0.5) / n
        r = math.sqrt(1.0 - y * y)
        d = np.array([math.cos(golden * i) * r, y, math.sin(golden * i) * r])
        eye = centre + dist * d
        z = (centre - eye) / np.linalg.norm(centre - eye)        # OpenCV: +z forward
        up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
        x = np.cross(z, -up)                                     # +x right, +y down
        x /= np.linalg.norm(x)
        yv = np.cross(z, x)
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, yv, z, eye
        poses.append(pose)
    return k, poses


def clraster_job(mesh: Mesh, k: np.ndarray, poses: list[np.ndarray], width: int, height: int,
                 cull: str, near: float, far: float) -> tuple[Callable[[], None], np.ndarray]:
    r = Renderer(width, height)
    cams = [Camera.from_intrinsics(k, width, height, pose=p, near=near, far=far)
            for p in poses]

    def one(cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # metric depth and normals made on the device (the resolve stage), as the batch
        # paths ask for them; Frame.linear_depth / normals return those arrays
        fr = r.render(mesh, cam, cull=cull, outputs=("ids", "linear_depth", "normals"))
        return fr.linear_depth(cam), fr.triangle_id, fr.normals(mesh)

    first = one(cams[0])[1].copy()

    def run() -> None:
        for cam in cams:
            one(cam)
    return run, first


def open3d_job(mesh: Mesh, k: np.ndarray, poses: list[np.ndarray], width: int, height: int
               ) -> tuple[Callable[[], None], np.ndarray] | None:
    try:
        import open3d as o3d
    except ImportError:
        return None
    scene = o3d.t.geometry.RaycastingScene()
    tm = o3d.t.geometry.TriangleMesh()
    tm.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))
    tm.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, np.int32))
    scene.add_triangles(tm)
    k_o3d = k.copy()
    k_o3d[:2, 2] += 0.5          # Open3D's pixel centres at (u + 0.5, v + 0.5)
    intr = o3d.core.Tensor(k_o3d)
    extrs = [o3d.core.Tensor(np.linalg.inv(p)) for p in poses]

    def one(extr) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rays = scene.create_rays_pinhole(intr, extr, width, height)
        ans = scene.cast_rays(rays)
        return (ans["t_hit"].numpy(), ans["primitive_ids"].numpy().astype(np.int64),
                ans["primitive_normals"].numpy())

    ids = one(extrs[0])[1]
    first = np.where(ids == np.iinfo(np.uint32).max, -1, ids)

    def run() -> None:
        for e in extrs:
            one(e)
    return run, first


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cull", choices=("back", "none", "both"), default="both")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    mesh = Mesh.load(a.mesh)
    k, poses = sphere_poses(mesh, a.views, w, h)
    lo, hi = mesh.bounds()
    radius = float(np.linalg.norm(hi - lo)) / 2.0
    dist = float(np.linalg.norm(poses[0][:3, 3] - (lo + hi) / 2.0))
    near, far = max(dist - 1.5 * radius, 1e-3 * dist), dist + 1.5 * radius
    jobs: dict[str, Callable[[], None]] = {}
    firsts: dict[str, np.ndarray] = {}
    for cull in (("back", "none") if a.cull == "both" else (a.cull,)):
        jobs[f"clraster cull={cull}"], firsts[cull] = clraster_job(mesh, k, poses, w, h, cull,
                                                                   near, far)
    o3d_job = open3d_job(mesh, k, poses, w, h)
    if o3d_job is not None:
        jobs["open3d raycast"], ref = o3d_job
        for cull, ids in firsts.items():
            agree = float(np.mean(ids == ref))
            print(f"first view: clraster cull={cull} ids agree with Open3D's on "
                  f"{100 * agree:.2f}% of pixels")
    else:
        print("open3d not importable: timing clraster only")
    rates: dict[str, list[float]] = {name: [] for name in jobs}
    names = list(jobs)
    for rep in range(a.repeat):
        for name in names if rep % 2 == 0 else names[::-1]:
            t0 = time.perf_counter()
            jobs[name]()
            rates[name].append(len(poses) / (time.perf_counter() - t0))
            print(f"run {rep + 1}: {name:<20} {rates[name][-1]:7.2f} views/s", flush=True)
    med = {n: statistics.median(v) for n, v in rates.items()}
    print(f"{a.views} views of {a.mesh} ({mesh.n_faces:,} triangles) at {w}x{h}, depth + ids "
          f"+ normals, median of {a.repeat}:")
    for n, v in med.items():
        ratio = f" ({v / med['open3d raycast']:.2f}x Open3D)" if "open3d raycast" in med else ""
        print(f"  {n:<20} {v:7.2f} views/s{ratio}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
