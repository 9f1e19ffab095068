"""The viewer's pictures: what a rendered frame looks like in each mode, as packed pixels.

Every mapping returns an (H, W) uint32 array of packed RGBX pixels (little-endian bytes R,
G, B, 255), which ``.view(np.uint8).reshape(H, W, 4)`` turns into the RGBX image that the
JPEG encoder takes without a copy. Each is a table lookup or a few float32 operations per
pixel, so colouring a 1280×720 frame costs a few milliseconds (bench/README.md's log),
far less than the render; `clraster.shade.shade` (its host path, ~200 ms at 720p for the 10M
plant) is the reference the shaded table reproduces (`tests/test_viewer.py`).

Modes (`MODES`): ``shaded`` (flat two-sided Lambert, `clraster.shade.shade`'s formula and
defaults: ``albedo · (ambient + (1 − ambient) · |n · l|)``, precomputed per triangle),
``depth`` (eye distance on a log scale between the camera's near and far planes),
``overdraw`` (fragments tested per pixel, heat ramp saturating at `OVERDRAW_TOP`), ``hiz``
(one level of the Hi-Z pyramid — the farthest depth over each texel's footprint, the
pyramid the occlusion test reads, built by the NumPy twin's `build`, which the device's
pyramid equals texel for texel — drawn like ``depth``), ``ids`` (each triangle id hashed to
a colour by a bijection of 24-bit numbers, so a lossless picture gives the ids back:
`ids_from_rgb`), and ``fates`` (the third-person view with clusters coloured by their fate
in the first-person frame: `clraster.viewer.inspect`).
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np

from ..culling.fates import Fate
from ..output.annotate import DEPTH_RAMP, HEAT, ramp

__all__ = ["BACKGROUND", "FATE_COLORS", "MODES", "OVERDRAW_TOP", "depth_pixels",
           "encode", "face_table", "hiz_pixels", "ids_from_rgb", "ids_pixels", "overdraw_pixels",
           "pack", "rgb", "shaded_pixels"]

MODES = ("shaded", "depth", "fates", "overdraw", "hiz", "ids")
#: Background of the shaded, fates and ids pictures (ids: black is id −1).
BACKGROUND = (28, 30, 36)
#: RGB of each cluster fate: the demo's colours (`clraster.demo.FATE_COLORS`; the viewer
#: sits below the command lines and cannot import them, a test keeps the two equal).
FATE_COLORS = {
    Fate.DRAWN: (70, 200, 90),
    Fate.FRUSTUM_CULLED: (80, 130, 230),
    Fate.BACKFACE_CULLED: (250, 170, 40),
    Fate.OCCLUSION_CULLED: (215, 55, 65),
}
#: The overdraw ramp saturates at this many fragments per pixel (fixed, so that the colours
#: mean the same from frame to frame while walking).
OVERDRAW_TOP = 16
#: Entries of the depth ramp's lookup table (log distance quantized to this many steps).
DEPTH_STEPS = 1024
#: Odd multiplier of the ids mode's hash (``(id + 1) · M mod 2²⁴``, invertible mod 2²⁴).
_ID_MULT = 0x9E3779B1 & 0xFFFFFF
_ID_INV = pow(_ID_MULT, -1, 1 << 24)
# shade's flat defaults (clraster.output.shade: _ALBEDO, _AMBIENT, DEFAULT_LIGHT_DIR)
_ALBEDO = np.array([0.80, 0.82, 0.88])
_AMBIENT = 0.22
_LIGHT = np.array([0.35, 0.85, 0.45]) / np.linalg.norm([0.35, 0.85, 0.45])


def pack(rgb_u8: Any) -> np.ndarray:
    """Packed RGBX uint32 of uint8 RGB values (..., 3)."""
    c = np.asarray(rgb_u8, np.uint32)
    return c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16) | np.uint32(0xFF000000)


def rgb(pixels: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB of packed (H, W) uint32 pixels (a copy)."""
    return np.ascontiguousarray(pixels.view(np.uint8).reshape(*pixels.shape, 4)[..., :3])


def _lut(stops: Any, n: int) -> np.ndarray:
    return pack(ramp(np.linspace(0.0, 1.0, n), stops))


_DEPTH_LUT = np.append(_lut(DEPTH_RAMP, DEPTH_STEPS), pack(BACKGROUND))   # last: background
_HEAT_LUT = _lut(HEAT, OVERDRAW_TOP + 1)


def face_table(scene: Any) -> np.ndarray:
    """uint32 (F + 1,) packed colour of every triangle id of `scene` (a `clraster.Scene`)
    under flat two-sided Lambert shading with `clraster.shade.shade`'s defaults (albedo,
    ambient, light direction, normals through each instance's ``M⁻ᵀ`` without a sign
    change), rounded as shade rounds; entry F (= index −1) is `BACKGROUND`, so
    ``table[triangle_id]`` is the picture. Computed once per scene (8 bytes per triangle
    while it runs, 4 kept)."""
    parts = [np.empty(0, np.uint32)]
    normals: dict[int, np.ndarray] = {}
    for inst in scene.instances:
        key = id(inst.mesh)
        if key not in normals:
            normals[key] = np.asarray(inst.mesh.face_normals(), np.float64)
        n = normals[key]
        m = np.linalg.inv(np.asarray(inst.transform, np.float64)[:3, :3]).T
        nw = n @ m.T
        length = np.linalg.norm(nw, axis=1)
        lam = np.abs(nw @ _LIGHT) / np.where(length > 0, length, 1.0)
        col = _ALBEDO * (_AMBIENT + (1.0 - _AMBIENT) * lam[:, None])
        parts.append(pack(np.clip(np.rint(col * 255.0), 0, 255)))
    parts.append(pack(np.array(BACKGROUND)).reshape(1))
    return np.concatenate(parts)


def shaded_pixels(ids: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Packed (H, W) shaded picture: ``table[ids]`` (`face_table`; −1 → background)."""
    return table[ids]


def _distance(depth: np.ndarray, projection: np.ndarray) -> np.ndarray:
    """float32 eye distance along the view axis of window depth ``d = (z/w + 1)/2`` under a
    perspective `projection` (its z rows): ``p23 / (p22 − p32 · z_ndc)``."""
    p22, p23, p32 = (np.float32(projection[i, j]) for i, j in ((2, 2), (2, 3), (3, 2)))
    zn = depth * np.float32(2.0) - np.float32(1.0)
    return p23 / (p22 - p32 * zn)


def depth_pixels(depth: np.ndarray, projection: np.ndarray, near: float, far: float
                 ) -> np.ndarray:
    """Packed (H, W) picture of float32 window depth (cleared to 1.0 = background): eye
    distance on a log scale from `near` (ramp start) to `far` (ramp end), `DEPTH_STEPS`
    steps, through the perspective `projection` ((4, 4), the frame's)."""
    d = np.asarray(depth, np.float32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        dist = _distance(d, projection)
        t = np.log(np.maximum(dist, np.float32(near)) / np.float32(near))
    t *= np.float32((DEPTH_STEPS - 1) / math.log(far / near))
    idx = np.clip(t, 0, DEPTH_STEPS - 1).astype(np.int32)
    idx[~(d < 1.0)] = DEPTH_STEPS   # background (and NaN): the table's last entry
    return _DEPTH_LUT[idx]


def hiz_pixels(depth: np.ndarray, level: int, projection: np.ndarray, near: float,
               far: float) -> tuple[np.ndarray, int]:
    """(packed (H, W) picture, level shown) of Hi-Z pyramid level `level` (clamped to the
    pyramid's levels) of float32 window `depth`, each texel drawn over its level-0
    footprint and coloured as `depth_pixels` colours its value (the farthest depth under
    the footprint)."""
    from ..pipeline.reference.pyramid import build

    levels = build(np.asarray(depth, np.float32))
    k = int(min(max(level, 0), len(levels) - 1))
    h, w = levels[0].shape
    big = np.repeat(np.repeat(levels[k], 1 << k, axis=0), 1 << k, axis=1)[:h, :w]
    return depth_pixels(big, projection, near, far), k


def overdraw_pixels(overdraw: np.ndarray) -> np.ndarray:
    """Packed (H, W) heat picture of fragments tested per pixel, 0 black to `OVERDRAW_TOP`
    or more white (`clraster.output.annotate.HEAT`)."""
    return _HEAT_LUT[np.minimum(np.asarray(overdraw), OVERDRAW_TOP)]


def ids_pixels(ids: np.ndarray) -> np.ndarray:
    """Packed (H, W) picture of triangle ids: colour ``c = (id + 1) · M mod 2²⁴`` as
    R = c & 255, G = c >> 8 & 255, B = c >> 16, background (−1) black. A bijection for ids
    below 2²⁴ − 1 (`ids_from_rgb` inverts it)."""
    c = ((np.asarray(ids).astype(np.uint32) + np.uint32(1)) * np.uint32(_ID_MULT)) \
        & np.uint32(0xFFFFFF)
    return c | np.uint32(0xFF000000)


def ids_from_rgb(image: Any) -> np.ndarray:
    """int64 (H, W) triangle ids of an (H, W, ≥3) uint8 ids picture (`ids_pixels`), −1 for
    black."""
    a = np.asarray(image)[..., :3].astype(np.int64)
    c = a[..., 0] | (a[..., 1] << 8) | (a[..., 2] << 16)
    return ((c * _ID_INV) & 0xFFFFFF) - 1


def encode(pixels: np.ndarray, fmt: str, quality: int = 80) -> bytes:
    """Packed (H, W) pixels as ``"jpeg"`` (simplejpeg where installed — libjpeg-turbo,
    1.5× faster than Pillow here (bench/README.md), GIL released — else Pillow) or
    ``"png"`` (lossless, Pillow, fast compression)."""
    img = pixels.view(np.uint8).reshape(*pixels.shape, 4)
    if fmt == "jpeg":
        try:
            import simplejpeg
        except ImportError:
            simplejpeg = None
        if simplejpeg is not None:
            return bytes(simplejpeg.encode_jpeg(img, quality=quality, colorspace="RGBX",
                                                colorsubsampling="420", fastdct=True))
    from PIL import Image

    pic = Image.frombuffer("RGBX", (img.shape[1], img.shape[0]), img, "raw", "RGBX", 0, 1)
    out = io.BytesIO()
    if fmt == "jpeg":
        pic.convert("RGB").save(out, "JPEG", quality=quality)
    elif fmt == "png":
        pic.convert("RGB").save(out, "PNG", compress_level=1)
    else:
        raise ValueError(f"image format must be 'jpeg' or 'png', got {fmt!r}")
    return out.getvalue()
