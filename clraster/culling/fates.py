"""What happened to every cluster in one frame: drawn, or which culling step removed it.

``Renderer.render(..., fates=True)`` fills ``Frame.fates`` with a :class:`ClusterFates`: one
:class:`Fate` per (instance, cluster) pair of the scene, addressed by the same key the
occlusion history uses (``instance_key_base[instance] + cluster``, the cluster index being
local to the instance's mesh, as in `clusters.clusters_of`). Its counts equal the frame's
culling funnel (`FrameStats`): FRUSTUM_CULLED = ``clusters_frustum_culled`` (clusters of
instances culled whole included), BACKFACE_CULLED = ``clusters_cone_culled``,
OCCLUSION_CULLED = ``clusters_occlusion_culled``, DRAWN = the rest (sent to setup).

`ClusterFates.face_fate` maps (instance, face) pairs, e.g. the split triangle ids of another
view of the same scene, to the fate of the cluster that holds the face: that is how the
demo's culling inspector colours a third-person render.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from .clusters import clusters_of

if TYPE_CHECKING:
    from ..world.mesh import Mesh
    from ..world.scene import Scene

__all__ = ["ClusterFates", "Fate"]


class Fate(IntEnum):
    """Fate of one cluster in one frame."""

    DRAWN = 0  #: sent to triangle setup (its triangles may still be culled one by one)
    FRUSTUM_CULLED = 1  #: outside the view frustum (alone, or its whole instance)
    BACKFACE_CULLED = 2  #: its normal cone faces away (cluster back-face culling)
    OCCLUSION_CULLED = 3  #: its box is hidden behind the depth pyramid (two-phase occlusion)


@dataclass(frozen=True)
class ClusterFates:
    """Per-cluster fates of one frame of ``scene``.

    K = ``instance_key_base[-1]``, the number of (instance, cluster) pairs of the scene
    (empty instances have no clusters).

    Attributes:
        scene: the `Scene` rendered (a bare Mesh is wrapped in a one-instance scene).
        instance_key_base: int64 (I + 1,): the keys of instance i are
            ``instance_key_base[i]:instance_key_base[i + 1]``, one per cluster of its mesh.
        instance: int32 (K,): each key's instance.
        cluster: int32 (K,): each key's cluster, local to the instance's mesh.
        fate: uint8 (K,): each key's `Fate`.
    """

    scene: Scene
    instance_key_base: np.ndarray
    instance: np.ndarray
    cluster: np.ndarray
    fate: np.ndarray

    @classmethod
    def from_plan(cls, plan, occluded_keys: np.ndarray | None = None) -> ClusterFates:
        """Fates from a frame plan (`drawlist.FramePlan` culled with ``keep_cone_culled``)
        and the keys the occlusion test removed (int64, None without occlusion)."""
        base = np.asarray(plan.pool.instance_key_base, np.int64)
        n_keys = np.diff(base)
        inst = np.repeat(np.arange(n_keys.size, dtype=np.int32), n_keys)
        cluster = (np.arange(inst.size, dtype=np.int64)
                   - np.repeat(base[:-1], n_keys)).astype(np.int32)
        fate = np.full(inst.size, Fate.FRUSTUM_CULLED, np.uint8)
        dl = plan.draw_list
        fate[base[dl.instance] + dl.cluster] = Fate.DRAWN
        if dl.cone_culled is not None and dl.cone_culled.size:
            pairs = dl.cone_culled.astype(np.int64)
            fate[base[pairs[:, 0]] + pairs[:, 1]] = Fate.BACKFACE_CULLED
        if occluded_keys is not None:
            fate[occluded_keys] = Fate.OCCLUSION_CULLED
        return cls(plan.scene, base, inst, cluster, fate)

    def __len__(self) -> int:
        return int(self.fate.size)

    def counts(self) -> dict[Fate, int]:
        """Clusters per fate (every fate present, zeros included)."""
        c = np.bincount(self.fate, minlength=len(Fate))
        return {f: int(c[f]) for f in Fate}

    def key(self, instance: npt.ArrayLike, cluster: npt.ArrayLike) -> np.ndarray:
        """int64 keys of (instance, mesh-local cluster) pairs (any matching shapes)."""
        i = np.asarray(instance, np.int64)
        c = np.asarray(cluster, np.int64)
        n = self.instance_key_base.size - 1
        if i.size and (i.min() < 0 or i.max() >= n):
            raise ValueError(f"instance indices must be in [0, {n}), got "
                             f"{int(i.min())}..{int(i.max())}")
        if c.size and (np.any(c < 0)
                       or np.any(c >= np.diff(self.instance_key_base)[i])):
            raise ValueError("cluster indices must be in [0, clusters of the instance's mesh)")
        return self.instance_key_base[i] + c

    def face_cluster(self, instance: npt.ArrayLike, face: npt.ArrayLike) -> np.ndarray:
        """int32 mesh-local cluster holding face ``face`` of instance ``instance`` (arrays
        of any matching shapes; faces index the instance's mesh)."""
        mesh_of, face_base, face_cl = self.scene.memo(("fates.face_cluster",), self._faces)
        i = np.asarray(instance, np.int64)
        f = np.asarray(face, np.int64)
        n = self.instance_key_base.size - 1
        if i.size and (i.min() < 0 or i.max() >= n):
            raise ValueError(f"instance indices must be in [0, {n}), got "
                             f"{int(i.min())}..{int(i.max())}")
        counts = np.asarray(self.scene.face_counts, np.int64)
        if f.size and (np.any(f < 0) or np.any(f >= counts[i])):
            raise ValueError("face indices must be in [0, faces of the instance's mesh)")
        return face_cl[face_base[mesh_of[i]] + f]

    def face_fate(self, instance: npt.ArrayLike, face: npt.ArrayLike) -> np.ndarray:
        """uint8 `Fate` of the cluster holding each (instance, face) pair."""
        i = np.asarray(instance, np.int64)
        return self.fate[self.instance_key_base[i] + self.face_cluster(i, face)]

    def id_fate(self, triangle_id: npt.ArrayLike) -> np.ndarray:
        """int8 `Fate` of each triangle id of this scene (e.g. a ``Frame.triangle_id`` of
        any view of it); −1 where the id is −1 (background)."""
        inst, face = self.scene.split_ids(triangle_id)
        out = np.full(inst.shape, -1, np.int8)
        hit = inst >= 0
        out[hit] = self.face_fate(inst[hit], face[hit])
        return out

    def _faces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per scene: unique-mesh index per instance, first face of each unique mesh in the
        concatenation, and the mesh-local cluster of every face of every unique mesh."""
        index: dict[int, int] = {}
        meshes: list[Mesh] = []
        mesh_of = np.empty(len(self.scene.instances), np.int64)
        for k, inst in enumerate(self.scene.instances):
            mesh_of[k] = index.setdefault(id(inst.mesh), len(meshes))
            if mesh_of[k] == len(meshes):
                meshes.append(inst.mesh)
        parts = []
        for mesh in meshes:
            cm = clusters_of(mesh)
            fc = np.empty(cm.face_ids.size, np.int32)
            fc[cm.face_ids] = np.repeat(np.arange(cm.n_clusters, dtype=np.int32),
                                        cm.n_triangles)
            parts.append(fc)
        sizes = np.array([p.size for p in parts], np.int64)
        face_base = np.zeros(len(parts), np.int64)
        np.cumsum(sizes[:-1], out=face_base[1:])
        face_cl = np.concatenate(parts) if parts else np.zeros(0, np.int32)
        return mesh_of, face_base, face_cl
