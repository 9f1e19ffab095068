"""Plant equipment: unique meshes, each in its own frame (origin on the floor, footprint
centred on the origin unless said otherwise). `s` is the base tessellation (even, >= 8).

:data:`CATALOG` maps each equipment name to its builder; :func:`plant_catalog` builds them
all at one tessellation. Every mesh is closed and wound counter-clockwise seen from outside.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ...base.checks import check_int
from ..mesh import Mesh
from .dimensions import CLEAR, STOREY
from .primitives import (
    Y_TO_X,
    Parts,
    arc,
    cylinders,
    lathe,
    rotation_y,
    torus,
    translation,
    unit_cylinder,
    uv_sphere,
)

__all__ = ["CATALOG", "plant_catalog"]

_F64 = np.float64

def _tank_vertical(radius: float, height: float, dome: float, sides: int, dome_steps: int,
                   stiffeners: int) -> Parts:
    r = [0.0, radius + 0.03, radius + 0.03, radius]  # a base ring, then the shell
    y = [0.0, 0.0, 0.12, 0.12]
    for k in range(1, stiffeners + 1):  # stiffening rings: bumps in the profile
        yk = height * k / (stiffeners + 1)
        r += [radius, radius + 0.04, radius + 0.04, radius]
        y += [yk - 0.05, yk - 0.05, yk + 0.05, yk + 0.05]
    r += [radius]
    y += [height]
    dr, dy = arc(radius, height, 0.0, height + dome, dome_steps)
    parts = Parts().add(lathe(r + dr, y + dy, sides))
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
    parts = Parts().add(uv_sphere(radius, max(4, s), 2 * s), translation(0, centre, 0))
    a = np.pi / 4 + np.arange(4) * np.pi / 2
    feet = np.stack([0.7 * np.cos(a), np.zeros(4), 0.7 * np.sin(a)], -1)
    parts.cyl(feet, feet + [0, centre, 0], 0.06, max(8, s // 2))
    parts.cyl([0, centre + radius - 0.1, 0], [0, centre + radius + 0.25, 0], 0.1, s)
    return parts.mesh()


def _horizontal_vessel(radius: float, length: float, axis_y: float, s: int,
                       flanged: bool) -> Parts:
    """A vessel along x: dished heads, optional body flanges, two saddles, nozzles."""
    half = length / 2.0
    steps = max(2, s // 3)
    head = 0.45 * radius
    r0, y0 = arc(0.0, -half - head, radius, -half, steps)
    r = [0.0] + r0
    y = [-half - head] + y0
    if flanged:
        fl = radius + 0.1
        r += [fl, fl, radius, radius, fl, fl, radius]
        y += [-half, -half + 0.12, -half + 0.12, half - 0.12, half - 0.12, half, half]
    else:
        r += [radius]
        y += [half]
    r1, y1 = arc(radius, half, 0.0, half + head, steps)
    body = lathe(r + r1, y + y1, 3 * s)
    parts = Parts().add(body, translation(0, axis_y, 0) @ Y_TO_X)
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
    parts = Parts().add(lathe(r, y, 4 * s), translation(0, axis_y, 0) @ Y_TO_X)
    # generator: ribbed cylinder
    gr, gy = [0.0], [1.6]
    n_rib = max(3, s // 3)
    for k in range(n_rib):
        y0 = 1.7 + 1.5 * k / n_rib
        gr += [0.95, 0.95, 1.0, 1.0, 0.95] if k == 0 else [0.95, 1.0, 1.0, 0.95]
        gy += [1.6, y0, y0, y0 + 0.06, y0 + 0.06] if k == 0 else [y0, y0, y0 + 0.06, y0 + 0.06]
    gr += [0.95, 0.0]
    gy += [3.4, 3.4]
    parts.add(lathe(gr, gy, 3 * s), translation(0, axis_y, 0) @ Y_TO_X)
    parts.box([-3.2, 0.0, -1.0], [3.5, axis_y - 0.9, 1.0])  # pedestal
    parts.box([-2.7, axis_y - 0.04, -1.35], [1.3, axis_y + 0.04, 1.35])  # split flange
    # steam lines: vertical pipes into the casing top
    xs = np.linspace(-2.2, 0.8, 3) + rng.uniform(-0.1, 0.1, 3)
    bases = np.stack([xs, np.full(3, axis_y + 0.5), np.zeros(3)], -1)
    parts.cyl(bases, bases + [0, CLEAR - axis_y - 0.5, 0], 0.16, 2 * s)
    return parts.mesh()


def _motor_parts(s: int, length: float, radius: float, axis_y: float) -> Parts:
    parts = Parts()
    r = [0.0, radius, radius, 0.0]
    y = [-length / 2, -length / 2, length / 2, length / 2]
    parts.add(lathe(r, y, 2 * s), translation(0, axis_y, 0) @ Y_TO_X)
    n_fin = max(6, s // 2)
    a = np.pi * np.arange(n_fin) / (n_fin - 1)  # fins over the top half
    for k in range(n_fin):  # radial cooling fins, boxes rotated about the shaft
        rot = np.eye(4)
        c, sn = math.cos(a[k]), math.sin(a[k])
        rot[1, 1], rot[1, 2], rot[2, 1], rot[2, 2] = c, -sn, sn, c
        parts.box([-length / 2 + 0.05, radius - 0.02, -0.008],
                  [length / 2 - 0.05, radius + 0.05, 0.008], translation(0, axis_y, 0) @ rot)
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
    parts.add(lathe(r, y, 2 * s), translation(0, 0.5, 0) @ Y_TO_X)
    parts.cyl([0.88, 0.5, 0.0], [1.1, 0.5, 0.0], 0.1, s)
    parts.cyl([1.08, 0.5, 0.0], [1.12, 0.5, 0.0], 0.16, s)
    parts.cyl([0.74, 0.7, 0.0], [0.74, 1.15, 0.0], 0.08, s)
    parts.cyl([0.74, 1.1, 0.0], [0.74, 1.15, 0.0], 0.13, s)
    return parts.mesh()


def _valve_stand(s: int) -> Mesh:
    parts = Parts().box([-0.2, 0.0, -0.2], [0.2, 0.6, 0.2])  # pedestal
    parts.add(uv_sphere(0.16, max(4, s // 2), 2 * s), translation(0, 0.78, 0))  # body
    parts.cyl([-0.45, 0.78, 0.0], [0.45, 0.78, 0.0], 0.08, s)  # pipe stubs
    parts.cyl([[-0.3, 0.78, 0.0], [0.26, 0.78, 0.0]], [[-0.26, 0.78, 0.0], [0.3, 0.78, 0.0]],
              0.13, s)  # flanges
    parts.cyl([0.0, 0.9, 0.0], [0.0, 1.35, 0.0], 0.03, s)  # stem
    parts.add(torus(0.2, 0.02, 2 * s, max(6, s // 2)), translation(0, 1.3, 0))  # handwheel
    for k in range(3):  # spokes
        parts.box([-0.2, -0.012, -0.012], [0.2, 0.012, 0.012],
                  translation(0, 1.3, 0) @ rotation_y(k * np.pi / 3))
    return parts.mesh()


def _cabinet(s: int, width: float, height: float, depth: float, doors: int) -> Mesh:
    """Cabinet against a wall at its back (z = −depth/2), doors on its +z face."""
    parts = Parts().box([-width / 2, 0.1, -depth / 2], [width / 2, height, depth / 2])
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
    parts = Parts().box([-0.9, 0.0, -0.45], [0.9, 0.8, 0.45])
    tilt = np.eye(4)
    a = math.radians(30)
    tilt[1, 1], tilt[1, 2], tilt[2, 1], tilt[2, 2] = math.cos(a), -math.sin(a), math.sin(a), \
        math.cos(a)
    panel = translation(0, 0.8, -0.1) @ tilt
    parts.box([-0.88, 0.0, -0.35], [0.88, 0.06, 0.35], panel)
    nk = max(3, s // 2)
    kx, kz = np.meshgrid(np.linspace(-0.75, 0.75, nk), [-0.2, 0.0, 0.2], indexing="xy")
    p0 = np.stack([kx.ravel(), np.full(kx.size, 0.06), kz.ravel()], -1)
    parts.add(cylinders(p0, p0 + [0, 0.04, 0], 0.025, max(6, s // 2)), panel)  # knobs
    parts.box([-0.8, 0.8, -0.45], [0.8, 1.4, -0.38])  # screen wall
    return parts.mesh()


def _transformer(s: int) -> Mesh:
    parts = Parts().box([-0.7, 0.0, -0.45], [0.7, 1.6, 0.45])
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
    bushing = lathe(r, y, s)
    for x in (-0.4, 0.0, 0.4):
        parts.add(bushing, translation(x, 1.6, 0.0))
    return parts.mesh()


def _drum(s: int) -> Mesh:
    r = [0.0, 0.28, 0.28, 0.295, 0.295, 0.28, 0.28, 0.295, 0.295, 0.28, 0.28, 0.0]
    y = [0.0, 0.0, 0.28, 0.28, 0.31, 0.31, 0.57, 0.57, 0.6, 0.6, 0.88, 0.88]
    return Parts().add(lathe(r, y, 2 * s)).mesh()


def _crate(s: int) -> Mesh:
    parts = Parts().box([-0.48, 0.0, -0.48], [0.48, 0.96, 0.48])
    e, w = 0.5, 0.05  # edge battens, slightly proud of the core
    lo = [[-e, 0, -e], [e - w, 0, -e], [-e, 0, e - w], [e - w, 0, e - w],
          [-e, 0, -e], [-e, 1 - w, -e], [-e, 0, e - w], [-e, 1 - w, e - w],
          [-e, 0, -e], [-e, 1 - w, -e], [e - w, 0, -e], [e - w, 1 - w, -e]]
    hi = [[-e + w, 1, -e + w], [e, 1, -e + w], [-e + w, 1, e], [e, 1, e],
          [e, w, -e + w], [e, 1, -e + w], [e, w, e], [e, 1, e],
          [-e + w, w, e], [-e + w, 1, e], [e, w, e], [e, 1, e]]
    return parts.box(lo, hi).mesh()


def _shelf(s: int) -> Mesh:
    parts = Parts().box([[-1.0, 0, -0.25], [0.96, 0, -0.25]], [[-0.96, 2.2, 0.25],
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
    return Parts().add(lathe(r, y, s)).mesh()


def _extinguisher(s: int) -> Mesh:
    r = [0.0, 0.09, 0.09] + arc(0.09, 0.55, 0.0, 0.65, max(2, s // 4))[0]
    y = [0.0, 0.0, 0.55] + arc(0.09, 0.55, 0.0, 0.65, max(2, s // 4))[1]
    parts = Parts().add(lathe(r, y, s))
    parts.cyl([0.0, 0.62, 0.0], [0.12, 0.66, 0.0], 0.015, max(6, s // 2))
    return parts.mesh()


def _railing(s: int) -> Mesh:
    """A 2 m railing section along +x from x = 0, posts at both ends."""
    parts = Parts().box([[0, 0, -0.025], [1.95, 0, -0.025]], [[0.05, 1.1, 0.025],
                                                                 [2.0, 1.1, 0.025]])
    ns = max(6, s // 2)
    parts.cyl([[0.0, 1.07, 0.0], [0.0, 0.55, 0.0]], [[2.0, 1.07, 0.0], [2.0, 0.55, 0.0]], 0.025,
              ns)
    parts.box([0.0, 0.0, -0.01], [2.0, 0.12, 0.01])  # toe board
    return parts.mesh()


def _column(s: int) -> Mesh:
    """A steel I-column, floor to ceiling."""
    return Parts().box([[-0.15, 0, -0.15], [-0.15, 0, 0.12], [-0.015, 0, -0.12]],
                        [[0.15, CLEAR, -0.12], [0.15, CLEAR, 0.15], [0.015, CLEAR, 0.12]]
                        ).mesh()


def _cable_tray(s: int) -> Mesh:
    """A 1 m cable tray along +x with cables (instanced with a scale along x)."""
    parts = Parts().box([[0, 0, -0.2], [0, 0, -0.2], [0, 0, 0.18]],
                         [[1, 0.02, 0.2], [1, 0.1, -0.18], [1, 0.1, 0.2]])
    nc = max(3, s // 4)
    zs = np.linspace(-0.14, 0.14, nc)
    p0 = np.stack([np.zeros(nc), np.full(nc, 0.05), zs], -1)
    parts.cyl(p0, p0 + [1, 0, 0], 0.025, max(6, s // 2))
    return parts.mesh()


def _platform(s: int) -> Mesh:
    """A mezzanine 2 m (x) × 5 m (z) at 2.8 m, on legs, railing on its +x edge, a ladder."""
    h = 2.8
    parts = Parts().box([0.0, h - 0.1, 0.0], [2.0, h, 5.0])
    parts.box([[0.0, 0, 0.0], [1.85, 0, 0.0], [0.0, 0, 4.85], [1.85, 0, 4.85]],
              [[0.15, h - 0.1, 0.15], [2.0, h - 0.1, 0.15], [0.15, h - 0.1, 5.0],
               [2.0, h - 0.1, 5.0]])
    rail = _railing(s)
    rv, rf = rail.vertices.astype(_F64), rail.faces.astype(np.int64)
    turn = rotation_y(-np.pi / 2)  # section along +z
    for z in (0.0, 2.0):
        parts.add((rv, rf), translation(1.95, h, z) @ turn)
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
    parts = Parts().box(np.stack([i * tread, np.zeros(n), np.zeros(n)], -1),
                         np.stack([(i + 1) * tread, (i + 1) * rise, np.full(n, 1.2)], -1))
    posts = np.arange(0, n, 4)
    parts.box(np.stack([posts * tread + 0.1, (posts + 1) * rise, np.full(posts.size, 1.13)], -1),
              np.stack([posts * tread + 0.15, (posts + 1) * rise + 1.0,
                        np.full(posts.size, 1.18)], -1))
    parts.cyl([0.1, rise + 1.0, 1.155], [n * tread, STOREY + 1.0, 1.155], 0.03, max(6, s // 2))
    return parts.mesh()


#: Equipment name → builder of its mesh at base tessellation `s` (see plant_catalog).
CATALOG: dict[str, Callable[[int], Mesh]] = {
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
    "pipe": lambda s: Mesh(*unit_cylinder(s)),
}


def plant_catalog(tessellation: int = 12) -> dict[str, Mesh]:
    """The plant's equipment meshes at a given base tessellation (sides of a small pipe).

    Each is closed and wound counter-clockwise seen from outside, in its own frame with
    the origin on the floor (the lamp hangs below its origin; ``pipe`` is the unit
    cylinder, radius 1 from y = 0 to 1; ``cable_tray`` is 1 m long along +x).
    """
    s = check_int(tessellation, "tessellation", 3)
    return {name: make(s) for name, make in CATALOG.items()}
