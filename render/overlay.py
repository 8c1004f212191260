"""2-D overlays on rendered frames: text labels, the colour and force-scale legend, and the grid of panels.

Text is drawn with Pillow when it is installed, otherwise with a built-in 5x7 bitmap font in NumPy. Frames are
(H, W, 3) uint8 RGB arrays throughout.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

__all__ = ["draw_text_block", "draw_legend", "grid", "grid_shape", "even_size"]

_FG = (30, 30, 34)
_BOX = (255, 255, 255)


@lru_cache(maxsize=8)
def _pil_font(size: int):
    try:
        from PIL import ImageFont
    except ImportError:
        return None
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


def _font_size(height: int) -> int:
    return max(9, int(round(height / 32)))


def draw_text_block(img: np.ndarray, lines, corner: str = "tl", swatches=None) -> np.ndarray:
    """Draw ``lines`` (str) in a translucent white box at a corner ("tl", "bl") of ``img`` (H, W, 3) uint8.

    swatches: optional RGB colours (0-255), one per line or None, drawn as a small dot before the line.
    Returns a new array.
    """
    lines = [str(x) for x in lines if str(x)]
    if not lines:
        return img
    swatches = list(swatches) if swatches is not None else [None] * len(lines)
    size = _font_size(img.shape[0])
    font = _pil_font(size)
    if font is not None:
        return _pil_block(img, lines, corner, swatches, font, size)
    return _bitmap_block(img, lines, corner, swatches, max(1, size // 9))


def _pil_block(img, lines, corner, swatches, font, size):
    from PIL import Image, ImageDraw

    im = Image.fromarray(img).convert("RGBA")
    layer = Image.new("RGBA", im.size, (0, 0, 0, 0))
    d = ImageDraw.Draw(layer)
    pad, gap = size // 2, size // 4
    sw = size if any(s is not None for s in swatches) else 0
    widths = [d.textbbox((0, 0), ln, font=font)[2] for ln in lines]
    line_h = size + gap
    w = max(widths) + 2 * pad + (sw + gap if sw else 0)
    h = len(lines) * line_h + 2 * pad - gap
    x0 = pad
    y0 = pad if corner == "tl" else im.size[1] - h - pad
    d.rounded_rectangle([x0, y0, x0 + w, y0 + h], radius=pad, fill=(*_BOX, 200))
    for i, (ln, c) in enumerate(zip(lines, swatches)):
        y = y0 + pad + i * line_h
        x = x0 + pad
        if sw:
            if c is not None:
                r = size * 0.32
                cx, cy = x + sw / 2, y + size / 2 + 1
                d.ellipse([cx - r, cy - r, cx + r, cy + r], fill=(*c, 255))
            x += sw + gap
        d.text((x, y), ln, font=font, fill=(*_FG, 255))
    return np.asarray(Image.alpha_composite(im, layer).convert("RGB")).copy()


# 5x7 bitmap glyphs (rows top to bottom, 5 bits each), for when Pillow is missing. Lower case draws as upper case.
_GLYPHS = {
    "A": "0e11111f111111", "B": "1e11111e11111e", "C": "0e11101010110e", "D": "1e11111111111e",
    "E": "1f10101e10101f", "F": "1f10101e101010", "G": "0e11101713110f", "H": "1111111f111111",
    "I": "0e04040404040e", "J": "0702020202120c", "K": "11121418141211", "L": "1010101010101f",
    "M": "111b1515111111", "N": "11111915131111", "O": "0e11111111110e", "P": "1e11111e101010",
    "Q": "0e111111151209", "R": "1e11111e141211", "S": "0f10100e01011e", "T": "1f040404040404",
    "U": "1111111111110e", "V": "11111111110a04", "W": "11111115151b11", "X": "11110a040a1111",
    "Y": "11110a04040404", "Z": "1f01020408101f", "0": "0e11131519110e", "1": "040c040404040e",
    "2": "0e11010204081f", "3": "1f02040201110e", "4": "02060a121f0202", "5": "1f101e0101110e",
    "6": "0608101e11110e", "7": "1f010204080808", "8": "0e11110e11110e", "9": "0e11110f01020c",
    ".": "0000000000000c", ",": "00000000000c08", ":": "000c0c000c0c00", "-": "0000001f000000",
    "=": "00001f001f0000", "/": "01010204081010", "(": "02040808080402", ")": "08040202020408",
    "%": "18190204081303", "+": "0004041f040400", "_": "0000000000001f", "'": "0c040800000000",
    "#": "0a0a1f0a1f0a0a", "|": "04040404040404", " ": "00000000000000",
}


def _glyph(ch: str) -> np.ndarray:
    code = _GLYPHS.get(ch.upper(), _GLYPHS["-"] if ch not in " " else _GLYPHS[" "])
    rows = [int(code[i:i + 2], 16) for i in range(0, 14, 2)]
    return np.array([[(r >> (4 - b)) & 1 for b in range(5)] for r in rows], dtype=bool)


def _bitmap_block(img, lines, corner, swatches, scale):
    out = img.copy()
    cw, ch = 6 * scale, 9 * scale
    pad = 3 * scale
    sw = ch if any(s is not None for s in swatches) else 0
    w = max(len(ln) for ln in lines) * cw + 2 * pad + sw
    h = len(lines) * ch + 2 * pad
    H, W = out.shape[:2]
    x0, y0 = pad, (pad if corner == "tl" else H - h - pad)
    ys, xs = slice(max(y0, 0), min(y0 + h, H)), slice(max(x0, 0), min(x0 + w, W))
    out[ys, xs] = (0.25 * out[ys, xs] + 0.75 * np.array(_BOX)).astype(np.uint8)
    for i, (ln, c) in enumerate(zip(lines, swatches)):
        y = y0 + pad + i * ch
        x = x0 + pad
        if sw and c is not None:
            out[y + scale: y + 6 * scale, x + scale: x + 6 * scale] = c
        x += sw
        for j, character in enumerate(ln):
            g = np.kron(_glyph(character), np.ones((scale, scale), dtype=bool))
            yy, xx = y + scale, x + j * cw
            if yy + g.shape[0] > H or xx + g.shape[1] > W:
                continue
            region = out[yy: yy + g.shape[0], xx: xx + g.shape[1]]
            region[g] = _FG
    return out


def draw_legend(img: np.ndarray, newtons_per_cm: float | None, has_contacts: bool, has_env: bool,
                colors: dict) -> np.ndarray:
    """The colour key and force scale in the bottom-left corner."""
    lines, sw = [], []
    if has_contacts:
        lines.append("hand-object contact")
        sw.append(colors["contact"])
    if has_env:
        lines.append("object-table contact")
        sw.append(colors["env_contact"])
    if newtons_per_cm is not None:
        lines.append(f"force: 1 cm = {newtons_per_cm:g} N")
        sw.append(colors["force"])
    return draw_text_block(img, lines, "bl", sw) if lines else img


def grid_shape(n: int, max_cols: int | None = None) -> tuple[int, int]:
    """(rows, cols) of a near-square grid of ``n`` panels (one row up to 3 panels)."""
    if n <= 3:
        return 1, n
    cols = math.ceil(math.sqrt(n))
    if max_cols:
        cols = min(cols, max_cols)
    return math.ceil(n / cols), cols


def grid(panels: list[np.ndarray], rows: int, cols: int, gap: int = 2, fill: int = 255) -> np.ndarray:
    """Lay out equal-sized panels (H, W, 3) row by row, ``gap`` pixels apart; empty cells are ``fill``."""
    H, W = panels[0].shape[:2]
    out = np.full((rows * H + (rows - 1) * gap, cols * W + (cols - 1) * gap, 3), 200, dtype=np.uint8)
    for k in range(rows * cols):
        r, c = divmod(k, cols)
        y, x = r * (H + gap), c * (W + gap)
        out[y:y + H, x:x + W] = panels[k] if k < len(panels) else fill
    return out


def even_size(img: np.ndarray) -> np.ndarray:
    """Crop one row / column if needed so both sizes are even (H.264 in yuv420p needs that)."""
    H, W = img.shape[:2]
    return img[: H - H % 2, : W - W % 2]
