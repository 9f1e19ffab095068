"""The procedural power plant (:func:`plant`): layout, furnishing, pipe runs, and its cameras.

Layout dimensions live in :mod:`clraster.scenes.dimensions`; the equipment meshes in
:mod:`clraster.scenes.equipment`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...base.checks import check_int, check_size
from ..camera import Camera
from ..mesh import Mesh
from ..scene import Scene
from .dimensions import (
    BAND,
    CLEAR,
    CORRIDOR,
    EYE_HEIGHT,
    OUTER,
    ROOM_X,
    ROOM_Z,
    SLAB,
    STOREY,
    WALL,
)
from .equipment import CATALOG
from .primitives import VF, boxes, cylinders, rotation_y, scaling, translation

__all__ = ["plant", "plant_inside_camera", "plant_overview_camera"]

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
            return translation(i * ROOM_X, y, zc1)
        return translation((i + 1) * ROOM_X, y, zc0) @ rotation_y(np.pi)


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
        m = translation(x, y, z) @ rotation_y(yaw)
        if scale is not None:
            m = m @ scaling(*scale)
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
                    result.append(("drum", m @ translation(dx, 0, dz)))
        elif name == "crates":
            result.append(("crate", m @ translation(-0.55, 0, 0)))
            result.append(("crate", m @ translation(0.55, 0, 0) @ rotation_y(0.3)))
            if rng.random() < 0.5:
                result.append(("crate", m @ translation(-0.5, 1.0, 0) @ rotation_y(-0.2)))
        elif name == "cabinet_pair":
            result.append(("cabinet_tall", m @ translation(-0.51, 0, 0)))
            result.append(("cabinet_tall", m @ translation(0.51, 0, 0)))
        elif name in ("tank_small", "tank_medium", "sphere_tank"):
            sr, sh = rng.uniform(0.85, 1.05), rng.uniform(0.85, 1.15)
            result.append((name, m @ rotation_y(rng.uniform(0, 2 * np.pi)) @ scaling(sr, sh, sr)))
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
    return translation(*shift) @ m


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
    return Mesh(*boxes(lo, hi))


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
    return Mesh(*boxes(lo, hi))


# Stair placement, in the room frame of (band 0, side 0, room nx − 1): the flight runs
# along local x from 0.9, against the outer wall side (local z from ROOM_Z − 1.55).
_STAIR_X0 = 0.9
_STAIR_Z0 = ROOM_Z - OUTER - 1.25


def _stair_frame(lay: _Layout, storey: int) -> np.ndarray:
    return lay.room_frame(0, 0, lay.nx - 1, storey) @ translation(_STAIR_X0, 0.0, _STAIR_Z0)


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
    return Mesh(*boxes(lo, hi))


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
            out.append(cylinders(p0[m], p1[m], radius[m], sides))
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
    n = check_int(n_triangles, "n_triangles", _MIN_TRIANGLES)
    seed = check_int(seed, "seed", 0)
    rng = np.random.default_rng([seed, n])
    s = _tessellation(n)
    catalog = {name: make(s) for name, make in CATALOG.items()}
    counts = {name: m.n_faces for name, m in catalog.items()}
    bounds = {name: m.bounds() for name, m in catalog.items()}

    # Equipment is meant to be about 45% of the triangles, pipes most of the rest.
    per_room = _expected_room_faces(counts, bounds) + 2 * counts["lamp"] + 200.0
    rooms = max(2, round(0.45 * n / per_room))
    lay = _layout_for(rooms)

    placed: list[tuple[str, np.ndarray]] = []  # fixed items (always placed)
    optional: list[tuple[str, np.ndarray]] = []  # equipment (dropped if over budget)
    shell: list[tuple[Mesh, np.ndarray]] = []

    slab = Mesh(*boxes([0.0, -SLAB, 0.0], [lay.width, 0.0, lay.depth]))
    shell.append((slab, np.eye(4)))
    shell.append((slab, translation(0, lay.storeys * STOREY, 0)))
    if lay.storeys > 1:
        holed = _slab_with_hole(lay)
        for k in range(1, lay.storeys):
            shell.append((holed, translation(0, k * STOREY, 0)))
    walls = _outer_walls(lay)
    stair_room = (0, 0, lay.nx - 1) if lay.storeys > 1 else None
    for k in range(lay.storeys):
        shell.append((walls, translation(0, k * STOREY, 0)))
        part = _partitions(lay, rng, stair_room)
        shell.append((part, translation(0, k * STOREY, 0)))

    for k in range(lay.storeys):
        y = k * STOREY
        for b in range(lay.bands):
            zc0, zc1 = lay.corridor_z(b)
            mid = (zc0 + zc1) / 2
            # corridor: lamps every 4 m, a cable tray along one wall, extinguishers
            for x in np.arange(2.0, lay.width - 1.0, 4.0):
                placed.append(("lamp", translation(x, y + CLEAR, mid)))
            tray_len = lay.width - 2 * OUTER
            placed.append(("cable_tray", translation(OUTER, y + CLEAR - 0.4, zc0 + 0.35)
                           @ scaling(tray_len, 1.0, 1.0)))
            for j, x in enumerate(np.arange(ROOM_X, lay.width - 1.0, 2 * ROOM_X)):
                z = zc0 + 0.25 if j % 2 == 0 else zc1 - 0.25
                placed.append(("extinguisher", translation(x + 0.5, y, z)))
            for side in (0, 1):
                for i in range(lay.nx):
                    frame = lay.room_frame(b, side, i, k)
                    placed.append(("lamp", frame @ translation(4.0, CLEAR, 3.6)))
                    for _ in range(int(rng.integers(0, 3))):  # risers in corners
                        cx, cz = (0.35, 6.35) if rng.random() < 0.5 else (7.65, 6.35)
                        r = rng.uniform(0.05, 0.1)
                        placed.append(("pipe", frame @ translation(cx, 0, cz)
                                       @ scaling(r, CLEAR, r)))
                    if stair_room == (b, side, i):
                        if k < lay.storeys - 1:
                            placed.append(("stair", _stair_frame(lay, k)))
                        if k > 0:  # guard rail along the opening's open side
                            for x in (_STAIR_X0 + 1.0, _STAIR_X0 + 3.0, _STAIR_X0 + 5.0):
                                placed.append(("railing", frame @ translation(
                                    x, 0.0, _STAIR_Z0 - 0.15)))
                        optional.append(("cabinet_low", frame @ translation(
                            1.5, 0, 1.0) @ rotation_y(np.pi / 2)))
                        continue
                    if i > 0 and rng.random() < 0.35:  # against the corridor wall
                        name = _pick(rng, _CORRIDOR_KINDS)
                        u = 1.2 if rng.random() < 0.5 else ROOM_X - 1.2
                        back = -WALL / 2 + bounds[name][0][2]  # its back on the wall face
                        optional.append((name, frame @ translation(u, 0, back)
                                         @ rotation_y(np.pi)))
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
    w, h = check_size(width, height)
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
    w, h = check_size(width, height)
    lo, hi = scene.bounds()
    return Camera.framing(lo, hi, direction=(-0.8, 0.7, 1.3), fov_y=45.0, aspect=w / h)
