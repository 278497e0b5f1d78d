"""Piecewise-linear transfer functions (render contract §2)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .strict_json import as_numbers, as_object


class TransferFunctionError(ValueError):
    """A transfer function that breaks the contract (unsorted, NaN, negative density)."""


def _check_breakpoints(name: str, s: np.ndarray) -> None:
    if s.ndim != 1 or s.size == 0:
        raise TransferFunctionError(f"{name}: needs at least one breakpoint")
    if not np.all(np.isfinite(s)):
        raise TransferFunctionError(f"{name}: breakpoint values must be finite")
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
        if not (np.all(np.isfinite(self.color_rgb)) and np.all(np.isfinite(self.density_tau))):
            raise TransferFunctionError("transfer function values must be finite")
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

    @property
    def breakpoints(self) -> np.ndarray:
        """All scalar values where kappa or tau may change slope."""
        return np.union1d(self.color_s, self.density_s)
