"""Surface colour for shading: vertex colours, base-colour textures and their sampling.

Used by `clraster.shade`; plain NumPy, no OpenCL. Conventions (the ones glTF files give
once trimesh has loaded them, and OBJ files give as written):

* **UV** ``(u, v)``: float, ``u`` to the right, ``v`` *up*: ``v = 0`` is the bottom row of
  the image, ``v = 1`` its top (trimesh flips glTF's v-down coordinates to this on load).
  Texel ``(row r, column c)`` of an (H, W) image has its centre at
  ``u = (c + 0.5)/W``, ``v = 1 − (r + 0.5)/H`` (OpenGL's texel centres). Wrapping is
  *repeat* (glTF's default sampler): ``u`` and ``u + 1`` sample the same colour.
* **Filtering** is bilinear between the four nearest texel centres (no mipmaps: for
  minified textures use `clraster.shade.render_shaded` with ``ssaa``).
* **Colours** are RGB(A) in display space (the numbers in the file, no sRGB decoding);
  uint8 arrays mean 0..255, float arrays 0..1. Alpha is read and ignored: shading is
  opaque (glTF ``alphaMode: OPAQUE``), the output alpha is coverage only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    import trimesh

__all__ = ["NormalMap", "Texture", "as_colors", "colors_from_trimesh", "normal_map_from_trimesh",
           "perturb_normals", "sample_bilinear", "texture_from_trimesh", "vertex_tangents"]


def as_colors(value: npt.ArrayLike, rows: int, name: str) -> np.ndarray:
    """`value` as float64 (rows, 3) RGB in [0, 1].

    Accepts (rows, 3) or (rows, 4) (alpha dropped); an integer array is 0..255, a float
    array 0..1.

    Raises:
        ValueError: wrong shape, a non-numeric dtype, or values outside the range.
    """
    arr = np.asarray(value)
    if arr.ndim != 2 or arr.shape[0] != rows or arr.shape[1] not in (3, 4):
        raise ValueError(f"{name} must have shape ({rows}, 3) or ({rows}, 4) (RGB or RGBA per "
                         f"row), got shape {arr.shape}")
    if arr.dtype.kind in "iu":
        if arr.size and (int(arr.min()) < 0 or int(arr.max()) > 255):
            raise ValueError(f"{name}: integer colours must be in 0..255, got "
                             f"{int(arr.min())}..{int(arr.max())}")
        return arr[:, :3].astype(np.float64) / 255.0
    if arr.dtype.kind != "f":
        raise ValueError(f"{name} must be uint8 (0..255) or float (0..1) colours, got dtype "
                         f"{arr.dtype}")
    out = arr[:, :3].astype(np.float64)
    if out.size and not (np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() <= 1.0):
        raise ValueError(f"{name}: float colours must be finite and in [0, 1]; use uint8 for "
                         f"0..255")
    return out


def _as_image(value: Any) -> np.ndarray:
    """A texture image as float64 (H, W, 3) RGB in [0, 1] (PIL images accepted)."""
    if hasattr(value, "convert") and hasattr(value, "size"):  # a PIL image
        value = np.asarray(value.convert("RGB"))
    img = np.asarray(value)
    if img.ndim == 2:  # greyscale
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4) or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"texture image must have shape (H, W, 3) or (H, W, 4) with H, W > 0, "
                         f"got shape {img.shape}")
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    flat = as_colors(img.reshape(-1, img.shape[2]), img.shape[0] * img.shape[1],
                     "texture image")
    return flat.reshape(img.shape[0], img.shape[1], 3)


@dataclass(frozen=True)
class Texture:
    """A base-colour texture on a mesh: per-vertex UVs, an image and a colour factor.

    The surface colour at a point is ``factor · image(uv)`` (glTF's ``baseColorFactor ·
    baseColorTexture``), or ``factor`` alone when `image` is None.

    Attributes:
        uv: float64 (N, 2), one (u, v) per mesh vertex (v up, see the module docstring);
            None when `image` is None.
        image: float64 (H, W, 3) RGB in [0, 1], row 0 at the top (as image files store
            it), or None.
        factor: float64 (3,) RGB multiplier in [0, 1].
    """

    uv: np.ndarray | None
    image: np.ndarray | None
    factor: np.ndarray

    @classmethod
    def make(cls, uv: npt.ArrayLike | None, image: Any, factor: npt.ArrayLike = (1.0, 1.0, 1.0),
             *, n_vertices: int | None = None) -> Texture:
        """Validated `Texture` from user inputs.

        Args:
            uv: (N, 2) float UVs per vertex (None only without an image).
            image: (H, W, 3|4) uint8 (0..255) or float (0..1) array, a PIL image, or None.
            factor: RGB(A) multiplier, uint8 0..255 or float 0..1 (alpha dropped).
            n_vertices: when given, `uv` must have that many rows.

        Raises:
            ValueError: wrong shapes or dtypes, non-finite UVs, colours out of range.
        """
        fac = as_colors(np.asarray(factor).reshape(1, -1), 1, "texture factor")[0]
        if image is None:
            return cls(None, None, fac)
        img = _as_image(image)
        if uv is None:
            raise ValueError("a texture image needs per-vertex uv coordinates (N, 2)")
        u = np.asarray(uv)
        if u.ndim != 2 or u.shape[1] != 2 or u.dtype.kind not in "iuf":
            raise ValueError(f"uv must be a real (N, 2) array (u, v per vertex), got shape "
                             f"{u.shape} dtype {u.dtype}")
        if n_vertices is not None and u.shape[0] != n_vertices:
            raise ValueError(f"uv has {u.shape[0]} rows but the mesh has {n_vertices} "
                             f"vertices: one (u, v) per vertex")
        u = u.astype(np.float64)
        if not np.all(np.isfinite(u)):
            raise ValueError("uv must be finite (NaN or Inf found)")
        return cls(u, img, fac)


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with repeat wrapping: float64 (K, 3) colours at uv (K, 2).

    `image` is float (H, W, C) with row 0 at the top; `uv` uses v up with texel centres at
    ``((c + 0.5)/W, 1 − (r + 0.5)/H)`` (module docstring), so a UV at a texel centre returns
    that texel exactly.
    """
    h, w = image.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = (1.0 - uv[:, 1]) * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    # floor/mod in float64 then int: repeat wrapping for any finite UV, negative included
    c0 = np.mod(x0, w).astype(np.int64)
    r0 = np.mod(y0, h).astype(np.int64)
    c1 = (c0 + 1) % w
    r1 = (r0 + 1) % h
    top = image[r0, c0] * (1.0 - fx) + image[r0, c1] * fx
    bottom = image[r1, c0] * (1.0 - fx) + image[r1, c1] * fx
    return top * (1.0 - fy) + bottom * fy


def colors_from_trimesh(tm: trimesh.Trimesh) -> tuple[str, np.ndarray] | None:
    """The explicit colours of a trimesh mesh: ``("vertex", (N, 3))`` or ``("face", (M, 3))``
    float64 RGB in [0, 1], or None when it has none (no colour visual, or only trimesh's
    default grey, or a texture: see `texture_from_trimesh`)."""
    visual: Any = getattr(tm, "visual", None)
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        return "vertex", as_colors(visual.vertex_colors, len(tm.vertices), "vertex_colors")
    if kind == "face":
        return "face", as_colors(visual.face_colors, len(tm.faces), "face_colors")
    return None


def texture_from_trimesh(tm: trimesh.Trimesh) -> Texture | None:
    """The base colour of a trimesh mesh with a ``TextureVisuals`` (glTF, OBJ + MTL), or None.

    * glTF PBR material (`trimesh.visual.material.PBRMaterial`): ``baseColorFactor`` (default
      white) times ``baseColorTexture`` sampled at the mesh's UVs (trimesh stores them
      v up, which is this module's convention).
    * Simple material (OBJ/MTL): its ``image`` (``map_Kd``) when there is one, else its
      ``diffuse`` colour (``Kd``) as a constant — as trimesh itself colours it.

    UVs need one row per vertex (trimesh's loaders split vertices on UV seams for that).
    A material without a texture gives a constant-colour `Texture` (``image`` None).
    """
    visual = getattr(tm, "visual", None)
    if getattr(visual, "kind", None) != "texture":
        return None
    material = getattr(visual, "material", None)
    if material is None:
        return None
    uv = getattr(visual, "uv", None)
    n = len(tm.vertices)
    if uv is not None and len(uv) != n:
        uv = None
    if hasattr(material, "baseColorTexture"):  # PBRMaterial
        image = material.baseColorTexture
        factor = material.baseColorFactor
        factor = (1.0, 1.0, 1.0) if factor is None else np.asarray(factor)
    else:  # SimpleMaterial: trimesh colours with the image alone when there is one
        image = getattr(material, "image", None)
        factor = (1.0, 1.0, 1.0) if image is not None else np.asarray(
            getattr(material, "diffuse", (255, 255, 255)))
    if image is not None and uv is None:
        image = None  # no usable UVs: fall back to the factor alone
    return Texture.make(uv, image, factor, n_vertices=n)


# -- tangent-space normal maps -------------------------------------------------------------------

@dataclass(frozen=True)
class NormalMap:
    """A tangent-space normal map on a mesh (glTF ``normalTexture``).

    A texel ``c`` (RGB in [0, 1]) encodes the normal ``(2c − 1)`` in the surface's tangent
    frame: x along the tangent (the direction of increasing u), y along the bitangent
    (increasing v: glTF's "+Y up", OpenGL's convention), z along the surface normal.
    The xy part is multiplied by `scale` (glTF ``normalTexture.scale``). Sampled bilinearly
    with repeat wrapping at the interpolated UVs, as `sample_bilinear`.

    Attributes:
        uv: float64 (N, 2) per-vertex UVs (v up). image: float64 (H, W, 3) in [0, 1].
        scale: float.
    """

    uv: np.ndarray
    image: np.ndarray
    scale: float = 1.0

    @classmethod
    def make(cls, uv: npt.ArrayLike, image: Any, scale: float = 1.0, *,
             n_vertices: int | None = None) -> NormalMap:
        """Validated `NormalMap`; `uv` and `image` as for `Texture.make`.

        Raises:
            ValueError: wrong shapes or dtypes, non-finite UVs or scale.
        """
        tex = Texture.make(uv, image, n_vertices=n_vertices)
        if not np.isfinite(scale):
            raise ValueError(f"normal map scale must be finite, got {scale}")
        assert tex.uv is not None and tex.image is not None
        return cls(tex.uv, tex.image, float(scale))


def normal_map_from_trimesh(tm: trimesh.Trimesh) -> NormalMap | None:
    """The tangent-space normal map of a trimesh mesh whose material has one (glTF PBR
    ``normalTexture``, loaded by trimesh), or None (no map, or no per-vertex UVs)."""
    visual = getattr(tm, "visual", None)
    if getattr(visual, "kind", None) != "texture":
        return None
    image = getattr(getattr(visual, "material", None), "normalTexture", None)
    uv = getattr(visual, "uv", None)
    if image is None or uv is None or len(uv) != len(tm.vertices):
        return None
    return NormalMap.make(uv, image, n_vertices=len(tm.vertices))


def vertex_tangents(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray,
                    normals: np.ndarray | None = None) -> np.ndarray:
    """float64 (N, 4) per-vertex tangents from UVs (Lengyel's method): xyz the unit tangent
    (direction of increasing u in the surface, orthogonalized against the vertex normal
    `normals` (N, 3); default the area-weighted one), w = ±1 the handedness, so that the
    bitangent is ``w · (n × t)`` (glTF's rule). Each face adds its (UV-area-weighted)
    ∂p/∂u and ∂p/∂v to its vertices; faces with degenerate UVs add nothing; a vertex with
    no usable tangent gets any unit vector orthogonal to its normal and w = 1."""
    v = vertices.astype(np.float64)
    tri = v[faces]
    tuv = uv[faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d1, d2 = tuv[:, 1] - tuv[:, 0], tuv[:, 2] - tuv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    ok = np.abs(det) > 1e-20
    sign = np.where(det < 0, -1.0, 1.0)[:, None]
    # ∂p/∂u, ∂p/∂v times |det| (= 2·UV area): a face weighs by its UV area, never divided
    sdir = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * sign
    tdir = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * sign
    sdir[~ok] = 0.0
    tdir[~ok] = 0.0
    n_v = v.shape[0]
    t_acc = np.zeros((n_v, 3))
    b_acc = np.zeros((n_v, 3))
    for k in range(3):
        for c in range(3):
            t_acc[:, c] += np.bincount(faces[:, k], weights=sdir[:, c], minlength=n_v)
            b_acc[:, c] += np.bincount(faces[:, k], weights=tdir[:, c], minlength=n_v)
    if normals is None:
        cross = np.cross(e1, e2)
        acc = np.zeros((n_v, 3))
        for k in range(3):
            for c in range(3):
                acc[:, c] += np.bincount(faces[:, k], weights=cross[:, c], minlength=n_v)
        ln = np.linalg.norm(acc, axis=1, keepdims=True)
        normals = np.divide(acc, ln, out=np.zeros_like(acc), where=ln > 0)
    n = normals.astype(np.float64)
    t = t_acc - n * np.einsum("kc,kc->k", n, t_acc)[:, None]
    length = np.linalg.norm(t, axis=1)
    weak = length < 1e-12
    if weak.any():   # any direction orthogonal to the normal
        alt = np.where(np.abs(n[weak, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        t[weak] = alt - n[weak] * np.einsum("kc,kc->k", n[weak], alt)[:, None]
        length[weak] = np.linalg.norm(t[weak], axis=1)
    length[length == 0] = 1.0
    out = np.empty((n_v, 4))
    out[:, :3] = t / length[:, None]
    out[:, 3] = np.where(np.einsum("kc,kc->k", np.cross(n, out[:, :3]), b_acc) < 0.0, -1.0, 1.0)
    return out


def perturb_normals(nmap: NormalMap, tangents: np.ndarray, faces: np.ndarray,
                    face: np.ndarray, bary: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """float64 (K, 3) unit normals of K surface points with the normal map applied.

    Args:
        nmap: the map. tangents: (N, 4) from `vertex_tangents`. faces: the mesh's (M, 3).
        face: (K,) face index per point. bary: (K, 3) barycentrics in the face's vertex
            order. normals: (K, 3) unit surface normals at the points (face or smooth), in
            the same space as the mesh's vertices.
    """
    tri = faces[face]
    uv = np.einsum("kj,kjc->kc", bary, nmap.uv[tri])
    t4 = np.einsum("kj,kjc->kc", bary, tangents[tri])
    c = sample_bilinear(nmap.image, uv) * 2.0 - 1.0
    c[:, :2] *= nmap.scale
    n = normals
    t = t4[:, :3] - n * np.einsum("kc,kc->k", n, t4[:, :3])[:, None]
    tl = np.linalg.norm(t, axis=1, keepdims=True)
    t = np.divide(t, tl, out=np.zeros_like(t), where=tl > 0)
    b = np.cross(n, t) * np.where(t4[:, 3:4] < 0.0, -1.0, 1.0)
    out = c[:, 0:1] * t + c[:, 1:2] * b + c[:, 2:3] * n
    ol = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, ol, out=n.copy(), where=ol > 0)
