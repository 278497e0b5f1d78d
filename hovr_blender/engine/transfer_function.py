"""Piecewise-linear transfer functions (render contract §2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .strict_json import as_numbers, as_object


# Every number of a transfer function (breakpoint values, colours, densities) lies within
# +-MAX_VALUE: the field's frame takes differences and logarithms of breakpoint spans
# (engine/field_frame.py), and the kernels multiply densities by lengths in float32 (max 3.4e38).
MAX_VALUE = 1.0e30


class TransferFunctionError(ValueError):
    """A transfer function that breaks the contract (unsorted, NaN, negative density, beyond
    +-MAX_VALUE)."""


def _check_bounded(name: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        raise TransferFunctionError(f"{name} must be finite")
    if a.size and np.abs(a).max() > MAX_VALUE:
        raise TransferFunctionError(f"{name} must lie within +-{MAX_VALUE:g}, got {np.abs(a).max():.6g}")


def _check_breakpoints(name: str, s: np.ndarray) -> None:
    if s.ndim != 1 or s.size == 0:
        raise TransferFunctionError(f"{name}: needs at least one breakpoint")
    _check_bounded(f"{name}: breakpoint values", s)
    if np.any(np.diff(s) <= 0):
        raise TransferFunctionError(f"{name}: breakpoint values must be strictly increasing, got "
                                    f"[{', '.join(f'{v:.6g}' for v in s)}]")


@dataclass(frozen=True)
class TransferFunction:
    """kappa(s) (RGB, scene-linear) and tau(s) >= 0 (extinction per world unit), clamped outside."""

    color_s: np.ndarray  # (Kc,) float64, strictly increasing
    color_rgb: np.ndarray  # (Kc, 3)
    density_s: np.ndarray  # (Kd,)
    density_tau: np.ndarray  # (Kd,)

    def __post_init__(self):
        for name in ("color_s", "color_rgb", "density_s", "density_tau"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        _check_breakpoints("colour", self.color_s)
        _check_breakpoints("density", self.density_s)
        if self.color_rgb.shape != (self.color_s.size, 3):
            raise TransferFunctionError("colour: each breakpoint needs (s, r, g, b)")
        if self.density_tau.shape != self.density_s.shape:
            raise TransferFunctionError("density: each breakpoint needs (s, tau)")
        _check_bounded("colour values", self.color_rgb)
        _check_bounded("density values", self.density_tau)
        if np.any(self.density_tau < 0):
            raise TransferFunctionError("density must be >= 0")

    @classmethod
    def from_contract(cls, tf: dict) -> "TransferFunction":
        """From the view file's ``transfer_function`` object."""
        tf = as_object(tf, "transfer_function", TransferFunctionError)
        for key in ("color", "density"):
            if key not in tf:
                raise TransferFunctionError(f"transfer_function needs 'color' [[s,r,g,b],...] and "
                                            f"'density' [[s,tau],...]: '{key}' is missing")
        color = as_numbers(tf["color"], "transfer_function.color (rows of [s, r, g, b])", TransferFunctionError, 4)
        density = as_numbers(tf["density"], "transfer_function.density (rows of [s, tau])", TransferFunctionError, 2)
        return cls(color[:, 0], color[:, 1:4], density[:, 0], density[:, 1])

    @classmethod
    def from_rgba_ramp(cls, positions, rgba, density_scale: float, value_min: float = 0.0, value_max: float = 1.0):
        """One ramp for both (Blender ColorRamp, linear): RGB is kappa, alpha*density_scale is tau.

        Ramp positions in [0, 1] map linearly onto [value_min, value_max]. Coincident positions
        (a step) are separated by a relative 1e-9 so breakpoints stay strictly increasing.
        """
        if not (np.isfinite(value_min) and np.isfinite(value_max) and value_max > value_min):
            raise TransferFunctionError(f"value range must have Value Max > Value Min, got "
                                        f"[{value_min:.6g}, {value_max:.6g}]")
        pos = np.asarray(positions, dtype=np.float64)
        rgba = np.asarray(rgba, dtype=np.float64).reshape(-1, 4)
        order = np.argsort(pos, kind="stable")
        pos, rgba = pos[order], rgba[order]
        s = value_min + pos * (value_max - value_min)
        for i in range(1, s.size):  # keep steps as (nearly) vertical ramps
            if s[i] <= s[i - 1]:
                s[i] = np.nextafter(s[i - 1], np.inf) + 1e-9 * max(1.0, abs(s[i - 1]))
        return cls(s, rgba[:, :3], s.copy(), rgba[:, 3] * float(density_scale))

    def to_contract(self) -> dict:
        return {
            "color": [[float(s), *map(float, c)] for s, c in zip(self.color_s, self.color_rgb)],
            "density": [[float(s), float(t)] for s, t in zip(self.density_s, self.density_tau)],
        }

    def color(self, s) -> np.ndarray:
        s = np.asarray(s, dtype=np.float64)
        return np.stack([np.interp(s, self.color_s, self.color_rgb[:, c]) for c in range(3)], axis=-1)

    def density(self, s) -> np.ndarray:
        return np.interp(np.asarray(s, dtype=np.float64), self.density_s, self.density_tau)

    def max_density(self, lo: float, hi: float) -> float:
        """The largest tau(s) for s in [lo, hi] (piecewise linear: at the ends or a breakpoint)."""
        inside = self.density_tau[(self.density_s > lo) & (self.density_s < hi)]
        return float(max(self.density([lo, hi]).max(), inside.max() if inside.size else 0.0))

    @property
    def breakpoints(self) -> np.ndarray:
        """All scalar values where kappa or tau may change slope."""
        return np.union1d(self.color_s, self.density_s)
