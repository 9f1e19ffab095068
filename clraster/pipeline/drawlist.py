"""From a scene and a cull result to the arrays the vertex and setup stages read.

`GeometryPool` is built once per scene (and cached by the renderer): every unique mesh's
vertices and clusters concatenated. `instance_matrices` makes a view's per-instance
matrices and `draw_records` turns (a subset of) a `cull.DrawList` into `Draw` records with
each draw's place in this frame's vertex and triangle streams (`draws.FrameDraws`);
`FramePlan` holds both for one frame, `plan_frame` makes it. The OpenCL renderer uploads
these arrays; the NumPy twin reads the very same ones.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ..base.checks import CameraLike, view_projection
from ..base.config import CLIP_TEST_DRAWS, guard_band_factors
from ..base.layout import CLUSTER_MAX, DRAW_DTYPE, DRAW_INSIDE, DRAW_MIRRORED, DRAW_NO_CLIP
from ..culling.clusters import clusters_of
from ..culling.cull import ViewCull
from ..culling.frustum import PLANE_NAMES
from ..world.mesh import Mesh
from ..world.precision import check_depth_range
from ..world.scene import Scene
from .draws import FrameDraws, depth_rows

if TYPE_CHECKING:
    from ..culling.cull import DrawList


@dataclass(frozen=True)
class GeometryPool:
    """All unique meshes of a scene, clustered, concatenated.

    positions: float32 (V, 3) vertices of every unique mesh's clusters, mesh after mesh and
        cluster after cluster (a vertex shared by clusters once per cluster), each relative
        to its mesh's origin (`mesh_origin`).
    mesh_origin: float64 (number of unique meshes, 3): subtracted from the mesh's vertices
        (exactly: float32 values, see `_mesh_origin`) and folded back into each instance's
        matrix by `instance_matrices`, so that a mesh baked far from the origin (georeferenced,
        ~1e6) is stored as small float32 coordinates and its 1e6 offset cancels against the
        camera's in float64 (camera-relative rendering). Zero for meshes near the origin.
    vert_ids: int32 (V,) pool vertex index of each cluster-local vertex (the identity:
        positions are stored in cluster order, and the kernels read a cluster's positions
        in place, without this array; `GeometryStage.upload_pool` checks it).
    local_tris: uint8 (T, 4) local vertex indices of each clustered triangle (4th byte
        padding). face_ids: int32 (T,) the triangle's face index in its mesh.
    clusters: int32 (C, 4) per global cluster (tri_offset, n_tris, vert_offset, n_verts)
        into local_tris/face_ids and vert_ids.
    mesh_cluster_base: int64 (number of unique meshes,) global index of each mesh's cluster 0.
    instance_mesh: int64 (I,) unique-mesh index of each instance.
    aabb_min, aabb_max: float64 (C, 3) object-space cluster bounds; bounded: bool (C,) False
        for clusters with non-finite vertices (never occlusion-tested: always drawn).
    instance_key_base: int64 (I + 1,): (instance i, cluster c of its mesh) has the key
        instance_key_base[i] + c, unique over the scene (visibility history).
    """

    positions: np.ndarray
    vert_ids: np.ndarray
    local_tris: np.ndarray
    face_ids: np.ndarray
    clusters: np.ndarray
    mesh_cluster_base: np.ndarray
    instance_mesh: np.ndarray
    aabb_min: np.ndarray
    aabb_max: np.ndarray
    bounded: np.ndarray
    instance_key_base: np.ndarray
    mesh_origin: np.ndarray

    if TYPE_CHECKING:   # set by `models`, not a dataclass field
        _models: ClassVar[tuple[np.ndarray, np.ndarray, np.ndarray]]

    def pool_clusters(self, instance: np.ndarray, cluster: np.ndarray) -> np.ndarray:
        """int64 (D,): the pool cluster (row of `clusters`) of each (instance, cluster of
        its mesh) pair, int arrays (D,) each."""
        return (np.take(self.mesh_cluster_base, np.take(self.instance_mesh, instance))
                + np.asarray(cluster, np.int64))

    def models(self, mats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(model float64 (I, 4, 4), mirrored bool (I,)) for the scene's transforms
        ``mats`` (I, 4, 4) (`Scene.transforms`): each instance's transform · the translation
        by its mesh's pool origin (`instance_matrices`), and whether its 3×3 part has a negative
        determinant. Both depend on the scene only, not the view, so they are kept for the
        last ``mats`` seen (by identity: `Scene.transforms` is memoized per scene version,
        a new version is a new array, and the one kept here stays alive, so its id cannot
        be reused): the draw layout remade them every frame (np.linalg.det, the origin
        matrices, two matmuls), which was most of the draw layout's time for a small
        scene."""
        kept = self.__dict__.get("_models")
        if kept is not None and kept[0] is mats:
            return kept[1], kept[2]
        origin = np.zeros((len(mats), 4, 4))
        origin[:] = np.eye(4)
        origin[:, :3, 3] = self.mesh_origin[self.instance_mesh] if len(mats) else 0.0
        model = np.matmul(mats, origin)
        mirrored = (np.linalg.det(mats[:, :3, :3]) < 0.0 if len(mats)
                    else np.zeros(0, bool))
        model.flags.writeable = False
        mirrored.flags.writeable = False
        object.__setattr__(self, "_models", (mats, model, mirrored))
        return model, mirrored

    @classmethod
    def build(cls, scene) -> GeometryPool:
        meshes: list = []
        index: dict[int, int] = {}
        inst_mesh = []
        for inst in scene.instances:
            k = index.setdefault(id(inst.mesh), len(meshes))
            if k == len(meshes):
                meshes.append(inst.mesh)
            inst_mesh.append(k)
        pos, vids, ltris, fids, cl, cbase, lo, hi, bnd = [], [], [], [], [], [], [], [], []
        origins = []
        v0 = t0 = vv0 = c0 = 0
        for mesh in meshes:
            cm = clusters_of(mesh)
            origin = _mesh_origin(mesh)
            origins.append(origin)
            # float32 minus a float32 value near it: exact (Sterbenz), so the stored
            # positions plus the origin are the mesh's own vertices
            mpos = (np.asarray(mesh.vertices, np.float64) - origin).astype(np.float32)
            # Stored in cluster order, a cluster's vertices side by side (shared ones once
            # per cluster, ~1.16x the mesh's on the dragon), vert_ids the identity: the
            # vertex stage reads them in sequence. Gathered through the mesh's vertex order
            # (vert_ids into it), a cache miss per vertex was a third of the vertex stage's
            # samples (perf, dragon 871K at 1080p).
            pos.append(mpos[cm.vert_ids])
            vids.append(np.arange(vv0, vv0 + cm.vert_ids.shape[0], dtype=np.int64))
            lt = np.zeros((cm.local_tris.shape[0], 4), np.uint8)
            lt[:, :3] = cm.local_tris
            ltris.append(lt)
            fids.append(cm.face_ids)
            c = np.empty((cm.n_clusters, 4), np.int64)
            c[:, 0] = cm.tri_offset[:-1] + t0
            c[:, 1] = np.diff(cm.tri_offset)
            c[:, 2] = cm.vert_offset[:-1] + vv0
            c[:, 3] = np.diff(cm.vert_offset)
            cl.append(c)
            cbase.append(c0)
            lo.append(np.asarray(cm.aabb_min, np.float64))
            hi.append(np.asarray(cm.aabb_max, np.float64))
            bnd.append(np.asarray(cm.bounded, bool))
            v0 += cm.vert_ids.shape[0]
            t0 += cm.local_tris.shape[0]
            vv0 += cm.vert_ids.shape[0]
            c0 += cm.n_clusters
        for total, what in ((v0, "vertices"), (t0, "triangles"), (vv0, "cluster vertices")):
            if total >= 2**31:
                raise ValueError(f"the scene's unique meshes hold {total:,} {what}; at most "
                                 "2**31 - 1 are supported")
        if c0 and int(np.concatenate(cl)[:, [1, 3]].max()) > CLUSTER_MAX:
            raise ValueError(f"clusters must have at most {CLUSTER_MAX} triangles and vertices")

        def cat(parts, dtype, shape):
            return (np.ascontiguousarray(np.concatenate(parts), dtype) if parts
                    else np.zeros(shape, dtype))

        inst_mesh_a = np.asarray(inst_mesh, np.int64)
        n_cl = np.array([clusters_of(m).n_clusters for m in meshes], np.int64)
        key_base = np.zeros(len(inst_mesh) + 1, np.int64)
        np.cumsum(n_cl[inst_mesh_a] if inst_mesh else [], out=key_base[1:])
        return cls(cat(pos, np.float32, (0, 3)), cat(vids, np.int32, (0,)),
                   cat(ltris, np.uint8, (0, 4)), cat(fids, np.int32, (0,)),
                   cat(cl, np.int32, (0, 4)), np.asarray(cbase, np.int64), inst_mesh_a,
                   cat(lo, np.float64, (0, 3)), cat(hi, np.float64, (0, 3)),
                   cat(bnd, bool, (0,)), key_base,
                   np.asarray(origins, np.float64).reshape(-1, 3))


#: A mesh whose bounds centre lies more than this many times its size from the origin is
#: stored relative to that centre (`_mesh_origin`).
ORIGIN_FAR = 16.0


def _mesh_origin(mesh) -> np.ndarray:
    """float64 (3,): the origin `GeometryPool` stores ``mesh`` relative to. Per axis, the
    centre of its finite bounds, rounded to float32, where that centre lies more than
    ORIGIN_FAR times the mesh's size from the origin (only there does float32 lose much
    precision to the offset); else zero, so meshes around the origin keep their exact
    float32 positions and images (and so do the sub-meshes of `distributed.partition`, a
    part of a mesh around the origin being far less than 16 of its own sizes away from
    it)."""
    v = np.asarray(mesh.vertices, np.float64)
    fin = v[np.all(np.isfinite(v), axis=1)]
    if fin.shape[0] == 0:
        return np.zeros(3)
    lo, hi = fin.min(0), fin.max(0)
    centre = (lo + hi) / 2
    far = np.abs(centre) > ORIGIN_FAR * float((hi - lo).max())
    if not far.any():
        return np.zeros(3)
    origin = np.where(far, centre, 0.0).astype(np.float32).astype(np.float64)
    # subtraction must stay exact: each |v - origin| <= |v| keeps the float32 spacing of v
    # (Sterbenz: v/2 <= origin <= 2v per coordinate), else no origin for that axis
    ok = np.all((fin == 0) | ((fin / np.where(origin == 0, 1, origin) >= 0.5)
                              & (fin / np.where(origin == 0, 1, origin) <= 2.0)), axis=0)
    return np.where(ok & (origin != 0), origin, 0.0)


def instance_matrices(pool: GeometryPool, scene, view_proj: np.ndarray,
                      clip_planes: np.ndarray | None = None, n_clipping: int | None = None
                      ) -> FrameDraws:
    """This view's per-instance arrays, with no draws yet (`draw_records` adds them).

    view_proj: float64 (4, 4). Each instance's matrix (view-projection · model · the
    translation by its mesh's pool origin) is formed in float64 and rounded to float32 once,
    for both the device and the twin: a camera and an instance both ~1e6 from the world
    origin cancel there, in float64, before anything becomes float32 (camera-relative
    rendering). clip_planes: float64 (K, 4) world-space user clip planes
    (`checks.check_clip_planes`), moved to each instance's object space in float64
    (`FrameDraws.uplanes`); the first ``n_clipping`` of them (default all) clip, the rest
    only reject and cull (`uclip`)."""
    mats = scene.transforms()   # memoized per scene version (5K instances: 6 ms to stack)
    model, _ = pool.models(mats)
    mvps64 = np.matmul(np.asarray(view_proj, np.float64), model)
    mvps = mvps64.astype(np.float32)
    if not np.isfinite(mvps).all():
        raise ValueError("an instance's view-projection · model matrix is not finite in "
                         "float32")
    # plane · model: the distance of an object-space point p is plane · (model · [p, 1])
    uplanes = (np.einsum("kj,ijl->ikl", clip_planes, model) if clip_planes is not None
               else np.zeros((len(mats), 0, 4)))
    k = uplanes.shape[1]
    uclip = (1 << (k if n_clipping is None else n_clipping)) - 1
    # (mvps and mvps64 are fresh C-contiguous arrays: their reshapes are contiguous views)
    return FrameDraws(np.zeros(0, DRAW_DTYPE), 0, 0, mvps.reshape(-1, 16),
                      mvps64.reshape(-1, 16), depth_rows(mvps64), np.ascontiguousarray(uplanes),
                      uclip)


def draw_records(pool: GeometryPool, scene, frame: FrameDraws, instance: np.ndarray,
                 cluster: np.ndarray, inside: np.ndarray,
                 no_clip: np.ndarray | None = None) -> FrameDraws:
    """``frame`` (`instance_matrices`) with the draws (instance, mesh-local cluster,
    inside) (D,) each, in that order, as `Draw` records: their places in the frame's
    vertex and triangle streams follow the order. Draws of instances whose transform has a
    negative determinant get DRAW_MIRRORED: their faces keep their outward side (the Scene
    rule, as glTF). ``no_clip``: bool (D,) or None (none), the draws that get DRAW_NO_CLIP
    (`ViewCull.clip_free`)."""
    inst = np.asarray(instance, np.int64)
    d = np.zeros(inst.size, DRAW_DTYPE)
    n_verts = n_tris = 0
    if inst.size:   # (nothing in view: no records to fill, ~12 µs of small NumPy calls)
        _, mirrored = pool.models(scene.transforms())
        gcl = pool.pool_clusters(inst, cluster)
        # np.take, not pool.clusters[gcl]: NumPy's fancy indexing of rows took ~1 ms for the
        # 83K draws of the 10M plant (its general mapiter path), take 0.06 ms
        info = np.take(pool.clusters, gcl, axis=0)
        # (np.take, and bool columns times the flag bits, rather than fancy indexing and
        # np.where: fewer passes over the draws, every frame)
        d["cluster"] = gcl
        d["instance"] = inst
        end_v = np.cumsum(info[:, 3], dtype=np.int64)
        end_t = np.cumsum(info[:, 1], dtype=np.int64)
        d["vert_base"] = end_v - info[:, 3]
        d["tri_base"] = end_t - info[:, 1]
        d["face_base"] = np.take(np.asarray(scene.face_base, np.int64), inst)
        flags = d["flags"]
        np.multiply(np.asarray(inside, bool), DRAW_INSIDE, out=flags, casting="unsafe")
        if mirrored.any():
            flags |= np.take(mirrored, inst) * np.int32(DRAW_MIRRORED)
        if no_clip is not None:
            flags |= np.asarray(no_clip, bool) * np.int32(DRAW_NO_CLIP)
        # the cumulative sums' last entries are the sums (exact integers)
        n_verts, n_tris = int(end_v[-1]), int(end_t[-1])
    if n_verts >= 2**31 or n_tris >= 2**31:
        raise ValueError("a frame may draw at most 2**31 - 1 vertices and triangles")
    return FrameDraws(d, n_verts, n_tris, frame.mvps, frame.mvps64, frame.zrows,
                      frame.uplanes, frame.uclip)


def key_boxes(pool: GeometryPool, scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-space AABBs of every (instance, cluster) pair, indexed by key
    (pool.instance_key_base[instance] + cluster): float64 (K, 3) mins and maxs, from each
    cluster's object-space box's 8 corners through its instance transform, and bool (K,)
    bounded. Depends only on the scene: computed once per scene version."""
    n_keys = np.diff(pool.instance_key_base)
    inst = np.repeat(np.arange(n_keys.size), n_keys)
    local = np.arange(inst.size) - np.repeat(pool.instance_key_base[:-1], n_keys)
    gcl = pool.pool_clusters(inst, local)
    lo, hi = pool.aabb_min[gcl], pool.aabb_max[gcl]
    mats = scene.transforms()
    wlo = np.full(lo.shape, np.inf)
    whi = np.full(lo.shape, -np.inf)
    for bits in np.ndindex(2, 2, 2):   # the 8 corners, each through its instance matrix
        c = np.where(np.array(bits)[None, :] != 0, hi, lo)
        m = mats[inst]
        wc = np.einsum("kij,kj->ki", m[:, :3, :3], c) + m[:, :3, 3]
        np.minimum(wlo, wc, out=wlo)
        np.maximum(whi, wc, out=whi)
    return wlo, whi, pool.bounded[gcl]


#: The near and far planes' bits of a culling plane mask (`frustum.PLANE_NAMES` order).
_NEAR_FAR = (1 << PLANE_NAMES.index("near")) | (1 << PLANE_NAMES.index("far"))


class FramePlan:
    """Everything both renderers need before the vertex stage: the scene, its pool, the
    view's culling (`cull.ViewCull`: instances classified, pairs culled on demand) and the
    view-projection (float64 (4, 4)). The draw list (every pair culled) is made when first
    asked for; hierarchical occlusion culling (`twophase`) culls only the pairs it needs
    and sets the frame's draw list itself. The draw records are laid out when asked for:
    all of them (`frame`), or a subset (`draws_of`, `draws_for`: two-phase occlusion
    culling draws a few of the frame's clusters, and laying out the 83K of the 10M
    plant's first-person view took ~1.8 ms)."""

    def __init__(self, scene: Scene, pool: GeometryPool, culler: ViewCull,
                 matrices: Callable[[], FrameDraws], view_proj: np.ndarray,
                 size: tuple[int, int] | None = None) -> None:
        self.scene = scene
        self.pool = pool
        self.culler = culler
        self.view_proj = view_proj
        self._make_matrices = matrices
        #: the guard-band factors of the image (width, height) the plan is for; None: no
        #: size known, no draw is marked DRAW_NO_CLIP
        self.guard_band: tuple[float, float] | None = None
        if size is not None:
            kx, ky = guard_band_factors(*size)
            self.guard_band = float(kx), float(ky)
        self._draw_list: DrawList | None = None
        self._frame: FrameDraws | None = None

    @functools.cached_property
    def matrices(self) -> FrameDraws:
        """`instance_matrices` of this view (no draws), made when the first draws are laid
        out: a frame with nothing in view never needs them (~40 µs of an empty frame with
        the caches cold)."""
        return self._make_matrices()

    @property
    def draw_list(self) -> DrawList:
        """The frame's draw list: every pair culled (`ViewCull.all`), unless set."""
        if self._draw_list is None:
            self._draw_list = self.culler.all()
        return self._draw_list

    @draw_list.setter
    def draw_list(self, dl: DrawList) -> None:
        self._draw_list = dl
        self._frame = None

    @property
    def frame(self) -> FrameDraws:
        """All the draws of the draw list, in its order, laid out once."""
        if self._frame is None:
            self._frame = self.draws_for(self.draw_list)
        return self._frame

    @property
    def empty(self) -> bool:
        """Nothing to draw (every cluster has at least one triangle)."""
        return len(self.draw_list) == 0

    def draws_of(self, mask: np.ndarray) -> FrameDraws:
        """The draws where ``mask`` (bool (D,), over the draw list) is set: `draws_for`
        of the draw list."""
        return self.draws_for(self.draw_list, mask)

    def draws_for(self, dl: DrawList, mask: np.ndarray | None = None) -> FrameDraws:
        """The draws of ``dl`` (a draw list of this view), or those where ``mask`` (bool
        (D,)) is set, in the list's order, laid out on their own (their places in the
        vertex and triangle streams follow from the subset), without laying out the
        rest.

        Draws that are not INSIDE the frustum get DRAW_NO_CLIP when `ViewCull.clip_free`
        says none of their triangles can be clipped (a mesh crossing the image's edges,
        seen from close by), tested while there are at most `CLIP_TEST_DRAWS` of them: a
        pass whose draws all have one of the two flags enqueues binning behind setup
        without waiting for setup's clip count (`clraster.pipeline.stages.setup`)."""
        inst, cl, ins = dl.instance, dl.cluster, dl.inside
        if mask is not None:
            inst, cl, ins = inst[mask], cl[mask], ins[mask]
        no_clip = None
        out = np.flatnonzero(~ins)
        # (user planes that clip make setup wait regardless: GeometryStage.upload_frame;
        # and a draw whose instance's box crosses the near or far plane is rarely free of
        # clipping, while one such draw makes the pass wait: the camera inside a scene)
        if (self.guard_band is not None and 0 < out.size <= CLIP_TEST_DRAWS
                and not (self.matrices.n_user and self.matrices.uclip)
                and not (self.culler.inst_mask[inst[out]] & _NEAR_FAR).any()):
            no_clip = np.zeros(ins.shape, bool)
            no_clip[out] = self.culler.clip_free(inst[out], cl[out], *self.guard_band)
        return draw_records(self.pool, self.scene, self.matrices, inst, cl, ins, no_clip)


class PlanCache:
    """Keeps the scene (made from a bare Mesh when needed) and geometry pool of the last
    target, so repeated frames of the same mesh or scene reuse them. Thread-safe: a
    renderer and its `Renderer.view_partner` plan views at the same time from one cache
    (what it hands out is only read)."""

    def __init__(self) -> None:
        self._key: tuple[Any, ...] | None = None
        self._value: tuple[Mesh | Scene, Scene, GeometryPool] | None = None
        self._lock = threading.Lock()

    def scene_and_pool(self, target: Mesh | Scene) -> tuple[Scene, GeometryPool]:
        key: tuple[Any, ...]
        if isinstance(target, Mesh):
            key = ("mesh", id(target))
        elif isinstance(target, Scene):
            key = ("scene", id(target), target.version)
        else:
            raise ValueError(f"expected a clraster.Mesh or clraster.Scene, got "
                             f"{type(target).__name__}")
        with self._lock:
            if self._key != key or self._value is None or self._value[0] is not target:
                scene = Scene.from_mesh(target) if isinstance(target, Mesh) else target
                self._value = (target, scene, GeometryPool.build(scene))
                self._key = key
            return self._value[1], self._value[2]


def plan_frame(target: Mesh | Scene, camera: CameraLike, width: int, height: int, *,
               cull: str, frustum: bool, cones: bool, cache: PlanCache,
               keep_cone_culled: bool = False, clip_planes: np.ndarray | None = None,
               cull_planes: np.ndarray | None = None) -> FramePlan:
    """Cull ``target`` (a Mesh or a Scene; the cache keeps its scene and pool) for
    ``camera`` and lay out this frame's draws (``keep_cone_culled``: see
    `cull.build_draw_list`). ``clip_planes``: float64 (K, 4) world-space user clip planes
    (checked, `checks.check_clip_planes`) or None: clusters wholly outside one are culled
    and the rest clipped. ``cull_planes``: float64 (K', 4) planes that only cull and reject
    (a polygon window's, `window.window_planes_for`), never clip."""
    vp = view_projection(camera, width, height)
    scene, pool = cache.scene_and_pool(target)
    check_depth_range(camera, width, height, scene)
    n_clipping = None if clip_planes is None else clip_planes.shape[0]
    if cull_planes is not None and cull_planes.shape[0]:
        n_clipping = n_clipping or 0
        clip_planes = (cull_planes if clip_planes is None
                       else np.concatenate([clip_planes, cull_planes]))
    culler = ViewCull(scene, vp, frustum=frustum, cones=cones, cull=cull,
                      keep_cone_culled=keep_cone_culled, clip_planes=clip_planes)
    return FramePlan(scene, pool, culler,
                     lambda: instance_matrices(pool, scene, vp, clip_planes, n_clipping), vp,
                     (width, height))
