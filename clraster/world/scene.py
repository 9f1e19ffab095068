"""Scenes: instances of meshes placed by object → world transforms.

A :class:`Scene` is an ordered list of :class:`Instance` objects. Several instances may share
one `Mesh` object (its clusters and bounding data are then computed once).

Triangle ids. A frame drawn from a scene reports, per pixel, one int32 triangle id (−1 for
background). Instance i's face f has id ``face_base[i] + f``, where ``face_base`` is the
running total of face counts in instance order (``face_base[0] == 0``); so ids are the face
indices of the concatenation of all instances' meshes in scene order, and a one-instance
scene's ids are the mesh's own face indices. :meth:`Scene.split_ids` maps ids back to
(instance, face). Ids are int32 in frames, so a scene holds fewer than 2**31 faces.

Names. Each instance may carry a name and the name of its geometry (both None unless
given): :meth:`Scene.from_trimesh` keeps a trimesh scene's node names
(:attr:`Scene.instance_names`) and geometry names (:attr:`Scene.geometry_names`), and
:meth:`Scene.geometry_of` maps a frame's triangle ids back to geometry names.

Transforms are float64 (4, 4) affine matrices for column vectors (``world = T @ [x, y, z,
1]``), last row ``(0, 0, 0, 1)``, invertible and well conditioned. Mirroring transforms
(negative determinant) are allowed: they turn the winding of the instance's faces, which the
culler takes into account.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..base.checks import check_mat4
from .mesh import Mesh

if TYPE_CHECKING:
    import trimesh

__all__ = ["Instance", "Scene", "SceneWarning"]

#: named by the module's public path (users' logging settings name it)
log = logging.getLogger("clraster.scene")

#: Largest condition number (2-norm, linear 3×3 part) accepted for a transform. Beyond it the
#: matrix is numerically singular for float32 rendering.
MAX_TRANSFORM_COND = 1e8
#: Triangle ids are int32 in frames.
MAX_SCENE_FACES = (1 << 31) - 1


class SceneWarning(UserWarning):
    """Part of a scene file was skipped (e.g. nodes scaled to zero)."""


def _zero_scale(transform: np.ndarray) -> bool:
    """True if the 3×3 part of ``transform`` collapses space to a point (all-zero
    scale), the way glTF files hide nodes."""
    lin = np.asarray(transform, np.float64)[:3, :3]
    return bool(np.all(np.isfinite(lin)) and np.abs(lin).max() == 0.0)


def _check_transform(value: npt.ArrayLike | None, what: str) -> np.ndarray:
    """`value` as a validated, read-only float64 (4, 4) affine matrix (identity if None)."""
    if value is None:
        out = np.eye(4)
        out.flags.writeable = False
        return out
    arr = check_mat4(value, what)
    if np.max(np.abs(arr[3] - (0.0, 0.0, 0.0, 1.0))) > 1e-12:
        raise ValueError(f"{what} is not affine: its last row is {arr[3].tolist()}, expected "
                         f"[0, 0, 0, 1] (projective object transforms are not supported)")
    arr[3] = (0.0, 0.0, 0.0, 1.0)
    lin = arr[:3, :3]
    sv = np.linalg.svd(lin, compute_uv=False)
    if not (sv[-1] > 0.0 and sv[0] / sv[-1] <= MAX_TRANSFORM_COND):
        cond = math.inf if sv[-1] == 0.0 else sv[0] / sv[-1]
        raise ValueError(f"{what} is not invertible (singular values {sv.tolist()}, "
                         f"condition number {cond:.3g} > {MAX_TRANSFORM_COND:.0e}); use a "
                         f"non-zero scale on every axis")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class Instance:
    """One placement of a mesh.

    Attributes:
        mesh: the `Mesh` (shared, not copied).
        transform: float64 (4, 4), read-only (a validated copy of what was given; None
            means identity): object → world for column vectors, affine, invertible
            (condition number of its 3×3 part <= `MAX_TRANSFORM_COND`).

    Raises:
        ValueError: `mesh` is not a `Mesh`, or the transform is invalid (wrong shape,
            NaN/Inf, not affine, singular or badly conditioned).
    """

    mesh: Mesh
    transform: np.ndarray  # None (identity) or array-like is accepted and converted

    def __post_init__(self) -> None:
        if not isinstance(self.mesh, Mesh):
            raise ValueError(f"mesh must be a clraster.Mesh, got {type(self.mesh).__name__}; "
                             f"build one with clraster.Mesh(vertices, faces)")
        object.__setattr__(self, "transform", _check_transform(self.transform, "transform"))


class _MeshInfo:
    """Per-mesh bounding data, computed once: object AABB over finite referenced vertices,
    whether there is one, and whether every referenced vertex is finite."""

    __slots__ = ("lo", "hi", "has_finite", "all_finite")

    def __init__(self, mesh: Mesh) -> None:
        f = mesh.faces
        if f.shape[0] == 0:
            self.has_finite, self.all_finite = False, True
            self.lo = self.hi = np.full(3, np.nan)
            return
        used = np.zeros(mesh.n_vertices, dtype=bool)
        used[f.ravel()] = True
        finite = np.isfinite(mesh.vertices).all(axis=1)
        self.all_finite = bool(finite[used].all())
        self.has_finite = bool((finite & used).any())
        if self.has_finite:
            self.lo, self.hi = mesh.bounds()
        else:
            self.lo = self.hi = np.full(3, np.nan)


class Scene:
    """An ordered collection of mesh instances.

    Args:
        instances: `Instance` objects or ``(mesh, transform)`` pairs, in draw order.

    Attributes that change with :meth:`add` are recomputed on access; `version` increases
    by one on every change, so a renderer can cache uploads per (scene, version).
    See the module docstring for the triangle-id convention.

    Winding rule (glTF 2.0): faces keep their outward side under any instance transform.
    An instance whose transform has a negative determinant (a mirror) reverses its faces'
    screen winding, and the renderers swap back and front for it, so it renders exactly
    as the same geometry baked with trimesh's ``apply_transform`` (which reverses each
    face's vertex order) — culling, normal cones and shading normals alike.
    """

    def __init__(self, instances: Iterable[Instance | tuple[Mesh, npt.ArrayLike]] = ()) -> None:
        self._instances: list[Instance] = []
        self._face_counts: list[int] = []
        self._instance_names: list[str | None] = []
        self._geometry_names: list[str | None] = []
        self._n_faces = 0
        self._version = 0
        self._infos: dict[int, _MeshInfo] = {}
        self._memo: dict[Any, Any] = {}
        self._mesh_memo: dict[tuple[int, Any], Any] = {}
        for item in instances:
            if isinstance(item, Instance):
                self._append(item)
            else:
                try:
                    mesh, transform = item
                except (TypeError, ValueError):
                    raise ValueError(f"instance {len(self._instances)}: expected an Instance "
                                     f"or a (mesh, transform) pair, got "
                                     f"{type(item).__name__}") from None
                self.add(mesh, transform)

    # -- building -------------------------------------------------------------------------

    def add(self, mesh: Mesh, transform: npt.ArrayLike | None = None, *,
            name: str | None = None, geometry: str | None = None) -> int:
        """Append an instance of `mesh` placed by `transform` (identity if None).

        Args:
            name: the instance's name (e.g. a scene-graph node), kept in `instance_names`.
            geometry: the name of its geometry, kept in `geometry_names` (what
                `geometry_of` maps triangle ids to).

        Returns:
            The new instance's index.

        Raises:
            ValueError: `mesh` is not a `Mesh`; the transform is invalid (the message names
                the instance); or the scene would reach 2**31 faces.
        """
        index = len(self._instances)
        for what, value in (("name", name), ("geometry", geometry)):
            if value is not None and not isinstance(value, str):
                raise ValueError(f"instance {index}: {what} must be a string or None, got "
                                 f"{type(value).__name__}")
        try:
            inst = Instance(mesh, transform)   # type: ignore[arg-type]  # converted there
        except ValueError as exc:
            raise ValueError(f"instance {index}: {exc}") from None
        return self._append(inst, name, geometry)

    def _append(self, inst: Instance, name: str | None = None,
                geometry: str | None = None) -> int:
        index = len(self._instances)
        m = inst.mesh.n_faces
        if self._n_faces + m > MAX_SCENE_FACES:
            raise ValueError(f"instance {index}: adding {m:,} faces would bring the scene to "
                             f"{self._n_faces + m:,}; triangle ids are int32, so a scene holds "
                             f"at most {MAX_SCENE_FACES:,} faces: split it into several scenes")
        self._instances.append(inst)
        self._instance_names.append(name)
        self._geometry_names.append(geometry)
        self._face_counts.append(m)
        self._n_faces += m
        self._version += 1
        self._memo.clear()
        return index

    @classmethod
    def from_mesh(cls, mesh: Mesh, transform: npt.ArrayLike | None = None) -> Scene:
        """A scene with one instance of `mesh` (identity transform by default): its triangle
        ids are the mesh's face indices."""
        scene = cls()
        scene.add(mesh, transform)
        return scene

    @classmethod
    def load(cls, path: str | Path) -> Scene:
        """Read a file with trimesh (``process=False``, so face order is the file's).

        A trimesh Scene (glTF/GLB, multi-object OBJ, ...) gives one instance per graph node
        that holds a triangle mesh, in ``graph.nodes_geometry`` order, with the node's world
        transform; each geometry becomes one `Mesh` shared by all its nodes; node and
        geometry names are kept (`from_trimesh`). Non-triangle geometry (points, paths) is
        skipped. A single-mesh file gives one instance with the identity transform.

        Raises:
            FileNotFoundError: `path` does not exist.
            ValueError: trimesh cannot read it, it holds no triangle mesh, or a node's
                transform is invalid. Nodes whose transform scales to zero (a common way to
                hide a node) are skipped with a `SceneWarning` instead.
        """
        import trimesh

        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"scene file not found: {str(p)!r}")
        try:
            loaded = trimesh.load(str(p), process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ValueError(f"could not read scene file {str(p)!r}: "
                             f"{type(exc).__name__}: {exc}") from exc
        if isinstance(loaded, trimesh.Trimesh):
            return cls.from_mesh(Mesh.from_trimesh(loaded))
        if not isinstance(loaded, trimesh.Scene):
            raise ValueError(f"{str(p)!r} holds no triangle mesh (trimesh read a "
                             f"{type(loaded).__name__})")
        return cls._from_trimesh_scene(loaded, repr(str(p)))

    @classmethod
    def from_trimesh(cls, tm: trimesh.Scene | trimesh.Trimesh) -> Scene:
        """A scene made from a trimesh object, in memory (what `load` does after reading).

        A ``trimesh.Scene`` gives one instance per graph node that holds a triangle mesh,
        in ``graph.nodes_geometry`` order, placed by the node's world transform
        (``tm.graph[node]``); each geometry becomes one `Mesh` (its vertices and faces in
        trimesh's order, nothing merged) shared by all its nodes. Node names go to
        `instance_names`, geometry names (keys of ``tm.geometry``) to `geometry_names`, so
        ``scene.geometry_of(frame.triangle_id)`` names the geometry seen at each pixel.
        Non-triangle geometry (points, paths) is skipped; nodes scaled to zero are skipped
        with a `SceneWarning`. A ``trimesh.Trimesh`` gives one instance, identity transform,
        no names.

        The result is a new Scene (renderers convert a trimesh object once and cache it:
        `clraster.inputs.as_target`); ids are the same on every conversion of the same
        object.

        Raises:
            TypeError: `tm` is neither a trimesh.Scene nor a trimesh.Trimesh.
            ValueError: it holds no triangle mesh, or a node's transform is invalid.
        """
        import trimesh

        if isinstance(tm, trimesh.Trimesh):
            return cls.from_mesh(Mesh.from_trimesh(tm))
        if not isinstance(tm, trimesh.Scene):
            raise TypeError(f"from_trimesh expects a trimesh.Scene or trimesh.Trimesh, got "
                            f"{type(tm).__name__}")
        return cls._from_trimesh_scene(tm, "trimesh scene")

    @classmethod
    def _from_trimesh_scene(cls, loaded: trimesh.Scene, where: str) -> Scene:
        """`from_trimesh` of a trimesh.Scene; ``where`` starts error messages (a file's
        path for `load`)."""
        import trimesh

        scene = cls()
        meshes: dict[Any, Mesh] = {}
        skipped = 0
        hidden: list[str] = []
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry.get(geom_name)
            if not isinstance(geom, trimesh.Trimesh):
                skipped += 1
                continue
            if _zero_scale(transform):
                # scale 0 is a common way to hide a node (glTF animations, editors): it
                # draws nothing, so skip it rather than refuse the file
                hidden.append(str(node))
                continue
            mesh = meshes.get(geom_name)
            if mesh is None:
                mesh = meshes[geom_name] = Mesh.from_trimesh(geom)
            try:
                scene.add(mesh, transform, name=str(node), geometry=str(geom_name))
            except ValueError as exc:
                raise ValueError(f"{where}, node {node!r}: {exc}") from exc
        if skipped:
            log.info("%s: skipped %d node(s) without a triangle mesh", where, skipped)
        if hidden:
            warnings.warn(f"{where}: skipped {len(hidden)} node(s) scaled to zero (hidden, "
                          f"they draw nothing): {', '.join(hidden[:5])}"
                          f"{', ...' if len(hidden) > 5 else ''}", SceneWarning, stacklevel=3)
        if scene.n_instances == 0:
            raise ValueError(f"{where} holds no triangle mesh")
        return scene

    # -- data -----------------------------------------------------------------------------

    @property
    def instances(self) -> tuple[Instance, ...]:
        """The instances, in draw order."""
        return tuple(self._instances)

    @property
    def instance_names(self) -> tuple[str | None, ...]:
        """Each instance's name (a trimesh scene's node name), or None, in draw order."""
        return tuple(self._instance_names)

    @property
    def geometry_names(self) -> tuple[str | None, ...]:
        """Each instance's geometry name (a key of a trimesh scene's ``geometry``), or
        None, in draw order (several instances may share one)."""
        return tuple(self._geometry_names)

    def geometry_of(self, ids: npt.ArrayLike) -> np.ndarray:
        """Geometry names of triangle ids.

        Args:
            ids: integer array of any shape (e.g. a frame's ``triangle_id``), values in
                [−1, n_faces), as `split_ids` takes them.

        Returns:
            An object array of the same shape: the `geometry_names` entry of each id's
            instance (None for background, −1, and for instances without a name).
        """
        inst, _ = self.split_ids(ids)
        names = np.empty(len(self._geometry_names) + 1, dtype=object)
        names[:-1] = self._geometry_names
        names[-1] = None
        return names[inst]   # background (−1) picks the trailing None

    @property
    def n_instances(self) -> int:
        return len(self._instances)

    @property
    def n_faces(self) -> int:
        """Total faces over all instances (< 2**31)."""
        return self._n_faces

    @property
    def n_empty(self) -> int:
        """Instances whose mesh has no face: allowed, they draw nothing (counted as
        "empty, skipped" by the culler)."""
        return sum(1 for m in self._face_counts if m == 0)

    @property
    def version(self) -> int:
        """Increases by one on every change (each :meth:`add`)."""
        return self._version

    @property
    def face_counts(self) -> np.ndarray:
        """int64 (I,): faces per instance."""
        return self.memo("face_counts", lambda: _frozen(np.array(self._face_counts, np.int64)))

    @property
    def face_base(self) -> np.ndarray:
        """int64 (I,), read-only: the triangle id of (instance i, face f) is
        ``face_base[i] + f``."""
        def make() -> np.ndarray:
            base = np.zeros(len(self._face_counts), np.int64)
            np.cumsum(self._face_counts[:-1], out=base[1:])
            return _frozen(base)
        return self.memo("face_base", make)

    def split_ids(self, ids: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Map triangle ids back to (instance, face).

        Args:
            ids: integer array of any shape (e.g. a frame's ``triangle_id``), values in
                [−1, n_faces); −1 is background.

        Returns:
            (instance, face): int32 arrays of the same shape; both −1 where ``ids == −1``.

        Raises:
            ValueError: non-integer ids, or ids outside [−1, n_faces).
        """
        arr = np.asarray(ids)
        if arr.dtype.kind not in "iu" and not (arr.size == 0 and arr.dtype.kind == "f"):
            raise ValueError(f"ids must be integers (triangle ids), got dtype {arr.dtype}")
        a = arr.astype(np.int64)
        if a.size:
            lo, hi = int(a.min()), int(a.max())
            if lo < -1 or hi >= self._n_faces:
                raise ValueError(f"ids span [{lo}, {hi}]; valid ids are −1 (background) and "
                                 f"0..{self._n_faces - 1} for this scene ({self._n_faces} "
                                 f"faces)")
        base = self.face_base
        inst = np.searchsorted(base, a, side="right") - 1
        bg = a == -1
        face = a - base[np.maximum(inst, 0)] if base.size else np.zeros_like(a)
        inst = np.where(bg, -1, inst).astype(np.int32)
        face = np.where(bg, -1, face).astype(np.int32)
        return inst, face

    def transforms(self) -> np.ndarray:
        """float64 (I, 4, 4), read-only: the instances' transforms."""
        def make() -> np.ndarray:
            if not self._instances:
                return _frozen(np.zeros((0, 4, 4)))
            return _frozen(np.stack([inst.transform for inst in self._instances]))
        return self.memo("transforms", make)

    def _info(self, mesh: Mesh) -> _MeshInfo:
        info = self._infos.get(id(mesh))  # the scene holds the mesh: its id stays unique
        if info is None:
            info = self._infos[id(mesh)] = _MeshInfo(mesh)
        return info

    def object_aabbs(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-instance object-space bounds (min, max), each float64 (I, 3), read-only,
        over the mesh's finite referenced vertices; NaN rows where there is none."""
        def make() -> tuple[np.ndarray, np.ndarray]:
            infos = [self._info(inst.mesh) for inst in self._instances]
            lo = np.array([i.lo for i in infos], np.float64).reshape(-1, 3)
            hi = np.array([i.hi for i in infos], np.float64).reshape(-1, 3)
            return _frozen(lo), _frozen(hi)
        return self.memo("object_aabbs", make)

    @property
    def has_bounds(self) -> np.ndarray:
        """bool (I,): the instance's mesh has a finite vertex referenced by a face (its
        `world_aabbs` row is defined)."""
        return self.memo("has_bounds", lambda: _frozen(np.array(
            [self._info(i.mesh).has_finite for i in self._instances], dtype=bool)))

    @property
    def bounded(self) -> np.ndarray:
        """bool (I,): the instance has faces and every vertex they reference is finite, so
        its `world_aabbs` row bounds everything it draws. Instances with a NaN/Inf vertex
        are not bounded: the renderer must draw them (it drops and counts those triangles)
        and culling must never remove them as a whole."""
        return self.memo("bounded", lambda: _frozen(np.array(
            [inst.mesh.n_faces > 0 and self._info(inst.mesh).all_finite
             for inst in self._instances], dtype=bool)))

    @property
    def empty(self) -> np.ndarray:
        """bool (I,): the instance's mesh has no face."""
        return self.memo("empty", lambda: _frozen(np.array(self._face_counts, np.int64) == 0))

    def world_aabbs(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space bounds of each instance: (mins, maxs), float64 (I, 3), read-only.

        The 8 corners of the mesh's object AABB (finite referenced vertices) transformed and
        boxed, so each row contains the instance's finite geometry. Rows are NaN where the
        mesh has no finite referenced vertex (see `has_bounds`); where some vertex is NaN/Inf
        (`bounded` False) the row bounds only the finite part.
        """
        def make() -> tuple[np.ndarray, np.ndarray]:
            lo, hi = self.object_aabbs()
            n = lo.shape[0]
            if n == 0:
                return _frozen(np.zeros((0, 3))), _frozen(np.zeros((0, 3)))
            t = self.transforms()
            sel = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1],
                            [1, 0, 0], [1, 0, 1], [1, 1, 0], [1, 1, 1]], dtype=bool)
            corners = np.where(sel[None], hi[:, None, :], lo[:, None, :])  # (I, 8, 3)
            world = np.einsum("ijk,ick->icj", t[:, :3, :3], corners) + t[:, None, :3, 3]
            return _frozen(world.min(axis=1)), _frozen(world.max(axis=1))
        return self.memo("world_aabbs", make)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World AABB ``(min, max)``, each (3,) float64, over all instances' finite geometry
        (the union of the defined `world_aabbs` rows).

        Raises:
            ValueError: no instance has a finite referenced vertex (e.g. an empty scene).
        """
        lo, hi = self.world_aabbs()
        ok = self.has_bounds
        if not ok.any():
            raise ValueError(f"scene has no finite geometry ({self.n_instances} instances, "
                             f"{self.n_faces} faces): bounds are undefined")
        return lo[ok].min(axis=0), hi[ok].max(axis=0)

    def memo(self, key: Any, make: Callable[[], Any]) -> Any:
        """Derived data cached until the scene changes: ``make()`` on first use of `key`
        after a change. Used by the culler for its per-scene structures."""
        try:
            return self._memo[key]
        except KeyError:
            value = self._memo[key] = make()
            return value

    def mesh_memo(self, mesh: Mesh, key: Any, make: Callable[[], Any]) -> Any:
        """Per-mesh derived data (clusters, cluster BVH), cached for the scene's lifetime
        (kept across :meth:`add`: meshes are immutable and the scene keeps them alive)."""
        k = (id(mesh), key)
        try:
            return self._mesh_memo[k]
        except KeyError:
            value = self._mesh_memo[k] = make()
            return value

    def __len__(self) -> int:
        return len(self._instances)

    def __repr__(self) -> str:
        return (f"Scene(n_instances={self.n_instances}, n_faces={self.n_faces}, "
                f"version={self.version})")


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
