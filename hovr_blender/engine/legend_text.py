"""Text for the colour legend drawn with numpy alone: the glyphs of DejaVu Sans Condensed rasterised
once per size (legend_font.npz, scripts/make_legend_font.py; its licence: legend_font.LICENSE) and
placed pixel by pixel, so the legend reads the same in the CLI's PNG and in F12's image on every
Blender (4.2 bundles no Pillow; blf draws into images only from 4.5). A size not stored is drawn
with the largest stored size below it; a character the font file lacks is drawn as '?'.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import numpy as np

FONT_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "legend_font.npz")
# the middle of a line of digits and capitals lies this share of the font size above the baseline
MIDDLE = 0.36


@dataclass(frozen=True)
class Face:
    """One stored size: the glyphs' coverage in one row (atlas) and per glyph (atlas x, width, left
    bearing, advance), looked up by character."""

    size: int
    ascent: int
    atlas: np.ndarray  # (line, total width) uint8
    meta: np.ndarray  # (glyphs, 4) float32
    index: dict  # character -> row of meta

    def glyph(self, ch: str):
        row = self.meta[self.index.get(ch, self.index["?"])]
        x, width = int(row[0]), int(row[1])
        return self.atlas[:, x:x + width], int(row[2]), float(row[3])


@functools.lru_cache(maxsize=1)
def _font() -> dict:
    with np.load(FONT_FILE, allow_pickle=False) as f:
        chars = [chr(int(c)) for c in f["chars"]]
        index = {ch: k for k, ch in enumerate(chars)}
        return {int(s): Face(int(s), int(a), f[f"atlas_{s}"], f[f"meta_{s}"], index)
                for s, a in zip(f["sizes"], f["ascents"])}


def face(px: int) -> Face:
    """The stored size for a font of `px` pixels: the largest not above it (else the smallest)."""
    faces = _font()
    sizes = sorted(faces)
    fitting = [s for s in sizes if s <= int(px)]
    return faces[fitting[-1] if fitting else sizes[0]]


def text_width(text: str, px: int) -> int:
    """The pixels `text` takes across at `px`."""
    f = face(px)
    return int(round(sum(f.glyph(ch)[2] for ch in text)))


def fit_text(text: str, px: int, width: int) -> str:
    """`text`, shortened with an ellipsis to fit `width` pixels at `px` (empty where nothing fits)."""
    if text_width(text, px) <= width:
        return text
    for n in range(len(text) - 1, 0, -1):
        short = text[:n].rstrip() + "\u2026"
        if text_width(short, px) <= width:
            return short
    return ""


def draw_text(mask: np.ndarray, x: float, y: float, text: str, px: int, anchor: str = "left") -> None:
    """Add `text`'s coverage (0..1) into `mask` (H, W), its vertical middle at row y, starting at
    column x ("left") or ending there ("right"); what falls outside the mask is cut."""
    f = face(px)
    pen = float(x) - (text_width(text, px) if anchor == "right" else 0.0)
    top = int(round(y + MIDDLE * f.size)) - f.ascent
    height, width = mask.shape
    for ch in text:
        glyph, left, advance = f.glyph(ch)
        gx = int(round(pen)) + left
        x0, x1 = max(gx, 0), min(gx + glyph.shape[1], width)
        y0, y1 = max(top, 0), min(top + glyph.shape[0], height)
        if x0 < x1 and y0 < y1:
            part = glyph[y0 - top:y1 - top, x0 - gx:x1 - gx] / 255.0
            np.maximum(mask[y0:y1, x0:x1], part, out=mask[y0:y1, x0:x1])
        pen += advance
