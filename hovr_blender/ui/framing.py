"""Sizes, framing and sanity checks of a first picture, without bpy (tested without Blender).

Blender's defaults are made for metre-sized scenes: a 2 cm domain sits inside the default
camera's 0.1 m clip start and is ~2% opaque at one unit of extinction per metre. These
functions turn a volume's extent into the numbers a first picture needs (a density per world
unit, a step in world units, a camera position, clip planes) and say in words when a picture
will be empty.
"""
from __future__ import annotations

import numpy as np

DENSITY_UNITS = ("RELATIVE", "WORLD")
# Blender's default camera looks at the origin from (7.36, -6.93, 4.96): new cameras keep that view.
DEFAULT_VIEW = (-7.36, 6.93, -4.96)


def box_corners(lo, hi) -> np.ndarray:
    """(8, 3) corners of the axis-aligned box [lo, hi]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                     for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def transform_points(points, matrix) -> np.ndarray:
    M = np.asarray(matrix, float).reshape(4, 4)
    return np.asarray(points, float) @ M[:3, :3].T + M[:3, 3]


def volume_diagonal(lo, hi, matrix=None) -> float:
    """Length of the volume's bounding-box diagonal in world units: the object-space box
    (lo, hi) carried by the object's matrix, so rotating the object keeps it, scaling scales it."""
    d = np.asarray(hi, float) - np.asarray(lo, float)
    if matrix is not None:
        d = np.asarray(matrix, float).reshape(4, 4)[:3, :3] @ d
    return float(np.linalg.norm(d))


def density_per_world_unit(density: float, units: str, diagonal: float) -> float:
    """The contract's density scale (extinction per world unit at ramp alpha 1).

    RELATIVE: `density` is the optical depth across the bounding-box diagonal, so the look
    does not depend on the data's units (density 4 at alpha 1 leaves e^-4 ~ 2% of the light
    through the longest path); WORLD: `density` already is per world unit."""
    if units == "WORLD":
        return float(density)
    if units != "RELATIVE":
        raise ValueError(f"unknown density units {units!r}; one of {', '.join(DENSITY_UNITS)}")
    if not (np.isfinite(diagonal) and diagonal > 0):
        raise ValueError(f"the volume has no extent (bounding-box diagonal {diagonal:g}): cannot make its "
                         "density relative to its size; set Density units to Per World Unit")
    return float(density) / float(diagonal)


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


def _axes(forward, up):
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    if np.linalg.norm(r) < 1e-9:  # looking along up: any perpendicular will do
        r = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 1.0, 0.0])
    r /= np.linalg.norm(r)
    return f, r, np.cross(r, f)


def fit_view(corners, forward, up, tan_half_x: float, tan_half_y: float, orthographic: bool = False,
             margin: float = 1.1):
    """Where a camera looking along `forward` (roll from `up`) must stand to see every corner.

    Returns (eye, ortho_height or None, near, far): the eye on the line through the box's
    centre, the image height in world units an orthographic camera needs, and the view-axis
    depths of the nearest and farthest corner from that eye. `margin` leaves room around
    the box (1.1: the box spans ~90% of the limiting image side)."""
    p = np.asarray(corners, float)
    f, r, u = _axes(forward, up)
    c = 0.5 * (p.min(axis=0) + p.max(axis=0))
    x, y, z = (p - c) @ r, (p - c) @ u, (p - c) @ f
    size = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))) or 1.0
    if orthographic:
        height = 2.0 * margin * max(np.abs(y).max(), np.abs(x).max() * tan_half_y / tan_half_x)
        d = float(-z.min() + size)  # the eye a box-size in front of the box
        eye = c - d * f
        return eye, float(height), float(d + z.min()), float(d + z.max())
    tx, ty = tan_half_x / margin, tan_half_y / margin
    d = float(max((np.abs(x) / tx - z).max(), (np.abs(y) / ty - z).max(), -z.min() + 1e-3 * size))
    eye = c - d * f
    return eye, None, float(d + z.min()), float(d + z.max())


def clip_planes(near: float, far: float) -> tuple[float, float]:
    """Clip start/end that keep the depth range [near, far] well inside, with the ratio
    far/start bounded so the viewport's depth buffer keeps its precision."""
    span = max(far - near, 1e-12)
    start = max(0.5 * near, 1e-4 * far, 1e-6)
    if start >= near:
        start = max(near - 0.5 * span, 1e-6 * far)
    return float(start), float(far + span)


def look_at_matrix(eye, forward, up) -> np.ndarray:
    """Camera-to-world 4x4 of a Blender camera (looks down its local -Z, +Y up)."""
    f, r, u = _axes(forward, up)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, eye
    return m


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
