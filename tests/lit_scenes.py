"""Small scenes of quads and boxes for the lighting and screen-space pass tests
(tests/test_lights.py, tests/test_post.py): parts are (vertices (N, 3), faces (M, 3)) pairs,
joined into one `clraster.Mesh` by `mesh_of`."""

from __future__ import annotations

import numpy as np
import trimesh

import clraster


def quad(c, ex, ey):
    """The quad centred at ``c`` with half-edges ``ex``, ``ey``: counter-clockwise seen from
    the side ``ex × ey`` points to."""
    c, ex, ey = (np.asarray(a, float) for a in (c, ex, ey))
    return np.array([c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey]), np.array(
        [[0, 1, 2], [0, 2, 3]])


def box(lo, hi):
    """The axis-aligned box [lo, hi] (trimesh's, outward faces)."""
    b = trimesh.creation.box(bounds=[lo, hi])
    return np.asarray(b.vertices), np.asarray(b.faces)


def mesh_of(*parts) -> clraster.Mesh:
    """One Mesh of the parts, in order."""
    vs, fs, o = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + o)
        o += len(v)
    return clraster.Mesh(np.vstack(vs).astype(np.float32), np.vstack(fs))


#: a 8 × 8 floor at y = 0, its normal +y
FLOOR = quad((0, 0, 0), (4, 0, 0), (0, 0, -4))
