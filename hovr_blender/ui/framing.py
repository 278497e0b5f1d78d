"""Sizes, framing and sanity checks of a first picture, without bpy (tested without Blender).

Blender's defaults are made for metre-sized scenes: a 2 cm domain sits inside the default
camera's 0.1 m clip start and is ~2% opaque at one unit of extinction per metre. These
functions turn a volume's extent into the numbers a first picture needs (a density per world
unit, a step in world units, clip planes) and say in words when a picture will be empty; the
camera's place and the volume's first look are engine/first_view.py's.
"""
from __future__ import annotations

import numpy as np


def box_corners(lo, hi) -> np.ndarray:
    """(8, 3) corners of the axis-aligned box [lo, hi]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                     for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def transform_points(points, matrix) -> np.ndarray:
    M = np.asarray(matrix, float).reshape(4, 4)
    return np.asarray(points, float) @ M[:3, :3].T + M[:3, 3]


STEP_UNITS = ("RELATIVE", "WORLD")


def step_world_length(h: float, steps_across: float, units: str, diagonals) -> float:
    """The contract's step h (world units) of a scene's volumes.

    RELATIVE: `steps_across` steps along the bounding-box diagonal of the smallest volume
    (h = its diagonal / steps_across), so every volume is sampled at least that finely
    whatever the data's units; WORLD: `h` already is in world units."""
    if units == "WORLD":
        return float(h)
    if units != "RELATIVE":
        raise ValueError(f"unknown step units {units!r}; one of {', '.join(STEP_UNITS)}")
    if not (np.isfinite(steps_across) and steps_across >= 1):
        raise ValueError(f"Steps Across must be at least 1, got {steps_across:g}")
    diagonals = [float(d) for d in diagonals]
    if not diagonals:
        raise ValueError("no volume to measure the step against")
    smallest = min(diagonals)
    if not (np.isfinite(smallest) and smallest > 0):
        raise ValueError(f"a volume has no extent (bounding-box diagonal {smallest:g}): cannot make the step "
                         "relative to its size; set Step units to World Units")
    return smallest / float(steps_across)


def depth_range(corners, eye, forward) -> tuple[float, float]:
    f = np.asarray(forward, float)
    z = (np.asarray(corners, float) - np.asarray(eye, float)) @ (f / np.linalg.norm(f))
    return float(z.min()), float(z.max())


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def clip_warning(corners, eye, forward, clip_start: float, clip_end: float, camera: str = "the camera") -> str | None:
    """Words for a volume the clip planes hide in whole or in part; None when they do not."""
    near, far = depth_range(corners, eye, forward)
    fix = "use Frame Volume (View > Frame HOVR Volume) or lower Clip Start / raise Clip End"
    if far <= 0:
        return f"the volume is behind {camera}: {fix}"
    if far <= clip_start:
        return (f"the volume lies entirely before {camera}'s Clip Start ({_fmt(clip_start)} m; volume at "
                f"{_fmt(max(near, 0))}-{_fmt(far)} m): nothing renders; {fix}")
    if near >= clip_end:
        return (f"the volume lies entirely beyond {camera}'s Clip End ({_fmt(clip_end)} m; volume at "
                f"{_fmt(near)}-{_fmt(far)} m): nothing renders; {fix}")
    if near < clip_start and near > 0:
        return f"{camera}'s Clip Start ({_fmt(clip_start)} m) cuts into the volume (nearest at {_fmt(near)} m); {fix}"
    if far > clip_end:
        return f"{camera}'s Clip End ({_fmt(clip_end)} m) cuts off the volume (farthest at {_fmt(far)} m); {fix}"
    return None


# Below this largest opacity a picture reads as "nothing there" on most backgrounds.
FAINT_ALPHA = 0.02


def image_warning(alpha) -> str | None:
    """Words for an empty or nearly transparent render (alpha = 1 - T per pixel), from the image
    alone: a frame shaded from cached segments evaluates no field and is still a picture."""
    alpha = np.asarray(alpha, float)
    peak = float(alpha.max()) if alpha.size else 0.0
    if peak <= 1e-6:
        return ("the image is empty: no ray met a visible part of the volume (camera aimed elsewhere or clipped, "
                "or the ramp's alpha is zero over Value Min..Max); try Frame Volume and Fit to Data Range")
    if peak < FAINT_ALPHA:
        return (f"the image is nearly transparent (largest opacity {100 * peak:.2g}%): raise the volume's Density "
                "or check Value Min/Max against the data (Fit to Data Range)")
    return None
