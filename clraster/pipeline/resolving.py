"""What the resolve stage reads besides the frame's buffers, made once for both of its
mirrors (kernels/resolve.cl through `clraster.pipeline.stages.resolve`, and the NumPy twin
`clraster.pipeline.reference.resolve`): the scene's face table and instance tables
(`ResolveTables`, once per geometry pool) and one view's camera-relative instance matrices
(`ResolveView`, per frame).

The resolve stage turns each pixel's (triangle id, barycentrics) into the outputs of
`clraster.base.checks.RESOLVE_OUTPUTS`. Per covered pixel, in float64:

* instance i: the last one whose first triangle id (``Scene.face_base``) is ≤ the id;
  face f = id − face_base[i]; its three vertices a, b, c are pool positions
  (`GeometryPool.positions`, object space relative to the mesh's pool origin), found
  through the face table.
* the surface point ``q = (b0·a + b1·b) + b2·c`` in object space (barycentrics relative to
  the face's own vertex order, as the raster writes them), moved to the world by the
  instance's model matrix (its transform, with the mesh's pool origin folded in):
  points = ``M·q + t``; off = points − eye; linear_depth = ``off · fwd`` (fwd: the unit
  world view axis); distance = ``|off|``, or linear_depth for an orthographic camera
  (parallel rays). This is the exact surface point of `clraster.Frame.points`: its error
  is the float32 barycentrics' (~1e-7 of the triangle's size; float64 adds ~1e-16 of the
  coordinates), not the float32 window depth run back through the projection, whose
  metric error grows as distance² (~1e-6 relative at moderate range).
* normals: the face normal ``normalize((b − a) × (c − a))`` of `Mesh.face_normals`
  (float32, a table per scene), or (smooth) the barycentric blend of the mesh's area-weighted
  vertex normals (`clraster.output.shade.vertex_normals`; the face normal where that blend
  is shorter than 1e-6), then ``normalize(M⁻ᵀ n)`` — glTF's rule, no sign change for a
  mirroring instance — rounded to float32; for camera space, that times V⁻ᵀ (V the view's
  3×3 part), normalized. Zero for degenerate faces.

Every sum is written in one order (`clraster.output.surface`), which the host outputs of
`clraster.output.outputs` follow too: a frame's device-made outputs are the bits the host
computes from the same frame.

Background pixels (id −1): mask False, metric depths inf, points and normals 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..base.layout import FACE_ROW_WORDS
from ..output.outputs import CameraAxes, camera_axes
from ..output.shade import vertex_normals
from ..world.scene import Scene
from .drawlist import GeometryPool

__all__ = ["OUTPUT_BITS", "RESOLVE_SPAN", "SHADE_SPAN", "ResolveTables", "ResolveView",
           "ShadeSources", "resolve_bits", "resolve_tables", "resolve_view", "shade_sources"]

#: resolve output → its bit in the kernel's ``want`` mask (generated as -D options).
OUTPUT_BITS = {"mask": 1, "linear_depth": 2, "distance": 4, "points": 8, "normals": 16,
               "smooth_normals": 32, "camera_normals": 64, "smooth_camera_normals": 128}
#: Pixels per work-item of the resolve kernel (consecutive, row-major): large enough that
#: a frame is a few hundred work-items (each launch of one costs PoCL a loop iteration, not
#: a thread), small enough that 1080p still spreads over every core. Speed only.
RESOLVE_SPAN = 512
#: Pixels per work-item of the shading kernels (a multiple of their 16-pixel background
#: runs): as RESOLVE_SPAN, speed only.
SHADE_SPAN = 1024
#: Instances per bucket of the id → instance table, about (`ResolveTables.buckets`): the
#: forward scan from a bucket's first instance visits about this many. Speed and size only.
_BUCKET_INSTANCES = 2
#: Most entries of that table (4 bytes each).
_MAX_BUCKETS = 1 << 22
#: outputs made from the barycentrics (the surface point, or interpolated vertex normals)
NEED_BARY = frozenset({"linear_depth", "distance", "points", "smooth_normals",
                       "smooth_camera_normals"})
#: outputs that need the camera's view (eye, view axis, eye-space rotation)
NEED_CAMERA = frozenset({"linear_depth", "distance", "points", "camera_normals",
                         "smooth_camera_normals"})
NEED_SMOOTH = frozenset({"smooth_normals", "smooth_camera_normals"})


def resolve_bits(names: tuple[str, ...]) -> int:
    """The kernel's ``want`` mask of the resolve outputs ``names``."""
    bits = 0
    for n in names:
        bits |= OUTPUT_BITS[n]
    return bits


@dataclass(frozen=True)
class ResolveTables:
    """One scene's tables for the resolve stage (I instances, U unique meshes, F faces of
    the unique meshes, V pool vertices).

    inst_base: int32 (I,) triangle id of each instance's face 0 (``Scene.face_base``).
    inst_mesh: int32 (I,) unique mesh (pool order) of each instance.
    mesh_fbase: int32 (U,) row of each unique mesh's face 0 in ``face_verts``.
    face_verts: int32 (F, 3) pool vertex indices (rows of `GeometryPool.positions`) of each
        face's three vertices, in the face's own order.
    face_normals: float32 (F, 3) unit object-space face normals, rows as ``face_verts``
        (each mesh's `Mesh.face_normals`: what the host shades and outputs with).
    normal_mats: float64 (I, 9) row-major M⁻ᵀ of each instance's 3×3 part (zero for a
        singular one: its normals are zero).
    vnormals: float32 (V, 3) area-weighted unit vertex normals in pool order (made on the
        first smooth request: `smooth_normals`; per face, quantized, for smooth shading:
        `face_vertex_normals`).
    """

    inst_base: np.ndarray
    inst_mesh: np.ndarray
    mesh_fbase: np.ndarray
    face_verts: np.ndarray
    face_normals: np.ndarray
    normal_mats: np.ndarray
    meshes: tuple[Any, ...]

    def buckets(self) -> tuple[np.ndarray, int]:
        """(bucket int32 (B,), shift): ``bucket[id >> shift]`` is the last instance whose
        first id is ≤ ``id >> shift << shift``, so the instance of ``id`` is found by a
        forward scan from it (kernels/shade.cl shade_one); ~`_BUCKET_INSTANCES` instances
        per bucket (cached)."""
        got = self.__dict__.get("_buckets")
        if got is None:
            n_inst = int(self.inst_base.size)
            total = int(self.inst_base[-1]) + int(self.meshes[int(self.inst_mesh[-1])].n_faces) \
                if n_inst else 0
            want = max(1, min(n_inst // _BUCKET_INSTANCES, _MAX_BUCKETS))
            shift = 0
            while (total >> shift) > want:
                shift += 1
            starts = np.arange((total >> shift) + 1, dtype=np.int64) << shift
            bucket = (np.searchsorted(self.inst_base, starts, side="right") - 1
                      if n_inst else np.zeros(starts.size, np.int64))
            got = (np.ascontiguousarray(np.maximum(bucket, 0), np.int32), shift)
            object.__setattr__(self, "_buckets", got)
        return got

    def inst_rows(self) -> np.ndarray:
        """int32 (I,): the row of an id's face in ``face_verts`` is ``id + inst_rows[i]``
        (``mesh_fbase[inst_mesh[i]] − inst_base[i]``; cached)."""
        got = self.__dict__.get("_inst_rows")
        if got is None:
            got = np.ascontiguousarray(
                self.mesh_fbase[self.inst_mesh].astype(np.int64) - self.inst_base, np.int32)
            object.__setattr__(self, "_inst_rows", got)
        return got

    def shade_normal_mats(self) -> np.ndarray:
        """float32 (I, 12): ``normal_mats`` as three rows of 4 (float4 loads; cached)."""
        got = self.__dict__.get("_shade_nrm")
        if got is None:
            got = np.zeros((self.inst_base.size, 3, 4), np.float32)
            got[:, :, :3] = self.normal_mats.reshape(-1, 3, 3)
            got = got.reshape(-1, 12)
            object.__setattr__(self, "_shade_nrm", got)
        return got

    def vertex_bases(self) -> np.ndarray:
        """int64 (U,): pool row of each unique mesh's first vertex (cached)."""
        got = self.__dict__.get("_vbase")
        if got is None:
            from ..culling.clusters import clusters_of

            sizes = [clusters_of(m).vert_ids.shape[0] for m in self.meshes]
            got = np.zeros(len(sizes), np.int64)
            if sizes:
                np.cumsum(sizes[:-1], out=got[1:])
            object.__setattr__(self, "_vbase", got)
        return got

    def face_rows(self) -> np.ndarray:
        """int32 (F, FACE_ROW_WORDS): per row of ``face_verts``, its three pool vertices, its unit
        object-space normal (``face_normals``, float32 bits) and two zeros: the device's one
        face table (kernels/common.h FACE_V / FACE_N), so a pixel's vertices and normal
        are one cache line (two tables were a miss each). 32 bytes a face, made anew for
        each upload, not kept here."""
        out = np.zeros((self.face_verts.shape[0], FACE_ROW_WORDS), np.int32)
        out[:, :3] = self.face_verts
        out[:, 3:6] = np.ascontiguousarray(self.face_normals, np.float32).view(np.int32)
        return out

    def face_vertex_normals(self, pool: GeometryPool) -> np.ndarray:
        """int16 (F, 16): per row of ``face_verts``, its three vertices' normals
        (`smooth_normals`) as snorm16, ``round(32767 · n)``, x y z of each vertex in the
        face's order, then 7 zeros: one 32-byte row (a cache line) per face for the
        shading kernel's smooth lanes (kernels/resolve.cl FACE_VN_ROW). 32 bytes a face:
        the dragon's 871K faces take 28 MB, so it is made anew for each upload, not kept
        here (the shading stage keeps its device copy)."""
        vn = self.smooth_normals(pool)
        out = np.zeros((self.face_verts.shape[0], 16), np.int16)
        if out.shape[0]:
            q = np.rint(vn[self.face_verts].reshape(-1, 9) * np.float32(32767.0))
            out[:, :9] = np.clip(q, -32767, 32767)
        return out

    def smooth_normals(self, pool: GeometryPool) -> np.ndarray:
        """float32 (V, 3) vertex normals parallel to ``pool.positions`` (cached)."""
        got = self.__dict__.get("_vnormals")
        if got is None:
            from ..culling.clusters import clusters_of

            parts = [vertex_normals(m)[clusters_of(m).vert_ids] for m in self.meshes]
            got = (np.ascontiguousarray(np.concatenate(parts), np.float32) if parts
                   else np.zeros((0, 3), np.float32))
            object.__setattr__(self, "_vnormals", got)
        return got


def resolve_tables(pool: GeometryPool, scene: Scene) -> ResolveTables:
    """The `ResolveTables` of ``scene`` drawn from ``pool`` (`GeometryPool.build(scene)`),
    made once and kept on the pool (a pool belongs to one scene version)."""
    got = pool.__dict__.get("_resolve_tables")
    if got is not None:
        return got
    n_inst = len(scene.instances)
    inst_mesh = np.asarray(pool.instance_mesh, np.int64)
    n_mesh = int(pool.mesh_cluster_base.size)
    meshes: list[Any] = [None] * n_mesh
    for i in range(n_inst):
        u = int(inst_mesh[i])
        if meshes[u] is None:
            meshes[u] = scene.instances[i].mesh
    n_faces = np.array([m.n_faces for m in meshes], np.int64)
    mesh_fbase = np.zeros(n_mesh, np.int64)
    if n_mesh:
        np.cumsum(n_faces[:-1], out=mesh_fbase[1:])
    total = int(n_faces.sum())
    face_verts = np.zeros((total, 3), np.int32)
    cl = np.asarray(pool.clusters, np.int64)
    if cl.shape[0]:
        n_tris = cl[:, 1]
        cluster = np.repeat(np.arange(cl.shape[0]), n_tris)       # cluster of each triangle
        mesh = np.searchsorted(pool.mesh_cluster_base, cluster, side="right") - 1
        rows = mesh_fbase[mesh] + np.asarray(pool.face_ids, np.int64)
        verts = cl[cluster, 2][:, None] + np.asarray(pool.local_tris[:, :3], np.int64)
        face_verts[rows] = verts
    face_normals = (np.concatenate([m.face_normals() for m in meshes]) if meshes
                    else np.zeros((0, 3), np.float32))
    tables = ResolveTables(
        np.ascontiguousarray(scene.face_base, np.int32).reshape(-1),
        inst_mesh.astype(np.int32), mesh_fbase.astype(np.int32), face_verts,
        np.ascontiguousarray(face_normals, np.float32), _normal_matrices(scene.transforms()),
        tuple(meshes))
    object.__setattr__(pool, "_resolve_tables", tables)
    return tables


def _normal_matrices(mats: np.ndarray) -> np.ndarray:
    """float64 (I, 9): M⁻ᵀ of each transform's 3×3 part, row-major; zero where singular."""
    m3 = np.asarray(mats, np.float64).reshape(-1, 4, 4)[:, :3, :3]
    out = np.zeros((m3.shape[0], 3, 3))
    ok = np.abs(np.linalg.det(m3)) > 0.0 if m3.shape[0] else np.zeros(0, bool)
    if ok.any():
        out[ok] = np.transpose(np.linalg.inv(m3[ok]), (0, 2, 1))
    return np.ascontiguousarray(out.reshape(-1, 9))


@dataclass(frozen=True)
class ResolveView:
    """One frame's view for the resolve stage.

    names: the resolve outputs asked for (`clraster.base.checks.RESOLVE_OUTPUTS`); want:
    their bits (`OUTPUT_BITS`). model: float64 (I, 12) row-major 3×4 ``[M₃ | t]`` per
    instance (model matrix with the mesh's pool origin folded in,
    `GeometryPool.models`): object point → world point. cam: float64 (16,)
    the view axis fwd (3), the eye (3), V⁻ᵀ row-major (9, world → eye-space normals), and
    1.0 for an orthographic camera (else 0.0). view, projection: float64 (4, 4) the
    camera's matrices (the frame keeps them: `clraster.Frame.resolved_camera`), or None
    when no output needs the camera.
    """

    names: tuple[str, ...]
    want: int
    model: np.ndarray
    cam: np.ndarray
    view: np.ndarray | None
    projection: np.ndarray | None


def check_resolve_camera(names: tuple[str, ...], camera: Any, width: int, height: int
                         ) -> CameraAxes | None:
    """ValueError now, before anything is drawn, when a resolve output asked for needs a
    camera with ``view`` and ``projection`` (`camera_axes`) and ``camera`` has none; else
    the camera's axes where an output needs them (for `resolve_view`), or None."""
    need = [n for n in names if n in NEED_CAMERA]
    if not need:
        return None
    try:
        return camera_axes(camera, width, height)
    except ValueError as exc:
        raise ValueError(f"outputs {', '.join(need)}: {exc}") from None


def resolve_view(pool: GeometryPool, scene: Scene, camera: Any, width: int, height: int,
                 names: tuple[str, ...], axes: CameraAxes | None = None) -> ResolveView:
    """The `ResolveView` of ``camera`` for the resolve outputs ``names``; ``axes``: the
    camera's `camera_axes` when already made (`check_resolve_camera`)."""
    model, _ = pool.models(scene.transforms())
    cam = np.zeros(16)
    view = proj = None
    if any(n in NEED_CAMERA for n in names):
        view, proj, eye, fwd, ortho = axes or camera_axes(camera, width, height)
        cam[0:3], cam[3:6] = fwd, eye
        cam[6:15] = np.linalg.inv(view[:3, :3]).T.reshape(-1)
        cam[15] = 1.0 if ortho else 0.0
    return ResolveView(names, resolve_bits(names),
                       np.ascontiguousarray(model[:, :3, :].reshape(-1, 12)), cam, view, proj)


#: inst_src bits (kernels/resolve.cl SRC_*)
SRC_VCOL, SRC_FCOL, SRC_TEX = 1, 2, 4


@dataclass(frozen=True)
class ShadeSources:
    """The colour sources of a scene's instances for the shading kernels (kernels/resolve.cl
    shade_one), made by `shade_sources`.

    inst_src: int32 (I, 8) per instance: SRC_* bits, vertex colour offset, face colour
        offset, uv offset, texel offset, texture width, texture height, 0. A pool vertex v
        of the instance's mesh has its colour at ``colours[v + offset]`` and its uv at
        ``uvs[v + offset]``; face f its colour at ``colours[f + offset]``; texel (r, c) is
        ``texels[offset + r·width + c]``.
    colours: float32 (N, 4) RGB0 in [0, 1]; uvs: float32 (M, 2); texels: float32 (T, 4).
    factor: float64 (I, 3): the texture's factor, ones where none.
    colored: bool (I,): the instance has a colour source (its albedo is not the default).
    """

    inst_src: np.ndarray
    colours: np.ndarray
    uvs: np.ndarray
    texels: np.ndarray
    factor: np.ndarray
    colored: np.ndarray


def shade_sources(tables: ResolveTables, sources: list[tuple[Any, Any, Any]]) -> ShadeSources:
    """`ShadeSources` of ``sources``: per instance (vertex colours float (N, 3) or None, face
    colours float (F, 3) or None, a `clraster.output.textures.Texture` or None), the mesh's
    own vertex and face order. An array shared by instances of one mesh is stored once."""
    from ..culling.clusters import clusters_of

    n = len(sources)
    inst_src = np.zeros((n, 8), np.int32)
    factor = np.ones((n, 3))
    colored = np.zeros(n, bool)
    vbase = tables.vertex_bases()
    cols: list[np.ndarray] = []
    uvs: list[np.ndarray] = []
    texels: list[np.ndarray] = []
    sizes = {"c": 0, "u": 0, "t": 0}
    blocks: dict[tuple[str, int, int], int] = {}

    def block(kind: str, u: int, arr: np.ndarray, make: Any, into: list[np.ndarray]) -> int:
        key = (kind, u, id(arr))
        got = blocks.get(key)
        if got is None:
            rows = make(arr)
            got = blocks[key] = sizes[kind[0]]
            into.append(rows)
            sizes[kind[0]] += rows.shape[0]
        return got

    def per_vertex(u: int) -> Any:
        vid = clusters_of(tables.meshes[u]).vert_ids
        return lambda a: np.asarray(a)[vid]

    def rgb0(a: np.ndarray) -> np.ndarray:
        out = np.zeros((a.shape[0], 4), np.float32)
        out[:, :3] = a
        return out

    for i, (vc, fc, tex) in enumerate(sources):
        u = int(tables.inst_mesh[i])
        bits = 0
        if vc is not None:
            bits |= SRC_VCOL
            inst_src[i, 1] = block("cv", u, vc, lambda a, u=u: rgb0(per_vertex(u)(a)), cols) \
                - vbase[u]
        if fc is not None:
            bits |= SRC_FCOL
            inst_src[i, 2] = block("cf", u, fc, rgb0, cols)
        if tex is not None:
            factor[i] = tex.factor
            if tex.image is not None:
                bits |= SRC_TEX
                inst_src[i, 3] = block("uv", u, tex.uv, per_vertex(u), uvs) - vbase[u]
                img = tex.image
                inst_src[i, 4] = block("tex", -1, img, lambda a: rgb0(a.reshape(-1, 3)), texels)
                inst_src[i, 5], inst_src[i, 6] = img.shape[1], img.shape[0]
        inst_src[i, 0] = bits
        colored[i] = vc is not None or fc is not None or tex is not None

    def cat(parts: list[np.ndarray], width: int) -> np.ndarray:
        return (np.ascontiguousarray(np.concatenate(parts), np.float32) if parts
                else np.zeros((1, width), np.float32))

    return ShadeSources(inst_src, cat(cols, 4), cat(uvs, 2), cat(texels, 4), factor, colored)
