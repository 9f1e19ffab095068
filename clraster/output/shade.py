"""Turning a rendered frame into pictures: Lambert shading and depth images.

`shade` colours a frame from its buffers (``triangle_id``, and ``barycentrics`` for smooth
shading, vertex colours and textures), so it applies equally to frames from the OpenCL
renderer and from the NumPy reference. `render_shaded` renders and shades in one call, with
optional supersampled anti-aliasing. Colour sources (vertex colours, textures, per-instance
colours) and their conventions are in `clraster.output.textures`.

Normals. A face's normal is ``normalize((b − a) × (c − a))`` in its mesh's object space
(`Mesh.face_normals`); smooth shading interpolates area-weighted vertex normals
(`vertex_normals`) with the frame's perspective-correct barycentrics. An instance of a
`Scene` maps them to world space with the inverse transpose of its transform's 3×3 part,
``M⁻ᵀ n``, and *no* sign change for a mirroring transform (negative determinant). That is
glTF's rule: a mirroring node flips the winding, so the normal that pointed out of the
object still points out of its mirror image (the world-space winding normal
``(Mb − Ma) × (Mc − Ma) = det(M)·M⁻ᵀ n`` would point in). clraster's culling follows the
same rule (the `Scene` docstring): setup swaps back and front for mirroring instances
(DRAW_MIRRORED) and the normal cones test them for the same side as the others, so with
``cull="back"`` a closed mirrored mesh shows its outside. Lighting is two-sided by default
(``|n · l|``).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from ..base.checks import check_flag
from ..world.inputs import as_target
from ..world.mesh import Mesh
from ..world.scene import Instance, Scene
from .effects import Effects
from .lights import Light
from .surface import blend_rows, dot_rows, mat3_rows, unit_rows
from .textures import (
    Texture,
    as_colors,
    colors_from_trimesh,
    sample_bilinear,
    texture_from_trimesh,
)

__all__ = ["DEFAULT_LIGHT_DIR", "Light", "depth_image", "pixel_normals", "render_shaded", "shade",
           "vertex_normals"]

#: World-space direction *towards* the light used when none is given: up, right, front.
DEFAULT_LIGHT_DIR = (0.35, 0.85, 0.45)
_ALBEDO = np.array([0.80, 0.82, 0.88])  # a light blue-grey
_AMBIENT = 0.22
#: Grey levels of the depth image: nearest covered pixel → 0, farthest → _DEPTH_FAR;
#: background is 255, so it stays distinguishable from the farthest surface.
_DEPTH_FAR = 235
#: Largest supersampling factor of `render_shaded` (k² samples per pixel).
MAX_SSAA = 8


class _FrameLike(Protocol):
    @property
    def triangle_id(self) -> np.ndarray: ...


#: Per-mesh area-weighted vertex normals, computed once per Mesh object (meshes are
#: immutable) and dropped with it.
_VERTEX_NORMALS: weakref.WeakKeyDictionary[Mesh, np.ndarray] = weakref.WeakKeyDictionary()


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """(N, 3) float32 unit vertex normals of `mesh`, read-only, computed once per mesh.

    Each vertex gets the sum of ``(b − a) × (c − a)`` over the faces that use it (so a face
    weighs by its area), normalized: the usual smooth-shading normal, pointing to the side
    from which those faces are counter-clockwise. Zero for unreferenced vertices, vertices
    whose faces cancel, and faces with a non-finite vertex (they contribute nothing).
    """
    cached = _VERTEX_NORMALS.get(mesh)
    if cached is not None:
        return cached
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces
    n_v = mesh.n_vertices
    acc = np.zeros((n_v, 3))
    if f.shape[0]:
        tri = v[f]
        with np.errstate(invalid="ignore", over="ignore"):
            cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        cross[~np.isfinite(cross).all(axis=1)] = 0.0
        # bincount per (corner, axis): vectorized scatter-add, much faster than np.add.at
        for k in range(3):
            for c in range(3):
                acc[:, c] += np.bincount(f[:, k], weights=cross[:, c], minlength=n_v)
    out = _normalize(acc).astype(np.float32)
    out.flags.writeable = False
    _VERTEX_NORMALS[mesh] = out
    return out


def _normalize(n: np.ndarray) -> np.ndarray:
    """Rows of `n` (K, 3) float64 scaled to unit length; zero (or non-finite) rows → 0."""
    length = np.linalg.norm(n, axis=1)
    ok = np.isfinite(length) & (length > 0.0)
    out = np.zeros_like(n)
    out[ok] = n[ok] / length[ok, None]
    return out


# -- targets and their colour sources ------------------------------------------------------

@dataclass(frozen=True)
class _Part:
    """What one instance brings to shading (a Mesh target is one instance)."""

    mesh: Mesh
    vertex_colors: np.ndarray | None  # float64 (N, 3) in [0, 1]
    face_colors: np.ndarray | None  # float64 (M, 3) in [0, 1]
    texture: Texture | None

    @property
    def colored(self) -> bool:
        return (self.vertex_colors is not None or self.face_colors is not None
                or self.texture is not None)


@dataclass(frozen=True)
class _Resolved:
    geometry: Mesh | Scene  # what the frame was (or will be) rendered from
    scene: Scene | None  # None for a Mesh target: ids are its face indices
    parts: list[_Part]  # one per instance
    n_faces: int

    @property
    def plain(self) -> bool:
        """No instance has a colour source."""
        got = self.__dict__.get("_plain")
        if got is None:
            got = not any(p.colored for p in self.parts)
            object.__setattr__(self, "_plain", got)
        return got


def _trimesh_type(obj: Any, name: str) -> bool:
    """`obj` is a ``trimesh.<name>`` (without importing trimesh for other objects)."""
    if not type(obj).__module__.startswith("trimesh"):
        return False
    import trimesh

    return isinstance(obj, getattr(trimesh, name))


def _is_texture_spec(value: Any) -> bool:
    return isinstance(value, (Texture, tuple))


def _texture(value: Any, mesh: Mesh, what: str) -> Texture | None:
    if value is None or value is False or value is True:
        return None
    if isinstance(value, Texture):
        if value.uv is not None and value.uv.shape[0] != mesh.n_vertices:
            raise ValueError(f"{what}: uv has {value.uv.shape[0]} rows, the mesh "
                             f"{mesh.n_vertices} vertices")
        return value
    if isinstance(value, tuple) and len(value) in (2, 3):
        try:
            return Texture.make(*value, n_vertices=mesh.n_vertices)
        except ValueError as exc:
            raise ValueError(f"{what}: {exc}") from None
    raise ValueError(f"{what} must be True, False, a (uv, image) or (uv, image, factor) "
                     f"tuple or a clraster.output.textures.Texture, got {type(value).__name__}")


def _per_instance(value: Any, n: int, shared: bool, name: str, single: Callable[[Any], bool]
                  ) -> list[Any]:
    """A scene option as one entry per instance: a list gives them, one value is used for
    every instance when they all share one mesh."""
    if isinstance(value, list):
        if len(value) != n:
            raise ValueError(f"{name}: a list gives one entry per instance; got {len(value)} "
                             f"for {n} instances")
        return value
    if value is None or value is False or value is True or not single(value):
        return [value] * n
    if not shared:
        raise ValueError(f"{name}: one value for a scene whose instances use different "
                         f"meshes is ambiguous; give a list with one entry (or None) per "
                         f"instance")
    return [value] * n


#: The plain parts of clraster Scenes (no colour option given): (version, parts), per scene.
_PLAIN_PARTS: weakref.WeakKeyDictionary[Scene, tuple[int, list[_Part]]] = (
    weakref.WeakKeyDictionary())


def _resolve(target: Any, colors: Any, texture: Any) -> _Resolved:
    if (isinstance(target, Scene) and (colors is None or colors is False)
            and (texture is None or isinstance(texture, bool))):
        # nothing to validate per instance (a clraster Scene has no colours of its own):
        # the parts depend on the scene alone, kept per version (a frame of the 10M plant's
        # 5,349 instances spent ~20 ms here, more than its shading)
        kept = _PLAIN_PARTS.get(target)
        if kept is None or kept[0] != target.version:
            kept = (target.version, [_Part(inst.mesh, None, None, None)
                                     for inst in target.instances])
            _PLAIN_PARTS[target] = kept
        res = _Resolved(target, target, kept[1], target.n_faces)
        object.__setattr__(res, "_plain", True)
        return res
    # trimesh geometry per instance, whose own colours and texture apply unless the
    # options say otherwise (None for clraster targets)
    sources: list[Any] = []
    if _trimesh_type(target, "Trimesh") or _trimesh_type(target, "Scene"):
        geometry = as_target(target)   # the renderers' conversion (cached): ids match
        if isinstance(geometry, Mesh):
            sources = [target]
        else:
            names = getattr(geometry, "geometry_names", (None,) * geometry.n_instances)
            sources = [None if name is None else target.geometry.get(name) for name in names]
    elif isinstance(target, (Mesh, Scene)):
        geometry = target
    else:
        raise ValueError(f"expected a clraster.Mesh or clraster.Scene (or a trimesh.Trimesh "
                         f"or trimesh.Scene) target, got {type(target).__name__}")
    if isinstance(geometry, Mesh):
        meshes = [geometry]
        col_specs: list[Any] = [colors]
        tex_specs: list[Any] = [texture]
    else:
        meshes = [inst.mesh for inst in geometry.instances]
        n = len(meshes)
        shared = len({id(m) for m in meshes}) <= 1
        col_specs = _per_instance(colors, n, shared, "colors", lambda v: not isinstance(v, bool))
        tex_specs = _per_instance(texture, n, shared, "texture", _is_texture_spec)
    many = isinstance(geometry, Scene)
    # validate an entry shared by many instances once per mesh (or trimesh geometry)
    col_cache: dict[tuple[int, int], tuple[np.ndarray | None, np.ndarray | None]] = {}
    tex_cache: dict[tuple[int, int], Texture | None] = {}
    parts: list[_Part] = []
    for i, m in enumerate(meshes):
        src = sources[i] if sources else None
        spec = col_specs[i]
        key = (id(m), id(spec) if spec is not None or src is None else id(src))
        if key not in col_cache:
            vc = fc = None
            if spec is None and src is not None:
                auto = colors_from_trimesh(src)
                if auto is not None:
                    vc, fc = (auto[1], None) if auto[0] == "vertex" else (None, auto[1])
            elif spec is not None and spec is not False:
                vc = as_colors(spec, m.n_vertices, f"colors[{i}]" if many else "colors")
            col_cache[key] = (vc, fc)
        vc, fc = col_cache[key]
        spec = tex_specs[i]
        key = (id(m), id(spec) if spec is not True or src is None else id(src))
        if key not in tex_cache:
            tex_cache[key] = (texture_from_trimesh(src) if spec is True and src is not None
                              else _texture(spec, m, f"texture[{i}]" if many else "texture"))
        parts.append(_Part(m, vc, fc, tex_cache[key]))
    scene = geometry if isinstance(geometry, Scene) else None
    return _Resolved(geometry, scene, parts, geometry.n_faces)


def _ids(frame: _FrameLike, n_faces: int) -> np.ndarray:
    ids = np.asarray(frame.triangle_id)
    if ids.ndim != 2 or ids.dtype.kind not in "iu":
        raise ValueError(f"frame.triangle_id must be an (H, W) integer array, got shape "
                         f"{ids.shape} dtype {ids.dtype}")
    if ids.size and (int(ids.min()) < -1 or int(ids.max()) >= n_faces):
        raise ValueError(f"frame.triangle_id holds ids outside [-1, {n_faces}) "
                         f"(range {int(ids.min())}..{int(ids.max())}): was the frame "
                         f"rendered from this mesh?")
    return ids


def _light(light_dir: npt.ArrayLike | None, light: npt.ArrayLike | None) -> np.ndarray:
    if light_dir is not None and light is not None:
        raise ValueError("give the light direction once: light= or light_dir=, not both")
    given = light if light is not None else light_dir
    out = np.asarray(DEFAULT_LIGHT_DIR if given is None else given, dtype=np.float64)
    if out.shape != (3,) or not np.all(np.isfinite(out)) or not np.any(out):
        raise ValueError(f"light_dir must be a finite, non-zero 3-vector, got {out.tolist()}")
    return out / np.linalg.norm(out)


def _background(background: Any) -> np.ndarray:
    bg = np.asarray(background)
    if bg.shape != (3,) or bg.dtype.kind not in "iu" or np.any((bg < 0) | (bg > 255)):
        raise ValueError(f"background must be three integers in 0..255 (R, G, B), "
                         f"got {background!r}")
    return bg


# -- the per-pixel work --------------------------------------------------------------------

@dataclass
class _Pixels:
    """The covered pixels of a frame, in row-major order (K of them)."""

    covered: np.ndarray  # bool (H, W)
    inst: np.ndarray  # int64 (K,)
    face: np.ndarray  # int64 (K,)
    bary: np.ndarray | None  # float64 (K, 3), when asked for
    groups: list[tuple[int, np.ndarray]]  # (part index, pixel indices) per visible part


def _pixels(frame: _FrameLike, res: _Resolved, need_bary: bool) -> _Pixels:
    ids = _ids(frame, res.n_faces)
    covered = ids >= 0
    flat = ids[covered].astype(np.int64)
    if res.scene is None:
        inst = np.zeros(flat.shape, np.int64)
        face = flat
    else:
        i32, f32 = res.scene.split_ids(flat)
        inst, face = i32.astype(np.int64), f32.astype(np.int64)
    bary = None
    if need_bary:
        b = getattr(frame, "barycentrics", None)
        if b is None:
            raise ValueError("smooth shading, vertex colours and textures need the frame's "
                             "barycentrics ((H, W, 3) float, e.g. a clraster.Frame)")
        b = np.asarray(b)
        if b.shape != ids.shape + (3,):
            raise ValueError(f"frame.barycentrics must have shape {ids.shape + (3,)}, got "
                             f"{b.shape}")
        bary = b[covered].astype(np.float64)
    if res.scene is None:  # one instance: no sort
        groups = [(0, np.arange(flat.size))] if flat.size else []
        return _Pixels(covered, inst, face, bary, groups)
    # group the pixels by instance with one stable sort (never one mask per instance)
    order = np.argsort(inst, kind="stable")
    present, starts = np.unique(inst[order], return_index=True)
    ends = np.append(starts[1:], order.size)
    groups = [(int(i), order[s:e]) for i, s, e in zip(present, starts, ends, strict=True)]
    return _Pixels(covered, inst, face, bary, groups)


def _normal_matrices(scene: Scene) -> np.ndarray:
    """float64 (I, 3, 3): M⁻ᵀ of each instance's 3×3 part (normals to world space; no sign
    change for mirroring transforms, see the module docstring)."""
    t = scene.transforms()
    if t.shape[0] == 0:
        return np.zeros((0, 3, 3))
    return np.transpose(np.linalg.inv(t[:, :3, :3]), (0, 2, 1))


def _world_normals(res: _Resolved, px: _Pixels, smooth: bool) -> np.ndarray:
    """float64 (K, 3) unit world-space normals of the covered pixels (zero for degenerate
    faces), rounded to float32 values: ``normalize(M⁻ᵀ n)`` of the float32 face normal or
    the blended vertex normals, in the order of kernels/resolve.cl
    (`clraster.output.surface`), so a frame's device-made normals are these bits."""
    n = np.zeros((px.face.size, 3))
    for i, sel in px.groups:
        mesh = res.parts[i].mesh
        fn = mesh.face_normals()[px.face[sel]].astype(np.float64)
        if smooth:
            assert px.bary is not None
            tri = mesh.faces[px.face[sel]]
            vn = vertex_normals(mesh)[tri].astype(np.float64)
            sn = blend_rows(px.bary[sel], vn[:, 0], vn[:, 1], vn[:, 2])
            # vertex normals that cancel (a fold, a crease of opposite windings) give no
            # direction: keep the face's own there
            weak = ~(np.sqrt(dot_rows(sn, sn)) >= 1e-6)
            sn[weak] = fn[weak]
            fn = sn
        n[sel] = fn
    if res.scene is not None:
        n = mat3_rows(_normal_matrices(res.scene).reshape(-1, 9)[px.inst], n)
    return unit_rows(n).astype(np.float32).astype(np.float64)


def _base_colors(res: _Resolved, px: _Pixels, per_instance_colors: Any) -> np.ndarray:
    """float64 (K, 3): the surface colour of each covered pixel before lighting."""
    k = px.face.size
    base = np.ones((k, 3))
    has = np.zeros(k, bool)
    for i, sel in px.groups:
        part = res.parts[i]
        if not part.colored:
            continue
        has[sel] = True
        face = px.face[sel]
        if part.face_colors is not None:
            base[sel] *= part.face_colors[face]
        if part.vertex_colors is not None or (part.texture is not None
                                              and part.texture.image is not None):
            assert px.bary is not None
            tri = part.mesh.faces[face]
            b = px.bary[sel]
            if part.vertex_colors is not None:
                base[sel] *= np.einsum("kj,kjc->kc", b, part.vertex_colors[tri])
            if part.texture is not None and part.texture.image is not None:
                assert part.texture.uv is not None
                uv = np.einsum("kj,kjc->kc", b, part.texture.uv[tri])
                base[sel] *= sample_bilinear(part.texture.image, uv)
        if part.texture is not None:
            base[sel] *= part.texture.factor
    if per_instance_colors is not None:
        base *= _instance_tints(res, px, per_instance_colors)[px.inst]
        has[:] = True
    base[~has] = _ALBEDO
    return base


def _instance_tints(res: _Resolved, px: _Pixels, spec: Any) -> np.ndarray:
    """float64 (I, 3) from an (I, 3|4) array or a callable ``f(index, instance)`` (called
    for the instances seen in the frame only)."""
    n = len(res.parts)
    if callable(spec):
        tints = np.ones((n, 3))
        for i, _ in px.groups:
            inst = (res.scene.instances[i] if res.scene is not None
                    else Instance(res.parts[0].mesh, np.eye(4)))
            tints[i] = as_colors(np.asarray(spec(i, inst)).reshape(1, -1), 1,
                                 f"per_instance_colors({i}, ...)")[0]
        return tints
    return as_colors(spec, n, "per_instance_colors")


def _shade_covered(frame: _FrameLike, res: _Resolved, *, smooth: bool,
                   per_instance_colors: Any, light: np.ndarray, two_sided: bool
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(covered (H, W) bool, rgb float64 (K, 3)) for the covered pixels, row-major."""
    need_bary = smooth or any(p.vertex_colors is not None or (
        p.texture is not None and p.texture.image is not None) for p in res.parts)
    px = _pixels(frame, res, need_bary)
    if not smooth and res.scene is None:
        # flat, one mesh: Lambert per face, then gathered (the image is the same as it was
        # before smooth shading and scenes existed, bit for bit)
        mesh = res.parts[0].mesh
        lam = (mesh.face_normals().astype(np.float64) @ light)[px.face]
    else:
        lam = _world_normals(res, px, smooth) @ light
    lam = np.abs(lam) if two_sided else np.maximum(lam, 0.0)
    base = _base_colors(res, px, per_instance_colors)
    return px.covered, base * (_AMBIENT + (1.0 - _AMBIENT) * lam[:, None])


class _Same:
    """A key equal to another holding the very same objects (kept alive by it, so their
    identities cannot pass to new objects while it is compared)."""

    __slots__ = ("objs",)

    def __init__(self, objs: tuple[Any, ...]) -> None:
        self.objs = objs

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, _Same) and len(other.objs) == len(self.objs)
                and all(a is b for a, b in zip(self.objs, other.objs, strict=True)))

    __hash__ = None  # type: ignore[assignment]


def _shade_on_device(frame: _FrameLike, res: _Resolved, k: int, *, smooth: bool,
                     per_instance_colors: Any, light: np.ndarray, two_sided: bool,
                     background: np.ndarray, alpha: bool) -> np.ndarray | None:
    """`_compose`'s image made on the device of the OpenCL renderer that rendered ``frame``
    (``frame.source``; kernels/shade.cl shade_pixels, shade_ssaa; this module's NumPy
    path is its twin, equal within 1/255), or None where the host path shades: a frame from
    the twin or without a renderer, or one without the barycentrics its shading needs (the
    host path then says so). Ids out of range raise as on the host."""
    src = getattr(frame, "source", None)
    renderer = src() if src is not None else None
    if renderer is None or not hasattr(renderer, "shade_frame"):
        return None
    ids = np.asarray(frame.triangle_id)
    if ids.ndim != 2 or ids.dtype.kind not in "iu":
        return None   # the host path's error
    parts = res.parts
    textured = not res.plain and any(
        p.vertex_colors is not None or (p.texture is not None and p.texture.image is not None)
        for p in parts)
    if (smooth or textured) and getattr(frame, "barycentrics", None) is None:
        return None
    n = len(parts)
    max_id = res.n_faces - 1
    tints = None
    if callable(per_instance_colors):
        seen = renderer.seen_instances(frame, res.geometry, max_id)
        if seen is None:
            _ids(frame, res.n_faces)   # raises: ids out of range
            return None
        tints = np.ones((n, 3))
        for i in np.flatnonzero(seen):
            inst = (res.scene.instances[i] if res.scene is not None
                    else Instance(parts[0].mesh, np.eye(4)))
            tints[i] = as_colors(np.asarray(per_instance_colors(int(i), inst)).reshape(1, -1),
                                 1, f"per_instance_colors({i}, ...)")[0]
    elif per_instance_colors is not None:
        tints = as_colors(per_instance_colors, n, "per_instance_colors")
    inst_col = np.zeros((n, 4), np.float32)
    sources: list[tuple[Any, Any, Any]] | None = None
    key = None
    if res.plain:
        inst_col[:, :3] = _ALBEDO if tints is None else tints
    else:
        colored = np.fromiter((p.colored for p in parts), bool, n)
        factor = np.ones((n, 3))
        for j, p in enumerate(parts):
            if p.texture is not None:
                factor[j] = p.texture.factor
        base = factor * (tints if tints is not None else 1.0)
        if tints is None:
            base[~colored] = _ALBEDO
        inst_col[:, :3] = base
        key = _Same(tuple(x for p in parts
                          for x in (p.mesh, p.vertex_colors, p.face_colors, p.texture)))
        sources = [(p.vertex_colors, p.face_colors, p.texture) for p in parts]

    img = renderer.shade_frame(frame, res.geometry, smooth=smooth, light=light,
                               ambient=_AMBIENT, two_sided=two_sided, inst_col=inst_col,
                               sources=sources, sources_key=key,
                               identity=res.scene is None, max_id=max_id,
                               background=background, alpha=alpha, k=k)
    if img is None:
        _ids(frame, res.n_faces)   # raises: ids out of range
    return img


def _to_u8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)


# -- public API ----------------------------------------------------------------------------

def shade(frame: _FrameLike, target: Any, *, smooth: bool = False, colors: Any = None,
          texture: Any = True, per_instance_colors: Any = None,
          background: tuple[int, int, int] = (255, 255, 255), alpha: bool = False,
          light_dir: npt.ArrayLike | None = None, light: npt.ArrayLike | None = None,
          two_sided: bool = True) -> np.ndarray:
    """Lambert-shaded image of `frame`: (H, W, 3) uint8 RGB (or (H, W, 4) RGBA), row 0 on top.

    Each covered pixel gets ``albedo · (ambient + (1 − ambient) · |n · l|)``, with ``l`` the
    unit light direction and ``n`` the pixel's unit world-space normal: its face's normal
    (flat, the default) or the interpolated vertex normals (``smooth=True``); see the module
    docstring for normals of scene instances and mirroring transforms. Lighting is two-sided
    (``|n · l|``) unless ``two_sided=False`` (``max(n · l, 0)``), so open meshes and
    inconsistently wound faces look right with culling off. Faces with a zero normal
    (degenerate) get ambient only. Pixels with ``triangle_id == −1`` get `background`.

    The albedo is the product of the colour sources that apply to the pixel — vertex colours
    interpolated with the barycentrics, the texture sampled at the interpolated UVs times its
    factor, face colours (trimesh), the instance's colour — or a light blue-grey where none
    does. Colours are linear blends of the numbers given (no sRGB decoding); see
    `clraster.output.textures` for the UV convention (v up, texel centres, repeat wrapping,
    bilinear).

    Args:
        frame: anything with ``triangle_id``, an (H, W) integer array of triangle ids (−1 =
            background), and, for smooth shading, vertex colours and textures,
            ``barycentrics`` (H, W, 3), e.g. a :class:`clraster.Frame`.
        target: what the frame was rendered from: a `Mesh` (ids = face indices), a `Scene`
            (ids mapped by `Scene.split_ids`), or a ``trimesh.Trimesh`` (rendered as
            ``Mesh.from_trimesh``; its vertex or face colours and its base-colour texture
            are used unless `colors` / `texture` say otherwise).
        smooth: interpolate area-weighted vertex normals (`vertex_normals`) instead of
            using face normals.
        colors: per-vertex colours, (N, 3|4) uint8 0..255 or float 0..1 (alpha ignored);
            None: a trimesh target's own; False: none. For a `Scene`: a list with one entry
            (array or None) per instance, or one array when all instances share one mesh.
        texture: True (a trimesh target's own base-colour texture, if any), False (none),
            ``(uv (N, 2), image (H, W, 3|4))`` or ``(uv, image, factor)``, or a
            `clraster.output.textures.Texture` (e.g. from
            `clraster.output.textures.texture_from_trimesh`).
            For a `Scene`: a list with one entry per instance, or one texture when all
            instances share one mesh.
        per_instance_colors: a colour per instance: an (I, 3|4) array (uint8 or float, as
            `colors`), or a callable ``f(index, instance) -> RGB`` called once for each
            instance seen in the frame. A `Mesh` target is one instance (index 0).
        background: RGB 0..255 for uncovered pixels.
        alpha: return RGBA, alpha 255 on covered pixels and 0 on the background.
        light_dir, light: world-space direction towards the light, (3,), any non-zero
            length (two names for one option; give at most one); default
            :data:`DEFAULT_LIGHT_DIR`.
        two_sided: ``|n · l|`` (default) or ``max(n · l, 0)``.

    Raises:
        ValueError: ids out of range for `target`, a zero or non-finite light direction, a
            background that is not three values in 0..255, colours or textures of the wrong
            shape or range, or missing barycentrics where they are needed.
    """
    return _compose(frame, _resolve(target, colors, texture), 1, smooth=smooth,
                    per_instance_colors=per_instance_colors, background=background,
                    alpha=alpha, light=_light(light_dir, light), two_sided=two_sided)


def _compose(frame: _FrameLike, res: _Resolved, k: int, *, smooth: bool,
             per_instance_colors: Any, background: Any, alpha: bool, light: np.ndarray,
             two_sided: bool) -> np.ndarray:
    """The output image of a frame k× the output size in each axis (k = 1: `shade`)."""
    bg = _background(background)
    img = _shade_on_device(frame, res, k, smooth=smooth, per_instance_colors=per_instance_colors,
                           light=light, two_sided=two_sided, background=bg, alpha=alpha)
    if img is not None:
        return img
    covered, rgb = _shade_covered(frame, res, smooth=smooth,
                                  per_instance_colors=per_instance_colors, light=light,
                                  two_sided=two_sided)
    if k == 1:
        # quantize the covered pixels only and write the background as given
        h, w = covered.shape
        out = np.empty((h, w, 4 if alpha else 3), np.uint8)
        out[..., :3] = bg
        out[covered, :3] = _to_u8(rgb)
        if alpha:
            out[..., 3] = np.where(covered, 255, 0)
        return out
    h, w = covered.shape[0] // k, covered.shape[1] // k
    img = np.empty((k * h, k * w, 3))
    img[...] = bg / 255.0
    img[covered] = rgb
    if not alpha:
        return _to_u8(img.reshape(h, k, w, k, 3).mean(axis=(1, 3)))
    # average the colour over the covered samples only (straight alpha): a half-covered
    # pixel keeps the surface's colour at half alpha, not a blend with the background
    cov = covered.astype(np.float64)
    prem = (img * cov[..., None]).reshape(h, k, w, k, 3).sum(axis=(1, 3))
    cnt = cov.reshape(h, k, w, k).sum(axis=(1, 3))
    color = np.where(cnt[..., None] > 0, prem / np.maximum(cnt, 1.0)[..., None], bg / 255.0)
    out = np.empty((h, w, 4), np.uint8)
    out[..., :3] = _to_u8(color)
    out[..., 3] = _to_u8(cnt / (k * k))
    return out


def pixel_normals(frame: _FrameLike, target: Any, *, smooth: bool = False) -> np.ndarray:
    """(H, W, 3) float32 unit world-space normals of the frame's visible surface; zeros on
    the background and on degenerate faces.

    The normals `shade` lights with (module docstring): face normals, or with ``smooth``
    the interpolated area-weighted vertex normals; through ``M⁻ᵀ`` for scene instances,
    outward also for mirroring transforms. `target` as in `shade`.
    """
    res = _resolve(target, False, False)
    px = _pixels(frame, res, smooth)
    out = np.zeros(px.covered.shape + (3,), np.float32)
    out[px.covered] = _world_normals(res, px, smooth)
    return out


class _FixedViewCamera:
    """A camera that gives one view-projection whatever the image size: the user camera's
    matrix for the output size, used at k× that size (NDC does not depend on pixels)."""

    def __init__(self, matrix: np.ndarray) -> None:
        self.matrix = matrix

    def view_projection(self, width: int, height: int) -> np.ndarray:
        return self.matrix


def _scaled_window(window: Any, k: int) -> Any:
    """`window` (any `clraster.clip2d.as_polygon` form, in output pixels) in the pixels of
    the k× frame: every vertex times k, so the k × k samples of an output pixel are inside
    it exactly where their positions, in output pixels, are inside the window given."""
    from ..clip.clip2d import Polygon2D, as_polygon
    from ..clip.window import WINDOW_MAX_COORD

    what = "render_kwargs['window']"
    try:
        poly = as_polygon(window)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None
    limit = WINDOW_MAX_COORD / k
    if max(float(np.abs(r).max()) for r in poly.rings) > limit:
        raise ValueError(f"{what}: with ssaa={k} the window is drawn at {k}x its pixel "
                         f"coordinates, which must then lie within ±{WINDOW_MAX_COORD:.0f}; "
                         f"keep the window's coordinates within ±{limit:g} output pixels "
                         f"(clip it to the image) or lower ssaa")
    # a uniform positive scale keeps the rings simple, oriented and nested as as_polygon
    # checked them: no need to validate them again (O(n²) per ring)
    return Polygon2D._trusted(poly.exterior * k, [h * k for h in poly.holes])


#: ``render`` keywords given in output pixels, and how `render_shaded` scales each by k for
#: the k× frame. `Renderer.render` has one (the window polygon); the others are not in
#: pixels and pass as given: clip_planes are world-space planes, the rest flags and names.
_PIXEL_RENDER_KWARGS: dict[str, Callable[[Any, int], Any]] = {"window": _scaled_window}


def _scaled_render_kwargs(render_kwargs: dict[str, Any] | None, k: int) -> dict[str, Any]:
    """A copy of `render_kwargs` for the k× frame: the pixel-space ones
    (`_PIXEL_RENDER_KWARGS`) scaled by k, the others as given (the caller's dict untouched)."""
    out = dict(render_kwargs or {})
    if k > 1:
        for name, scale in _PIXEL_RENDER_KWARGS.items():
            if out.get(name) is not None:
                out[name] = scale(out[name], k)
    return out


#: Supersampling renderers made by `render_shaded`, per user renderer and size.
_SCALED: weakref.WeakKeyDictionary[Any, dict[tuple[int, int], Any]] = (
    weakref.WeakKeyDictionary())


def _scaled_renderer(renderer: Any, width: int, height: int) -> Any:
    try:
        per = _SCALED.setdefault(renderer, {})
    except TypeError:  # not weakly referenceable: no cache
        per = {}
    made = per.get((width, height))
    if made is None:
        kwargs: dict[str, Any] = {}
        if getattr(renderer, "config", None) is not None:
            kwargs["config"] = renderer.config
        if getattr(renderer, "context", None) is not None:
            kwargs["context"] = renderer.context
        made = per[(width, height)] = type(renderer)(width, height, **kwargs)
    return made


def render_shaded(renderer: Any, target: Any, camera: Any, *, ssaa: int = 1,
                  width: int | None = None, height: int | None = None,
                  render_kwargs: dict[str, Any] | None = None, smooth: bool = False,
                  colors: Any = None, texture: Any = True, per_instance_colors: Any = None,
                  background: tuple[int, int, int] = (255, 255, 255), alpha: bool = False,
                  light_dir: npt.ArrayLike | None = None, light: npt.ArrayLike | None = None,
                  two_sided: bool = True, lights: Any = None, shadows: bool = False,
                  ssao: Any = False, aa: str | None = None, style: str = "lambert",
                  outlines: Any = False, normal_map: Any = True, return_layers: bool = False
                  ) -> Any:
    """Render `target` and shade it, optionally with supersampled anti-aliasing.

    With ``ssaa = k > 1`` the frame is rendered at k·width × k·height with the *same* view
    (the camera's view-projection for width × height, so a camera whose matrix depends on
    the pixel count, like an intrinsics camera, keeps its view), shaded in floating point
    and box-filtered down: each output pixel is the mean of its k × k samples, so edges get
    intermediate colours between the surface and the background; with ``alpha=True`` they
    get partial alpha instead, the colour being averaged over the covered samples only
    (straight, not premultiplied, RGBA). ``ssaa=1`` gives exactly `shade`'s image.

    Args:
        renderer: a renderer (anything with ``width``, ``height`` and ``render(target,
            camera, **kw)``, e.g. :class:`clraster.Renderer` or
            ``clraster.reference.Renderer``; for ``ssaa > 1`` a second one of the same type
            is made at k× size with the same ``config`` (and OpenCL context), cached per
            renderer and size), or a factory ``f(width, height) -> renderer`` (then give
            `width` and `height`).
        target: a `Mesh`, `Scene` or ``trimesh.Trimesh`` (converted once, used for both
            rendering and shading).
        camera: the camera, e.g. :class:`clraster.Camera`.
        ssaa: samples per pixel along each axis, 1..`MAX_SSAA`.
        width, height: output size; default the renderer's.
        render_kwargs: keywords for ``renderer.render`` (cull, occlusion, window, ...), in
            the terms of the width × height output: a ``window`` polygon is in output
            pixels and is scaled by k for the k× frame, so every ssaa draws the same
            region, its edge pixels blended (anti-aliased like the mesh's); world-space
            ``clip_planes`` and the flags pass as given. The dict is not modified.
        smooth, colors, texture, per_instance_colors, background, alpha, light_dir, light,
            two_sided: as in `shade`.
        lights: a `clraster.output.lights.Light` or a list of them (directional, spot)
            instead of the one light of `light_dir`; `clraster.output.effects` gives the
            lighting sum.
        shadows: shadow maps for every light (a depth pass each through a renderer of the
            same type; `clraster.output.lights`).
        ssao: screen-space ambient occlusion: True (radius 3% of the target's bounding
            diagonal), a radius in world units, or a `clraster.output.post.SSAO`.
        aa: ``"fxaa"`` (FXAA 3.11 on the output image, after any ssaa) or None.
        style: ``"lambert"`` or ``"cel"`` (each light's term in bands).
        outlines: True or a `clraster.output.post.Outlines`: depth and normal
            discontinuities and silhouettes drawn in a colour.
        normal_map: True (a trimesh target's own glTF ``normalTexture``), False, or a
            `clraster.output.textures.NormalMap` (a list: one per instance).
        return_layers: also return a `clraster.output.effects.ShadeLayers` (lit fraction
            per light, ambient occlusion, normals).

    Returns:
        (height, width, 3) uint8 RGB, or (height, width, 4) RGBA with ``alpha=True``;
        with ``return_layers=True`` the pair (image, layers).

    Raises:
        ValueError: `ssaa` not an integer in 1..`MAX_SSAA`, no size for a factory, a
            supersampled size beyond the renderer's limit, a ``window`` that is not a valid
            polygon or whose coordinates times k exceed
            `clraster.window.WINDOW_MAX_COORD`, and `shade`'s errors.
    """
    if isinstance(ssaa, bool) or not isinstance(ssaa, (int, np.integer)) or not (
            1 <= ssaa <= MAX_SSAA):
        raise ValueError(f"ssaa must be an integer in 1..{MAX_SSAA} (samples per pixel along "
                         f"each axis), got {ssaa!r}")
    k = int(ssaa)
    light_vec = _light(light_dir, light)
    _background(background)  # refuse a bad option before rendering
    is_renderer = hasattr(renderer, "render")
    if not is_renderer and not callable(renderer):
        raise ValueError(f"renderer must be a renderer (with .render) or a factory "
                         f"f(width, height), got {type(renderer).__name__}")
    if is_renderer:
        w = int(renderer.width if width is None else width)
        h = int(renderer.height if height is None else height)
    elif width is None or height is None:
        raise ValueError("with a renderer factory, give width and height")
    else:
        w, h = int(width), int(height)
    kwargs = _scaled_render_kwargs(render_kwargs, k)   # refuse a bad window before rendering
    res = _resolve(target, colors, texture)
    if is_renderer and (renderer.width, renderer.height) == (k * w, k * h):
        r = renderer
    elif is_renderer:
        r = _scaled_renderer(renderer, k * w, k * h)
    else:
        r = renderer(k * w, k * h)
    cam = camera
    if k > 1:
        vp = np.asarray(camera.view_projection(w, h), np.float64)
        if not np.array_equal(vp, np.asarray(camera.view_projection(k * w, k * h))):
            cam = _FixedViewCamera(vp)
    fx = Effects.make(lights=lights, shadows=shadows, ssao=ssao, aa=aa, style=style,
                      outlines=outlines, normal_map=normal_map, return_layers=return_layers)
    frame = r.render(res.geometry, cam, **kwargs)
    if not fx.active(target):
        return _compose(frame, res, k, smooth=smooth, per_instance_colors=per_instance_colors,
                        background=background, alpha=alpha, light=light_vec,
                        two_sided=two_sided)
    # the effects (clraster.output.effects) take over from the surface colour and normals
    px = _pixels(frame, res, frame.barycentrics is not None)
    return fx.finish(renderer=r, frame=frame, target=target,
                     vp=np.asarray(cam.view_projection(k * w, k * h), np.float64),
                     covered=px.covered, inst=px.inst, face=px.face, bary=px.bary,
                     base=_base_colors(res, px, per_instance_colors),
                     normals=_world_normals(res, px, smooth), k=k,
                     background=_background(background), alpha=alpha, ambient=_AMBIENT,
                     light_towards=light_vec, two_sided=two_sided,
                     render_kwargs=render_kwargs)


def _depth_buffer(depth: Any, reversed_z: Any, what: str = "depth"
                  ) -> tuple[np.ndarray, bool]:
    """(float64 (H, W) depth buffer, whether it is reversed-Z) from a frame or an array.

    A frame (anything with ``depth`` that is not an array, e.g. a `clraster.Frame`) says
    its own convention by its ``reversed_z``; `reversed_z` may repeat it but never
    contradict it (raises ValueError). A bare array has none: `reversed_z` says it, None
    meaning standard window depth (``(z/w + 1)/2``, the renderers' default).
    """
    if reversed_z is not None:
        reversed_z = check_flag(reversed_z, "reversed_z")
    buf = depth
    if not isinstance(depth, np.ndarray) and hasattr(depth, "depth"):
        buf = depth.depth
        own = getattr(depth, "reversed_z", None)
        if own is not None:
            own = bool(own)
            if reversed_z is not None and reversed_z != own:
                raise ValueError(
                    f"reversed_z={reversed_z} contradicts the frame, which was rendered "
                    f"{'with' if own else 'without'} reversed-Z (frame.reversed_z={own}); "
                    f"leave reversed_z out when passing a frame")
            reversed_z = own
    try:
        d = np.asarray(buf, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be an (H, W) array of window depths or a frame with "
                         f"a depth buffer (e.g. a clraster.Frame), got "
                         f"{type(depth).__name__}") from None
    if d.ndim != 2:
        raise ValueError(f"{what} must be an (H, W) array, got shape {d.shape}")
    return d, bool(reversed_z)


def depth_image(depth: Any, *, reversed_z: bool | None = None) -> np.ndarray:
    """Greyscale view of a depth buffer: (H, W) uint8, near = dark, background white.

    Covered pixels are mapped linearly from the nearest (0) to the farthest covered depth
    (235); background pixels are 255. When all covered pixels share one depth they are 0;
    an all-background buffer is all 255. Non-finite depths count as background. The picture
    is the same for a frame rendered with reversed-Z as for the same frame rendered with
    standard depth (up to float32 rounding, at most one grey level).

    Args:
        depth: a frame (`clraster.Frame`, or anything with ``depth`` and ``reversed_z``):
            its depth buffer is read by its own convention. Or a bare (H, W) array of
            depths, whose convention `reversed_z` gives.
        reversed_z: the convention of a bare array: False or None (the default) for
            standard window depth ``(z/w + 1)/2`` in [0, 1], covered where ``< 1.0`` (the
            buffer is cleared to 1.0); True for reversed-Z ``(1 − z/w)/2``, 1 at the near
            plane, covered where ``> 0.0`` (cleared to 0.0). With a frame, leave it out (or
            give the frame's own value).

    Raises:
        ValueError: not an (H, W) buffer, `reversed_z` not True/False/None, or `reversed_z`
            contradicting the frame's ``reversed_z``.
    """
    d, rev = _depth_buffer(depth, reversed_z)
    finite = np.isfinite(d)
    # reversed-Z: larger is nearer; negate so that "nearest" is the minimum in both
    covered = finite & (d > 0.0) if rev else finite & (d < 1.0)
    out = np.full(d.shape, 255, dtype=np.uint8)
    if covered.any():
        vals = -d[covered] if rev else d[covered]
        lo, hi = vals.min(), vals.max()
        scale = _DEPTH_FAR / (hi - lo) if hi > lo else 0.0
        out[covered] = np.clip(np.rint((vals - lo) * scale), 0, _DEPTH_FAR).astype(np.uint8)
    return out
