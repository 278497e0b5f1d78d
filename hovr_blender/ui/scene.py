"""Plain-data steps of a Blender render that need no bpy: ramp -> transfer function, core
image -> Blender's passes, field histograms (the looks and value ranges: engine/looks.py). Tested
without Blender."""
from __future__ import annotations

import numpy as np

from ..engine.transfer_function import TransferFunction, TransferFunctionError


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
    if not (np.isfinite(density_scale) and density_scale >= 0):
        raise TransferFunctionError(f"density scale must be >= 0, got {density_scale:.6g}")
    if len(positions) == 0:
        raise TransferFunctionError("transfer function ramp has no colour stops")
    return TransferFunction.from_rgba_ramp(positions, rgba, density_scale, value_min, value_max)


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


def flip_rows(a) -> np.ndarray:
    """(H, W[, C]) with row 0 at the top -> flat float32, row 0 at the bottom (RenderPass.rect)."""
    return np.ascontiguousarray(np.asarray(a, dtype=np.float32)[::-1]).ravel()


def depth_pass(camera, t, alpha) -> np.ndarray:
    """Blender's Depth pass from the core's depth output (H, W, rows from the top).

    The core gives t along each unit ray where 1 - T first reaches 0.5 (t_max otherwise);
    Blender's Depth (Cycles' camera_z_depth) is the distance along the view axis, so t is
    converted per pixel. Pixels whose opacity never reaches 0.5 (alpha < 0.5: T only
    decreases along a ray) get the far clip distance, where Cycles would write 1e10."""
    from .blender_camera import view_depth

    far = camera.extra.get("clip", (0.0, camera.t_max))[1]
    z = view_depth(camera, t)
    z = np.where(np.asarray(alpha) >= 0.5, z, far)
    return flip_rows(z)


def value_histogram(values, value_min: float, value_max: float, bins: int = 16) -> np.ndarray:
    """Fraction of the samples in each of `bins` equal bins of [value_min, value_max]."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0 or not value_max > value_min:
        return np.zeros(bins)
    counts, _ = np.histogram(values, bins=bins, range=(value_min, value_max))
    return counts / values.size
