"""The value axis the kernels work on: each volume's field mapped affinely, f' = a f + b, so
that float32 sees its transfer function's band near zero and of unit width, whatever the
field's offset or units (pressure in pascals near 101,325, temperatures in kelvin), and so that
several volumes share one axis and one transfer function.

For one volume the frame is the transfer function's own: its breakpoints' midpoint goes to 0
and their span to 1. The image is the same function of the same data (the map and the
breakpoints move together, exactly, in float64 on the host); only float32's rounding moves,
from the field's magnitude to its variation around the transfer function.

Several volumes: each gets its own frame, and the frames are laid side by side on the axis in
blocks that hold each volume's whole data range, with gaps between them; the combined transfer
function is each volume's in its block, held at its end values up to the block's edges
(as the contract clamps it), so no value of one volume ever reads another's transfer function.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .transfer_function import TransferFunction

FLOAT32_EPS = float(np.finfo(np.float32).eps)
GAP = 1.0  # between blocks, in frame units
# float32 resolves the finest transfer-function feature to this fraction of its width, or warns
RESOLUTION = 1e-4


@dataclass(frozen=True)
class FieldFrame:
    """f' = scale[k] f + shift[k] for the elements of volume k."""

    scale: np.ndarray  # (V,)
    shift: np.ndarray  # (V,)

    def apply(self, values, volume: int = 0):
        return self.scale[volume] * np.asarray(values, dtype=np.float64) + self.shift[volume]


def _band(tf: TransferFunction) -> tuple[float, float]:
    """(centre, width) of a transfer function's breakpoints."""
    s = np.concatenate([tf.color_s, tf.density_s])
    lo, hi = float(s.min()), float(s.max())
    width = hi - lo
    if not width > 0:  # one breakpoint (a constant function): any unit frame around it
        width = max(abs(lo), 1.0)
    return 0.5 * (lo + hi), width


def _finest(tf: TransferFunction, width: float) -> float:
    """The narrowest gap between consecutive breakpoints, in frame units."""
    gaps = [np.diff(s) for s in (tf.color_s, tf.density_s) if s.size > 1]
    g = min((float(d.min()) for d in gaps), default=width)
    return g / width


def _clamped(s, v, lo, hi):
    """Breakpoints s (frame units) of one function, cut to [lo, hi] and held at the values it
    takes there: the contract's clamping, made explicit at the block's edges."""
    s = np.asarray(s, float)
    v = np.asarray(v, float)
    inner = (s > lo) & (s < hi)
    at = lambda x: np.array([np.interp(x, s, v[:, k]) for k in range(v.shape[1])]) if v.ndim == 2 else np.interp(x, s, v)
    return np.concatenate([[lo], s[inner], [hi]]), np.concatenate([[at(lo)], v[inner], [at(hi)]])


def frame(tfs, data_ranges):
    """(FieldFrame, the transfer function in frame units, warnings) for volumes with transfer
    functions `tfs` and data ranges [(lo, hi), ...] (in their own units)."""
    tfs = list(tfs)
    scale, shift, warnings = [], [], []
    if len(tfs) == 1:
        centre, width = _band(tfs[0])
        scale, shift = [1.0 / width], [-centre / width]
        out = _map(tfs[0], scale[0], shift[0])
        _check(tfs[0], width, 0.5, warnings, "")
        return FieldFrame(np.array(scale), np.array(shift)), out, warnings
    color_s, color_rgb, density_s, density_tau = [], [], [], []
    upper = None
    for k, (tf, (dlo, dhi)) in enumerate(zip(tfs, data_ranges)):
        centre, width = _band(tf)
        a = 1.0 / width
        lo_k = min(a * (dlo - centre), -0.5)  # the block: the data and the band, in frame units
        hi_k = max(a * (dhi - centre), 0.5)
        offset = 0.0 if upper is None else upper + GAP - lo_k
        scale.append(a)
        shift.append(offset - a * centre)
        lo_k, hi_k = lo_k + offset, hi_k + offset
        mapped = _map(tf, a, offset - a * centre)
        for s, v, out_s, out_v in ((mapped.color_s, mapped.color_rgb, color_s, color_rgb),
                                   (mapped.density_s, mapped.density_tau, density_s, density_tau)):
            cs, cv = _clamped(s, v, lo_k, hi_k)
            out_s.append(cs)
            out_v.append(cv)
        upper = hi_k
        _check(tf, width, max(abs(lo_k), abs(hi_k)), warnings, f"volume {k + 1}: ")
    combined = TransferFunction(np.concatenate(color_s), np.concatenate(color_rgb),
                                np.concatenate(density_s), np.concatenate(density_tau))
    return FieldFrame(np.array(scale), np.array(shift)), combined, warnings


def _map(tf: TransferFunction, a: float, b: float) -> TransferFunction:
    return TransferFunction(a * tf.color_s + b, tf.color_rgb, a * tf.density_s + b, tf.density_tau)


def _check(tf, width, magnitude, warnings, prefix):
    """Warn where float32 cannot resolve the finest feature of the transfer function in this
    frame (its values near `magnitude` are rounded to eps * magnitude)."""
    finest = _finest(tf, width)
    if FLOAT32_EPS * magnitude > RESOLUTION * finest:
        warnings.append(f"{prefix}the transfer function's finest feature ({finest * width:.3g} wide, "
                        f"{finest:.2g} of its span) is below what float32 resolves here; "
                        "render with precision float64")
