"""A built-in example scene: procedural, deterministic, no files needed.

Used by ``clraster render example`` and by tests that want a realistic scene (closed
objects that occlude each other, standing on a large ground plane that runs out of the
frame) without the shared test meshes.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .mesh import Mesh

__all__ = ["example_mesh", "torus_knot"]


def torus_knot(p: int = 2, q: int = 3, *, knot_radius: float = 1.0, tube_radius: float = 0.15,
               segments: int = 512, sides: int = 32) -> trimesh.Trimesh:
    """A closed tube around the (p, q) torus knot, centred at the origin in the XY plane.

    The centre line is ``r(t) = knot_radius · (2 + cos qt)/3 · (cos pt, sin pt)``,
    ``z = −knot_radius · sin(qt)/3``, swept by a circle of `tube_radius` in the Frenet
    normal plane. ``2 · segments · sides`` triangles, counter-clockwise seen from outside.
    """
    if segments < 3 or sides < 3:
        raise ValueError(f"segments and sides must be >= 3, got {segments}, {sides}")
    t = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)

    def curve(s: np.ndarray) -> np.ndarray:
        r = (2.0 + np.cos(q * s)) / 3.0
        return knot_radius * np.stack([r * np.cos(p * s), r * np.sin(p * s),
                                       -np.sin(q * s) / 3.0], axis=1)

    # Frenet frame from central differences: the (p, q) knot has no inflection points, so
    # the frame is smooth and closes on itself after one turn (no seam twist).
    h = 1e-4
    c, c_next, c_prev = curve(t), curve(t + h), curve(t - h)
    tangent = c_next - c_prev
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = c_next - 2.0 * c + c_prev
    normal -= np.einsum("ij,ij->i", normal, tangent)[:, None] * tangent
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)

    a = np.linspace(0.0, 2.0 * np.pi, sides, endpoint=False)
    ring = np.cos(a)[None, :, None] * normal[:, None] + np.sin(a)[None, :, None] * binormal[:, None]
    vertices = (c[:, None] + tube_radius * ring).reshape(-1, 3)

    i = np.arange(segments)[:, None]
    j = np.arange(sides)[None, :]
    v00 = i * sides + j
    v10 = ((i + 1) % segments) * sides + j
    v11 = ((i + 1) % segments) * sides + (j + 1) % sides
    v01 = i * sides + (j + 1) % sides
    # (N, B, T) is right-handed, so going round the ring (N → B) then along the curve (T)
    # is counter-clockwise seen from outside with this vertex order.
    faces = np.concatenate([np.stack([v00, v01, v11], -1).reshape(-1, 3),
                            np.stack([v00, v11, v10], -1).reshape(-1, 3)])
    return trimesh.Trimesh(vertices, faces, process=False)


def _ground(half: float, cells: int) -> trimesh.Trimesh:
    """A square grid in the plane y = 0, normal +Y (counter-clockwise seen from above)."""
    g = np.linspace(-half, half, cells + 1)
    x, z = np.meshgrid(g, g, indexing="xy")  # row index = z, column index = x
    vertices = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1)
    r = np.arange(cells)[:, None] * (cells + 1)
    k = np.arange(cells)[None, :]
    a, b = r + k, r + k + 1  # (x, z), (x + 1, z)
    c, d = a + cells + 1, b + cells + 1  # (x, z + 1), (x + 1, z + 1)
    # Normal of (a, c, b) is (c − a) × (b − a) = (+Z) × (+X) = +Y: counter-clockwise from above.
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3),
                            np.stack([b, c, d], -1).reshape(-1, 3)])
    return trimesh.Trimesh(vertices, faces, process=False)


def _placed(tm: trimesh.Trimesh, offset: tuple[float, float, float],
            rotation: np.ndarray | None = None) -> trimesh.Trimesh:
    tm = tm.copy()
    if rotation is not None:
        tm.apply_transform(rotation)
    tm.apply_translation(offset)
    return tm


def example_mesh() -> Mesh:
    """The example scene as one :class:`Mesh` (about 60K triangles), identical every call.

    Contents, in face order: a 64×64-cell ground plane (y = 0, 8 × 8 units), a (2, 3) torus
    knot standing above the origin, an icosphere, a torus lying flat, three boxes and a
    cylinder, all closed and counter-clockwise seen from outside (so back-face culling
    removes only hidden faces). World +Y is up; the scene spans about
    x, z ∈ [−4, 4], y ∈ [0, 2.9].
    """
    parts = _example_parts()
    vertices = []
    faces = []
    base = 0
    for part in parts:
        vertices.append(np.asarray(part.vertices, dtype=np.float64))
        faces.append(np.asarray(part.faces, dtype=np.int64) + base)
        base += len(part.vertices)
    return Mesh(np.concatenate(vertices), np.concatenate(faces))


def _example_parts() -> list[trimesh.Trimesh]:
    """The parts of :func:`example_mesh`, in face order (the ground plane first)."""
    rot_x = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])
    rot_y = trimesh.transformations.rotation_matrix(np.pi / 6, [0, 1, 0])
    return [
        _ground(4.0, 64),
        _placed(torus_knot(knot_radius=1.2, tube_radius=0.17, segments=768, sides=24),
                (0.0, 1.55, 0.0)),
        _placed(trimesh.creation.icosphere(subdivisions=4, radius=0.7), (2.4, 0.7, 1.6)),
        _placed(trimesh.creation.torus(major_radius=0.6, minor_radius=0.22,
                                       major_sections=96, minor_sections=32),
                (2.2, 0.22, -2.0), rot_x),
        _placed(trimesh.creation.box(extents=(0.9, 0.9, 0.9)), (-2.4, 0.45, 1.8), rot_y),
        _placed(trimesh.creation.box(extents=(0.6, 1.8, 0.6)), (-2.6, 0.9, -1.8)),
        _placed(trimesh.creation.box(extents=(1.6, 0.3, 0.5)), (-0.6, 0.15, 2.6), rot_y),
        _placed(trimesh.creation.cylinder(radius=0.35, height=1.2, sections=64),
                (0.9, 0.6, -2.6), rot_x),
    ]
