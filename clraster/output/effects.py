"""The lighting effects of `clraster.shade.render_shaded`: lights with shadow maps, ambient
occlusion, normal maps, cel shading, outlines, FXAA, and the per-pixel layers behind them.

render_shaded renders the frame, resolves each covered pixel's surface colour and world
normal as `shade` does, and hands them to `finish`, which composes, per covered pixel::

    rgb = albedo · (ambient · ao + (1 − ambient) · Σ_lights intensity · color · d)
    d   = lit · |n · l|          (max(n · l, 0) with two_sided=False)

with ``l`` the unit direction towards the light, ``lit`` the light's shadow-map visibility
(`clraster.output.lights`; 1 without shadows) times a spot's cone factor, ``ao`` the SSAO
factor (`clraster.output.post`; 1 without), ``n`` the normal after the normal map, and with
``style="cel"`` each ``d`` quantized to `CEL_LEVELS` bands. With one directional light and
nothing else this is `shade`'s Lambert image. Outlines replace the colour of their pixels;
supersampling averages k × k samples; FXAA runs last, on the output-size image.

The per-pixel passes (shadow lookups, SSAO, FXAA) run where `passes_for(renderer)` says:
on the device for an OpenCL renderer once `clraster.pipeline.stages.post` is imported, in
NumPy otherwise — the same results within float rounding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..base.checks import check_flag
from ..world.inputs import as_target
from ..world.mesh import Mesh
from ..world.scene import Scene
from .lights import Light, LightError, ShadowMap, frame_points, shadow_map, spot_factor
from .post import SSAO, Outlines, PostError, cel_quantize, outline_mask, passes_for
from .textures import NormalMap, normal_map_from_trimesh, perturb_normals, vertex_tangents

__all__ = ["CEL_LEVELS", "SSAO_RADIUS_FRACTION", "Effects", "ShadeLayers"]

#: Bands of ``style="cel"``.
CEL_LEVELS = 3
#: ``ssao=True``: the radius is this fraction of the target's bounding-box diagonal.
SSAO_RADIUS_FRACTION = 0.03
AA_MODES = ("none", "fxaa")
STYLES = ("lambert", "cel")


@dataclass
class ShadeLayers:
    """What render_shaded computed per pixel (``return_layers=True``), at the output size
    (with ``ssaa = k`` each value is the mean of its k × k samples; normals renormalized).

    Attributes:
        lit: float32 (H, W, L): per light, the fraction of it reaching the visible point
            (shadow-map visibility × a spot's cone factor), 0 on the background.
        ao: float32 (H, W): ambient occlusion factor (1: open; all 1 without ``ssao``).
        normals: float32 (H, W, 3) unit world normals lit with (normal maps applied),
            zero on the background.
        covered: float32 (H, W): fraction of the pixel's samples that hit geometry.
        shadow_maps: per light its `clraster.output.lights.ShadowMap`, or None (no shadows).
    """

    lit: np.ndarray
    ao: np.ndarray
    normals: np.ndarray
    covered: np.ndarray
    shadow_maps: list[ShadowMap | None] = field(default_factory=list)


def _lights(lights: Any) -> tuple[Light, ...] | None:
    if lights is None:
        return None
    if isinstance(lights, Light):
        return (lights,)
    if isinstance(lights, Sequence) and not isinstance(lights, (str, bytes)):
        bad = [type(x).__name__ for x in lights if not isinstance(x, Light)]
        if bad or not lights:
            raise LightError(f"lights must be a non-empty list of clraster.shade.Light "
                             f"(Light.directional / Light.spot), got {bad or 'an empty list'}")
        return tuple(lights)
    raise LightError(f"lights must be a Light or a list of them, got {type(lights).__name__}")


def _ssao(value: Any) -> SSAO | None:
    if value is None or value is False:
        return None
    if value is True:
        return SSAO()
    if isinstance(value, SSAO):
        return value
    if isinstance(value, (int, float, np.floating, np.integer)):
        return SSAO(radius=float(value))
    raise PostError(f"ssao must be True, False, a radius in world units or a "
                    f"clraster.output.post.SSAO, got {type(value).__name__}")


def _outlines(value: Any) -> Outlines | None:
    if value is None or value is False:
        return None
    if value is True:
        return Outlines()
    if isinstance(value, Outlines):
        return value
    raise PostError(f"outlines must be True, False or a clraster.output.post.Outlines, got "
                    f"{type(value).__name__}")


@dataclass(frozen=True)
class Effects:
    """render_shaded's effect options, checked (`Effects.make`)."""

    lights: tuple[Light, ...] | None = None
    shadows: bool = False
    ssao: SSAO | None = None
    aa: str = "none"
    style: str = "lambert"
    outlines: Outlines | None = None
    normal_map: Any = True
    return_layers: bool = False

    @classmethod
    def make(cls, *, lights: Any = None, shadows: Any = False, ssao: Any = False,
             aa: Any = None, style: Any = "lambert", outlines: Any = False,
             normal_map: Any = True, return_layers: Any = False) -> Effects:
        """Checked options; raises `LightError` or `PostError` (ValueErrors) saying which
        option is wrong and what it takes."""
        aa_mode = "none" if aa is None else aa
        if aa_mode not in AA_MODES:
            raise PostError(f"aa must be None, 'none' or 'fxaa' (for supersampling use "
                            f"ssaa=k), got {aa!r}")
        if style not in STYLES:
            raise PostError(f"style must be 'lambert' or 'cel', got {style!r}")
        if not (normal_map is None or isinstance(normal_map, (bool, NormalMap, list))):
            raise PostError(f"normal_map must be True (a trimesh target's own), False, a "
                            f"clraster.output.textures.NormalMap or a list of them (one per "
                            f"instance), got {type(normal_map).__name__}")
        return cls(_lights(lights), check_flag(shadows, "shadows"), _ssao(ssao), aa_mode,
                   style, _outlines(outlines), normal_map, check_flag(return_layers,
                                                                      "return_layers"))

    def active(self, target: Any) -> bool:
        """Whether render_shaded needs `finish` (anything beyond `shade`'s image)."""
        return (self.lights is not None or self.shadows or self.ssao is not None
                or self.aa != "none" or self.style != "lambert" or self.outlines is not None
                or self.return_layers or bool(self.normal_map is not None
                                              and self.normal_map is not False
                                              and _has_normal_maps(target, self.normal_map)))

    def finish(self, *, renderer: Any, frame: Any, target: Any, vp: np.ndarray,
               covered: np.ndarray, inst: np.ndarray, face: np.ndarray,
               bary: np.ndarray | None, base: np.ndarray, normals: np.ndarray, k: int,
               background: np.ndarray, alpha: bool, ambient: float, light_towards: np.ndarray,
               two_sided: bool, render_kwargs: dict[str, Any] | None
               ) -> np.ndarray | tuple[np.ndarray, ShadeLayers]:
        """The image (and layers) of a frame k× the output size (module docstring).

        Args:
            renderer: what rendered `frame` (its passes and shadow maps use its type and
                context). frame: the frame. target: the target as the user gave it.
            vp: float64 (4, 4) the view-projection the frame was rendered with.
            covered: bool (kH, kW). inst, face: int64 (K,) per covered pixel (row-major).
            bary: float64 (K, 3) or None. base: float64 (K, 3) albedo. normals: float64
                (K, 3) unit world normals (render_shaded's flat or smooth ones).
            background: int (3,) RGB. ambient: the ambient share. light_towards: the unit
                default light direction (towards the light) when `lights` is None.
        """
        geometry = as_target(target)
        depth = np.asarray(frame.depth, np.float32)
        rev = bool(getattr(frame, "reversed_z", False))
        n = _apply_normal_maps(self.normal_map, target, geometry, inst, face, bary, normals)
        n_img = np.zeros(covered.shape + (3,), np.float32)
        n_img[covered] = n
        passes = passes_for(renderer)
        world = frame_points(depth, covered, vp, rev)
        lights = self.lights or (Light.directional(-light_towards),)
        lit_layer = np.zeros(covered.shape + (len(lights),), np.float32)
        maps: list[ShadowMap | None] = []
        light_sum = np.zeros((world.shape[0], 3))
        for j, light in enumerate(lights):
            ndotl = np.einsum("kc,kc->k", n, light.towards(world))
            lam = np.abs(ndotl) if two_sided else np.maximum(ndotl, 0.0)
            smap = None
            if self.shadows and world.shape[0]:
                smap = shadow_map(renderer, geometry, light, world, render_kwargs)
                vis = passes.shadow(smap, light, depth, n_img, vp, rev)[covered]
            else:
                vis = spot_factor(light, world)
            maps.append(smap)
            lit_layer[covered, j] = vis
            d = lam * vis
            if self.style == "cel":
                d = cel_quantize(np.clip(d, 0.0, 1.0), CEL_LEVELS)
            light_sum += (light.intensity * d)[:, None] * light.color[None, :]
        ao_img = np.ones(covered.shape, np.float32)
        if self.ssao is not None and world.shape[0]:
            lo, hi = geometry.bounds()
            params = self.ssao.checked(SSAO_RADIUS_FRACTION * float(np.linalg.norm(hi - lo)))
            ao_img = passes.ssao(depth, n_img, vp, rev, params)
        ao = ao_img[covered].astype(np.float64)[:, None]
        rgb = base * (ambient * ao + (1.0 - ambient) * light_sum)
        if self.outlines is not None:
            edge = outline_mask(covered, _linear_depth(depth, vp, rev), n_img, self.outlines)
            rgb[edge[covered]] = np.asarray(self.outlines.color, np.float64) / 255.0
        image = _compose(covered, rgb, k, background, alpha)
        out = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        if self.aa == "fxaa":
            # on the 8-bit image, as FXAA runs on its RGBA8 target; alpha is kept
            if alpha:
                out[..., :3] = passes.fxaa(out[..., :3])
            else:
                out = passes.fxaa(out)
        if not self.return_layers:
            return out
        return out, ShadeLayers(_down(lit_layer, k), _down(ao_img, k), _down_normals(n_img, k),
                                _down(covered.astype(np.float32), k), maps)


def _linear_depth(depth: np.ndarray, vp: np.ndarray, rev: bool) -> np.ndarray:
    """(H, W) a depth that grows linearly along the view axis: the clip w of the pixel's
    point (perspective), or the window depth itself (orthographic, where w is constant)."""
    if not np.any(vp[3, :3]):
        return depth.astype(np.float64) * (-1.0 if rev else 1.0) + (1.0 if rev else 0.0)
    from .post import world_positions

    p = world_positions(depth, vp, rev)
    return p @ vp[3, :3] + vp[3, 3]


def _compose(covered: np.ndarray, rgb: np.ndarray, k: int, background: np.ndarray,
             alpha: bool) -> np.ndarray:
    """float64 (H, W, 3|4) in [0, 1] at the output size: `shade`'s compositing (background,
    straight alpha over the covered samples, k × k box filter)."""
    bg = np.asarray(background, np.float64) / 255.0
    hh, ww = covered.shape
    h, w = hh // k, ww // k
    img = np.empty((hh, ww, 3))
    img[...] = bg
    img[covered] = rgb
    if not alpha:
        return img.reshape(h, k, w, k, 3).mean(axis=(1, 3))
    cov = covered.astype(np.float64)
    prem = (img * cov[..., None]).reshape(h, k, w, k, 3).sum(axis=(1, 3))
    cnt = cov.reshape(h, k, w, k).sum(axis=(1, 3))
    out = np.empty((h, w, 4))
    out[..., :3] = np.where(cnt[..., None] > 0, prem / np.maximum(cnt, 1.0)[..., None], bg)
    out[..., 3] = cnt / (k * k)
    return out


def _down(a: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return a
    h, w = a.shape[0] // k, a.shape[1] // k
    return a.reshape((h, k, w, k) + a.shape[2:]).mean(axis=(1, 3)).astype(np.float32)


def _down_normals(n: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return n
    m = _down(n, k).astype(np.float64)
    length = np.linalg.norm(m, axis=-1, keepdims=True)
    return np.divide(m, length, out=np.zeros_like(m), where=length > 1e-12).astype(np.float32)


# -- normal maps ---------------------------------------------------------------------------------

def _sources(target: Any, geometry: Mesh | Scene) -> list[Any]:
    """The trimesh mesh behind each instance (None where there is none)."""
    kind = type(target).__module__
    if not kind.startswith("trimesh"):
        return [None] * (1 if isinstance(geometry, Mesh) else geometry.n_instances)
    if isinstance(geometry, Mesh):
        return [target]
    names = geometry.geometry_names
    return [None if name is None else target.geometry.get(name) for name in names]


def _maps(spec: Any, target: Any, geometry: Mesh | Scene) -> list[NormalMap | None]:
    n = 1 if isinstance(geometry, Mesh) else geometry.n_instances
    if spec is None or spec is False:
        return [None] * n
    if spec is True:
        return [None if s is None else normal_map_from_trimesh(s)
                for s in _sources(target, geometry)]
    if isinstance(spec, NormalMap):
        return [spec] * n
    if len(spec) != n:
        raise PostError(f"normal_map: a list gives one entry per instance; got {len(spec)} "
                        f"for {n} instances")
    for x in spec:
        if x is not None and not isinstance(x, NormalMap):
            raise PostError(f"normal_map list entries must be NormalMap or None, got "
                            f"{type(x).__name__}")
    return list(spec)


def _has_normal_maps(target: Any, spec: Any) -> bool:
    if spec is True and not type(target).__module__.startswith("trimesh"):
        return False
    return any(m is not None for m in _maps(spec, target, as_target(target)))


def _apply_normal_maps(spec: Any, target: Any, geometry: Mesh | Scene, inst: np.ndarray,
                       face: np.ndarray, bary: np.ndarray | None, normals: np.ndarray
                       ) -> np.ndarray:
    maps = _maps(spec, target, geometry)
    if all(m is None for m in maps):
        return normals
    if bary is None:
        raise PostError("normal maps need the frame's barycentrics")
    out = normals.copy()
    for i, nmap in enumerate(maps):
        if nmap is None:
            continue
        sel = np.nonzero(inst == i)[0]
        if not sel.size:
            continue
        if isinstance(geometry, Mesh):
            mesh, m3 = geometry, np.eye(3)
        else:
            instance = geometry.instances[i]
            mesh, m3 = instance.mesh, instance.transform[:3, :3]
        if nmap.uv.shape[0] != mesh.n_vertices:
            raise PostError(f"normal_map[{i}]: uv has {nmap.uv.shape[0]} rows, the mesh "
                            f"{mesh.n_vertices} vertices")
        tang = vertex_tangents(mesh.vertices, mesh.faces, nmap.uv)
        # object-space normal from the world one (n_w ∝ M⁻ᵀ n_o, so n_o ∝ Mᵀ n_w), the map
        # applied there, back through M⁻ᵀ
        n_obj = normals[sel] @ m3
        n_obj /= np.maximum(np.linalg.norm(n_obj, axis=1, keepdims=True), 1e-300)
        pert = perturb_normals(nmap, tang, mesh.faces, face[sel], bary[sel], n_obj)
        nw = pert @ np.linalg.inv(m3)
        out[sel] = nw / np.maximum(np.linalg.norm(nw, axis=1, keepdims=True), 1e-300)
    return out

