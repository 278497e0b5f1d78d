"""Plain-data steps of a Blender render that need no bpy: ramp -> transfer function,
volume source -> mesh, core image -> Blender's Combined pass. Tested without Blender."""
from __future__ import annotations

import numpy as np

from .mesh import VolumeMesh
from .transfer_function import TransferFunction, TransferFunctionError


class SourceError(ValueError):
    """An object's data source the add-on cannot load."""


def transfer_function_from_ramp(interpolation: str, color_mode: str, positions, rgba,
                                density_scale: float, value_min: float, value_max: float) -> TransferFunction:
    """A Blender ColorRamp (already read into lists) as the contract's transfer function.

    Only linear RGB interpolation is the piecewise-linear function the contract defines;
    any other mode would render something else than the ramp shows, so it is refused.
    """
    if interpolation != "LINEAR":
        raise TransferFunctionError(f"transfer function ramp must use Linear interpolation, not {interpolation.title()}")
    if color_mode != "RGB":
        raise TransferFunctionError(f"transfer function ramp must interpolate in RGB, not {color_mode}")
    if not (np.isfinite(value_min) and np.isfinite(value_max) and value_max > value_min):
        raise TransferFunctionError(f"value range must have Value Max > Value Min, got [{value_min}, {value_max}]")
    if not (np.isfinite(density_scale) and density_scale >= 0):
        raise TransferFunctionError(f"density scale must be >= 0, got {density_scale}")
    if len(positions) == 0:
        raise TransferFunctionError("transfer function ramp has no colour stops")
    return TransferFunction.from_rgba_ramp(positions, rgba, density_scale, value_min, value_max)


def load_volume_source(source: str) -> VolumeMesh:
    """Object.hovr.source -> mesh in object space. "builtin:NAME" for the shipped datasets."""
    from ..io import builtin

    kind, _, name = source.partition(":")
    if kind == "builtin":
        if name not in builtin.BUILTIN:
            raise SourceError(f"unknown built-in dataset {name!r}; one of {', '.join(builtin.BUILTIN)}")
        return builtin.BUILTIN[name]()
    raise SourceError(f"unsupported volume source {source!r} (use builtin:NAME)")


def render_background(world_color, film_transparent: bool) -> np.ndarray:
    """What the core composites behind the volume: nothing for a transparent film."""
    if film_transparent:
        return np.zeros(3)
    return np.asarray(world_color if world_color is not None else (0.0, 0.0, 0.0), dtype=np.float64)[:3]


def combined_pass(rgba, film_transparent: bool) -> np.ndarray:
    """Core image (row 0 at the top) -> flat float32 RGBA for RenderPass.rect (row 0 at the bottom).

    The core was given a black background for a transparent film, so its RGB is C alone
    (premultiplied) and its alpha 1 - T; an opaque film has the background composited in
    and alpha 1.
    """
    img = np.array(np.asarray(rgba, dtype=np.float32)[::-1], dtype=np.float32, order="C")
    if img.ndim != 3 or img.shape[2] != 4:
        raise ValueError(f"expected an (H, W, 4) image, got shape {img.shape}")
    if not film_transparent:
        img[..., 3] = 1.0
    return img.ravel()
