"""The colour legend's layout, one home for the CLI's PNG (`hovr render --legend`, drawn here with
Pillow), Blender's viewport overlay (ui/legend_overlay.py, drawn with gpu and blf) and F12's result
(ui/legend_render.py: draw_legend, its text drawn with blf): a vertical
bar of the transfer function at the image's right edge, the value at five ticks beside it, and the
field's name (with its units, where known) above it.

The bar shows what a value looks like in the volume: the ramp's colour kappa(s) over the background
in proportion to its opacity tau(s) / max tau, so the values the ramp hides fade into the
background as they do in the picture. Coordinates are pixels from the image's top-left corner;
colours are scene-linear RGB.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TICKS = 5


@dataclass(frozen=True)
class LegendText:
    x: float  # the anchor: the text's right end ("right") or its left end ("left")
    y: float  # the text's vertical middle
    text: str
    anchor: str  # "right" or "left"


@dataclass(frozen=True)
class Legend:
    bar: tuple[int, int, int, int]  # (x0, y0, x1, y1), x1 and y1 excluded
    bar_rgb: np.ndarray  # (y1 - y0, 3) linear RGB, the top row first (the largest value)
    texts: tuple[LegendText, ...]
    text_rgb: tuple[float, float, float]  # linear: black or white, whichever stands out on the background
    font_px: int


def tick_label(value: float) -> str:
    return f"{value:.4g}"


def legend_layout(tf, value_min: float, value_max: float, title: str, width: int, height: int,
                  background=(0.0, 0.0, 0.0), units: str | None = None, top: int = 0) -> Legend:
    """The legend of transfer function `tf` (engine/transfer_function.py) over value_min..value_max
    for a width x height image, `top` pixels below its top edge (what covers the image there: a
    viewport's tool header)."""
    if not value_max > value_min:
        raise ValueError(f"legend: Value Max must exceed Value Min, got {value_min:.6g}..{value_max:.6g}")
    width, height = int(width), int(height)
    font = int(np.clip(round(height / 32), 9, 28))
    margin = max(4, font // 2)
    bar_w = max(6, font)
    x1 = width - margin
    x0 = x1 - bar_w
    top = int(np.clip(top, 0, height // 3))
    y0 = top + margin + 2 * font  # room for the title
    y1 = max(y0 + 2, top + int(round(0.55 * (height - top))))
    rows = y1 - y0
    s = value_max - (np.arange(rows) + 0.5) / rows * (value_max - value_min)
    tau = tf.density(s)
    peak = float(tf.density_tau.max())
    opacity = (tau / peak if peak > 0 else np.ones_like(tau))[:, None]
    bg = np.asarray(background, dtype=np.float64)[:3]
    bar_rgb = opacity * np.clip(tf.color(s), 0.0, None) + (1.0 - opacity) * bg
    luminance = float(bg @ [0.2126, 0.7152, 0.0722])
    text_rgb = (0.0, 0.0, 0.0) if luminance > 0.25 else (1.0, 1.0, 1.0)
    texts = [LegendText(x0 - font // 2, y0 + k / (TICKS - 1) * (rows - 1), tick_label(v), "right")
             for k, v in enumerate(np.linspace(value_max, value_min, TICKS))]
    name = f"{title} [{units}]" if units else title
    texts.append(LegendText(x1, top + margin + font // 2, name, "right"))
    return Legend((x0, y0, x1, y1), bar_rgb, tuple(texts), text_rgb, font)


def tf_value_range(tf) -> tuple[float, float]:
    """The value range a transfer function spans: its first to its last breakpoint."""
    lo = min(float(tf.color_s[0]), float(tf.density_s[0]))
    hi = max(float(tf.color_s[-1]), float(tf.density_s[-1]))
    return (lo, hi) if hi > lo else (lo - 0.5, hi + 0.5)


def pillow_text_mask(legend: Legend, width: int, height: int) -> np.ndarray:
    """(H, W) coverage of the legend's text, 0..1, drawn with Pillow's scalable font."""
    from PIL import Image, ImageDraw, ImageFont

    mask = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(mask)
    font = ImageFont.load_default(size=legend.font_px)
    for t in legend.texts:
        draw.text((t.x, t.y), t.text, fill=255, font=font, anchor="rm" if t.anchor == "right" else "lm")
    return np.asarray(mask, dtype=np.float64) / 255.0


def draw_legend(rgba, legend: Legend, text_mask=pillow_text_mask) -> np.ndarray:
    """(H, W, 4) linear RGBA with the legend drawn on it, opaque where it is: the bar's pixels set,
    the text composited over through `text_mask(legend, width, height)` ((H, W) coverage; Blender
    draws it with blf, ui/legend_render.py). Over straight or premultiplied alpha alike."""
    out = np.array(rgba, dtype=np.float64)
    height, width = out.shape[:2]
    x0, y0, x1, y1 = legend.bar
    out[y0:y1, x0:x1, :3] = legend.bar_rgb[:, None, :]
    out[y0:y1, x0:x1, 3] = 1.0
    a = np.clip(text_mask(legend, width, height), 0.0, 1.0)[..., None]
    out[..., :3] = (1.0 - a) * out[..., :3] + a * np.asarray(legend.text_rgb)
    out[..., 3:] = a + (1.0 - a) * out[..., 3:]
    return out
