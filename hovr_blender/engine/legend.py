"""The colour legend's layout, one home for the CLI's PNG (`hovr render --legend`), Blender's viewport
overlay (ui/legend_overlay.py, drawn with gpu and blf) and F12's result (ui/legend_render.py), the
images drawn here with numpy alone (draw_legend; the text: engine/legend_text.py).

At the image's right edge, from the edge inwards: a colour bar, the transfer function's colour over
the value range (Value Max at the top), continuous, each row at full colour whatever its opacity;
beside it the density as a curve, a filled profile whose width is the density over its peak, in
the row's colour, so thin tents read as peaks; tick marks and labels at round values, never closer
than a line of text apart (nice_ticks), and the field's name and units above. Coordinates are
pixels from the image's top-left corner; colours are scene-linear RGB.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import legend_text

LINE = 1.45  # tick labels' spacing at least this many font sizes: a line of text and a gap
FONT_SHARE = 1 / 30  # the font's size, of the image's height (within MIN_FONT..MAX_FONT pixels)
MIN_FONT, MAX_FONT = 7, 28
HALO = 0.6  # opacity of the 1-pixel halo around the text, in the colour opposite the text's


@dataclass(frozen=True)
class LegendText:
    x: float  # the anchor: the text's right end ("right") or its left end ("left")
    y: float  # the text's vertical middle
    text: str
    anchor: str  # "right" or "left"


@dataclass(frozen=True)
class Legend:
    bar: tuple[int, int, int, int]  # the colour bar (x0, y0, x1, y1), x1 and y1 excluded
    bar_rgb: np.ndarray  # (y1 - y0, 3) linear RGB, the top row first (the largest value)
    curve: tuple[int, int]  # the density curve's columns (x0, x1), beside the bar, over the bar's rows
    density: np.ndarray  # (y1 - y0,) the density over its peak, 0..1, a row
    ticks: tuple[tuple[int, int, int], ...]  # tick marks (x0, x1, y)
    texts: tuple[LegendText, ...]
    text_rgb: tuple[float, float, float]  # linear: black or white, whichever stands out on the background
    font_px: int


def nice_ticks(value_min: float, value_max: float, most: int) -> list[float]:
    """Round values (1, 2 or 5 times a power of ten) inside [value_min, value_max], at most `most` of
    them and as many as that allows; where fewer than two fit, the two ends."""
    span = value_max - value_min
    if most < 2 or not span > 0:
        return [value_max, value_min][:max(most, 1)]
    exponent = math.floor(math.log10(span / (most - 1)))
    best = []
    for e in range(exponent + 1, exponent - 3, -1):  # from coarse to fine: keep the finest that fits
        for m in (5, 2, 1):
            step = m * 10.0 ** e
            first = math.ceil(value_min / step - 1e-9)
            last = math.floor(value_max / step + 1e-9)
            n = last - first + 1
            if n > most:
                return best if len(best) >= 2 else [value_max, value_min]
            if n >= len(best):
                best = [k * step for k in range(last, first - 1, -1)]
    return best if len(best) >= 2 else [value_max, value_min]


def tick_labels(values) -> list[str]:
    """The tick values as text, all with the digits their spacing needs (1.5e-05, 0.35, 2000)."""
    values = [float(v) for v in values]
    if len(values) < 2:
        return [f"{v:.4g}" for v in values]
    step = min(abs(a - b) for a, b in zip(values, values[1:])) or abs(values[0]) or 1.0
    top = max(abs(v) for v in values)
    if top >= 1e6 or top < 1e-3:
        digits = max(0, math.floor(math.log10(top or 1.0)) - math.floor(math.log10(step) + 1e-9))
        return [f"{v:.{min(digits, 8)}e}".replace("e-0", "e-").replace("e+0", "e") for v in values]
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    return [f"{v:.{decimals}f}" if round(v, decimals) != 0 else f"{0:.{decimals}f}" for v in values]


def legend_layout(tf, value_min: float, value_max: float, title: str, width: int, height: int,
                  background=(0.0, 0.0, 0.0), units: str | None = None, top: int = 0) -> Legend:
    """The legend of transfer function `tf` (engine/transfer_function.py) over value_min..value_max
    for a width x height image, `top` pixels below its top edge (what covers the image there: a
    viewport's tool header)."""
    if not value_max > value_min:
        raise ValueError(f"legend: Value Max must exceed Value Min, got {value_min:.6g}..{value_max:.6g}")
    width, height = int(width), int(height)
    top = int(np.clip(top, 0, height // 3))
    font = int(np.clip(round((height - top) * FONT_SHARE), MIN_FONT, MAX_FONT))
    margin = max(3, font // 2)
    bar_w, curve_w, tick_w = max(4, round(0.6 * font)), max(6, round(1.6 * font)), max(2, font // 3)
    x1 = width - margin
    x0 = x1 - bar_w
    cx1, cx0 = x0, x0 - curve_w
    y0 = top + margin + math.ceil(1.8 * font)  # the title's line above, a gap, half the top label
    y1 = max(y0 + 2, min(top + round(0.62 * (height - top)), height - margin - font))
    rows = y1 - y0
    s = value_max - (np.arange(rows) + 0.5) / rows * (value_max - value_min)
    tau = tf.density(s)
    peak = float(tau.max())
    density = tau / peak if peak > 0 else np.zeros(rows)
    bar_rgb = np.clip(tf.color(s), 0.0, None)
    luminance = float(np.asarray(background, dtype=np.float64)[:3] @ [0.2126, 0.7152, 0.0722])
    text_rgb = (0.0, 0.0, 0.0) if luminance > 0.25 else (1.0, 1.0, 1.0)
    values = nice_ticks(value_min, value_max, 1 + int((rows - 1) // (LINE * font)))
    ys = [y0 + int(np.clip(round((value_max - v) / (value_max - value_min) * rows - 0.5), 0, rows - 1))
          for v in values]
    label_x = cx0 - tick_w - max(2, font // 3)
    texts = [LegendText(label_x, y, text, "right") for y, text in zip(ys, tick_labels(values))]
    name = f"{title} [{units}]" if units else title
    name = legend_text.fit_text(name, font, x1 - margin)
    if name:
        texts.append(LegendText(x1, top + margin + 0.6 * font, name, "right"))
    ticks = tuple((cx0 - tick_w, cx0, y) for y in ys)
    return Legend((x0, y0, x1, y1), bar_rgb, (cx0, cx1), density, ticks, tuple(texts), text_rgb, font)


def tf_value_range(tf) -> tuple[float, float]:
    """The value range a transfer function spans: its first to its last breakpoint."""
    lo = min(float(tf.color_s[0]), float(tf.density_s[0]))
    hi = max(float(tf.color_s[-1]), float(tf.density_s[-1]))
    return (lo, hi) if hi > lo else (lo - 0.5, hi + 0.5)


def text_mask(legend: Legend, width: int, height: int) -> np.ndarray:
    """(H, W) coverage of the legend's text, 0..1 (engine/legend_text.py)."""
    mask = np.zeros((height, width))
    for t in legend.texts:
        legend_text.draw_text(mask, t.x, t.y, t.text, legend.font_px, t.anchor)
    return mask


def marks_mask(legend: Legend, width: int, height: int) -> np.ndarray:
    """(H, W) coverage of the lines drawn in the text's colour: the tick marks, the density curve's
    edge and the frame around the bar and the curve."""
    mask = np.zeros((height, width))
    x0, y0, x1, y1 = legend.bar
    cx0, cx1 = legend.curve
    for xa, xb, y in legend.ticks:
        mask[y, xa:xb] = 1.0
    edge = np.round(cx1 - legend.density * (cx1 - cx0)).astype(int)
    rows = np.arange(y0, y1)
    lo = np.minimum(edge, np.concatenate([edge[:1], edge[:-1]]))  # joined to the row above: a line
    hi = np.maximum(edge, np.concatenate([edge[:1], edge[:-1]]))
    for r, a, b in zip(rows, lo, hi):
        mask[r, max(a - 1, cx0):min(b, cx1)] = 1.0
    mask[y0 - 1, cx0 - 1:x1 + 1] = mask[y1, cx0 - 1:x1 + 1] = 1.0  # the frame
    mask[y0 - 1:y1 + 1, cx0 - 1] = mask[y0 - 1:y1 + 1, x1] = 1.0
    return mask


def _halo(mask: np.ndarray) -> np.ndarray:
    """The mask grown by a pixel each way (where the halo goes)."""
    h, w = mask.shape
    padded = np.pad(mask, 1)
    return np.max([padded[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)], axis=0)


def draw_legend(rgba, legend: Legend) -> np.ndarray:
    """(H, W, 4) linear RGBA with the legend drawn on it, opaque where it is: the bar's pixels set,
    the density's profile in its rows' colours, the marks and text composited (the text over a
    faint halo, so it reads over the picture too).
    Over straight or premultiplied alpha alike."""
    out = np.array(rgba, dtype=np.float64)
    height, width = out.shape[:2]
    x0, y0, x1, y1 = legend.bar
    cx0, cx1 = legend.curve
    out[y0:y1, x0:x1, :3] = legend.bar_rgb[:, None, :]
    out[y0:y1, x0:x1, 3] = 1.0
    cols = np.arange(cx0, cx1)
    filled = cols[None, :] >= (cx1 - legend.density * (cx1 - cx0))[:, None]
    region = out[y0:y1, cx0:cx1]
    region[..., :3] = np.where(filled[..., None], legend.bar_rgb[:, None, :], region[..., :3])
    region[..., 3] = np.where(filled, 1.0, region[..., 3])
    text = text_mask(legend, width, height)
    ink = np.maximum(text, marks_mask(legend, width, height))
    halo = np.clip(_halo(text) - ink, 0.0, 1.0)
    halo[y0 - 1:y1 + 1, cx0 - 1:x1 + 1] = 0.0  # around the text only, never over the bar and the curve
    halo = HALO * halo[..., None]
    for a, rgb in ((halo, 1.0 - np.asarray(legend.text_rgb)), (ink[..., None], np.asarray(legend.text_rgb))):
        out[..., :3] = (1.0 - a) * out[..., :3] + a * rgb
        out[..., 3:] = a + (1.0 - a) * out[..., 3:]
    return out
