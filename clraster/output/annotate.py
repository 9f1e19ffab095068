"""Lettering, panels, colour ramps and colour bars drawn onto RGB pictures.

The picture helpers behind ``clraster demo`` (`clraster.demo`), kept apart from the
command's scene, camera and inspector logic. Every function draws in place into an image
``img`` of shape (H, W, 3), dtype uint8, row 0 at the top, column 0 at the left; whatever
falls outside the image is clipped.

Text is drawn with Pillow: `PIL.ImageFont.load_default` at a size, which is the Aileron
Regular font embedded in Pillow, rendered through FreeType (every Pillow wheel has it)
and anti-aliased over the pixels beneath. Sizes follow a UI scale, `ui_scale`: 1 below
720 pixels on the short side, 2 from 720, 3 from 1080 and so on, so the lettering keeps its
size relative to the picture. Layout is in units of `TEXT_HEIGHT` pixels per scale step:
the height of a line of text, from the top of its capitals to its baseline (descenders hang
about 2 more below); `draw_text` puts the top of the capitals where it is told.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

__all__ = ["DEPTH_RAMP", "HEAT", "TEXT_HEIGHT", "colorbar", "draw_text", "nice_step",
           "panel", "ramp", "text_width", "ui_scale"]

#: Height of a line of text above its baseline, in pixels per UI scale step; the layout
#: of panels and colour bars is built from it (the font inks 7 or 8: see `_FONT_SIZE`).
TEXT_HEIGHT = 7
#: Font size (pixels per em) per UI scale step. Aileron at 10 px inks capitals, digits and
#: ascenders 8 rows tall (7 and a faint anti-aliased one) and descenders 2 rows deep: the
#: `TEXT_HEIGHT` box give or take a row. Smaller sizes fit the box exactly but blur into
#: illegibility at scale 1 (9 and 9.5 px were tried).
_FONT_SIZE = 10


def ui_scale(width: int, height: int) -> int:
    """Scale step (int >= 1) of the lettering and the panels on a width × height picture."""
    return max(1, min(width, height) // 360)


@lru_cache(maxsize=8)
def _font(scale: int) -> tuple[ImageFont.FreeTypeFont | ImageFont.ImageFont, int]:
    """(font, ascent) at UI scale `scale`: ascent is the height in pixels of the ink of
    capitals, digits and ascenders above the baseline."""
    font = ImageFont.load_default(size=_FONT_SIZE * scale)
    return font, -int(font.getbbox("Hd0", anchor="ls")[1])


def text_width(s: str, scale: int) -> int:
    """Advance width of `s` in pixels (rounded up) at UI scale `scale`."""
    return int(math.ceil(_font(scale)[0].getlength(s)))


def draw_text(img: np.ndarray, x: int, y: int, s: str, color, scale: int = 1) -> None:
    """Draw `s` into `img` (H, W, 3) uint8 in RGB `color`, at UI scale `scale`, with the
    top of its capitals, digits and ascenders at row `y` (brackets may reach a row higher,
    descenders hang below the baseline) and its pen starting at column `x`; clipped."""
    h, w = img.shape[:2]
    font, ascent = _font(scale)
    base = y + ascent
    left, top, right, bottom = font.getbbox(s, anchor="ls")  # ink box around (0, baseline)
    # one pixel of margin: anti-aliasing may touch the pixel beside the ink box
    x0, y0 = max(0, x + left - 1), max(0, base + top - 1)
    x1, y1 = min(w, x + right + 1), min(h, base + bottom + 1)
    if x1 <= x0 or y1 <= y0:
        return
    # draw into a copy of just the pixels under the text, then put it back
    tile = Image.fromarray(np.ascontiguousarray(img[y0:y1, x0:x1]))
    ImageDraw.Draw(tile).text((x - x0, base - y0), s, fill=tuple(int(c) for c in color),
                              font=font, anchor="ls")
    img[y0:y1, x0:x1] = np.asarray(tile)


def panel(img: np.ndarray, x0: int, y0: int, x1: int, y1: int, alpha: float = 0.75) -> None:
    """Darken the rectangle [x0, x1) × [y0, y1) of `img` (clipped) so text on it stays
    legible: each pixel becomes ``(1 - alpha) · pixel + alpha · 12``."""
    h, w = img.shape[:2]
    x0, x1, y0, y1 = max(0, x0), min(w, x1), max(0, y0), min(h, y1)
    if x1 > x0 and y1 > y0:
        img[y0:y1, x0:x1] = (img[y0:y1, x0:x1] * (1.0 - alpha) + 12 * alpha).astype(np.uint8)


# -- colour ramps ----------------------------------------------------------------------
# A ramp is a sequence of stops (t, (r, g, b)), t increasing from 0 to 1, colours 0..255.

#: A perceptual-ish heat ramp (black → purple → red → orange → yellow → white).
HEAT = ((0.0, (0, 0, 4)), (0.15, (40, 11, 84)), (0.35, (120, 28, 109)),
        (0.55, (200, 60, 60)), (0.75, (245, 140, 30)), (0.9, (250, 220, 70)),
        (1.0, (252, 255, 210)))
#: Depth ramp: near = warm light, far = deep blue.
DEPTH_RAMP = ((0.0, (253, 231, 37)), (0.25, (94, 201, 98)), (0.5, (33, 145, 140)),
              (0.75, (59, 82, 139)), (1.0, (40, 10, 70)))


def ramp(t: np.ndarray, stops) -> np.ndarray:
    """Piecewise-linear colour ramp: t in [0, 1] (any shape) → uint8 (..., 3)."""
    xs = np.array([s[0] for s in stops])
    cs = np.array([s[1] for s in stops], np.float64)
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
    out = np.stack([np.interp(t, xs, cs[:, k]) for k in range(3)], axis=-1)
    return np.rint(out).astype(np.uint8)


def colorbar(img: np.ndarray, stops, ticks: list[tuple[float, str]], title: str) -> None:
    """A horizontal colour bar of ramp `stops` with tick labels (``(t in [0, 1], label)``)
    below it and a title above it, on a dark panel in the lower right corner of `img`."""
    h, w = img.shape[:2]
    s = ui_scale(w, h)
    bar_w = min(w - 16 * s, max(160, w // 3))
    bar_h = 8 * s
    pad = 6 * s
    label_w = max(text_width(lbl, s) for _, lbl in ticks)
    title_w = text_width(title, s)
    x1 = w - pad - label_w // 2 - 2 * s
    x0 = x1 - bar_w
    panel_x0 = min(x0 - label_w // 2, x1 - title_w) - pad
    y1 = h - pad - (TEXT_HEIGHT + 3) * s    # bar bottom, tick labels below
    y0 = y1 - bar_h
    ty = y0 - (TEXT_HEIGHT + 4) * s         # title above
    panel(img, panel_x0, ty - pad, w, h)
    img[y0:y1, x0:x1] = ramp(np.linspace(0, 1, x1 - x0), stops)[None, :, :]
    draw_text(img, x1 - title_w, ty, title, (235, 235, 235), s)
    for t, lbl in ticks:
        x = x0 + int(round(t * (x1 - x0 - 1)))
        img[y1:y1 + 2 * s, max(0, x - (s // 2)):x + max(1, s // 2 + 1)] = (235, 235, 235)
        # centred on its tick by advance width (the font's side bearings are even)
        draw_text(img, x - text_width(lbl, s) // 2, y1 + 3 * s, lbl, (235, 235, 235), s)


def nice_step(span: float, n: int = 5) -> float:
    """The smallest of 1, 2, 5, 10 × a power of ten that cuts `span` into at most `n`
    steps (1.0 when `span` <= 0): the tick spacing of a colour bar."""
    raw = span / max(n, 1)
    mag = 10.0 ** math.floor(math.log10(raw)) if raw > 0 else 1.0
    return next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
