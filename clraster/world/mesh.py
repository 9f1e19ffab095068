"""Indexed triangle meshes: the renderer's input geometry.

A :class:`Mesh` is immutable: ``vertices`` (N, 3) float32 and ``faces`` (M, 3) int32, both
C-contiguous and read-only, exactly as the kernels consume them. Face ``i`` is triangle id
``i`` in every output buffer. On equal depth the lower face index wins (what drawing in
index order with "first drawn wins" gives, whatever order the clusters are actually drawn
in), and the winding is kept as given: counter-clockwise as seen from the front, as OpenGL
assumes for back-face culling.

Vertices may be NaN or ±Inf: the renderer drops the triangles that use such a vertex and
counts them in its stats; :meth:`Mesh.bounds` ignores them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    import trimesh

__all__ = ["Mesh"]

_INT32_MAX = int(np.iinfo(np.int32).max)


def _as_nx3(value: npt.ArrayLike, name: str, what: str) -> np.ndarray:
    """`value` as an (n, 3) array; a 1-D empty input counts as (0, 3)."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an (n, 3) array of {what}; could not convert "
                         f"{type(value).__name__} ({exc})") from exc
    if arr.ndim == 1 and arr.size == 0:
        return arr.reshape(0, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) ({what}), got shape {arr.shape}")
    return arr


def _check_vertices(vertices: npt.ArrayLike) -> np.ndarray:
    arr = _as_nx3(vertices, "vertices", "x, y, z coordinates")
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"vertices must have a real numeric dtype (float or integer), got "
                         f"{arr.dtype}")
    if arr.shape[0] > _INT32_MAX:
        raise ValueError(f"too many vertices ({arr.shape[0]}): indices are int32, so at most "
                         f"{_INT32_MAX}")
    with np.errstate(over="ignore"):  # float64 beyond float32 range becomes ±Inf: allowed
        out = np.array(arr, dtype=np.float32, order="C", copy=True)
    out.flags.writeable = False
    return out


def _check_faces(faces: npt.ArrayLike, n_vertices: int) -> np.ndarray:
    arr = _as_nx3(faces, "faces", "vertex indices per triangle")
    # An empty Python sequence has no dtype of its own (NumPy says float64): accept it.
    untyped_empty = arr.size == 0 and not isinstance(faces, np.ndarray)
    if arr.dtype.kind not in "iu" and not untyped_empty:
        raise ValueError(f"faces must have an integer dtype (vertex indices), got "
                         f"{arr.dtype}; convert with np.asarray(faces, dtype=np.int32) if "
                         f"the values are whole numbers")
    if arr.size:
        hi = int(arr.max())
        if hi > _INT32_MAX:
            raise ValueError(f"faces holds index {hi}, too large for int32 "
                             f"(max {_INT32_MAX})")
        if int(arr.min()) < 0 or hi >= n_vertices:
            bad = (arr < 0) | (arr >= n_vertices)
            n_bad = int(bad.sum())
            f, k = divmod(int(np.flatnonzero(bad.ravel())[0]), 3)
            raise ValueError(f"faces holds {n_bad} index(es) outside [0, {n_vertices}) "
                             f"(n_vertices = {n_vertices}); first: faces[{f}, {k}] = "
                             f"{int(arr[f, k])}")
    out = np.array(arr, dtype=np.int32, order="C", copy=True)
    out.flags.writeable = False
    return out


class Mesh:
    """An immutable indexed triangle mesh.

    Args:
        vertices: array-like (N, 3) of a real numeric dtype; stored as C-contiguous
            read-only float32 (values beyond float32 range become ±Inf). NaN/Inf are
            allowed: triangles using them are dropped by the renderer and counted.
        faces: array-like (M, 3) of an integer dtype, indices into `vertices` in
            [0, N); stored as C-contiguous read-only int32. Winding is kept as given
            (counter-clockwise = front-facing). M = 0 and/or N = 0 is a valid, empty mesh;
            an empty 1-D sequence counts as shape (0, 3).

    The mesh copies its inputs, so later changes to the caller's arrays do not affect it.

    Raises:
        ValueError: wrong shape or dtype (bool, complex, object, float faces), face
            indices negative, ``>= N`` or beyond int32.
    """

    __slots__ = ("_vertices", "_faces", "_face_normals", "__weakref__")

    def __init__(self, vertices: npt.ArrayLike, faces: npt.ArrayLike) -> None:
        self._vertices = _check_vertices(vertices)
        self._faces = _check_faces(faces, self._vertices.shape[0])
        self._face_normals: np.ndarray | None = None

    # -- constructors -------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> Mesh:
        """Read a mesh file with trimesh (PLY, OBJ, STL, OFF, GLB, ...).

        Loaded with ``process=False``, so vertex and face order are the file's: triangle
        ids in the outputs are the file's face indices. Quads and polygons are triangulated
        by trimesh; a multi-object scene is concatenated into one mesh.

        Raises:
            FileNotFoundError: `path` does not exist.
            ValueError: trimesh cannot read it, or it holds no triangle (a point cloud, a
                lines-only OBJ, a 2-D drawing, a glTF with no mesh).
        """
        import trimesh

        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"mesh file not found: {str(p)!r}")
        try:
            tm = trimesh.load(str(p), force="mesh", process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ValueError(f"could not read mesh file {str(p)!r}: "
                             f"{type(exc).__name__}: {exc}") from exc
        if not isinstance(tm, trimesh.Trimesh):
            raise ValueError(f"{str(p)!r} holds no triangle mesh (trimesh read a "
                             f"{type(tm).__name__})")
        if len(tm.faces) == 0:
            # trimesh's force="mesh" turns points, lines and empty scenes into a Trimesh
            # with no face: rendering it would give a blank image without a word
            raise ValueError(f"{str(p)!r} holds no triangles ({len(tm.vertices):,} vertices, "
                             f"0 faces): it is a point cloud, lines or an empty scene; "
                             f"clraster renders triangle meshes")
        return cls.from_trimesh(tm)

    @classmethod
    def from_trimesh(cls, tm: trimesh.Trimesh) -> Mesh:
        """A Mesh with `tm`'s vertices and faces, in `tm`'s order (nothing is merged)."""
        import trimesh

        if not isinstance(tm, trimesh.Trimesh):
            raise TypeError(f"from_trimesh expects a trimesh.Trimesh, got "
                            f"{type(tm).__name__}; for a Scene use scene.to_geometry()")
        return cls(np.asarray(tm.vertices), np.asarray(tm.faces))

    # -- data ---------------------------------------------------------------------------

    @property
    def vertices(self) -> np.ndarray:
        """(N, 3) float32, C-contiguous, read-only: world-space positions."""
        return self._vertices

    @property
    def faces(self) -> np.ndarray:
        """(M, 3) int32, C-contiguous, read-only: vertex indices; row i is triangle id i."""
        return self._faces

    @property
    def n_vertices(self) -> int:
        return int(self._vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self._faces.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds ``(min, max)``, each (3,) float64.

        Taken over the vertices that some face references and that are finite in all
        three coordinates (unreferenced and NaN/Inf vertices are ignored).

        Raises:
            ValueError: no face references a finite vertex (e.g. an empty mesh).
        """
        used = np.zeros(self.n_vertices, dtype=bool)
        used[self._faces.ravel()] = True
        used &= np.isfinite(self._vertices).all(axis=1)
        if not used.any():
            raise ValueError(f"mesh has no finite vertex referenced by a face "
                             f"({self.n_vertices} vertices, {self.n_faces} faces): "
                             f"bounds are undefined")
        pts = self._vertices[used].astype(np.float64)
        return pts.min(axis=0), pts.max(axis=0)

    def face_normals(self) -> np.ndarray:
        """(M, 3) float32 unit normals, read-only, computed once.

        Normal of face (a, b, c) is ``normalize((b − a) × (c − a))``: it points towards
        the side from which the triangle is seen counter-clockwise. Zero for zero-area
        faces and faces with a non-finite vertex.
        """
        if self._face_normals is None:
            v = self._vertices.astype(np.float64)
            tri = v[self._faces]  # (M, 3, 3)
            with np.errstate(invalid="ignore", over="ignore"):
                n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
                length = np.linalg.norm(n, axis=1)
                ok = np.isfinite(length) & (length > 0.0)
                out = np.zeros_like(n)
                out[ok] = n[ok] / length[ok, None]
            normals = out.astype(np.float32)
            normals.flags.writeable = False
            self._face_normals = normals
        return self._face_normals

    def __repr__(self) -> str:
        return f"Mesh(n_vertices={self.n_vertices}, n_faces={self.n_faces})"
