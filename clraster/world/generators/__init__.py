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

Modules, bottom up: :mod:`.primitives` (boxes, lathe solids, spheres, tori, cylinders,
4×4 affine helpers, :class:`~.primitives.Parts`), :mod:`.dimensions` (the plant's layout
constants), :mod:`.equipment` (the plant's equipment meshes, :func:`plant_catalog`),
:mod:`.building` (the plant's layout, furnishing, pipe runs, cameras) and :mod:`.synthetic`
(instance grids, random scenes). This package re-exports their public names.
"""

from __future__ import annotations

from .building import plant, plant_inside_camera, plant_overview_camera
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
from .equipment import plant_catalog
from .synthetic import grid_camera, instance_grid, random_scene

__all__ = [
    "BAND",
    "CLEAR",
    "CORRIDOR",
    "EYE_HEIGHT",
    "OUTER",
    "ROOM_X",
    "ROOM_Z",
    "SLAB",
    "STOREY",
    "WALL",
    "grid_camera",
    "instance_grid",
    "plant",
    "plant_catalog",
    "plant_inside_camera",
    "plant_overview_camera",
    "random_scene",
]
