"""Lights and shadow maps for `clraster.shade.render_shaded`.

A `Light` is directional (parallel rays, a sun) or a spot (a position, an axis and a cone).
Its shadow map is a depth pass of the same scene through the same renderer (`shadow_map`):
``cull="none"`` (thin, one-sided occluders cast shadows from both sides), the renderer's own
frustum culling against the light's frustum, ids and depth only. For a directional light
the frustum is orthographic and fitted to what the camera sees: its x/y extent is the
bounding rectangle of the frame's visible points in the light's basis (plus the filter's
margin), its near plane is pulled back to the scene's bounds towards the light (anything
that can throw a shadow on a visible point lies between it and the light), its far plane
just behind the farthest visible point. A spot light's frustum is a square perspective one
around its axis with a field of view of twice the cone angle, drawn with reversed-Z (depth
precision where occluders are near the light and far from it alike).

The map stores *linear* light depth: the distance along the light's axis (+inf where
nothing was drawn). A visible point p is lit by the light where its own linear light depth,
less a bias, is at most the map's: ``z(p) − b ≤ map``. The bias is slope-scaled:
``b = τ · (constant + slope · (pcf + 1) · min(tan θ, TAN_MAX))`` with τ the world size of a
texel at p (constant for an orthographic map, ∝ depth for a spot), θ the angle between the
surface normal and the direction to the light (``|n·l|``, lighting being two-sided), so a
surface tilted away from the light gets the larger bias its depth slope across a texel — and
across the filter's footprint of pcf texels — needs, and a surface facing the light gets
about one texel. Percentage-closer filtering: the fraction of the (2·pcf + 1)² texels around
the one that holds p that pass the test, so shadow edges get (2·pcf + 1)² + 1 levels.

Points are reconstructed from the camera frame's window depth at the pixel centres through
the inverse view-projection (float64), the way the device kernel (kernels/shadow.cl) does;
`shadow_lookup` here is its NumPy twin.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..world.camera import Camera, look_at_matrix
from ..world.mesh import Mesh
from ..world.scene import Scene

__all__ = ["LIGHT_DIRECTIONAL", "LIGHT_SPOT", "TAN_MAX", "Light", "LightError", "ShadowMap",
           "frame_points", "ndc_grid", "shadow_lookup", "shadow_map", "spot_factor"]

LIGHT_DIRECTIONAL = 0
LIGHT_SPOT = 1
#: Largest slope factor tan θ of the bias: grazing light (θ → 90°) would otherwise push the
#: bias, and the gap between an object and its shadow, to infinity; beyond ~84° a surface
#: can show acne instead, and gets next to no light there anyway (cos θ < 0.1).
TAN_MAX = 10.0
#: Largest shadow map side in texels (a depth pass of that many pixels per light).
MAX_SHADOW_SIZE = 8192


class LightError(ValueError):
    """A light or a lighting option that cannot be used; the message says which and why."""


def _unit(value: npt.ArrayLike, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or not np.any(v):
        raise LightError(f"{name} must be a finite, non-zero 3-vector, got {np.asarray(value)!r}")
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class Light:
    """A light: build one with `Light.directional` or `Light.spot`.

    Attributes:
        kind: `LIGHT_DIRECTIONAL` or `LIGHT_SPOT`.
        direction: float64 (3,) unit direction the light *travels* (from the light into the
            scene; the opposite of `clraster.shade.shade`'s ``light_dir``, which points
            towards the light).
        position: float64 (3,) world position of a spot light; None for directional.
        cone: a spot's half-angle in degrees, (0, 89]: no light outside it.
        inner: half-angle in degrees within which a spot is at full strength, ≤ cone; the
            strength falls off smoothly (smoothstep in cos) between inner and cone.
        intensity: scale of the light's contribution (1: as `shade`'s single light).
        color: float64 (3,) RGB multiplier in [0, 1].
        shadow_size: shadow map side in texels.
        bias: constant bias in texels. slope_bias: slope-scaled bias factor (module docstring).
        pcf: percentage-closer filter radius in texels (0: one tap; 1: 3 × 3 taps).
    """

    kind: int
    direction: np.ndarray
    position: np.ndarray | None = None
    cone: float = 0.0
    inner: float = 0.0
    intensity: float = 1.0
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    shadow_size: int = 2048
    bias: float = 1.0
    slope_bias: float = 1.0
    pcf: int = 1

    @classmethod
    def directional(cls, direction: npt.ArrayLike, *, intensity: float = 1.0,
                    color: npt.ArrayLike = (1.0, 1.0, 1.0), shadow_size: int = 2048,
                    bias: float = 1.0, slope_bias: float = 1.0, pcf: int = 1) -> Light:
        """A light with parallel rays travelling along `direction` (world space, any length;
        e.g. ``(0, -1, 0)`` shines straight down). Other arguments: see the attributes.

        Raises:
            LightError: a zero or non-finite direction, or an option out of range.
        """
        light = cls(LIGHT_DIRECTIONAL, _unit(direction, "direction"), None, 0.0, 0.0,
                    float(intensity), np.asarray(color, np.float64), int(shadow_size),
                    float(bias), float(slope_bias), int(pcf))
        light._check()
        return light

    @classmethod
    def spot(cls, position: npt.ArrayLike, direction: npt.ArrayLike, cone: float = 30.0, *,
             inner: float | None = None, intensity: float = 1.0,
             color: npt.ArrayLike = (1.0, 1.0, 1.0), shadow_size: int = 1024,
             bias: float = 1.0, slope_bias: float = 1.0, pcf: int = 1) -> Light:
        """A spot light at `position` shining along `direction` within a cone of half-angle
        `cone` degrees (full strength within `inner`, default 0.8·cone). No fall-off with
        distance. Other arguments: see the attributes.

        Raises:
            LightError: a non-finite position, a zero direction, a cone outside (0, 89],
                ``inner`` outside [0, cone], or an option out of range.
        """
        pos = np.asarray(position, dtype=np.float64)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise LightError(f"position must be a finite 3-vector, got {np.asarray(position)!r}")
        cone = float(cone)
        if not 0.0 < cone <= 89.0:
            raise LightError(f"cone is the spot's half-angle in degrees and must be in "
                             f"(0, 89], got {cone}")
        inner_deg = 0.8 * cone if inner is None else float(inner)
        if not 0.0 <= inner_deg <= cone:
            raise LightError(f"inner must be in [0, cone={cone}] degrees, got {inner_deg}")
        light = cls(LIGHT_SPOT, _unit(direction, "direction"), pos, cone, inner_deg,
                    float(intensity), np.asarray(color, np.float64), int(shadow_size),
                    float(bias), float(slope_bias), int(pcf))
        light._check()
        return light

    def _check(self) -> None:
        if not (math.isfinite(self.intensity) and self.intensity >= 0.0):
            raise LightError(f"intensity must be finite and >= 0, got {self.intensity}")
        c = self.color
        if c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0.0 or c.max() > 1.0:
            raise LightError(f"color must be three floats in [0, 1], got {c.tolist()}")
        if not 16 <= self.shadow_size <= MAX_SHADOW_SIZE:
            raise LightError(f"shadow_size must be in 16..{MAX_SHADOW_SIZE} texels, got "
                             f"{self.shadow_size}")
        for name in ("bias", "slope_bias"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise LightError(f"{name} must be finite and >= 0 (texels), got {v}")
        if not 0 <= self.pcf <= 4:
            raise LightError(f"pcf is the filter radius in texels, 0..4, got {self.pcf}")

    def towards(self, world: np.ndarray) -> np.ndarray:
        """float64 (K, 3) unit directions from the points `world` (K, 3) to the light."""
        if self.kind == LIGHT_DIRECTIONAL:
            return np.broadcast_to(-self.direction, world.shape)
        assert self.position is not None
        d = self.position - world
        n = np.linalg.norm(d, axis=1, keepdims=True)
        return np.divide(d, n, out=np.zeros_like(d), where=n > 0)


def spot_factor(light: Light, world: np.ndarray) -> np.ndarray:
    """float64 (K,): the light's strength at the points `world` (K, 3) from its cone: 1 for a
    directional light; for a spot, smoothstep from cos(cone) (0) to cos(inner) (1) of the
    angle between its axis and the ray to the point."""
    if light.kind == LIGHT_DIRECTIONAL:
        return np.ones(world.shape[0])
    cosang = -(light.towards(world) @ light.direction)
    lo, hi = math.cos(math.radians(light.cone)), math.cos(math.radians(light.inner))
    if hi - lo < 1e-12:
        return (cosang >= lo).astype(np.float64)
    t = np.clip((cosang - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# -- reconstruction of the camera frame's visible points --------------------------------------

def ndc_grid(depth: np.ndarray, reversed_z: bool) -> np.ndarray:
    """float64 (H, W, 4) homogeneous NDC (x, y, z, 1) of the pixel centres of a depth buffer
    (row 0 on top: y = +1 at the top edge); z from window depth, or reversed-Z."""
    h, w = depth.shape
    out = np.empty((h, w, 4))
    out[..., 0] = ((np.arange(w) + 0.5) * (2.0 / w) - 1.0)[None, :]
    out[..., 1] = (1.0 - (np.arange(h) + 0.5) * (2.0 / h))[:, None]
    d = depth.astype(np.float64)
    out[..., 2] = 1.0 - 2.0 * d if reversed_z else 2.0 * d - 1.0
    out[..., 3] = 1.0
    return out


def frame_points(depth: np.ndarray, covered: np.ndarray, vp: np.ndarray,
                 reversed_z: bool) -> np.ndarray:
    """float64 (K, 3) world points of the covered pixels (row-major), from the window depth
    at the pixel centres through ``vp⁻¹`` (vp: the frame's (4, 4) view-projection)."""
    ndc = ndc_grid(depth, reversed_z)[covered]
    inv = np.linalg.inv(vp)
    # column by column, not ``ndc @ inv.T``: that product goes to BLAS, whose threads
    # fought PoCL's for the two cores (1 s for a 1280×720 frame in the demo)
    hom = ndc[:, 0:1] * inv[:, 0]
    for j in range(1, 4):
        hom += ndc[:, j:j + 1] * inv[:, j]
    return hom[:, :3] / hom[:, 3:4]


# -- shadow maps ----------------------------------------------------------------------------

@dataclass(frozen=True)
class ShadowMap:
    """One light's shadow map.

    Attributes:
        depth: float32 (S, S) linear light depth (distance along the light's axis from its
            eye), row 0 at the top; +inf where nothing was drawn.
        view: float64 (4, 4) world → light eye. projection: float64 (4, 4) light eye → clip.
        texel: world size of a texel: absolute for an orthographic map, per unit of linear
            depth for a perspective one (`perspective`).
        perspective: a spot light's map (True) or a directional one's.
    """

    depth: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    texel: float
    perspective: bool

    @property
    def view_projection(self) -> np.ndarray:
        return self.projection @ self.view


def _ortho(l: float, r: float, b: float, t: float, n: float, f: float) -> np.ndarray:  # noqa: E741
    m = np.zeros((4, 4))
    m[0, 0] = 2.0 / (r - l)
    m[1, 1] = 2.0 / (t - b)
    m[2, 2] = -2.0 / (f - n)
    m[0, 3] = -(r + l) / (r - l)
    m[1, 3] = -(t + b) / (t - b)
    m[2, 3] = -(f + n) / (f - n)
    m[3, 3] = 1.0
    return m


def _up_for(direction: np.ndarray) -> np.ndarray:
    return np.array([0.0, 1.0, 0.0]) if abs(direction[1]) < 0.9 else np.array([1.0, 0.0, 0.0])


def _bounds_corners(geometry: Mesh | Scene) -> np.ndarray:
    lo, hi = geometry.bounds()
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                     for z in (lo[2], hi[2])])


def _light_frustum(light: Light, geometry: Mesh | Scene, visible: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """(view, projection, texel, perspective) of the light's map for the visible points."""
    size = light.shadow_size
    corners = _bounds_corners(geometry)
    up = _up_for(light.direction)
    if light.kind == LIGHT_SPOT:
        assert light.position is not None
        pos = light.position
        view = look_at_matrix(pos, pos + light.direction, up)
        zs = -(corners @ view[:3, :3].T + view[:3, 3])[:, 2]
        # reversed-Z keeps float32 depth precise from near to far, so near can be tiny
        far = max(float(zs.max()), 1e-6) * 1.01 + 1e-6
        near = far * 1e-4
        half = math.radians(min(light.cone * 1.05 + 1.0, 89.5))
        tan_h = math.tan(half)
        proj = np.zeros((4, 4))
        proj[0, 0] = proj[1, 1] = 1.0 / tan_h
        proj[2, 2] = -(far + near) / (far - near)
        proj[2, 3] = -2.0 * far * near / (far - near)
        proj[3, 2] = -1.0
        return view, proj, 2.0 * tan_h / size, True
    # directional: orthographic, fitted to the visible points
    center = visible.mean(axis=0) if visible.shape[0] else corners.mean(axis=0)
    view = look_at_matrix(center, center + light.direction, up)
    vis = visible @ view[:3, :3].T + view[:3, 3] if visible.shape[0] else np.zeros((1, 3))
    cor = corners @ view[:3, :3].T + view[:3, 3]
    lo, hi = vis[:, :2].min(axis=0), vis[:, :2].max(axis=0)
    margin = light.pcf + 2
    ext = max(float((hi - lo).max()), 1e-9 * max(1.0, float(np.abs(cor).max())))
    texel = ext / (size - 2 * margin)
    mid = (lo + hi) / 2.0
    half = size * texel / 2.0
    # light eye at `center`: linear depth −z_eye; near: the scene's nearest point towards the
    # light, far: just behind the farthest visible point
    zvis, zcor = -vis[:, 2], -cor[:, 2]
    pad = 2.0 * texel + 1e-6 * float(np.abs(cor).max())
    near = float(zcor.min()) - pad
    far = float(zvis.max()) + pad
    proj = _ortho(mid[0] - half, mid[0] + half, mid[1] - half, mid[1] + half, near, far)
    return view, proj, texel, False


#: Depth-pass renderers per user renderer and map size (as render_shaded's supersampling
#: renderers: same type, config and OpenCL context).
_LIGHT_RENDERERS: weakref.WeakKeyDictionary[Any, dict[int, Any]] = weakref.WeakKeyDictionary()


def _renderer_for(renderer: Any, size: int) -> Any:
    if not hasattr(renderer, "render"):   # a factory f(width, height)
        return renderer(size, size)
    try:
        per = _LIGHT_RENDERERS.setdefault(renderer, {})
    except TypeError:
        per = {}
    made = per.get(size)
    if made is None:
        kwargs: dict[str, Any] = {}
        if getattr(renderer, "config", None) is not None:
            kwargs["config"] = renderer.config
        if getattr(renderer, "context", None) is not None:
            kwargs["context"] = renderer.context
        made = per[size] = type(renderer)(size, size, **kwargs)
    return made


def shadow_map(renderer: Any, geometry: Mesh | Scene, light: Light, visible: np.ndarray,
               render_kwargs: dict[str, Any] | None = None) -> ShadowMap:
    """Render `light`'s shadow map of `geometry` (module docstring).

    Args:
        renderer: the renderer of the camera frame (a second one of its type, config and
            context is made at shadow_size², cached) or a factory ``f(width, height)``.
        geometry: the Mesh or Scene the camera frame was drawn from.
        light: the light.
        visible: float64 (K, 3) world points the camera sees (a directional light's map is
            fitted to them; `frame_points`).
        render_kwargs: extra ``render`` keywords (e.g. ``clip_planes``: clipped-away
            geometry casts no shadow).
    """
    view, proj, texel, persp = _light_frustum(light, geometry, visible)
    cam = Camera.from_matrices(view, proj)
    r = _renderer_for(renderer, light.shadow_size)
    kwargs = {k: v for k, v in (render_kwargs or {}).items() if k == "clip_planes"}
    frame = r.render(geometry, cam, cull="none", occlusion=False, reversed_z=persp,
                     outputs=("depth", "ids"), **kwargs)
    d = np.asarray(frame.depth, np.float64)
    covered = np.asarray(frame.triangle_id) >= 0
    if persp:
        near = proj[2, 3] / (proj[2, 2] - 1.0)
        far = proj[2, 3] / (proj[2, 2] + 1.0)
        z_ndc = 1.0 - 2.0 * d
        lin = 2.0 * far * near / ((far + near) - z_ndc * (far - near))
    else:
        # ortho: z_ndc = −2/(f−n)·z_eye − (f+n)/(f−n), linear depth −z_eye
        z_ndc = 2.0 * d - 1.0
        lin = (z_ndc - proj[2, 3]) / -proj[2, 2]
    out = np.where(covered, lin, np.inf).astype(np.float32)
    return ShadowMap(out, view, proj, texel, persp)


def shadow_lookup(smap: ShadowMap, light: Light, depth: np.ndarray, normals: np.ndarray,
                  vp: np.ndarray, reversed_z: bool) -> np.ndarray:
    """float32 (H, W): the fraction of `light` that reaches each pixel's visible point past
    the occluders of `smap` (PCF, slope-scaled bias: module docstring) times the spot's cone
    factor; 0 on the background. The NumPy twin of kernels/shadow.cl.

    Args:
        smap: the light's map. light: the light.
        depth: float32 (H, W) window depth of the camera frame (background: 1.0, or 0.0
            with `reversed_z`).
        normals: float32 (H, W, 3) unit world normals of the frame (zero: no slope bias).
        vp: float64 (4, 4) the frame's view-projection.
        reversed_z: the frame's depth convention.
    """
    covered = (depth > 0.0) if reversed_z else (depth < 1.0)
    out = np.zeros(depth.shape, np.float32)
    if not covered.any():
        return out
    world = frame_points(depth, covered, vp, reversed_z)
    n = normals[covered].astype(np.float64)
    lit = _lookup(smap, light, world, n)
    out[covered] = (lit * spot_factor(light, world)).astype(np.float32)
    return out


def _lookup(smap: ShadowMap, light: Light, world: np.ndarray, n: np.ndarray) -> np.ndarray:
    eye = world @ smap.view[:3, :3].T + smap.view[:3, 3]
    zl = -eye[:, 2]
    clip = np.concatenate([eye, np.ones((eye.shape[0], 1))], axis=1) @ smap.projection.T
    size = smap.depth.shape[0]
    w = clip[:, 3]
    front = w > 0.0
    wsafe = np.where(front, w, 1.0)
    u = (clip[:, 0] / wsafe + 1.0) * 0.5 * size
    v = (1.0 - clip[:, 1] / wsafe) * 0.5 * size
    cos = np.abs(np.einsum("kc,kc->k", n, light.towards(world)))
    tan = np.minimum(np.sqrt(np.maximum(1.0 - cos * cos, 0.0)) / np.maximum(cos, 1.0 / TAN_MAX),
                     TAN_MAX)
    tau = smap.texel * zl if smap.perspective else np.full(zl.shape, smap.texel)
    bias = tau * (light.bias + light.slope_bias * (light.pcf + 1) * tan)
    ix = np.floor(u).astype(np.int64)
    iy = np.floor(v).astype(np.int64)
    test = zl - bias
    r = light.pcf
    count = np.zeros(zl.shape)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            tx, ty = ix + dx, iy + dy
            inside = (tx >= 0) & (tx < size) & (ty >= 0) & (ty < size)
            ref = smap.depth[np.clip(ty, 0, size - 1), np.clip(tx, 0, size - 1)]
            count += np.where(inside, test <= ref, True)
    frac = count / float((2 * r + 1) ** 2)
    if smap.perspective:   # behind the spot or outside its map: no light
        inside = front & (u >= 0) & (u < size) & (v >= 0) & (v < size)
        frac = np.where(inside, frac, 0.0)
    return frac
