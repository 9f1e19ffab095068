"""Procedural scenes for tests and benchmarks: deterministic, no files, vectorized NumPy.

* :func:`plant` — a multi-storey "power plant" in the spirit of the UNC Power Plant model
  (12M triangles, most of them hidden from any interior viewpoint): storeys of rooms on
  either side of long corridors, floors and ceilings, partition walls with doorways, outer
  walls with windows, stairs, and equipment at many scales (pipe runs, tanks, pumps,
  cabinets, transformers, turbines, railings). Its size follows ``n_triangles``.
* :func:`instance_grid` — copies of one mesh on a regular grid (many instances, one mesh).
* :func:`random_scene` — small random scenes for property tests, with degenerate cases.

Conventions of every generated mesh: metres, world +Y up, closed surfaces (every edge
shared by exactly two faces, so trimesh calls them watertight) wound counter-clockwise
seen from outside (positive signed volume). Instance transforms are float64 (4, 4)
object → world matrices with positive determinant (rotations, translations, positive and
possibly non-uniform scales), so winding stays outward in world space; only
``random_scene(..., mirrors=True)`` adds reflections on purpose.
Everything is a function of the arguments: the same call gives identical arrays.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .camera import Camera
from .mesh import Mesh
from .scene import Scene

__all__ = [
    "grid_camera",
    "instance_grid",
    "plant",
    "plant_catalog",
    "plant_inside_camera",
    "plant_overview_camera",
    "random_scene",
]

# -- plant dimensions (metres) ----------------------------------------------------------
# plant_inside_camera recovers the layout from the scene's bounds with these, so changing
# one changes both the generator and the camera.
ROOM_X = 8.0  #: room pitch along x (corridor direction), partition wall centre to centre
ROOM_Z = 7.0  #: room depth, from the corridor wall's centre line to the far wall's
CORRIDOR = 3.0  #: corridor pitch across z (clear width CORRIDOR − WALL)
BAND = 2.0 * ROOM_Z + CORRIDOR  #: a row of rooms, a corridor, a row of rooms
STOREY = 5.0  #: floor-to-floor height
SLAB = 0.3  #: floor / ceiling slab thickness (a slab's top is its storey's floor, y = k·STOREY)
WALL = 0.2  #: partition wall thickness (centred on its grid line)
OUTER = 0.3  #: outer wall thickness (inside the footprint)
CLEAR = STOREY - SLAB  #: clear height of a storey
EYE_HEIGHT = 1.7  #: eye height of the first-person camera above its floor

_DOOR_W, _DOOR_H = 1.4, 2.3
#: Openings from a room onto its corridor: (width, height, probability): a door, a wide
#: roll-up door, an open bay under a beam. Room contents keep out of the widest door's
#: path (local x in [2.5, 5.5], z < 1.9).
_OPENINGS = ((_DOOR_W, _DOOR_H, 0.5), (3.0, 3.2, 0.3), (ROOM_X - 0.6, 3.6, 0.2))
_WIN_SILL, _WIN_TOP, _WIN_W = 1.0, 3.2, 2.0
_SEG_LEN = 6.0  #: pipe section length between flanges
_RACK_TIERS = 4  #: pipe tiers under a ceiling (the lowest flange stays above 2.75 m)
_MIN_TRIANGLES = 2_000

_F64 = np.float64


# =======================================================================================
# Primitives. Each returns (vertices float64 (V, 3), faces int64 (F, 3)), closed and wound
# counter-clockwise seen from outside.
# =======================================================================================

VF = tuple[np.ndarray, np.ndarray]

# Unit-cube corner c = x + 2y + 4z (bits); 12 triangles with outward normals, checked by
# cross products: e.g. (0, 4, 6): (0,0,1) × (0,1,1) = (−1, 0, 0), the x = 0 face.
_CUBE_BITS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=_F64)
_CUBE_FACES = np.array([
    [0, 4, 6], [0, 6, 2],  # x = 0
    [1, 3, 7], [1, 7, 5],  # x = 1
    [0, 1, 5], [0, 5, 4],  # y = 0
    [2, 6, 7], [2, 7, 3],  # y = 1
    [0, 2, 3], [0, 3, 1],  # z = 0
    [4, 5, 7], [4, 7, 6],  # z = 1
], dtype=np.int64)


def _boxes(lo: npt.ArrayLike, hi: npt.ArrayLike) -> VF:
    """K axis-aligned boxes ``[lo_k, hi_k]`` (each (K, 3) or (3,)): 8K vertices, 12K faces."""
    lo = np.atleast_2d(np.asarray(lo, _F64))
    hi = np.atleast_2d(np.asarray(hi, _F64))
    lo, hi = np.broadcast_arrays(lo, hi)
    v = lo[:, None, :] + _CUBE_BITS[None] * (hi - lo)[:, None, :]
    f = _CUBE_FACES[None] + 8 * np.arange(lo.shape[0])[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def _lathe(r: npt.ArrayLike, y: npt.ArrayLike, sides: int, *, closed: bool = False) -> VF:
    """A surface of revolution about +Y from a profile of (radius, height) points.

    Open profile: from the bottom pole (r = 0) to the top pole (r = 0), all points between
    with r > 0, traversed so the solid is on the left in the (r, y) half-plane (up the
    outside): ``2·sides·(P − 2)`` faces for P points. Closed profile (a torus): a loop
    traversed counter-clockwise in the (r, y) plane, all r > 0: ``2·sides·P`` faces.
    Ring vertex j sits at angle θ_j = 2πj/sides as ``(r cos θ, y, −r sin θ)``; with that
    sign the quad (a, b, c), (a, c, d) below faces away from the axis.
    """
    r = np.asarray(r, _F64)
    y = np.asarray(y, _F64)
    n = int(sides)
    if closed:
        rr, yy = r, y
    else:
        if not (r[0] == 0.0 and r[-1] == 0.0 and np.all(r[1:-1] > 0.0)):
            raise AssertionError("open lathe profile must run pole (r=0) to pole")
        rr, yy = r[1:-1], y[1:-1]
    p = rr.shape[0]
    th = 2.0 * np.pi * np.arange(n) / n
    ring = np.stack([rr[:, None] * np.cos(th), np.broadcast_to(yy[:, None], (p, n)),
                     -rr[:, None] * np.sin(th)], axis=-1).reshape(-1, 3)
    j = np.arange(n)[None, :]
    jn = (j + 1) % n
    i = np.arange(p if closed else p - 1)[:, None]
    i1 = (i + 1) % p
    a, b, c, d = i * n + j, i * n + jn, i1 * n + jn, i1 * n + j
    faces = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    verts = [ring]
    if not closed:
        bot, top = p * n, p * n + 1
        jj, jjn = np.arange(n), (np.arange(n) + 1) % n
        last = (p - 1) * n
        faces.append(np.stack([np.full(n, bot), jjn, jj], -1))
        faces.append(np.stack([last + jj, last + jjn, np.full(n, top)], -1))
        verts.append(np.array([[0.0, y[0], 0.0], [0.0, y[-1], 0.0]]))
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def _arc(r0: float, y0: float, r1: float, y1: float, steps: int) -> tuple[list, list]:
    """Quarter-ellipse profile points after (r0, y0) up to (r1, y1): a dome (r1 = 0) or a
    dished bottom head (r0 = 0), ``steps`` points, end included."""
    phi = np.linspace(0.0, np.pi / 2.0, steps + 1)[1:]
    if r1 == 0.0:  # dome: radius shrinks from r0 to 0 while y rises from y0 to y1
        rs, ys = r0 * np.cos(phi), y0 + (y1 - y0) * np.sin(phi)
    else:  # bottom head: radius grows from 0 to r1 while y rises from y0 to y1
        rs, ys = r1 * np.sin(phi), y1 - (y1 - y0) * np.cos(phi)
    rs = np.where(np.abs(rs) < 1e-12, 0.0, rs)
    return list(rs), list(ys)


def _uv_sphere(radius: float, rings: int, sides: int) -> VF:
    """Sphere about the origin: `rings` latitude bands (poles included), `sides` around."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, rings + 1)
    r = radius * np.cos(phi)
    r[0] = r[-1] = 0.0
    return _lathe(r, radius * np.sin(phi), sides)


def _torus(major: float, minor: float, major_sides: int, minor_sides: int) -> VF:
    """Torus about +Y in the plane y = 0."""
    phi = 2.0 * np.pi * np.arange(minor_sides) / minor_sides
    return _lathe(major + minor * np.cos(phi), minor * np.sin(phi), major_sides, closed=True)


def _unit_cylinder(sides: int) -> VF:
    """Radius 1, from y = 0 to y = 1, flat caps with centre vertices: 4·sides faces."""
    return _lathe([0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0], sides)


def _bake(vf: VF, mats: np.ndarray) -> VF:
    """K copies of a template, copy k transformed by the affine ``mats[k]`` (K, 4, 4)."""
    v, f = vf
    mats = np.asarray(mats, _F64).reshape(-1, 4, 4)
    out = np.einsum("kij,vj->kvi", mats[:, :3, :3], v) + mats[:, None, :3, 3]
    faces = f[None] + (v.shape[0] * np.arange(mats.shape[0]))[:, None, None]
    return out.reshape(-1, 3), faces.reshape(-1, 3)


def _axis_frames(p0: np.ndarray, p1: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(K, 4, 4) affines taking the unit cylinder to radius r_k from p0_k to p1_k.

    Columns: local x → r·u, local y → (p1 − p0), local z → r·(u × w), with u ⟂ w; the
    determinant is r²·|p1 − p0| > 0, so winding is kept.
    """
    p0 = np.atleast_2d(np.asarray(p0, _F64))
    p1 = np.atleast_2d(np.asarray(p1, _F64))
    axis = p1 - p0
    w = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    helper = np.where((np.abs(w[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(u, w)
    r = np.broadcast_to(np.asarray(r, _F64), (p0.shape[0],))
    m = np.zeros((p0.shape[0], 4, 4))
    m[:, :3, 0] = r[:, None] * u
    m[:, :3, 1] = axis
    m[:, :3, 2] = r[:, None] * v
    m[:, :3, 3] = p0
    m[:, 3, 3] = 1.0
    return m


def _cylinders(p0: npt.ArrayLike, p1: npt.ArrayLike, r: npt.ArrayLike, sides: int) -> VF:
    """K capped cylinders of radius r_k from p0_k to p1_k: 4·sides faces each."""
    return _bake(_unit_cylinder(sides), _axis_frames(np.asarray(p0), np.asarray(p1), r))


def _transformed(vf: VF, m: np.ndarray) -> VF:
    v, f = vf
    return v @ m[:3, :3].T + m[:3, 3], f


def _translate(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _scale(sx: float, sy: float, sz: float) -> np.ndarray:
    return np.diag([sx, sy, sz, 1.0])


def _rot_y(angle: float) -> np.ndarray:
    """Rotation by `angle` radians about +Y (x → −z for a quarter turn)."""
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = c, s, -s, c
    return m


#: Proper rotations taking the lathe axis +Y to +X and to +Z.
_Y_TO_X = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


class _Parts:
    """Collects closed parts into one mesh (parts may interpenetrate: each stays closed)."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._n = 0

    def add(self, vf: VF, m: np.ndarray | None = None) -> _Parts:
        v, f = vf if m is None else _transformed(vf, m)
        self._v.append(v)
        self._f.append(f + self._n)
        self._n += v.shape[0]
        return self

    def box(self, lo: npt.ArrayLike, hi: npt.ArrayLike, m: np.ndarray | None = None) -> _Parts:
        return self.add(_boxes(lo, hi), m)

    def cyl(self, p0: npt.ArrayLike, p1: npt.ArrayLike, r: npt.ArrayLike, sides: int,
            m: np.ndarray | None = None) -> _Parts:
        return self.add(_cylinders(p0, p1, r, max(3, sides)), m)

    def vf(self) -> VF:
        return np.concatenate(self._v), np.concatenate(self._f)

    def mesh(self) -> Mesh:
        return Mesh(*self.vf())


# =======================================================================================
# Plant equipment: unique meshes, each in its own frame (origin on the floor, footprint
# centred on the origin unless said otherwise). `s` is the base tessellation (even, >= 8).
# =======================================================================================

def _tank_vertical(radius: float, height: float, dome: float, sides: int, dome_steps: int,
                   stiffeners: int) -> _Parts:
    r = [0.0, radius + 0.03, radius + 0.03, radius]  # a base ring, then the shell
    y = [0.0, 0.0, 0.12, 0.12]
    for k in range(1, stiffeners + 1):  # stiffening rings: bumps in the profile
        yk = height * k / (stiffeners + 1)
        r += [radius, radius + 0.04, radius + 0.04, radius]
        y += [yk - 0.05, yk - 0.05, yk + 0.05, yk + 0.05]
    r += [radius]
    y += [height]
    dr, dy = _arc(radius, height, 0.0, height + dome, dome_steps)
    parts = _Parts().add(_lathe(r + dr, y + dy, sides))
    ns = max(8, sides // 3)
    parts.cyl([0, height + dome * 0.5, 0], [0, height + dome + 0.2, 0], 0.08 * radius + 0.03,
              ns)
    parts.cyl([0, 0.6 * height, 0], [0, 0.6 * height, radius + 0.25], 0.1 * radius + 0.04, ns)
    parts.cyl([0, 0.25, 0], [radius + 0.3, 0.25, 0], 0.07 * radius + 0.03, ns)
    return parts


def _tank_small(s: int) -> Mesh:
    return _tank_vertical(0.45, 1.3, 0.3, 2 * s, max(2, s // 4), 0).mesh()


def _tank_medium(s: int) -> Mesh:
    return _tank_vertical(0.85, 2.6, 0.45, 3 * s, max(2, s // 3), 2).mesh()


def _tank_large(s: int) -> Mesh:
    return _tank_vertical(1.3, 3.4, 0.5, 4 * s, max(3, s // 2), 4).mesh()


def _sphere_tank(s: int) -> Mesh:
    radius, centre = 0.85, 2.1
    parts = _Parts().add(_uv_sphere(radius, max(4, s), 2 * s), _translate(0, centre, 0))
    a = np.pi / 4 + np.arange(4) * np.pi / 2
    feet = np.stack([0.7 * np.cos(a), np.zeros(4), 0.7 * np.sin(a)], -1)
    parts.cyl(feet, feet + [0, centre, 0], 0.06, max(8, s // 2))
    parts.cyl([0, centre + radius - 0.1, 0], [0, centre + radius + 0.25, 0], 0.1, s)
    return parts.mesh()


def _horizontal_vessel(radius: float, length: float, axis_y: float, s: int,
                       flanged: bool) -> _Parts:
    """A vessel along x: dished heads, optional body flanges, two saddles, nozzles."""
    half = length / 2.0
    steps = max(2, s // 3)
    head = 0.45 * radius
    r0, y0 = _arc(0.0, -half - head, radius, -half, steps)
    r = [0.0] + r0
    y = [-half - head] + y0
    if flanged:
        fl = radius + 0.1
        r += [fl, fl, radius, radius, fl, fl, radius]
        y += [-half, -half + 0.12, -half + 0.12, half - 0.12, half - 0.12, half, half]
    else:
        r += [radius]
        y += [half]
    r1, y1 = _arc(radius, half, 0.0, half + head, steps)
    body = _lathe(r + r1, y + y1, 3 * s)
    parts = _Parts().add(body, _translate(0, axis_y, 0) @ _Y_TO_X)
    for x in (-0.3 * length, 0.3 * length):
        parts.box([x - 0.15, 0.0, -0.75 * radius], [x + 0.15, axis_y - 0.6 * radius,
                                                    0.75 * radius])
    xs = np.array([-0.35, 0.0, 0.35]) * length
    tops = np.stack([xs, np.full(3, axis_y), np.zeros(3)], -1)
    parts.cyl(tops, tops + [0, radius + 0.3, 0], 0.12, s)
    parts.cyl(tops + [0, radius + 0.2, 0], tops + [0, radius + 0.3, 0], 0.2, s)
    return parts


def _tank_horizontal(s: int) -> Mesh:
    return _horizontal_vessel(0.8, 3.8, 1.1, s, flanged=False).mesh()


def _heat_exchanger(s: int) -> Mesh:
    return _horizontal_vessel(0.55, 3.6, 0.95, s, flanged=True).mesh()


def _turbine(s: int) -> Mesh:
    """A steam turbine + generator on a pedestal, shaft along x, about 6.4 m long."""
    rng = np.random.default_rng(7)  # fixed: the shape, not the scene, is random
    n_stage = max(4, s // 2)
    x = np.linspace(-2.6, 1.2, n_stage + 1)
    radius = np.linspace(0.55, 1.25, n_stage + 1)
    r = [0.0, 0.3, 0.3]
    y = [-3.0, -3.0, -2.6]
    for k in range(n_stage):  # casing: a stepped cone with a rib per stage
        r += [radius[k], radius[k] + 0.05, radius[k] + 0.05, radius[k + 1]]
        y += [x[k], x[k], x[k] + 0.08, x[k] + 0.08]
    r += [radius[-1], 0.3, 0.3, 0.0]
    y += [x[-1], x[-1], 1.6, 1.6]
    axis_y = 1.75
    parts = _Parts().add(_lathe(r, y, 4 * s), _translate(0, axis_y, 0) @ _Y_TO_X)
    # generator: ribbed cylinder
    gr, gy = [0.0], [1.6]
    n_rib = max(3, s // 3)
    for k in range(n_rib):
        y0 = 1.7 + 1.5 * k / n_rib
        gr += [0.95, 0.95, 1.0, 1.0, 0.95] if k == 0 else [0.95, 1.0, 1.0, 0.95]
        gy += [1.6, y0, y0, y0 + 0.06, y0 + 0.06] if k == 0 else [y0, y0, y0 + 0.06, y0 + 0.06]
    gr += [0.95, 0.0]
    gy += [3.4, 3.4]
    parts.add(_lathe(gr, gy, 3 * s), _translate(0, axis_y, 0) @ _Y_TO_X)
    parts.box([-3.2, 0.0, -1.0], [3.5, axis_y - 0.9, 1.0])  # pedestal
    parts.box([-2.7, axis_y - 0.04, -1.35], [1.3, axis_y + 0.04, 1.35])  # split flange
    # steam lines: vertical pipes into the casing top
    xs = np.linspace(-2.2, 0.8, 3) + rng.uniform(-0.1, 0.1, 3)
    bases = np.stack([xs, np.full(3, axis_y + 0.5), np.zeros(3)], -1)
    parts.cyl(bases, bases + [0, CLEAR - axis_y - 0.5, 0], 0.16, 2 * s)
    return parts.mesh()


def _motor_parts(s: int, length: float, radius: float, axis_y: float) -> _Parts:
    parts = _Parts()
    r = [0.0, radius, radius, 0.0]
    y = [-length / 2, -length / 2, length / 2, length / 2]
    parts.add(_lathe(r, y, 2 * s), _translate(0, axis_y, 0) @ _Y_TO_X)
    n_fin = max(6, s // 2)
    a = np.pi * np.arange(n_fin) / (n_fin - 1)  # fins over the top half
    for k in range(n_fin):  # radial cooling fins, boxes rotated about the shaft
        rot = np.eye(4)
        c, sn = math.cos(a[k]), math.sin(a[k])
        rot[1, 1], rot[1, 2], rot[2, 1], rot[2, 2] = c, -sn, sn, c
        parts.box([-length / 2 + 0.05, radius - 0.02, -0.008],
                  [length / 2 - 0.05, radius + 0.05, 0.008], _translate(0, axis_y, 0) @ rot)
    parts.cyl([length / 2, axis_y, 0], [length / 2 + 0.15, axis_y, 0], 0.04, s)  # shaft
    parts.box([-length / 2 + 0.05, 0.0, -radius * 0.8],
              [length / 2 - 0.05, axis_y - radius * 0.6, radius * 0.8])  # feet
    return parts


def _motor(s: int) -> Mesh:
    return _motor_parts(s, 0.8, 0.26, 0.36).mesh()


def _pump(s: int) -> Mesh:
    parts = _motor_parts(s, 0.7, 0.22, 0.5)
    parts.box([-0.7, 0.0, -0.3], [0.7, 0.22, 0.3])  # baseplate
    parts.cyl([0.45, 0.5, 0.0], [0.6, 0.5, 0.0], 0.07, s)  # coupling
    # volute casing: a disc about x, then suction (along x) and discharge (up) nozzles
    r = [0.0, 0.3, 0.33, 0.33, 0.3, 0.0]
    y = [0.6, 0.6, 0.65, 0.83, 0.88, 0.88]
    parts.add(_lathe(r, y, 2 * s), _translate(0, 0.5, 0) @ _Y_TO_X)
    parts.cyl([0.88, 0.5, 0.0], [1.1, 0.5, 0.0], 0.1, s)
    parts.cyl([1.08, 0.5, 0.0], [1.12, 0.5, 0.0], 0.16, s)
    parts.cyl([0.74, 0.7, 0.0], [0.74, 1.15, 0.0], 0.08, s)
    parts.cyl([0.74, 1.1, 0.0], [0.74, 1.15, 0.0], 0.13, s)
    return parts.mesh()


def _valve_stand(s: int) -> Mesh:
    parts = _Parts().box([-0.2, 0.0, -0.2], [0.2, 0.6, 0.2])  # pedestal
    parts.add(_uv_sphere(0.16, max(4, s // 2), 2 * s), _translate(0, 0.78, 0))  # body
    parts.cyl([-0.45, 0.78, 0.0], [0.45, 0.78, 0.0], 0.08, s)  # pipe stubs
    parts.cyl([[-0.3, 0.78, 0.0], [0.26, 0.78, 0.0]], [[-0.26, 0.78, 0.0], [0.3, 0.78, 0.0]],
              0.13, s)  # flanges
    parts.cyl([0.0, 0.9, 0.0], [0.0, 1.35, 0.0], 0.03, s)  # stem
    parts.add(_torus(0.2, 0.02, 2 * s, max(6, s // 2)), _translate(0, 1.3, 0))  # handwheel
    for k in range(3):  # spokes
        parts.box([-0.2, -0.012, -0.012], [0.2, 0.012, 0.012],
                  _translate(0, 1.3, 0) @ _rot_y(k * np.pi / 3))
    return parts.mesh()


def _cabinet(s: int, width: float, height: float, depth: float, doors: int) -> Mesh:
    """Cabinet against a wall at its back (z = −depth/2), doors on its +z face."""
    parts = _Parts().box([-width / 2, 0.1, -depth / 2], [width / 2, height, depth / 2])
    parts.box([-width / 2 + 0.03, 0.0, -depth / 2 + 0.03], [width / 2 - 0.03, 0.1,
                                                            depth / 2 - 0.03])  # plinth
    dw = width / doors
    n_slat = max(2, s // 3)
    z = depth / 2
    for k in range(doors):
        x0 = -width / 2 + k * dw
        parts.box([x0 + 0.02, 0.15, z], [x0 + dw - 0.02, height - 0.05, z + 0.015])  # door
        hx = x0 + (dw - 0.08 if k % 2 == 0 else 0.06)
        parts.box([hx, height * 0.45, z + 0.015], [hx + 0.02, height * 0.55, z + 0.05])
        ys = np.linspace(height * 0.65, height - 0.15, n_slat)  # ventilation louvres
        parts.box(np.stack([np.full(n_slat, x0 + 0.1), ys, np.full(n_slat, z + 0.015)], -1),
                  np.stack([np.full(n_slat, x0 + dw - 0.1), ys + 0.02,
                            np.full(n_slat, z + 0.03)], -1))
    return parts.mesh()


def _control_desk(s: int) -> Mesh:
    parts = _Parts().box([-0.9, 0.0, -0.45], [0.9, 0.8, 0.45])
    tilt = np.eye(4)
    a = math.radians(30)
    tilt[1, 1], tilt[1, 2], tilt[2, 1], tilt[2, 2] = math.cos(a), -math.sin(a), math.sin(a), \
        math.cos(a)
    panel = _translate(0, 0.8, -0.1) @ tilt
    parts.box([-0.88, 0.0, -0.35], [0.88, 0.06, 0.35], panel)
    nk = max(3, s // 2)
    kx, kz = np.meshgrid(np.linspace(-0.75, 0.75, nk), [-0.2, 0.0, 0.2], indexing="xy")
    p0 = np.stack([kx.ravel(), np.full(kx.size, 0.06), kz.ravel()], -1)
    parts.add(_cylinders(p0, p0 + [0, 0.04, 0], 0.025, max(6, s // 2)), panel)  # knobs
    parts.box([-0.8, 0.8, -0.45], [0.8, 1.4, -0.38])  # screen wall
    return parts.mesh()


def _transformer(s: int) -> Mesh:
    parts = _Parts().box([-0.7, 0.0, -0.45], [0.7, 1.6, 0.45])
    n_fin = max(4, s // 2)
    zs = np.linspace(-0.38, 0.38, n_fin)
    for side in (-1.0, 1.0):  # radiator fins on both ends
        x0, x1 = (0.7, 1.0) if side > 0 else (-1.0, -0.7)
        parts.box(np.stack([np.full(n_fin, x0), np.full(n_fin, 0.2), zs - 0.01], -1),
                  np.stack([np.full(n_fin, x1), np.full(n_fin, 1.45), zs + 0.01], -1))
    n_shed = max(3, s // 3)  # bushings: porcelain sheds as a zigzag profile
    r = [0.0, 0.09]
    y = [0.0, 0.0]
    for k in range(n_shed):
        y0 = 0.05 + 0.08 * k
        r += [0.07, 0.14, 0.07]
        y += [y0, y0 + 0.02, y0 + 0.05]
    r += [0.07, 0.0]
    y += [y[-1] + 0.05, y[-1] + 0.05]
    bushing = _lathe(r, y, s)
    for x in (-0.4, 0.0, 0.4):
        parts.add(bushing, _translate(x, 1.6, 0.0))
    return parts.mesh()


def _drum(s: int) -> Mesh:
    r = [0.0, 0.28, 0.28, 0.295, 0.295, 0.28, 0.28, 0.295, 0.295, 0.28, 0.28, 0.0]
    y = [0.0, 0.0, 0.28, 0.28, 0.31, 0.31, 0.57, 0.57, 0.6, 0.6, 0.88, 0.88]
    return _Parts().add(_lathe(r, y, 2 * s)).mesh()


def _crate(s: int) -> Mesh:
    parts = _Parts().box([-0.48, 0.0, -0.48], [0.48, 0.96, 0.48])
    e, w = 0.5, 0.05  # edge battens, slightly proud of the core
    lo = [[-e, 0, -e], [e - w, 0, -e], [-e, 0, e - w], [e - w, 0, e - w],
          [-e, 0, -e], [-e, 1 - w, -e], [-e, 0, e - w], [-e, 1 - w, e - w],
          [-e, 0, -e], [-e, 1 - w, -e], [e - w, 0, -e], [e - w, 1 - w, -e]]
    hi = [[-e + w, 1, -e + w], [e, 1, -e + w], [-e + w, 1, e], [e, 1, e],
          [e, w, -e + w], [e, 1, -e + w], [e, w, e], [e, 1, e],
          [-e + w, w, e], [-e + w, 1, e], [e, w, e], [e, 1, e]]
    return parts.box(lo, hi).mesh()


def _shelf(s: int) -> Mesh:
    parts = _Parts().box([[-1.0, 0, -0.25], [0.96, 0, -0.25]], [[-0.96, 2.2, 0.25],
                                                                  [1.0, 2.2, 0.25]])
    n = 5
    ys = np.linspace(0.1, 2.1, n)
    parts.box(np.stack([np.full(n, -0.96), ys, np.full(n, -0.24)], -1),
              np.stack([np.full(n, 0.96), ys + 0.03, np.full(n, 0.24)], -1))
    rng = np.random.default_rng(11)  # boxes on the shelves (fixed: part of the shape)
    k = max(4, s)
    lvl = rng.integers(0, n - 1, k)
    x = rng.uniform(-0.85, 0.7, k)
    wd = rng.uniform(0.1, 0.3, k)
    ht = rng.uniform(0.1, 0.3, k)
    parts.box(np.stack([x, ys[lvl] + 0.03, np.full(k, -0.2)], -1),
              np.stack([x + wd, ys[lvl] + 0.03 + ht, np.full(k, 0.15)], -1))
    return parts.mesh()


def _lamp(s: int) -> Mesh:
    """A ceiling lamp hanging below its origin (origin at the ceiling)."""
    r = [0.0, 0.3, 0.3, 0.06, 0.03, 0.03, 0.0]
    y = [-0.6, -0.6, -0.57, -0.42, -0.42, 0.0, 0.0]
    return _Parts().add(_lathe(r, y, s)).mesh()


def _extinguisher(s: int) -> Mesh:
    r = [0.0, 0.09, 0.09] + _arc(0.09, 0.55, 0.0, 0.65, max(2, s // 4))[0]
    y = [0.0, 0.0, 0.55] + _arc(0.09, 0.55, 0.0, 0.65, max(2, s // 4))[1]
    parts = _Parts().add(_lathe(r, y, s))
    parts.cyl([0.0, 0.62, 0.0], [0.12, 0.66, 0.0], 0.015, max(6, s // 2))
    return parts.mesh()


def _railing(s: int) -> Mesh:
    """A 2 m railing section along +x from x = 0, posts at both ends."""
    parts = _Parts().box([[0, 0, -0.025], [1.95, 0, -0.025]], [[0.05, 1.1, 0.025],
                                                                 [2.0, 1.1, 0.025]])
    ns = max(6, s // 2)
    parts.cyl([[0.0, 1.07, 0.0], [0.0, 0.55, 0.0]], [[2.0, 1.07, 0.0], [2.0, 0.55, 0.0]], 0.025,
              ns)
    parts.box([0.0, 0.0, -0.01], [2.0, 0.12, 0.01])  # toe board
    return parts.mesh()


def _column(s: int) -> Mesh:
    """A steel I-column, floor to ceiling."""
    return _Parts().box([[-0.15, 0, -0.15], [-0.15, 0, 0.12], [-0.015, 0, -0.12]],
                        [[0.15, CLEAR, -0.12], [0.15, CLEAR, 0.15], [0.015, CLEAR, 0.12]]
                        ).mesh()


def _cable_tray(s: int) -> Mesh:
    """A 1 m cable tray along +x with cables (instanced with a scale along x)."""
    parts = _Parts().box([[0, 0, -0.2], [0, 0, -0.2], [0, 0, 0.18]],
                         [[1, 0.02, 0.2], [1, 0.1, -0.18], [1, 0.1, 0.2]])
    nc = max(3, s // 4)
    zs = np.linspace(-0.14, 0.14, nc)
    p0 = np.stack([np.zeros(nc), np.full(nc, 0.05), zs], -1)
    parts.cyl(p0, p0 + [1, 0, 0], 0.025, max(6, s // 2))
    return parts.mesh()


def _platform(s: int) -> Mesh:
    """A mezzanine 2 m (x) × 5 m (z) at 2.8 m, on legs, railing on its +x edge, a ladder."""
    h = 2.8
    parts = _Parts().box([0.0, h - 0.1, 0.0], [2.0, h, 5.0])
    parts.box([[0.0, 0, 0.0], [1.85, 0, 0.0], [0.0, 0, 4.85], [1.85, 0, 4.85]],
              [[0.15, h - 0.1, 0.15], [2.0, h - 0.1, 0.15], [0.15, h - 0.1, 5.0],
               [2.0, h - 0.1, 5.0]])
    rail = _railing(s)
    rv, rf = rail.vertices.astype(_F64), rail.faces.astype(np.int64)
    turn = _rot_y(-np.pi / 2)  # section along +z
    for z in (0.0, 2.0):
        parts.add((rv, rf), _translate(1.95, h, z) @ turn)
    # ladder up the +x edge at z in [4.2, 4.8]
    parts.box([[2.0, 0, 4.2], [2.0, 0, 4.75]], [[2.05, h + 1.0, 4.25], [2.05, h + 1.0, 4.8]])
    n_rung = 9
    ys = np.linspace(0.3, h - 0.2, n_rung)
    p0 = np.stack([np.full(n_rung, 2.025), ys, np.full(n_rung, 4.25)], -1)
    parts.cyl(p0, p0 + [0, 0, 0.5], 0.015, max(6, s // 2))
    return parts.mesh()


def _stair(s: int) -> Mesh:
    """A straight flight along +x rising one storey: 26 solid steps, 1.2 m wide (z in
    [0, 1.2]), starting at x = 0, with a handrail on its +z side."""
    n = 26
    tread, rise = 0.26, STOREY / n
    i = np.arange(n)
    parts = _Parts().box(np.stack([i * tread, np.zeros(n), np.zeros(n)], -1),
                         np.stack([(i + 1) * tread, (i + 1) * rise, np.full(n, 1.2)], -1))
    posts = np.arange(0, n, 4)
    parts.box(np.stack([posts * tread + 0.1, (posts + 1) * rise, np.full(posts.size, 1.13)], -1),
              np.stack([posts * tread + 0.15, (posts + 1) * rise + 1.0,
                        np.full(posts.size, 1.18)], -1))
    parts.cyl([0.1, rise + 1.0, 1.155], [n * tread, STOREY + 1.0, 1.155], 0.03, max(6, s // 2))
    return parts.mesh()


_CATALOG: dict[str, Callable[[int], Mesh]] = {
    "tank_small": _tank_small,
    "tank_medium": _tank_medium,
    "tank_large": _tank_large,
    "sphere_tank": _sphere_tank,
    "tank_horizontal": _tank_horizontal,
    "heat_exchanger": _heat_exchanger,
    "turbine": _turbine,
    "pump": _pump,
    "motor": _motor,
    "valve": _valve_stand,
    "cabinet_tall": lambda s: _cabinet(s, 1.0, 2.1, 0.6, 2),
    "cabinet_wide": lambda s: _cabinet(s, 2.0, 1.2, 0.5, 4),
    "cabinet_low": lambda s: _cabinet(s, 1.2, 0.9, 0.6, 2),
    "control_desk": _control_desk,
    "transformer": _transformer,
    "drum": _drum,
    "crate": _crate,
    "shelf": _shelf,
    "lamp": _lamp,
    "extinguisher": _extinguisher,
    "railing": _railing,
    "column": _column,
    "cable_tray": _cable_tray,
    "platform": _platform,
    "stair": _stair,
    "pipe": lambda s: Mesh(*_unit_cylinder(s)),
}


def plant_catalog(tessellation: int = 12) -> dict[str, Mesh]:
    """The plant's equipment meshes at a given base tessellation (sides of a small pipe).

    Each is closed and wound counter-clockwise seen from outside, in its own frame with
    the origin on the floor (the lamp hangs below its origin; ``pipe`` is the unit
    cylinder, radius 1 from y = 0 to 1; ``cable_tray`` is 1 m long along +x).
    """
    s = _check_int(tessellation, "tessellation", 3)
    return {name: make(s) for name, make in _CATALOG.items()}


# =======================================================================================
# Plant layout
# =======================================================================================

@dataclass(frozen=True)
class _Layout:
    storeys: int
    bands: int
    nx: int  # rooms along a corridor, per side

    @property
    def width(self) -> float:
        return self.nx * ROOM_X

    @property
    def depth(self) -> float:
        return self.bands * BAND

    def corridor_z(self, band: int) -> tuple[float, float]:
        """Centre lines of the two corridor walls of `band`."""
        z0 = band * BAND + ROOM_Z
        return z0, z0 + CORRIDOR

    def room_frame(self, band: int, side: int, i: int, storey: int) -> np.ndarray:
        """Room-local → world: local x along the room (0..ROOM_X), local z from the corridor
        wall (0) into the room (..ROOM_Z), y up from the room's floor. side 0 = the row at
        lower z (turned half a turn, a proper rotation), side 1 = the row at higher z."""
        zc0, zc1 = self.corridor_z(band)
        y = storey * STOREY
        if side == 1:
            return _translate(i * ROOM_X, y, zc1)
        return _translate((i + 1) * ROOM_X, y, zc0) @ _rot_y(np.pi)


# Room contents are placed in room-local coordinates (see _Layout.room_frame): slots in
# two rows behind the strip in front of the corridor opening (x in [2.5, 5.5], z < 1.9),
# which stays clear; _fit then keeps every object inside the walls.
_SLOTS = ((1.5, 3.0), (4.0, 3.0), (6.5, 3.0), (1.5, 5.3), (4.0, 5.3), (6.5, 5.3))
#: Room interior in room-local coordinates (x0, x1, z0, z1): inside the wall faces.
_INTERIOR = (0.1 + 0.02, ROOM_X - 0.1 - 0.02, 0.1 + 0.02, ROOM_Z - OUTER - 0.02)
_ROOM_TYPES = ("pump", "tank", "electrical", "storage", "machine")
_ROOM_P = np.array([0.25, 0.2, 0.2, 0.15, 0.2])

_SLOT_KINDS = {
    "pump": (("pump", 4), ("motor", 2), ("valve", 2), ("cabinet_low", 1), ("tank_small", 1)),
    "tank": (("tank_medium", 3), ("tank_small", 2), ("sphere_tank", 2), ("drums", 1)),
    "electrical": (("cabinet_pair", 3), ("cabinet_wide", 2), ("transformer", 2),
                   ("control_desk", 1)),
    "storage": (("shelf", 3), ("crates", 2), ("drums", 2), ("cabinet_low", 1)),
}
#: Things standing against corridor walls (their backs at local z = lo).
_CORRIDOR_KINDS = (("cabinet_wide", 2), ("cabinet_low", 2), ("cabinet_tall", 1), ("valve", 1),
                   ("motor", 1))
_MACHINES = (("turbine", 2), ("heat_exchanger", 2), ("tank_horizontal", 2), ("tank_large", 1))


def _pick(rng: np.random.Generator, table: Sequence[tuple[str, int]]) -> str:
    w = np.array([t[1] for t in table], dtype=_F64)
    return table[int(rng.choice(len(table), p=w / w.sum()))][0]


def _furnish(kind: str, rng: np.random.Generator, bounds: dict[str, tuple[np.ndarray, np.ndarray]]
             ) -> list[tuple[str, np.ndarray]]:
    """Equipment of one room: (mesh name, room-local transform) pairs.

    `bounds` holds each catalog mesh's (lo, hi); every object is shifted (in x and z) so
    that its transformed bounding box lies inside the room's interior.
    """
    out: list[tuple[str, np.ndarray]] = []

    def put(name: str, x: float, z: float, yaw: float = 0.0, y: float = 0.0,
            scale: tuple[float, float, float] | None = None) -> None:
        m = _translate(x, y, z) @ _rot_y(yaw)
        if scale is not None:
            m = m @ _scale(*scale)
        out.append((name, m))

    quarter = lambda: float(rng.integers(0, 4)) * np.pi / 2  # noqa: E731
    if kind == "machine":
        big = _pick(rng, _MACHINES)
        if big == "tank_large":
            put(big, 2.3, 4.4, rng.uniform(0, 2 * np.pi))
            put(big, 5.7, 4.4, rng.uniform(0, 2 * np.pi))
        else:
            put(big, 4.0 if big != "turbine" else 4.2, 4.6, float(rng.integers(0, 2)) * np.pi)
        for x in (0.6, 7.4):
            put("column", x, 6.4)
        for x in (1.2, 6.8):
            if rng.random() < 0.7:
                put(_pick(rng, (("cabinet_low", 1), ("valve", 1), ("drums", 1))), x, 1.2,
                    quarter())
    elif kind == "tank" and rng.random() < 0.5:  # mezzanine along the left wall
        put("platform", 0.15, 1.6)
        for x, z in _SLOTS[1:3] + _SLOTS[4:]:
            put(_pick(rng, _SLOT_KINDS["tank"]), x, z, quarter())
    else:
        for x, z in _SLOTS:
            if rng.random() < 0.85:
                put(_pick(rng, _SLOT_KINDS[kind]), x + rng.uniform(-0.15, 0.15),
                    z + rng.uniform(-0.15, 0.15), quarter())
    # Expand groups and give tanks a non-uniform scale.
    result: list[tuple[str, np.ndarray]] = []
    for name, m in out:
        if name == "drums":
            for dx, dz in ((-0.35, -0.35), (0.35, -0.35), (-0.35, 0.35), (0.35, 0.35)):
                if rng.random() < 0.85:
                    result.append(("drum", m @ _translate(dx, 0, dz)))
        elif name == "crates":
            result.append(("crate", m @ _translate(-0.55, 0, 0)))
            result.append(("crate", m @ _translate(0.55, 0, 0) @ _rot_y(0.3)))
            if rng.random() < 0.5:
                result.append(("crate", m @ _translate(-0.5, 1.0, 0) @ _rot_y(-0.2)))
        elif name == "cabinet_pair":
            result.append(("cabinet_tall", m @ _translate(-0.51, 0, 0)))
            result.append(("cabinet_tall", m @ _translate(0.51, 0, 0)))
        elif name in ("tank_small", "tank_medium", "sphere_tank"):
            sr, sh = rng.uniform(0.85, 1.05), rng.uniform(0.85, 1.15)
            result.append((name, m @ _rot_y(rng.uniform(0, 2 * np.pi)) @ _scale(sr, sh, sr)))
        else:
            result.append((name, m))
    return [(name, _fit(m, *bounds[name])) for name, m in result]


def _fit(m: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """`m` moved in x and z so the box [lo, hi] it transforms lies inside _INTERIOR."""
    corners = np.stack(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij"), -1).reshape(-1, 3)
    pts = corners @ m[:3, :3].T + m[:3, 3]
    shift = np.zeros(3)
    for axis, (a, b) in ((0, _INTERIOR[:2]), (2, _INTERIOR[2:])):
        p, q = pts[:, axis].min(), pts[:, axis].max()
        if q - p > b - a:
            raise AssertionError("object larger than a room")
        shift[axis] = max(0.0, a - p) + min(0.0, b - q)
    return _translate(*shift) @ m


def _expected_room_faces(counts: dict[str, int],
                         bounds: dict[str, tuple[np.ndarray, np.ndarray]]) -> float:
    """Mean face count of a furnished room (by simulation with a fixed generator)."""
    rng = np.random.default_rng(12345)
    total = 0
    n = 64
    for _ in range(n):
        kind = _ROOM_TYPES[int(rng.choice(len(_ROOM_TYPES), p=_ROOM_P))]
        total += sum(counts[name] for name, _ in _furnish(kind, rng, bounds))
    return total / n


def _layout_for(rooms: int) -> _Layout:
    storeys = int(np.clip(round(0.9 * rooms ** (1 / 3)), 1, 40))
    per = max(2.0, rooms / storeys)
    bands = max(1, round(math.sqrt(per / 16.0)))
    nx = max(1, round(per / (2 * bands)))
    return _Layout(storeys, bands, nx)


def _interval_gaps(lo: float, hi: float, holes: Sequence[tuple[float, float]]
                   ) -> list[tuple[float, float]]:
    """The parts of [lo, hi] outside the sorted, disjoint `holes`."""
    out, at = [], lo
    for a, b in holes:
        if a > at:
            out.append((at, a))
        at = max(at, b)
    if hi > at:
        out.append((at, hi))
    return out


def _outer_walls(lay: _Layout) -> Mesh:
    """One storey of outer walls (y in [0, CLEAR]) with a window per room and corridor."""
    w, d = lay.width, lay.depth
    lo: list[list[float]] = []
    hi: list[list[float]] = []

    def wall(axis: int, a: float, b: float, t0: float, t1: float,
             centres: Sequence[float]) -> None:
        # a wall running along `axis` (0 = x, 2 = z) from a to b, thickness [t0, t1]
        holes = [(c - _WIN_W / 2, c + _WIN_W / 2) for c in sorted(centres)]
        spans = [(a, b, 0.0, _WIN_SILL), (a, b, _WIN_TOP, CLEAR)]
        spans += [(p, q, _WIN_SILL, _WIN_TOP) for p, q in _interval_gaps(a, b, holes)]
        for p, q, y0, y1 in spans:
            if axis == 0:
                lo.append([p, y0, t0])
                hi.append([q, y1, t1])
            else:
                lo.append([t0, y0, p])
                hi.append([t1, y1, q])

    xs = [(i + 0.5) * ROOM_X for i in range(lay.nx)]
    wall(0, 0.0, w, 0.0, OUTER, xs)
    wall(0, 0.0, w, d - OUTER, d, xs)
    zs = []
    for b in range(lay.bands):
        zs += [b * BAND + ROOM_Z / 2, b * BAND + ROOM_Z + CORRIDOR / 2,
               b * BAND + ROOM_Z + CORRIDOR + ROOM_Z / 2]
    wall(2, OUTER, d - OUTER, 0.0, OUTER, zs)
    wall(2, OUTER, d - OUTER, w - OUTER, w, zs)
    return Mesh(*_boxes(lo, hi))


def _partitions(lay: _Layout, storey_rng: np.random.Generator,
                stair: tuple[int, int, int] | None) -> Mesh:
    """Interior walls of one storey (y in [0, CLEAR]).

    Corridor walls have one opening per room: a door, a wide roll-up door, or an open bay
    (see _OPENINGS); walls between neighbouring rooms are solid, have a door, or are
    missing (a hall); walls between bands are solid.
    """
    w = lay.width
    lo: list[list[float]] = []
    hi: list[list[float]] = []
    h2 = WALL / 2
    p_open = np.array([o[2] for o in _OPENINGS])
    for b in range(lay.bands):
        for zc in lay.corridor_z(b):
            kinds = storey_rng.choice(len(_OPENINGS), size=lay.nx, p=p_open / p_open.sum())
            xc = (np.arange(lay.nx) + 0.5) * ROOM_X
            half = np.array([_OPENINGS[k][0] for k in kinds]) / 2
            top = np.array([_OPENINGS[k][1] for k in kinds])
            for p, q in _interval_gaps(OUTER, w - OUTER, list(zip(xc - half, xc + half,
                                                                  strict=True))):
                lo.append([p, 0.0, zc - h2])
                hi.append([q, CLEAR, zc + h2])
            for x, hw, y in zip(xc, half, top, strict=True):
                lo.append([x - hw, y, zc - h2])
                hi.append([x + hw, CLEAR, zc + h2])
        if b > 0:  # between the last row of band b − 1 and the first row of band b
            lo.append([OUTER, 0.0, b * BAND - h2])
            hi.append([w - OUTER, CLEAR, b * BAND + h2])
        zc0, zc1 = lay.corridor_z(b)
        rows = ((b * BAND + (OUTER if b == 0 else h2), zc0 - h2),
                (zc1 + h2, (b + 1) * BAND - (OUTER if b == lay.bands - 1 else h2)))
        for side, (z0, z1) in enumerate(rows):
            for i in range(1, lay.nx):
                x = i * ROOM_X
                u = storey_rng.random()
                near_stair = stair is not None and stair[:2] == (b, side) and \
                    i in (stair[2], stair[2] + 1)
                if u < 0.2 and not near_stair:
                    continue  # a hall: no wall between rooms i − 1 and i
                if u < 0.55:  # a doorway in the middle of the wall
                    zm = (z0 + z1) / 2
                    for p, q in ((z0, zm - _DOOR_W / 2), (zm + _DOOR_W / 2, z1)):
                        lo.append([x - h2, 0.0, p])
                        hi.append([x + h2, CLEAR, q])
                    lo.append([x - h2, _DOOR_H, zm - _DOOR_W / 2])
                    hi.append([x + h2, CLEAR, zm + _DOOR_W / 2])
                else:
                    lo.append([x - h2, 0.0, z0])
                    hi.append([x + h2, CLEAR, z1])
    return Mesh(*_boxes(lo, hi))


# Stair placement, in the room frame of (band 0, side 0, room nx − 1): the flight runs
# along local x from 0.9, against the outer wall side (local z from ROOM_Z − 1.55).
_STAIR_X0 = 0.9
_STAIR_Z0 = ROOM_Z - OUTER - 1.25


def _stair_frame(lay: _Layout, storey: int) -> np.ndarray:
    return lay.room_frame(0, 0, lay.nx - 1, storey) @ _translate(_STAIR_X0, 0.0, _STAIR_Z0)


def _slab_with_hole(lay: _Layout) -> Mesh:
    """A floor slab (y in [−SLAB, 0]) with the stair opening."""
    # The opening is the stair's footprint, in world coordinates of storey 0.
    corners = np.array([[0, 0, 0, 1], [6.76, 0, 1.2, 1]], dtype=_F64)
    pts = (_stair_frame(lay, 0) @ corners.T).T[:, :3]
    x0, x1 = sorted(pts[:, 0])
    z0, z1 = sorted(pts[:, 2])
    x0, x1, z0, z1 = x0 - 0.1, x1 + 0.1, max(z0 - 0.1, OUTER), z1 + 0.1
    w, d = lay.width, lay.depth
    lo = [[0, -SLAB, 0], [0, -SLAB, z1], [0, -SLAB, z0], [x1, -SLAB, z0]]
    hi = [[w, 0, z0], [w, 0, d], [x0, 0, z1], [w, 0, z1]]
    return Mesh(*_boxes(lo, hi))


def _pipe_runs(lay: _Layout, rng: np.random.Generator, budget: int, sides: int
               ) -> tuple[list[VF], int]:
    """Long pipe runs along x, sectioned with flanges, under the ceilings of corridors and
    rooms, tier by tier downwards; as many sections as fit in `budget` faces.

    All sections cost the same (4·sides faces), so the total misses `budget` by less than
    one section. When the candidate runs cannot hold `budget` at `sides`, sides grow.
    Returns one merged (vertices, faces) per storey that has pipes, in storey order, and
    the sides used.
    """
    # Candidate runs: (storey, y, z, radius) per run, tier by tier.
    runs_by_tier: list[np.ndarray] = []
    for t in range(_RACK_TIERS):
        rows = []
        y_off = CLEAR - 0.35 - 0.45 * t
        for k in range(lay.storeys):
            for b in range(lay.bands):
                zc0, zc1 = lay.corridor_z(b)
                mid = (zc0 + zc1) / 2
                for dz in np.linspace(-0.9, 0.9, 6):
                    rows.append((k, k * STOREY + y_off, mid + dz, rng.uniform(0.05, 0.14)))
                for v in np.linspace(1.0, 5.0, 8):
                    for z in (zc0 - v, zc1 + v):
                        rows.append((k, k * STOREY + y_off, z, rng.uniform(0.04, 0.12)))
        tier = np.array(rows, dtype=_F64)
        runs_by_tier.append(tier[rng.permutation(len(tier))])
    runs = np.concatenate(runs_by_tier)
    x0, x1 = OUTER, lay.width - OUTER
    n_seg = max(1, math.ceil((x1 - x0) / _SEG_LEN))
    per_run = 2 * n_seg - 1  # sections and flanges, alternating along x
    capacity = runs.shape[0] * per_run
    sides = max(sides, 2 * math.ceil(budget / (4 * capacity) / 2))
    n_cyl = min(capacity, max(0, round(budget / (4 * sides))))
    if n_cyl == 0:
        return [], sides
    xs = np.linspace(x0, x1, n_seg + 1)
    # per run: sections [xs_i, xs_i+1] with radius r, flanges at interior xs_i (1.6 r, 0.12 m)
    a = np.empty(per_run)
    c = np.empty(per_run)
    rs = np.empty(per_run)
    a[0::2], c[0::2], rs[0::2] = xs[:-1], xs[1:], 1.0
    a[1::2], c[1::2], rs[1::2] = xs[1:-1] - 0.06, xs[1:-1] + 0.06, 1.6
    run_id = np.arange(n_cyl) // per_run
    pos = np.arange(n_cyl) % per_run
    sel = runs[run_id]
    p0 = np.stack([a[pos], sel[:, 1], sel[:, 2]], -1)
    p1 = np.stack([c[pos], sel[:, 1], sel[:, 2]], -1)
    radius = sel[:, 3] * rs[pos]
    storey = sel[:, 0].astype(np.int64)
    out = []
    for k in range(lay.storeys):
        m = storey == k
        if m.any():
            out.append(_cylinders(p0[m], p1[m], radius[m], sides))
    return out, sides


def _tessellation(n_triangles: int) -> int:
    return max(8, 2 * round(6.0 * (n_triangles / 1e6) ** 0.3))


def plant(n_triangles: int = 1_000_000, *, seed: int = 0) -> Scene:
    """A procedural power plant of `n_triangles` triangles (±1%; tested to ±10%).

    Layout (metres, +Y up): `storeys` storeys of height :data:`STOREY` (the floor of
    storey k at y = k·STOREY), each with rooms (:data:`ROOM_X` along x, :data:`ROOM_Z`
    deep) on both sides of corridors that run the full length of the building along +x,
    in `bands` bands of :data:`BAND` (room row, corridor, room row). Bounds are exactly
    ``x ∈ [0, nx·ROOM_X]``, ``y ∈ [−SLAB, storeys·STOREY]``, ``z ∈ [0, bands·BAND]``
    (:func:`plant_inside_camera` relies on that). Outer walls have a window per room and
    per corridor end; each room opens onto its corridor by a door, a wide door or an open
    bay; walls between rooms are solid, have a door, or are missing (halls). A stair
    climbs every storey through an opening in the slab (east end room of the first band).
    Rooms hold equipment (pumps, motors, valves, vertical, spherical and horizontal tanks,
    cabinets, control desks, transformers, shelves, drums, crates, turbines, heat
    exchangers, mezzanines with railings and ladders, risers), corridors lamps, cable
    trays, cabinets and extinguishers; flanged pipe runs fill ceilings in tiers.

    Scene structure: the shell is a few meshes (one solid slab instanced as ground and
    roof, one slab with the stair opening instanced per upper floor, the outer walls
    instanced per storey, one partition mesh per storey); the pipe runs are one big mesh
    per storey (about half the triangles: 140K faces each at 1M, 700K at 10M); the rest
    are instances of about 25 catalog meshes (:func:`plant_catalog`), about 170
    instances at 100K triangles, 1,200 at 1M, 5,400 at 10M, some with non-uniform scale.

    Everything grows with `n_triangles`: the number of rooms (roughly n^0.6: 16 at 100K,
    120 at 1M, 530 at 10M), hence storeys and bands, and the tessellation (sides of a
    small pipe: 8 up to about 400K, 12 at 1M, 24 at 10M, as n^0.3). The pipe runs absorb the
    remainder of the budget, so the count is within one pipe section of the request.

    All meshes are closed and wound counter-clockwise seen from outside; transforms have
    positive determinant. The result depends only on (n_triangles, seed); building 1M
    triangles takes about 0.2 s, 10M about 1 s (most of the triangles are instanced).

    Raises:
        ValueError: n_triangles not an integer or below 2000 (the smallest building, one
            storey of two rooms, needs about 1,500), seed not a non-negative integer.
    """
    n = _check_int(n_triangles, "n_triangles", _MIN_TRIANGLES)
    seed = _check_int(seed, "seed", 0)
    rng = np.random.default_rng([seed, n])
    s = _tessellation(n)
    catalog = {name: make(s) for name, make in _CATALOG.items()}
    counts = {name: m.n_faces for name, m in catalog.items()}
    bounds = {name: m.bounds() for name, m in catalog.items()}

    # Equipment is meant to be about 45% of the triangles, pipes most of the rest.
    per_room = _expected_room_faces(counts, bounds) + 2 * counts["lamp"] + 200.0
    rooms = max(2, round(0.45 * n / per_room))
    lay = _layout_for(rooms)

    placed: list[tuple[str, np.ndarray]] = []  # fixed items (always placed)
    optional: list[tuple[str, np.ndarray]] = []  # equipment (dropped if over budget)
    shell: list[tuple[Mesh, np.ndarray]] = []

    slab = Mesh(*_boxes([0.0, -SLAB, 0.0], [lay.width, 0.0, lay.depth]))
    shell.append((slab, np.eye(4)))
    shell.append((slab, _translate(0, lay.storeys * STOREY, 0)))
    if lay.storeys > 1:
        holed = _slab_with_hole(lay)
        for k in range(1, lay.storeys):
            shell.append((holed, _translate(0, k * STOREY, 0)))
    walls = _outer_walls(lay)
    stair_room = (0, 0, lay.nx - 1) if lay.storeys > 1 else None
    for k in range(lay.storeys):
        shell.append((walls, _translate(0, k * STOREY, 0)))
        part = _partitions(lay, rng, stair_room)
        shell.append((part, _translate(0, k * STOREY, 0)))

    for k in range(lay.storeys):
        y = k * STOREY
        for b in range(lay.bands):
            zc0, zc1 = lay.corridor_z(b)
            mid = (zc0 + zc1) / 2
            # corridor: lamps every 4 m, a cable tray along one wall, extinguishers
            for x in np.arange(2.0, lay.width - 1.0, 4.0):
                placed.append(("lamp", _translate(x, y + CLEAR, mid)))
            tray_len = lay.width - 2 * OUTER
            placed.append(("cable_tray", _translate(OUTER, y + CLEAR - 0.4, zc0 + 0.35)
                           @ _scale(tray_len, 1.0, 1.0)))
            for j, x in enumerate(np.arange(ROOM_X, lay.width - 1.0, 2 * ROOM_X)):
                z = zc0 + 0.25 if j % 2 == 0 else zc1 - 0.25
                placed.append(("extinguisher", _translate(x + 0.5, y, z)))
            for side in (0, 1):
                for i in range(lay.nx):
                    frame = lay.room_frame(b, side, i, k)
                    placed.append(("lamp", frame @ _translate(4.0, CLEAR, 3.6)))
                    for _ in range(int(rng.integers(0, 3))):  # risers in corners
                        cx, cz = (0.35, 6.35) if rng.random() < 0.5 else (7.65, 6.35)
                        r = rng.uniform(0.05, 0.1)
                        placed.append(("pipe", frame @ _translate(cx, 0, cz)
                                       @ _scale(r, CLEAR, r)))
                    if stair_room == (b, side, i):
                        if k < lay.storeys - 1:
                            placed.append(("stair", _stair_frame(lay, k)))
                        if k > 0:  # guard rail along the opening's open side
                            for x in (_STAIR_X0 + 1.0, _STAIR_X0 + 3.0, _STAIR_X0 + 5.0):
                                placed.append(("railing", frame @ _translate(
                                    x, 0.0, _STAIR_Z0 - 0.15)))
                        optional.append(("cabinet_low", frame @ _translate(
                            1.5, 0, 1.0) @ _rot_y(np.pi / 2)))
                        continue
                    if i > 0 and rng.random() < 0.35:  # against the corridor wall
                        name = _pick(rng, _CORRIDOR_KINDS)
                        u = 1.2 if rng.random() < 0.5 else ROOM_X - 1.2
                        back = -WALL / 2 + bounds[name][0][2]  # its back on the wall face
                        optional.append((name, frame @ _translate(u, 0, back)
                                         @ _rot_y(np.pi)))
                    kind = _ROOM_TYPES[int(rng.choice(len(_ROOM_TYPES), p=_ROOM_P))]
                    optional += [(name, frame @ m) for name, m in _furnish(kind, rng, bounds)]

    shell_faces = sum(m.n_faces for m, _ in shell)
    fixed = shell_faces + sum(counts[name] for name, _ in placed)
    opt_faces = np.array([counts[name] for name, _ in optional], dtype=np.int64)
    # Equipment may use up to 70% of what the shell leaves; over that, drop a random subset.
    room_for_opt = max(0, int(0.7 * (n - fixed)))
    if opt_faces.sum() > room_for_opt:
        order = rng.permutation(len(optional))
        keep = np.zeros(len(optional), dtype=bool)
        keep[order[np.cumsum(opt_faces[order]) <= room_for_opt]] = True
        optional = [o for o, k in zip(optional, keep, strict=True) if k]
        opt_faces = opt_faces[keep]
    pipe_budget = n - fixed - int(opt_faces.sum())
    pipes, _ = _pipe_runs(lay, rng, pipe_budget, s)

    scene = Scene()
    for mesh, m in shell:
        scene.add(mesh, m)
    for vf in pipes:
        scene.add(Mesh(*vf), np.eye(4))
    for name, m in placed + optional:
        scene.add(catalog[name], m)
    return scene


def _plant_dims(scene: Scene) -> tuple[np.ndarray, np.ndarray, int, int]:
    lo, hi = (np.asarray(a, _F64) for a in scene.bounds())
    storeys = round((hi[1] - lo[1] - SLAB) / STOREY)
    bands = round((hi[2] - lo[2]) / BAND)
    ok = storeys >= 1 and bands >= 1 and abs(storeys * STOREY + SLAB - (hi[1] - lo[1])) < 1e-3 \
        and abs(bands * BAND - (hi[2] - lo[2])) < 1e-3
    if not ok:
        raise ValueError(f"scene bounds {lo.tolist()} .. {hi.tolist()} do not match a "
                         f"plant() building (height storeys·{STOREY} + {SLAB}, depth "
                         f"bands·{BAND}); pass a scene made by clraster.scenes.plant")
    return lo, hi, storeys, bands


def plant_inside_camera(scene: Scene, width: int, height: int, *, storey: int = 0,
                        band: int = 0) -> Camera:
    """First-person camera in a corridor of a :func:`plant` scene, looking along it.

    The eye stands at the west end (low x) of corridor `band` on floor `storey`, on the
    corridor's centre line, :data:`EYE_HEIGHT` above the floor, looking towards +x down the
    whole building. Vertical field of view 60° (the horizontal one is at least 60° for
    portrait images), near 0.1 m, far the length of the building's diagonal. Most of the
    building is outside the frustum or hidden behind walls and floors from here.

    The layout is recovered from ``scene.bounds()``, so the scene must come from
    :func:`plant` (ValueError otherwise); width and height must be positive integers.
    """
    w, h = _check_size(width, height)
    lo, hi, storeys, bands = _plant_dims(scene)
    if not 0 <= storey < storeys or not 0 <= band < bands:
        raise ValueError(f"storey must be in [0, {storeys}) and band in [0, {bands}) for "
                         f"this plant, got storey={storey}, band={band}")
    z = lo[2] + band * BAND + ROOM_Z + CORRIDOR / 2
    eye = np.array([lo[0] + OUTER + 0.6, lo[1] + SLAB + storey * STOREY + EYE_HEIGHT, z])
    fov = 60.0 if w >= h else math.degrees(2 * math.atan(math.tan(math.radians(30)) * h / w))
    far = float(np.linalg.norm(hi - lo))
    return Camera.look_at(eye, eye + [1.0, 0.0, 0.0], (0.0, 1.0, 0.0), fov_y=fov, near=0.1,
                          far=far)


def plant_overview_camera(scene: Scene, width: int, height: int) -> Camera:
    """Third-person camera outside a :func:`plant` scene that frames the whole building,
    seen from above its south-west (high z, low x) corner; fov 45°, see Camera.framing."""
    w, h = _check_size(width, height)
    lo, hi = scene.bounds()
    return Camera.framing(lo, hi, direction=(-0.8, 0.7, 1.3), fov_y=45.0, aspect=w / h)


# =======================================================================================
# Instance grids and random scenes
# =======================================================================================

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
    nx = _check_int(nx, "nx", 1)
    ny = _check_int(ny, "ny", 1)
    nz = _check_int(nz, "nz", 1)
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
        scene.add(mesh, _translate(*off))
    return scene


def grid_camera(scene: Scene, width: int, height: int) -> Camera:
    """A camera that frames the whole scene (e.g. an :func:`instance_grid`) from above
    and to the front-right, fov 45° (see Camera.framing)."""
    w, h = _check_size(width, height)
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
        return Mesh(*_boxes(-e / 2, e / 2))
    if kind == 1:
        return Mesh(*_uv_sphere(0.5, int(rng.integers(3, 12)), int(rng.integers(4, 24))))
    if kind == 2:  # torus
        return Mesh(*_torus(0.4, rng.uniform(0.05, 0.2), int(rng.integers(6, 32)),
                            int(rng.integers(3, 12))))
    return Mesh(*_cylinders([0, -0.5, 0], [0, 0.5, 0], rng.uniform(0.1, 0.5),
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
    seed = _check_int(seed, "seed", 0)
    n_instances = _check_int(n_instances, "n_instances", 1)
    extent = float(extent)
    if not (math.isfinite(extent) and extent >= 0.0):
        raise ValueError(f"extent must be finite and >= 0, got {extent}")
    n_meshes = max(1, n_instances // 2) if n_meshes is None else _check_int(
        n_meshes, "n_meshes", 1)
    rng = np.random.default_rng(seed)
    pool = [_random_mesh(rng) for _ in range(n_meshes)]
    choice = rng.integers(0, n_meshes, n_instances)
    meshes = [pool[c] for c in choice]
    if degenerate and n_instances >= 2:
        slots = rng.choice(n_instances, size=2, replace=False)
        e = rng.uniform(0.3, 1.0, 3)
        meshes[slots[0]] = Mesh(*_boxes([-e[0] / 2, 0, -e[2] / 2], [e[0] / 2, 0, e[2] / 2]))
        v, f = _uv_sphere(0.5, 8, 12)
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


# -- argument checks ---------------------------------------------------------------------

def _check_int(value: object, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def _check_size(width: int, height: int) -> tuple[int, int]:
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
            raise ValueError(f"{name} must be a positive integer (pixels), got {v!r}")
    return int(width), int(height)
