"""Mesh primitives of the procedural scenes, and the 4×4 affine helpers that place them.

Each primitive returns (vertices float64 (V, 3), faces int64 (F, 3)), closed (every edge
shared by exactly two faces) and wound counter-clockwise seen from outside. :class:`Parts`
collects such parts, each optionally transformed by a 4×4 affine, into one :class:`Mesh`.
The matrix helpers build float64 (4, 4) object → world affines (column vectors:
``world = m @ [x, y, z, 1]``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..mesh import Mesh

__all__ = [
    "VF",
    "Y_TO_X",
    "Y_TO_Z",
    "Parts",
    "arc",
    "axis_frames",
    "bake",
    "boxes",
    "cylinders",
    "lathe",
    "rotation_y",
    "scaling",
    "torus",
    "transformed",
    "translation",
    "unit_cylinder",
    "uv_sphere",
]

_F64 = np.float64

#: (vertices float64 (V, 3), faces int64 (F, 3)) of a primitive.
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


def boxes(lo: npt.ArrayLike, hi: npt.ArrayLike) -> VF:
    """K axis-aligned boxes ``[lo_k, hi_k]`` (each (K, 3) or (3,)): 8K vertices, 12K faces."""
    lo = np.atleast_2d(np.asarray(lo, _F64))
    hi = np.atleast_2d(np.asarray(hi, _F64))
    lo, hi = np.broadcast_arrays(lo, hi)
    v = lo[:, None, :] + _CUBE_BITS[None] * (hi - lo)[:, None, :]
    f = _CUBE_FACES[None] + 8 * np.arange(lo.shape[0])[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def lathe(r: npt.ArrayLike, y: npt.ArrayLike, sides: int, *, closed: bool = False) -> VF:
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


def arc(r0: float, y0: float, r1: float, y1: float, steps: int) -> tuple[list, list]:
    """Quarter-ellipse profile points after (r0, y0) up to (r1, y1): a dome (r1 = 0) or a
    dished bottom head (r0 = 0), ``steps`` points, end included."""
    phi = np.linspace(0.0, np.pi / 2.0, steps + 1)[1:]
    if r1 == 0.0:  # dome: radius shrinks from r0 to 0 while y rises from y0 to y1
        rs, ys = r0 * np.cos(phi), y0 + (y1 - y0) * np.sin(phi)
    else:  # bottom head: radius grows from 0 to r1 while y rises from y0 to y1
        rs, ys = r1 * np.sin(phi), y1 - (y1 - y0) * np.cos(phi)
    rs = np.where(np.abs(rs) < 1e-12, 0.0, rs)
    return list(rs), list(ys)


def uv_sphere(radius: float, rings: int, sides: int) -> VF:
    """Sphere about the origin: `rings` latitude bands (poles included), `sides` around."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, rings + 1)
    r = radius * np.cos(phi)
    r[0] = r[-1] = 0.0
    return lathe(r, radius * np.sin(phi), sides)


def torus(major: float, minor: float, major_sides: int, minor_sides: int) -> VF:
    """Torus about +Y in the plane y = 0."""
    phi = 2.0 * np.pi * np.arange(minor_sides) / minor_sides
    return lathe(major + minor * np.cos(phi), minor * np.sin(phi), major_sides, closed=True)


def unit_cylinder(sides: int) -> VF:
    """Radius 1, from y = 0 to y = 1, flat caps with centre vertices: 4·sides faces."""
    return lathe([0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0], sides)


def bake(vf: VF, mats: np.ndarray) -> VF:
    """K copies of a template, copy k transformed by the affine ``mats[k]`` (K, 4, 4)."""
    v, f = vf
    mats = np.asarray(mats, _F64).reshape(-1, 4, 4)
    out = np.einsum("kij,vj->kvi", mats[:, :3, :3], v) + mats[:, None, :3, 3]
    faces = f[None] + (v.shape[0] * np.arange(mats.shape[0]))[:, None, None]
    return out.reshape(-1, 3), faces.reshape(-1, 3)


def axis_frames(p0: np.ndarray, p1: np.ndarray, r: np.ndarray) -> np.ndarray:
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


def cylinders(p0: npt.ArrayLike, p1: npt.ArrayLike, r: npt.ArrayLike, sides: int) -> VF:
    """K capped cylinders of radius r_k from p0_k to p1_k: 4·sides faces each."""
    return bake(unit_cylinder(sides), axis_frames(np.asarray(p0), np.asarray(p1), np.asarray(r)))


def transformed(vf: VF, m: np.ndarray) -> VF:
    """(vertices, faces) with the vertices mapped by the affine `m` (4, 4); faces unchanged
    (so a negative determinant would flip the winding: keep `m` proper)."""
    v, f = vf
    return v @ m[:3, :3].T + m[:3, 3], f


def translation(x: float, y: float, z: float) -> np.ndarray:
    """Translation by (x, y, z) as a float64 (4, 4) affine."""
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def scaling(sx: float, sy: float, sz: float) -> np.ndarray:
    """Scale by (sx, sy, sz) along the axes as a float64 (4, 4) affine."""
    return np.diag([sx, sy, sz, 1.0])


def rotation_y(angle: float) -> np.ndarray:
    """Rotation by `angle` radians about +Y (x → −z for a quarter turn)."""
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(4)
    m[0, 0], m[0, 2], m[2, 0], m[2, 2] = c, s, -s, c
    return m


#: Proper rotations taking the lathe axis +Y to +X and to +Z.
Y_TO_X = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


class Parts:
    """Collects closed parts into one mesh (parts may interpenetrate: each stays closed)."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._n = 0

    def add(self, vf: VF, m: np.ndarray | None = None) -> Parts:
        v, f = vf if m is None else transformed(vf, m)
        self._v.append(v)
        self._f.append(f + self._n)
        self._n += v.shape[0]
        return self

    def box(self, lo: npt.ArrayLike, hi: npt.ArrayLike, m: np.ndarray | None = None) -> Parts:
        return self.add(boxes(lo, hi), m)

    def cyl(self, p0: npt.ArrayLike, p1: npt.ArrayLike, r: npt.ArrayLike, sides: int,
            m: np.ndarray | None = None) -> Parts:
        return self.add(cylinders(p0, p1, r, max(3, sides)), m)

    def vf(self) -> VF:
        return np.concatenate(self._v), np.concatenate(self._f)

    def mesh(self) -> Mesh:
        return Mesh(*self.vf())
