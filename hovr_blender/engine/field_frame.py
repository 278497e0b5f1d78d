"""The value axis the kernels work on: each volume's field mapped affinely, f' = a f + b, so
that float32 sees its transfer function's band near zero and of about unit width, whatever the
field's offset or units (pressure in pascals near 101,325, temperatures in kelvin), and so that
several volumes share one axis and one transfer function (docs/methods.md, "Precision").

For one volume the frame is the transfer function's own: the breakpoints' span goes to a width
in (1/2, 1] and, where the band lies further from 0 than its width, their midpoint to within
1/16 of 0. The image is the same function of the same
data (the map and the breakpoints move together, in float64 on the host); only float32's
rounding moves, from the field's magnitude to its variation around the transfer function.
The scale is a power of two and the shift a multiple of 1/8 of the frame's unit, so the map
is exact on the coefficients' scaling and a small transfer-function edit keeps the frame (and
the data already on the device).

Several volumes: each gets its own frame, and the frames are laid side by side on the axis in
blocks that hold each volume's whole data range, with gaps between them; the combined transfer
function is each volume's in its block, held at its end values up to the block's edges (as the
contract clamps it), so no value of one volume ever reads another's transfer function.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .transfer_function import TransferFunction

GAP = 1.0  # between blocks, in frame units
SHIFT_GRID = 0.125  # shifts are multiples of this (frame units): small edits keep the frame
# float32 must resolve the finest transfer-function feature to this fraction of its width, or
# the renderer warns: a rounding of the field by d moves a pixel by about d / (feature width)
# times the colour or opacity change across it, so 1e-4 keeps the image within its 1e-3
RESOLUTION = 1e-4


@dataclass(frozen=True)
class FieldFrame:
    """f' = scale[k] f + shift[k] for the elements of volume k."""

    scale: np.ndarray  # (V,) powers of two
    shift: np.ndarray  # (V,)

    def apply(self, values, volume: int = 0):
        return self.scale[volume] * np.asarray(values, dtype=np.float64) + self.shift[volume]

    @property
    def key(self) -> tuple:
        """Equal for equal frames (what the renderer's uploaded field depends on)."""
        return tuple(self.scale.tolist()), tuple(self.shift.tolist())


def band(tf: TransferFunction) -> tuple[float, float]:
    """(lowest, highest) breakpoint of a transfer function, colour and density together."""
    s = np.concatenate([tf.color_s, tf.density_s])
    return float(s.min()), float(s.max())


def finest_feature(tf: TransferFunction) -> float:
    """The narrowest gap between consecutive breakpoints (the band's width for a constant one)."""
    gaps = [float(np.diff(s).min()) for s in (tf.color_s, tf.density_s) if s.size > 1]
    lo, hi = band(tf)
    return min(gaps, default=max(hi - lo, abs(lo), 1.0))


def _scale(tf: TransferFunction) -> float:
    lo, hi = band(tf)
    width = hi - lo
    if not width > 0:  # one breakpoint (a constant function): any unit frame around it
        width = max(abs(lo), 1.0)
    return 2.0 ** -math.ceil(math.log2(width))


def _own_frame(tf: TransferFunction) -> tuple[float, float]:
    """(a, b) of one transfer function's frame. A band within its own width of 0 is not shifted:
    values near 0 keep float's finer resolution there, and shifting would only coarsen it."""
    a = _scale(tf)
    lo, hi = band(tf)
    centre = 0.5 * (lo + hi)
    if abs(centre) <= hi - lo:
        return a, 0.0
    return a, -SHIFT_GRID * round(a * centre / SHIFT_GRID)


def _clamped(s, v, lo, hi):
    """Breakpoints s (frame units) of one function, cut to [lo, hi] and held at the values it
    takes there: the contract's clamping, made explicit at the block's edges."""
    s = np.asarray(s, float)
    v = np.asarray(v, float)
    inner = (s > lo) & (s < hi)

    def at(x):
        return np.array([np.interp(x, s, v[:, k]) for k in range(v.shape[1])]) if v.ndim == 2 else np.interp(x, s, v)

    return np.concatenate([[lo], s[inner], [hi]]), np.concatenate([[at(lo)], v[inner], [at(hi)]])


def mapped(tf: TransferFunction, a: float, b: float) -> TransferFunction:
    """The transfer function of f' = a f + b (a > 0) that gives f's colours and densities."""
    return TransferFunction(a * tf.color_s + b, tf.color_rgb, a * tf.density_s + b, tf.density_tau)


def frame(tfs, data_ranges) -> tuple[FieldFrame, TransferFunction]:
    """(FieldFrame, the transfer function in frame units) for volumes with transfer functions
    `tfs` and data ranges [(lo, hi), ...] (in their own units)."""
    tfs = list(tfs)
    if len(tfs) == 1:
        a, b = _own_frame(tfs[0])
        return FieldFrame(np.array([a]), np.array([b])), mapped(tfs[0], a, b)
    scale, shift = [], []
    color_s, color_rgb, density_s, density_tau = [], [], [], []
    upper = None
    for tf, (dlo, dhi) in zip(tfs, data_ranges):
        a, b = _own_frame(tf)
        lo, hi = band(tf)
        # the block: the data and the band, in this volume's frame, then moved past the last one
        lo_k = min(a * dlo + b, a * lo + b) - 0.5
        hi_k = max(a * dhi + b, a * hi + b) + 0.5
        offset = 0.0 if upper is None else float(math.ceil(upper + GAP - lo_k))
        scale.append(a)
        shift.append(b + offset)
        lo_k, hi_k = lo_k + offset, hi_k + offset
        m = mapped(tf, a, b + offset)
        for s, v, out_s, out_v in ((m.color_s, m.color_rgb, color_s, color_rgb),
                                   (m.density_s, m.density_tau, density_s, density_tau)):
            cs, cv = _clamped(s, v, lo_k, hi_k)
            out_s.append(cs)
            out_v.append(cv)
        upper = hi_k
    combined = TransferFunction(np.concatenate(color_s), np.concatenate(color_rgb),
                                np.concatenate(density_s), np.concatenate(density_tau))
    return FieldFrame(np.array(scale), np.array(shift)), combined


def resolution_warnings(tfs, fr: FieldFrame, volume, lo, hi, rounding, precision: str) -> list[str]:
    """Where the field's rounding in `precision` cannot resolve a volume's finest transfer-function
    feature: per element of volume k (`volume` (N,) ints), its range [lo, hi] and the size of its
    evaluation's rounding, all in frame units. Only elements whose range meets the band count:
    the rest see a constant part of the transfer function; and none of a transfer function whose
    density is zero everywhere (an invisible volume has no feature to resolve)."""
    warnings = []
    for k, tf in enumerate(tfs):
        if not tf.density_tau.max() > 0:
            continue
        blo, bhi = (fr.apply(v, k) for v in band(tf))
        near = (volume == k) & (hi >= blo) & (lo <= bhi)
        if not near.any():
            continue
        worst = float(rounding[near].max())
        finest = finest_feature(tf) * fr.scale[k]
        if worst > RESOLUTION * finest:
            prefix = f"volume {k + 1}: " if len(tfs) > 1 else ""
            warnings.append(f"{prefix}{precision} rounds the field by up to {worst / fr.scale[k]:.3g} where the "
                            f"transfer function's finest feature is {finest / fr.scale[k]:.3g} wide; "
                            "render with precision float64 for an image within 1e-3")
    return warnings
