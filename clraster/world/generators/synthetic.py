"""Synthetic scenes: instance grids (many instances of one mesh) and small random scenes
for property tests, with degenerate cases."""

from __future__ import annotations

import math

import numpy as np

from ...base.checks import check_int, check_size
from ..camera import Camera
from ..mesh import Mesh
from ..scene import Scene
from .primitives import boxes, cylinders, torus, translation, uv_sphere

__all__ = ["grid_camera", "instance_grid", "random_scene"]

_F64 = np.float64


def instance_grid(mesh: Mesh, nx: int, ny: int = 1, nz: int = 1, *,
                  spacing: float = 1.5) -> Scene:
    """``nx · ny · nz`` copies of `mesh` on a regular grid centred on the origin.

    The pitch along each axis is ``spacing`` times the mesh's bounding-box extent on that
    axis (an axis on which the mesh is flat uses its largest extent instead), so
    ``spacing = 1.5`` leaves half a copy of gap between neighbours. Instance
    ``i + nx·(j + ny·k)`` is copy (i, j, k) (x fastest); transforms are translations.

    Raises:
        ValueError: counts not positive integers, spacing not finite and > 0, or a mesh
            without finite referenced vertices (see Mesh.bounds).
    """
    nx = check_int(nx, "nx", 1)
    ny = check_int(ny, "ny", 1)
    nz = check_int(nz, "nz", 1)
    spacing = float(spacing)
    if not (math.isfinite(spacing) and spacing > 0.0):
        raise ValueError(f"spacing must be finite and > 0 (a multiple of the mesh size), "
                         f"got {spacing}")
    lo, hi = mesh.bounds()
    ext = hi - lo
    size = float(ext.max()) or 1.0
    pitch = spacing * np.where(ext > 1e-6 * size, ext, size)
    centre = (lo + hi) / 2.0
    k, j, i = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij")
    idx = np.stack([i.ravel(), j.ravel(), k.ravel()], -1).astype(_F64)
    offsets = (idx - (np.array([nx, ny, nz]) - 1) / 2.0) * pitch - centre
    scene = Scene()
    for off in offsets:
        scene.add(mesh, translation(*off))
    return scene


def grid_camera(scene: Scene, width: int, height: int) -> Camera:
    """A camera that frames the whole scene (e.g. an :func:`instance_grid`) from above
    and to the front-right, fov 45° (see Camera.framing)."""
    w, h = check_size(width, height)
    lo, hi = scene.bounds()
    return Camera.framing(lo, hi, direction=(1.0, 0.8, 1.6), fov_y=45.0, aspect=w / h)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    return np.array([
        [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
        [2 * (b * c + a * d), a * a - b * b + c * c - d * d, 2 * (c * d - a * b)],
        [2 * (b * d - a * c), 2 * (c * d + a * b), a * a - b * b - c * c + d * d],
    ])


def _random_mesh(rng: np.random.Generator) -> Mesh:
    kind = int(rng.integers(0, 4))
    if kind == 0:  # box
        e = rng.uniform(0.2, 1.0, 3)
        return Mesh(*boxes(-e / 2, e / 2))
    if kind == 1:
        return Mesh(*uv_sphere(0.5, int(rng.integers(3, 12)), int(rng.integers(4, 24))))
    if kind == 2:  # torus
        return Mesh(*torus(0.4, rng.uniform(0.05, 0.2), int(rng.integers(6, 32)),
                            int(rng.integers(3, 12))))
    return Mesh(*cylinders([0, -0.5, 0], [0, 0.5, 0], rng.uniform(0.1, 0.5),
                            int(rng.integers(3, 24))))


def random_scene(seed: int, n_instances: int = 16, *, extent: float = 5.0,
                 n_meshes: int | None = None, degenerate: bool = True,
                 mirrors: bool = False) -> Scene:
    """A small random scene for property tests (culling must be conservative on it).

    `n_meshes` unique meshes (default ``max(1, n_instances // 2)``, so instances share
    meshes) drawn from boxes, UV spheres, tori and cylinders of random tessellation, each
    of size about 1, closed and wound outward. Each instance picks one of them and gets
    a random rotation, a scale per axis in [0.3, 3] (uniform or not; no mirror unless
    `mirrors`) and a translation in ``[−extent, extent]³``; objects may overlap.

    With `degenerate` (and n_instances >= 2), two instances are replaced by degenerate
    meshes: a flat box of zero thickness (zero-area side faces; its top and bottom
    coincide) and a sphere with one NaN vertex (its triangles must be dropped, the rest
    drawn).

    With `mirrors`, about one instance in five is also reflected (one scale negated:
    determinant < 0, so its faces are seen clockwise from outside in world space); the
    scene is otherwise the same as without. Same arguments, same scene.
    """
    seed = check_int(seed, "seed", 0)
    n_instances = check_int(n_instances, "n_instances", 1)
    extent = float(extent)
    if not (math.isfinite(extent) and extent >= 0.0):
        raise ValueError(f"extent must be finite and >= 0, got {extent}")
    n_meshes = max(1, n_instances // 2) if n_meshes is None else check_int(
        n_meshes, "n_meshes", 1)
    rng = np.random.default_rng(seed)
    pool = [_random_mesh(rng) for _ in range(n_meshes)]
    choice = rng.integers(0, n_meshes, n_instances)
    meshes = [pool[c] for c in choice]
    if degenerate and n_instances >= 2:
        slots = rng.choice(n_instances, size=2, replace=False)
        e = rng.uniform(0.3, 1.0, 3)
        meshes[slots[0]] = Mesh(*boxes([-e[0] / 2, 0, -e[2] / 2], [e[0] / 2, 0, e[2] / 2]))
        v, f = uv_sphere(0.5, 8, 12)
        v[int(rng.integers(0, v.shape[0]))] = np.nan
        meshes[slots[1]] = Mesh(v, f)
    scene = Scene()
    for mesh in meshes:
        m = np.eye(4)
        sc = np.exp(rng.uniform(math.log(0.3), math.log(3.0), 3))
        if rng.random() < 0.5:
            sc[:] = sc[0]
        flip = rng.random() < 0.2, int(rng.integers(0, 3))  # drawn always: same stream
        if mirrors and flip[0]:
            sc[flip[1]] = -sc[flip[1]]
        m[:3, :3] = _random_rotation(rng) * sc[None, :]
        m[:3, 3] = rng.uniform(-extent, extent, 3)
        scene.add(mesh, m)
    return scene
