"""Plain-data steps of a Blender render that need no bpy: ramp -> transfer function, core
image -> Blender's passes, transfer-function presets, field histograms and value ranges. Tested
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
    from .camera import view_depth

    far = camera.extra.get("clip", (0.0, camera.t_max))[1]
    z = view_depth(camera, t)
    z = np.where(np.asarray(alpha) >= 0.5, z, far)
    return flip_rows(z)


# Transfer-function presets: (name, description, [(ramp position, (r, g, b, alpha))]).
# Colours are scene-linear; alpha x density scale is the extinction.
def _tents(spec, width):
    stops = [(0.0, (0.0, 0.0, 0.0, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
    for centre, rgb in spec:
        stops += [(centre - width, (*rgb, 0.0)), (centre, (*rgb, 1.0)), (centre + width, (*rgb, 0.0))]
    return sorted(stops, key=lambda s: s[0])


DEFAULT_PRESET = "SMOOTH"  # a new transfer function's ramp: shows any field once its range is fitted
TF_PRESETS = {
    "TENTS": ("Three Tents", "Three thin coloured tents (isosurface-like shells)",
              _tents(((0.2, (1.0, 0.2, 0.1)), (0.5, (0.1, 1.0, 0.2)), (0.8, (0.2, 0.3, 1.0))), 0.04)),
    "SPIKES": ("Spikes", "Four narrow spikes, the style of the paper's figures",
               _tents(((0.2, (1.0, 0.1, 0.1)), (0.4, (1.0, 1.0, 0.1)), (0.6, (0.1, 1.0, 0.1)), (0.8, (0.1, 0.3, 1.0))), 0.01)),
    "SMOOTH": ("Smooth Ramp", "Blue to red, opacity rising with the value",
               [(0.0, (0.05, 0.1, 1.0, 0.0)), (0.5, (0.2, 1.0, 0.3, 0.3)), (1.0, (1.0, 0.1, 0.05, 1.0))]),
    "GREY": ("Grey Fog", "Uniform grey fog, denser for larger values",
             [(0.0, (0.8, 0.8, 0.8, 0.0)), (1.0, (0.8, 0.8, 0.8, 1.0))]),
}


def field_samples(mesh, samples_per_axis: int | None = None, max_values: int = 200_000) -> np.ndarray:
    """Field values on a lattice of reference points inside every element (for the value
    range and the histogram); the lattice shrinks for big meshes to keep this under ~max_values."""
    n = mesh.num_elements
    if samples_per_axis is None:
        samples_per_axis = int(np.clip(np.cbrt(max_values / max(n, 1)), 2, 9))
    values = mesh.field_samples(samples_per_axis)
    values = values[np.isfinite(values)]
    true_range = getattr(mesh, "true_range", None)  # a fitted derived field's exact range (io/derived.py)
    return values if true_range is None else np.clip(values, *true_range)


def value_histogram(values, value_min: float, value_max: float, bins: int = 16) -> np.ndarray:
    """Fraction of the samples in each of `bins` equal bins of [value_min, value_max]."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0 or not value_max > value_min:
        return np.zeros(bins)
    counts, _ = np.histogram(values, bins=bins, range=(value_min, value_max))
    return counts / values.size


# A field varies by less than this, relative to its magnitude, only by rounding: it is constant.
ROUNDING_RELATIVE = 1e-12
# Values all within this of zero are rounding around zero (a zero field computed in float64).
ROUNDING_ZERO = 1e-12


def _float32_distinct(lo: float, hi: float) -> tuple[float, float]:
    """(lo, hi) widened to the nearest float32 values apart: Value Min/Max are float32 properties."""
    lo32, hi32 = np.float32(lo), np.float32(hi)
    if hi32 > lo32:
        return lo, hi
    return float(np.nextafter(lo32, np.float32(-np.inf))), float(np.nextafter(hi32, np.float32(np.inf)))


def value_range(values) -> tuple[float, float, str | None]:
    """(Value Min, Value Max, warning or None) for sampled field values. A field constant up to
    rounding (its spread below ROUNDING_RELATIVE of its magnitude, or every value within
    ROUNDING_ZERO of zero) gets a range centred on its value, with a warning in words, rather than
    a ramp stretched over its round-off; a range float32 cannot tell apart is widened until it can."""
    values = np.asarray(values, dtype=np.float64)
    lo, hi = float(values.min()), float(values.max())
    magnitude = max(abs(lo), abs(hi))
    if magnitude <= ROUNDING_ZERO:
        return -1.0, 1.0, (f"the field is zero up to rounding (every value within \u00b1{magnitude:.2g}): Value "
                           "Min/Max set to -1..1, so it shows as one uniform value; set them by hand if values this "
                           "small are the data")
    if hi - lo <= ROUNDING_RELATIVE * magnitude:
        centre = 0.5 * (lo + hi)
        half = 0.5 * abs(centre)
        what = "constant" if hi == lo else f"constant up to rounding (spread {hi - lo:.2g})"
        return centre - half, centre + half, (f"the field is {what}: {centre:.6g} everywhere; Value Min/Max set "
                                              f"around it ({centre - half:.4g}..{centre + half:.4g})")
    lo, hi = _float32_distinct(lo, hi)
    return lo, hi, None
