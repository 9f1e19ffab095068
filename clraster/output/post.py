"""Per-pixel passes over a finished frame: screen-space ambient occlusion, FXAA 3.11, cel
quantization and outlines — the NumPy twins of kernels/post.cl, and the seam through which
`clraster.shade.render_shaded` finds a faster implementation of them.

**SSAO** (`ssao`). From the frame's window depth and world normals only, computed at half
resolution (one sample per 2×2 block: its top-left pixel) and brought back to full
resolution by a depth-aware upsample (`ssao_upsample`). Per covered low-res pixel
p with world point P (the depth at the pixel centre through the inverse view-projection,
float32, relative to a point by the camera) and world normal n (turned towards the camera:
lighting is two-sided), N taps lie on a fixed spiral in the screen disc of the projected
radius ``r_px = R · P₁₁ · H / (2w)`` in full-res pixels, halved on the low-res grid (w: the
clip w of P; the same for every pixel, no per-pixel rotation, so there is no noise to
blur and nothing flickers when the camera moves by a fraction of a pixel); tap i at radius
``α_i · r_px`` and angle ``2π · TURNS · α_i`` with ``α_i = (i + ½)/N``, read at the low-res
pixel whose square holds it. Each tap's point Q with ``v = Q − P`` adds
``(1 − |v|²/R²) · max(0, v·n/|v| − β)`` when ``|v| < R`` (nothing beyond the radius, behind
the surface, or on the background), and ``AO = clamp(1 − (strength / N) · Σ, 0, 1)``. R is in
world units: the point's neighbourhood that can occlude it. A plane with nothing within R
gets exactly 1 (v·n = 0 up to depth rounding, which β absorbs); an inside corner gets less.

**FXAA** (`fxaa`): Timothy Lottes' FXAA 3.11 "quality" PC path, preset 12 (5 search steps
of 1, 1.5, 2, 4, 12 pixels), subpix 0.75, edge threshold 0.166, minimum 0.0833, on the
8-bit display image as the original runs on its RGBA8 target: luma
``0.299 R + 0.587 G + 0.114 B`` of the 0..255 channel values (the minimum threshold scaled
by 255 with it), bilinear reads with clamp to edge, computed in float32 in the order of the
original shader, the blended colour rounded to the nearest 8-bit value (ties to even).

**Cel** (`cel_quantize`): each light's diffuse term ``d ∈ [0, 1]`` becomes
``min(⌊d · levels⌋, levels − 1) / (levels − 1)``. **Outlines** (`outline_mask`): a covered
pixel is on an outline where a 4-neighbour is background, or is farther by more than
``depth`` times its linear depth, or its normal differs by more than ``normal_deg`` degrees.

`Passes` is what render_shaded calls for SSAO, FXAA and shadow lookups; `NUMPY_PASSES` does
them here on the host. The OpenCL side (`clraster.pipeline.stages.post`) registers itself
with `register_passes` when imported, and `passes_for(renderer)` then gives its passes for
an OpenCL renderer (same results within float rounding; see its tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .lights import Light, ShadowMap, ndc_grid, shadow_lookup

__all__ = ["FXAA_STEPS", "NUMPY_PASSES", "SSAO", "Outlines", "Passes", "PostError",
           "cel_quantize", "fxaa", "luma", "outline_mask", "passes_for", "register_passes",
           "rgb8", "ssao", "ssao_inputs", "ssao_linear_depth", "ssao_origin",
           "ssao_prepare_matrix", "ssao_radius_scale", "ssao_taps", "ssao_taps_pass",
           "ssao_upsample", "world_positions"]

#: FXAA 3.11 preset 12: search step lengths in pixels (FXAA_QUALITY__P0..P4).
FXAA_STEPS = (1.0, 1.5, 2.0, 4.0, 12.0)
FXAA_SUBPIX = 0.75
FXAA_EDGE_THRESHOLD = 0.166
FXAA_EDGE_THRESHOLD_MIN = 0.0833
#: The minimum threshold in the luma units of 8-bit channels (float32 0.0833 · 255).
FXAA_EDGE_THRESHOLD_MIN_8 = np.float32(FXAA_EDGE_THRESHOLD_MIN) * np.float32(255.0)
#: Turns of the SSAO tap spiral; coprime with the usual tap counts, so taps spread in angle.
SSAO_TURNS = 7.0
#: Most SSAO taps per pixel.
MAX_SSAO_SAMPLES = 64


class PostError(ValueError):
    """An option of a per-pixel pass that cannot be used; the message says which and why."""


@dataclass(frozen=True)
class SSAO:
    """Screen-space ambient occlusion settings (module docstring).

    Attributes:
        radius: world units; geometry farther than this from a point does not occlude it.
            None: 3% of the target's bounding-box diagonal.
        samples: taps per pixel, 1..`MAX_SSAO_SAMPLES`.
        strength: scale of the occlusion sum (≥ 0).
        bias: β, the cosine a tap's direction must exceed above the surface (0..1).
    """

    radius: float | None = None
    samples: int = 8
    strength: float = 2.5
    bias: float = 0.1

    def checked(self, default_radius: float) -> SSAO:
        r = default_radius if self.radius is None else self.radius
        if isinstance(r, bool) or not (math.isfinite(float(r)) and float(r) > 0.0):
            raise PostError(f"ssao radius must be a finite world distance > 0, got {r!r}")
        if not 1 <= int(self.samples) <= MAX_SSAO_SAMPLES:
            raise PostError(f"ssao samples must be in 1..{MAX_SSAO_SAMPLES}, got {self.samples}")
        if not (math.isfinite(self.strength) and self.strength >= 0.0):
            raise PostError(f"ssao strength must be finite and >= 0, got {self.strength}")
        if not 0.0 <= self.bias < 1.0:
            raise PostError(f"ssao bias is a cosine in [0, 1), got {self.bias}")
        return SSAO(float(r), int(self.samples), float(self.strength), float(self.bias))


@dataclass(frozen=True)
class Outlines:
    """Outline settings (module docstring): relative depth jump `depth`, normal angle
    `normal_deg` in degrees, line colour `color` RGB 0..255."""

    depth: float = 0.02
    normal_deg: float = 50.0
    color: tuple[int, int, int] = (0, 0, 0)


# -- SSAO -------------------------------------------------------------------------------------

def world_positions(depth: np.ndarray, vp: np.ndarray, reversed_z: bool,
                    z_ndc: float | None = None) -> np.ndarray:
    """float64 (H, W, 3) world points at the pixel centres from window depth through
    ``vp⁻¹`` (meaningful on covered pixels only); with `z_ndc`, the points at that NDC depth
    instead (−1: on the near plane)."""
    ndc = ndc_grid(depth, reversed_z)
    if z_ndc is not None:
        ndc[..., 2] = z_ndc
    hom = ndc @ np.linalg.inv(vp).T
    with np.errstate(divide="ignore", invalid="ignore"):
        return hom[..., :3] / hom[..., 3:4]


def ssao_taps(samples: int) -> np.ndarray:
    """float32 (N, 2): tap i's offset as a fraction of the projected radius (module
    docstring's spiral), the same numbers for the kernel and the twin."""
    a = (np.arange(samples) + 0.5) / samples
    ang = 2.0 * math.pi * SSAO_TURNS * a
    return np.stack([a * np.cos(ang), a * np.sin(ang)], axis=1).astype(np.float32)


def ssao_origin(vp: np.ndarray) -> np.ndarray:
    """float64 (3,): the world point at the centre of the near plane, which SSAO's float32
    positions are relative to (camera-relative: precise wherever the scene is)."""
    hom = np.linalg.inv(vp) @ np.array([0.0, 0.0, -1.0, 1.0])
    return hom[:3] / hom[3]


def ssao_prepare_matrix(vp: np.ndarray) -> np.ndarray:
    """float32 (4, 4): ``vp⁻¹`` (float64) moved to `ssao_origin` (rows 0..2 less the origin
    times row 3) and rounded once; row 3 is ``vp⁻¹``'s own, so ``M · ndc`` has w = 1 / clip w,
    the reciprocal of `ssao_linear_depth`. What `ssao_inputs` and kernel ``ssao_prepare``
    unproject with."""
    ivp = np.linalg.inv(vp)
    m = ivp.copy()
    m[:3] -= ssao_origin(vp)[:, None] * ivp[3][None, :]
    return m.astype(np.float32)


def ssao_radius_scale(vp: np.ndarray, radius: float, height: int) -> np.float32:
    """float32 ``radius · ‖vp[1, :3]‖ · H/4``: a point's projected radius in *low-res* pixels
    is this times its ``1 / clip w``."""
    return np.float32(radius * float(np.linalg.norm(vp[1, :3])) * (height * 0.25))


def ssao_inputs(depth: np.ndarray, normals: np.ndarray, vp: np.ndarray, reversed_z: bool,
                radius: float) -> tuple[np.ndarray, np.ndarray]:
    """SSAO's first pass at half resolution: for each low-res pixel (i, j) of the
    ``(⌈H/2⌉, ⌈W/2⌉)`` grid, the full-res pixel (2i, 2j) it stands for. float32 (h2, w2, 4)
    positions relative to `ssao_origin` (inf on the background) with the projected radius in
    *low-res* pixels as w (0 on the background), and float32 (h2, w2, 4) normals turned
    towards the camera (0 on the background) with the pixel's `ssao_linear_depth` as w (inf
    on the background). The device splits this differently, to the same bits: kernel
    ``ssao_prepare`` writes the positions and the linear depths, kernel ``ssao`` turns its
    centre pixels' normals itself.

    All in float32, in the kernels' order: the pixel centre's NDC ``(nx, ny, nz, 1)``,
    ``hom = M · ndc`` (M = `ssao_prepare_matrix`, rows summed left to right), the linear
    depth ``z = 1 / hom.w``, the point ``p = hom.xyz · z``, the radius ``k · hom.w``
    (`ssao_radius_scale`); the normal is negated where it points along the view ray
    ``p − pn`` (pn: the pixel's point on the near plane, ``g.xyz / g.w`` with
    ``g = M · (nx, ny, −1, 1)``), tested without a division as ``n · (p · g.w − g.xyz) > 0``
    (g.w > 0)."""
    f32 = np.float32
    h, w = depth.shape
    d = np.ascontiguousarray(depth[::2, ::2], dtype=f32)
    covered = (d > 0.0) if reversed_z else (d < 1.0)
    m = ssao_prepare_matrix(vp)
    sx, sy = f32(2.0 / w), f32(2.0 / h)
    nx = ((np.arange(0, w, 2, dtype=f32) + f32(0.5)) * sx - f32(1.0))[None, :]
    ny = (f32(1.0) - (np.arange(0, h, 2, dtype=f32) + f32(0.5)) * sy)[:, None]
    nz = (f32(1.0) - f32(2.0) * d) if reversed_z else (f32(2.0) * d - f32(1.0))
    p4 = np.zeros(covered.shape + (4,), f32)
    n4 = np.zeros(covered.shape + (4,), f32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        hom = [((m[r, 0] * nx + m[r, 1] * ny) + m[r, 2] * nz) + m[r, 3] for r in range(4)]
        g = [((m[r, 0] * nx + m[r, 1] * ny) - m[r, 2]) + m[r, 3] for r in range(4)]
        z = f32(1.0) / hom[3]
        for c in range(3):
            p4[..., c] = np.where(covered, hom[c] * z, f32(np.inf))
        p4[..., 3] = np.where(covered, ssao_radius_scale(vp, radius, h) * hom[3], f32(0.0))
        ray = [p4[..., c] * g[3] - g[c] for c in range(3)]
        n = normals[::2, ::2].astype(f32)
        flip = ((n[..., 0] * ray[0] + n[..., 1] * ray[1]) + n[..., 2] * ray[2]) > f32(0.0)
    n = np.where(flip[..., None], -n, n)
    n4[..., :3] = np.where(covered[..., None], n, f32(0.0))
    n4[..., 3] = np.where(covered, z, f32(np.inf))
    return p4, n4


def ssao(depth: np.ndarray, normals: np.ndarray, vp: np.ndarray, reversed_z: bool,
         params: SSAO) -> np.ndarray:
    """float32 (H, W) ambient occlusion factor in [0, 1] (1: open), 1 on the background.

    Three passes (module docstring): `ssao_inputs` (world points relative to `ssao_origin`
    in float32, at half resolution), `ssao_taps_pass` (the taps, float32, at
    half resolution) and `ssao_upsample` (depth-aware, back to full resolution).

    Args:
        depth: float32 (H, W) window depth (background 1.0, or 0.0 with `reversed_z`).
        normals: float32 (H, W, 3) unit world normals.
        vp: float64 (4, 4) the view-projection the frame was rendered with.
        params: a checked `SSAO` (radius set).
    """
    assert params.radius is not None
    p4, n4 = ssao_inputs(depth, normals, vp, reversed_z, params.radius)
    return ssao_upsample(depth, n4[..., 3], ssao_taps_pass(p4, n4, params), vp, reversed_z)


def ssao_taps_pass(p4: np.ndarray, n4: np.ndarray, params: SSAO) -> np.ndarray:
    """SSAO's second pass in float32 over the half-resolution grid (the twin of kernel
    ``ssao``): float32 (h2, w2). A low-res pixel's centre is its full-res pixel's,
    ``(j + ¼, i + ¼)`` in low-res pixels; taps read the low-res pixel whose square holds
    them."""
    assert params.radius is not None
    f32 = np.float32
    h, w = p4.shape[:2]
    out = np.ones((h, w), np.float32)
    covered = p4[..., 3] > 0
    ys, xs = np.nonzero(covered)
    if not ys.size:
        return out
    p = p4[ys, xs, :3]
    nv = n4[ys, xs, :3]
    rpx = p4[ys, xs, 3]
    r2 = f32(params.radius) * f32(params.radius)
    inv_r2 = f32(1.0) / r2
    bias = f32(params.bias)
    occ = np.zeros(ys.size, np.float32)
    fx = xs.astype(np.float32) + f32(0.25)
    fy = ys.astype(np.float32) + f32(0.25)
    for ox, oy in ssao_taps(params.samples):
        qx = np.floor(fx + rpx * ox).astype(np.int64)
        qy = np.floor(fy + rpx * oy).astype(np.int64)
        ok = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
        qxc, qyc = np.clip(qx, 0, w - 1), np.clip(qy, 0, h - 1)
        ok &= covered[qyc, qxc] & ~((qx == xs) & (qy == ys))
        # a background tap's point is at infinity: |v|² < R² fails (inf, or nan × 0 in vn)
        with np.errstate(invalid="ignore", over="ignore"):
            v = p4[qyc, qxc, :3] - p
            vv = (v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) + v[:, 2] * v[:, 2]
            ok &= vv < r2
            vn = ((v[:, 0] * nv[:, 0] + v[:, 1] * nv[:, 1]) + v[:, 2] * nv[:, 2]) / np.sqrt(
                np.where(ok, vv, f32(1.0)))
            term = (f32(1.0) - vv * inv_r2) * np.maximum(vn - bias, f32(0.0))
        occ = occ + np.where(ok, term, f32(0.0))
    ao = f32(1.0) - (f32(params.strength) / f32(params.samples)) * occ
    out[ys, xs] = np.clip(ao, f32(0.0), f32(1.0))
    return out


#: `ssao_upsample`: a low-res sample counts for a full-res pixel when their linear depths
#: differ by at most this fraction of the pixel's.
SSAO_UPSAMPLE_DEPTH = 0.03


def ssao_linear_depth(depth: np.ndarray, ivp_w: np.ndarray, reversed_z: bool) -> np.ndarray:
    """float32 (H, W): the clip w (a depth linear along the view axis) of each pixel centre,
    ``1 / (vp⁻¹[3] · ndc)`` in float32 (the kernel ``ssao_upsample``'s expression);
    `ivp_w` float32 (4,) the last row of ``vp⁻¹``."""
    f32 = np.float32
    h, w = depth.shape
    nx = ((np.arange(w, dtype=f32) + f32(0.5)) * f32(2.0 / w) - f32(1.0))[None, :]
    ny = (f32(1.0) - (np.arange(h, dtype=f32) + f32(0.5)) * f32(2.0 / h))[:, None]
    d = depth.astype(f32)
    nz = (f32(1.0) - f32(2.0) * d) if reversed_z else (f32(2.0) * d - f32(1.0))
    with np.errstate(divide="ignore"):
        return f32(1.0) / (((ivp_w[0] * nx + ivp_w[1] * ny) + ivp_w[2] * nz) + ivp_w[3])


def ssao_upsample(depth: np.ndarray, z_low: np.ndarray, ao_low: np.ndarray, vp: np.ndarray,
                  reversed_z: bool) -> np.ndarray:
    """SSAO's third pass (kernel ``ssao_upsample``): float32 (H, W) from the float32
    (⌈H/2⌉, ⌈W/2⌉) low-res factor `ao_low` and linear depths `z_low` (`ssao_inputs`'s
    normals' w: inf on the background). Pixel (y, x) blends the low-res samples (y//2 + a,
    x//2 + b), a, b ∈ {0, 1} (clamped to the grid), with bilinear weights (their full-res
    pixels lie 0 or 1 pixel away: weights 1, ½·½ …) times a depth gate (covered, linear
    depth within `SSAO_UPSAMPLE_DEPTH` of the pixel's); where no sample passes the gate,
    the covered sample nearest in depth; 1 on the background and where none is covered.
    A pixel of even (y, x) gets its own sample exactly."""
    f32 = np.float32
    h, w = depth.shape
    h2, w2 = ao_low.shape
    covered = (depth > 0.0) if reversed_z else (depth < 1.0)
    ivp_w = np.linalg.inv(vp)[3].astype(f32)
    z = ssao_linear_depth(depth, ivp_w, reversed_z)
    zl = z_low
    y0 = (np.arange(h) >> 1)[:, None]
    x0 = (np.arange(w) >> 1)[None, :]
    ty = np.broadcast_to((np.arange(h) & 1).astype(f32)[:, None] * f32(0.5), (h, w))
    tx = np.broadcast_to((np.arange(w) & 1).astype(f32)[None, :] * f32(0.5), (h, w))
    tol = z * f32(SSAO_UPSAMPLE_DEPTH)
    num = np.zeros((h, w), f32)
    den = np.zeros((h, w), f32)
    best = np.full((h, w), np.inf, f32)
    best_ao = np.ones((h, w), f32)
    for a in (0, 1):
        for b in (0, 1):
            yy = np.minimum(y0 + a, h2 - 1)
            xx = np.minimum(x0 + b, w2 - 1)
            zq = zl[yy, xx]
            aq = ao_low[yy, xx]
            wy = ty if a else f32(1.0) - ty
            wx = tx if b else f32(1.0) - tx
            wgt = wy * wx
            dz = np.abs(zq - z)
            ok = dz <= tol
            num = num + np.where(ok, wgt * aq, f32(0.0))
            den = den + np.where(ok, wgt, f32(0.0))
            nearer = dz < best
            best = np.where(nearer, dz, best)
            best_ao = np.where(nearer, aq, best_ao)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > f32(0.0), num / den, best_ao)
    return np.where(covered, out, f32(1.0)).astype(f32)


# -- FXAA 3.11 ---------------------------------------------------------------------------------

def luma(rgb: np.ndarray) -> np.ndarray:
    """float32 (H, W) luma ``(0.299 R + 0.587 G) + 0.114 B`` of (H, W, 3) RGB, in the units
    of its channels (0..255 for the uint8 images `fxaa` takes)."""
    c = np.asarray(rgb).astype(np.float32)
    return (c[..., 0] * np.float32(0.299) + c[..., 1] * np.float32(0.587)
            + c[..., 2] * np.float32(0.114))


def rgb8(rgb: Any, name: str = "fxaa") -> np.ndarray:
    """`rgb` as a C-contiguous uint8 (H, W, 3) image, or a PostError saying what it was."""
    a = np.asarray(rgb)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or 0 in a.shape:
        raise PostError(f"{name} takes an 8-bit RGB image, uint8 (H, W, 3) with H, W >= 1, got "
                        f"{a.dtype} {a.shape}; quantize a float image in [0, 1] with "
                        f"np.rint(img * 255).astype(np.uint8) and drop any alpha first")
    return np.ascontiguousarray(a)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear read of float32 `img` (H, W[, C]) at pixel coordinates x, y (pixel centres
    at i + 0.5), clamped to the edge."""
    h, w = img.shape[:2]
    fx = x - np.float32(0.5)
    fy = y - np.float32(0.5)
    x0 = np.floor(fx)
    y0 = np.floor(fy)
    tx = fx - x0
    ty = fy - y0
    c0 = np.clip(x0.astype(np.int64), 0, w - 1)
    c1 = np.clip(x0.astype(np.int64) + 1, 0, w - 1)
    r0 = np.clip(y0.astype(np.int64), 0, h - 1)
    r1 = np.clip(y0.astype(np.int64) + 1, 0, h - 1)
    if img.ndim == 3:
        tx = tx[:, None]
        ty = ty[:, None]
    top = img[r0, c0] + (img[r0, c1] - img[r0, c0]) * tx
    bot = img[r1, c0] + (img[r1, c1] - img[r1, c0]) * tx
    return top + (bot - top) * ty


def fxaa(rgb: np.ndarray) -> np.ndarray:
    """FXAA 3.11 (module docstring) of an 8-bit display image, uint8 (H, W, 3): a new uint8
    (H, W, 3)."""
    img = rgb8(rgb)
    c = img.astype(np.float32)
    lum = luma(c)
    pad = np.pad(lum, 1, mode="edge")
    lM = lum
    lN, lS = pad[:-2, 1:-1], pad[2:, 1:-1]
    lW, lE = pad[1:-1, :-2], pad[1:-1, 2:]
    range_max = np.maximum(np.maximum(lN, lW), np.maximum(lE, np.maximum(lS, lM)))
    range_min = np.minimum(np.minimum(lN, lW), np.minimum(lE, np.minimum(lS, lM)))
    rng = range_max - range_min
    todo = ~(rng < np.maximum(FXAA_EDGE_THRESHOLD_MIN_8,
                              range_max * np.float32(FXAA_EDGE_THRESHOLD)))
    out = img.copy()
    ys, xs = np.nonzero(todo)
    if not ys.size:
        return out
    f32 = np.float32
    m = lM[ys, xs]
    n_, s_, w_, e_ = lN[ys, xs], lS[ys, xs], lW[ys, xs], lE[ys, xs]
    nw, se = pad[ys, xs], pad[ys + 2, xs + 2]
    ne, sw = pad[ys, xs + 2], pad[ys + 2, xs]
    rcp_range = f32(1.0) / rng[ys, xs]
    ns = n_ + s_
    we = w_ + e_
    subpix_nswe = ns + we
    edge_h1 = f32(-2.0) * m + ns
    edge_v1 = f32(-2.0) * m + we
    nese = ne + se
    nwne = nw + ne
    edge_h2 = f32(-2.0) * e_ + nese
    edge_v2 = f32(-2.0) * n_ + nwne
    nwsw = nw + sw
    swse = sw + se
    edge_h4 = np.abs(edge_h1) * f32(2.0) + np.abs(edge_h2)
    edge_v4 = np.abs(edge_v1) * f32(2.0) + np.abs(edge_v2)
    edge_h3 = f32(-2.0) * w_ + nwsw
    edge_v3 = f32(-2.0) * s_ + swse
    edge_h = np.abs(edge_h3) + edge_h4
    edge_v = np.abs(edge_v3) + edge_v4
    subpix_nwswnese = nwsw + nese
    horz = edge_h >= edge_v
    subpix_a = subpix_nswe * f32(2.0) + subpix_nwswnese
    n_ = np.where(horz, n_, w_)
    s_ = np.where(horz, s_, e_)
    subpix_b = subpix_a * f32(1.0 / 12.0) - m
    grad_n = n_ - m
    grad_s = s_ - m
    l_nn = n_ + m
    l_ss = s_ + m
    pair_n = np.abs(grad_n) >= np.abs(grad_s)
    gradient = np.maximum(np.abs(grad_n), np.abs(grad_s))
    length_sign = np.where(pair_n, f32(-1.0), f32(1.0))
    subpix_c = np.clip(np.abs(subpix_b) * rcp_range, f32(0.0), f32(1.0))
    pmx = xs.astype(np.float32) + f32(0.5)
    pmy = ys.astype(np.float32) + f32(0.5)
    # posB: half a pixel across the edge, towards the steeper neighbour
    pbx = np.where(horz, pmx, pmx + length_sign * f32(0.5))
    pby = np.where(horz, pmy + length_sign * f32(0.5), pmy)
    offx = np.where(horz, f32(1.0), f32(0.0))
    offy = np.where(horz, f32(0.0), f32(1.0))
    p0 = f32(FXAA_STEPS[0])
    pnx, pny = pbx - offx * p0, pby - offy * p0
    ppx, ppy = pbx + offx * p0, pby + offy * p0
    subpix_d = f32(-2.0) * subpix_c + f32(3.0)
    end_n = _bilinear(lum, pnx, pny)
    subpix_e = subpix_c * subpix_c
    end_p = _bilinear(lum, ppx, ppy)
    l_nn = np.where(pair_n, l_nn, l_ss)
    grad_scaled = gradient * f32(1.0 / 4.0)
    l_mm = m - l_nn * f32(0.5)
    subpix_f = subpix_d * subpix_e
    mlt_zero = l_mm < f32(0.0)
    end_n = end_n - l_nn * f32(0.5)
    end_p = end_p - l_nn * f32(0.5)
    done_n = np.abs(end_n) >= grad_scaled
    done_p = np.abs(end_p) >= grad_scaled
    for step in FXAA_STEPS[1:]:
        st = f32(step)
        pnx = np.where(done_n, pnx, pnx - offx * st)
        pny = np.where(done_n, pny, pny - offy * st)
        ppx = np.where(done_p, ppx, ppx + offx * st)
        ppy = np.where(done_p, ppy, ppy + offy * st)
        if step == FXAA_STEPS[-1]:
            break
        go_n, go_p = ~done_n, ~done_p
        if not (go_n.any() or go_p.any()):
            break
        end_n = np.where(go_n, _bilinear(lum, pnx, pny) - l_nn * f32(0.5), end_n)
        end_p = np.where(go_p, _bilinear(lum, ppx, ppy) - l_nn * f32(0.5), end_p)
        done_n = np.abs(end_n) >= grad_scaled
        done_p = np.abs(end_p) >= grad_scaled
    dst_n = np.where(horz, pmx - pnx, pmy - pny)
    dst_p = np.where(horz, ppx - pmx, ppy - pmy)
    good_n = (end_n < f32(0.0)) != mlt_zero
    good_p = (end_p < f32(0.0)) != mlt_zero
    span_rcp = f32(1.0) / (dst_p + dst_n)
    dir_n = dst_n < dst_p
    dst = np.minimum(dst_n, dst_p)
    good = np.where(dir_n, good_n, good_p)
    subpix_g = subpix_f * subpix_f
    pixel_offset = dst * (-span_rcp) + f32(0.5)
    subpix_h = subpix_g * f32(FXAA_SUBPIX)
    offset = np.maximum(np.where(good, pixel_offset, f32(0.0)), subpix_h)
    fx = np.where(horz, pmx, pmx + offset * length_sign)
    fy = np.where(horz, pmy + offset * length_sign, pmy)
    out[ys, xs] = np.rint(_bilinear(c, fx, fy)).astype(np.uint8)
    return out


# -- cel shading and outlines ------------------------------------------------------------------

def cel_quantize(diffuse: np.ndarray, levels: int) -> np.ndarray:
    """`diffuse` (any shape, values in [0, 1]) quantized to `levels` ≥ 2 bands (module
    docstring): float64, 0 below 1/levels, 1 from (levels − 1)/levels up."""
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 2:
        raise PostError(f"cel levels must be an integer >= 2, got {levels!r}")
    q = np.minimum(np.floor(np.asarray(diffuse, np.float64) * levels), levels - 1)
    return q / (levels - 1)


def outline_mask(covered: np.ndarray, lin_depth: np.ndarray, normals: np.ndarray,
                 params: Outlines) -> np.ndarray:
    """bool (H, W): covered pixels on an outline (module docstring).

    Args:
        covered: bool (H, W). lin_depth: float (H, W) linear (view-axis) depth, any value
            on the background. normals: float (H, W, 3) unit normals.
    """
    h, w = covered.shape
    out = np.zeros((h, w), bool)
    cos_max = math.cos(math.radians(params.normal_deg))
    z = np.where(covered, lin_depth, np.inf)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ys = slice(max(dy, 0), h + min(dy, 0))
        xs = slice(max(dx, 0), w + min(dx, 0))
        yd = slice(max(-dy, 0), h + min(-dy, 0))
        xd = slice(max(-dx, 0), w + min(-dx, 0))
        here, there = z[yd, xd], z[ys, xs]
        with np.errstate(invalid="ignore"):
            jump = there - here > params.depth * np.abs(here)
        crease = np.einsum("hwc,hwc->hw", normals[yd, xd], normals[ys, xs]) < cos_max
        out[yd, xd] |= covered[yd, xd] & (~covered[ys, xs] | jump | (crease & covered[ys, xs]))
    return out


# -- the passes render_shaded runs, and where they run ------------------------------------------

class Passes(Protocol):
    """The per-pixel passes of render_shaded (arguments as the NumPy functions of the same
    names: `clraster.output.lights.shadow_lookup`, `ssao`, `fxaa`)."""

    def shadow(self, smap: ShadowMap, light: Light, depth: np.ndarray, normals: np.ndarray,
               vp: np.ndarray, reversed_z: bool) -> np.ndarray: ...

    def ssao(self, depth: np.ndarray, normals: np.ndarray, vp: np.ndarray, reversed_z: bool,
             params: SSAO) -> np.ndarray: ...

    def fxaa(self, rgb: np.ndarray) -> np.ndarray: ...


class _NumpyPasses:
    """The passes on the host, in NumPy (any renderer; the twin of the kernels)."""

    def shadow(self, smap: ShadowMap, light: Light, depth: np.ndarray, normals: np.ndarray,
               vp: np.ndarray, reversed_z: bool) -> np.ndarray:
        return shadow_lookup(smap, light, depth, normals, vp, reversed_z)

    def ssao(self, depth: np.ndarray, normals: np.ndarray, vp: np.ndarray, reversed_z: bool,
             params: SSAO) -> np.ndarray:
        return ssao(depth, normals, vp, reversed_z, params)

    def fxaa(self, rgb: np.ndarray) -> np.ndarray:
        return fxaa(rgb)


NUMPY_PASSES: Passes = _NumpyPasses()
#: Factories ``f(renderer) -> Passes | None`` registered by faster implementations, most
#: recent first; the first that accepts a renderer runs its passes.
_FACTORIES: list[Callable[[Any], Passes | None]] = []


def register_passes(factory: Callable[[Any], Passes | None]) -> None:
    """Offer `factory` to `passes_for`: it returns passes for the renderers it can serve
    (e.g. an OpenCL renderer's context) and None for the others. Registering a factory
    twice keeps one copy."""
    if factory not in _FACTORIES:
        _FACTORIES.insert(0, factory)


def passes_for(renderer: Any) -> Passes:
    """The passes for frames of `renderer`: the first registered factory's that accepts it,
    else `NUMPY_PASSES`."""
    for factory in _FACTORIES:
        got = factory(renderer)
        if got is not None:
            return got
    return NUMPY_PASSES
