"""A volume's first picture, one home for Blender's import and the command line: the value range
and look an import gives a volume (File > Import with Fit Value Range: ui/import_operators.py,
ui/operators.py), the camera Frame Camera places (ui/operators.frame_volumes), and the view of a
data file without a view file (`hovr render FILE`, `hovr view FILE`: cli.py), made of the same
numbers, so that `hovr render FILE --size WxH` is Blender's first F12 after an import with the
defaults into its factory startup scene at that size (tests/blender/test_first_view.py).

Blender keeps a look's numbers (Value Min/Max, the ramp's positions and colours, Density) as
float32 properties: first_look rounds them as Blender stores them, so both read the same ramp.
Lengths are world units; colours scene-linear.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .camera_matrices import clipped, perspective_matrix, ray_camera_from_matrices
from .camera import RayCamera
from .looks import DEFAULT_DENSITY, DEFAULT_PRESET, FIRST_LOOK, FIRST_LOOKS, TF_PRESETS, field_samples, value_range
from .transfer_function import TransferFunction

# Blender's factory startup scene, as Blender keeps it (float32): its camera's matrix_world (at
# (7.36, -6.93, 4.96), rotated (63.56, 0, 46.69) degrees), whose local -Z is the view direction (a
# camera made where there is none looks the same way), lens and sensor (sensor fit Auto), the
# world's colour, the render size
FACTORY_MATRIX = ((0.6859206557273865, -0.32401347160339355, 0.6515582203865051, 7.358891487121582),
                  (0.7276763319969177, 0.305420845746994, -0.6141703724861145, -6.925790786743164),
                  (0.0, 0.8953956365585327, 0.44527140259742737, 4.958309173583984),
                  (0.0, 0.0, 0.0, 1.0))
FACTORY_FORWARD = tuple(-row[2] for row in FACTORY_MATRIX[:3])
FACTORY_UP = (0.0, 0.0, 1.0)
FACTORY_LENS_MM = 50.0
FACTORY_SENSOR_MM = 36.0
FACTORY_WORLD = (0.05087608844041824, 0.05087608844041824, 0.05087608844041824)
FACTORY_SIZE = (1920, 1080)
# a new scene's step (Render Properties > Quadrature > Steps Across: the smallest volume's
# diagonal / this). h = diagonal / 1000: PyFR's Taylor-Green box (diagonal 10.9) keeps about the
# world default 0.01, hump3D (diagonal 0.023) gets 2.3e-5 instead of a step half its size
DEFAULT_STEPS_ACROSS = 1000
FRAME_MARGIN = 1.1  # Frame Camera's room around the volumes: they span ~90% of the limiting side
MAX_FRAMING_POINTS = 50_000

DENSITY_UNITS = ("RELATIVE", "WORLD")


def _f32(x) -> float:
    return float(np.float32(x))


# ---------------------------------------------------------------------------------- the look


@dataclass(frozen=True)
class FirstLook:
    """What an import with Fit Value Range gives a volume: Value Min/Max fitted to its field's
    samples, the ramp's stops over them and its Density across the volume; `warning` says why a
    field constant up to rounding keeps the smooth ramp (there are no layers to place shells by)."""

    value_min: float
    value_max: float
    stops: tuple  # ((position, (r, g, b, alpha)), ...)
    density: float
    warning: str | None = None


def first_look(values, look: str = FIRST_LOOK, weights=None) -> FirstLook:
    """The volume's first look from its field's sampled values and the volume each stands for
    (looks.field_samples(..., weights=True)), each number as Blender's float32 properties keep it."""
    lo, hi, warning = value_range(values)
    lo, hi = _f32(lo), _f32(hi)
    if warning:
        stops, density = TF_PRESETS[DEFAULT_PRESET][2], DEFAULT_DENSITY
    else:
        stops, density = FIRST_LOOKS[look][2](values, lo, hi, weights)
    stops = tuple((_f32(p), tuple(_f32(c) for c in rgba)) for p, rgba in stops)
    return FirstLook(lo, hi, stops, _f32(density), warning)


def volume_diagonal(lo, hi, matrix=None) -> float:
    """Length of the volume's bounding-box diagonal in world units: the object-space box
    (lo, hi) carried by the object's matrix, so rotating the object keeps it, scaling scales it."""
    d = np.asarray(hi, float) - np.asarray(lo, float)
    if matrix is not None:
        d = np.asarray(matrix, float).reshape(4, 4)[:3, :3] @ d
    return float(np.linalg.norm(d))


def mesh_diagonal(mesh) -> float:
    """The diagonal of the box of a mesh's element corners (Blender's Density and step across the volume)."""
    v = mesh.vertices.reshape(-1, 3)
    return volume_diagonal(v.min(axis=0), v.max(axis=0))


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


def look_transfer_function(look: FirstLook, diagonal: float) -> TransferFunction:
    """The contract's transfer function of a look on a volume of that diagonal (Density across it),
    as Blender's F12 makes it from the ramp (ui/snapshot.resolve_units)."""
    positions = [p for p, _ in look.stops]
    rgba = [c for _, c in look.stops]
    return TransferFunction.from_rgba_ramp(positions, rgba, density_per_world_unit(look.density, "RELATIVE", diagonal),
                                           look.value_min, look.value_max)


# -------------------------------------------------------------------------------- the camera


def framing_points(mesh) -> np.ndarray:
    """(n, 3) object-space element corners of a mesh (at most ~MAX_FRAMING_POINTS, evenly strided):
    what Frame Camera fits, tighter than the bounding box for round domains."""
    v = np.unique(mesh.vertices.reshape(-1, 3), axis=0)
    return v[::max(1, len(v) // MAX_FRAMING_POINTS)]


def _axes(forward, up):
    f = np.asarray(forward, float)
    f = f / np.linalg.norm(f)
    r = np.cross(f, np.asarray(up, float))
    if np.linalg.norm(r) < 1e-9:  # looking along up: any perpendicular will do
        r = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 1.0, 0.0])
    r /= np.linalg.norm(r)
    return f, r, np.cross(r, f)


def fit_view(corners, forward, up, tan_half_x: float, tan_half_y: float, orthographic: bool = False,
             margin: float = FRAME_MARGIN):
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


def look_at_matrix(eye, forward, up) -> np.ndarray:
    """Camera-to-world 4x4 of a Blender camera (looks down its local -Z, +Y up)."""
    f, r, u = _axes(forward, up)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, eye
    return m


def euler_xyz(rotation) -> tuple[float, float, float]:
    """Blender's XYZ Euler angles (R = Rz Ry Rx) of a 3x3 rotation."""
    r = np.asarray(rotation, float)
    y = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
    if abs(r[2, 0]) < 1.0 - 1e-12:
        return float(np.arctan2(r[2, 1], r[2, 2])), float(y), float(np.arctan2(r[1, 0], r[0, 0]))
    return float(np.arctan2(-r[1, 2], r[1, 1])), float(y), 0.0  # looking straight along an axis


def euler_matrix(euler) -> np.ndarray:
    """The 3x3 rotation Blender makes of XYZ Euler angles (eulO_to_mat3: the float32 angles' sines and
    cosines in double, each entry rounded to float32), as float64 values."""
    i, j, h = (float(np.float32(a)) for a in euler)
    ci, cj, ch, si, sj, sh = math.cos(i), math.cos(j), math.cos(h), math.sin(i), math.sin(j), math.sin(h)
    cc, cs, sc, ss = ci * ch, ci * sh, si * ch, si * sh
    r = np.array([[cj * ch, sj * sc - cs, sj * cc + ss],
                  [cj * sh, sj * ss + cc, sj * cs - sc],
                  [-sj, cj * si, cj * ci]])
    return r.astype(np.float32).astype(np.float64)


def camera_pose(eye, forward, up) -> tuple[tuple, tuple, np.ndarray]:
    """(location, rotation_euler, matrix_world) of a camera at `eye` looking along `forward`, as
    Blender keeps it: location and XYZ Euler angles in float32, the matrix made from them
    (euler_matrix); Frame Camera sets the location and angles (ui/operators.frame_volumes)."""
    m = look_at_matrix(eye, forward, up)
    location = tuple(float(np.float32(v)) for v in m[:3, 3])
    euler = tuple(float(np.float32(a)) for a in euler_xyz(m[:3, :3]))
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = euler_matrix(euler), location
    return location, euler, matrix


def clip_planes(near: float, far: float) -> tuple[float, float]:
    """Clip start/end that keep the depth range [near, far] well inside, with the ratio
    far/start bounded so the viewport's depth buffer keeps its precision."""
    span = max(far - near, 1e-12)
    start = max(0.5 * near, 1e-4 * far, 1e-6)
    if start >= near:
        start = max(near - 0.5 * span, 1e-6 * far)
    return float(start), float(far + span)


def frame_tangents(rays: RayCamera) -> tuple[float, float]:
    """(tan of half the horizontal angle, of half the vertical) of a camera's rays, as Frame Camera
    reads them; for an orthographic camera, its half-width and half-height over its unit height."""
    ortho = rays.projection == "orthographic"
    bx, by = (rays.ou, rays.ov) if ortho else (rays.du, rays.dv)
    return float(np.linalg.norm(bx)) * rays.width / rays.height, float(np.linalg.norm(by))


def factory_camera(points, width: int, height: int) -> tuple[RayCamera, dict]:
    """(rays, contract camera): Frame Camera (ui/operators.frame_volumes) on Blender's factory camera
    for these world points at width x height, with Blender's arithmetic: the angles read at clip
    1e-3..1e3, the eye fitted, the matrix and clip planes kept in float32, the projection Blender
    computes from them (camera_pose, perspective_matrix). `rays` is F12's camera to its last bit;
    the contract camera (eye, target, up, field of view) the same camera in a view file's terms,
    whose float64 arithmetic rounds it apart by ~1e-7."""
    f32 = np.float32
    factory = np.array(FACTORY_MATRIX)
    probe = ray_camera_from_matrices(perspective_matrix(width, height, FACTORY_LENS_MM, FACTORY_SENSOR_MM,
                                                        f32(1e-3), f32(1e3)), factory, width, height)
    tan_x, tan_y = frame_tangents(probe)
    forward = -factory[:3, 2]
    eye, _, near, far = fit_view(points, forward, FACTORY_UP, tan_x, tan_y)
    matrix = camera_pose(eye, forward, FACTORY_UP)[2]
    clip_start, clip_end = (float(f32(c)) for c in clip_planes(near, far))
    projection = perspective_matrix(width, height, FACTORY_LENS_MM, FACTORY_SENSOR_MM, clip_start, clip_end)
    rays = clipped(ray_camera_from_matrices(projection, matrix, width, height), clip_start, clip_end)
    eye, view = matrix[:3, 3], -matrix[:3, 2]
    contract = {"projection": "perspective", "eye": [float(v) for v in eye],
                "target": [float(v) for v in eye + view / np.linalg.norm(view)], "up": list(FACTORY_UP),
                "fov_y_deg": float(np.degrees(2.0 * np.arctan(1.0 / float(projection[1, 1]))))}
    return rays, contract


@dataclass
class FirstView:
    """A data file's first view: the view file's object, F12's camera (factory_camera's rays; the
    object's camera is the same in the contract's terms) and the warnings an import reports."""

    view: dict
    camera: RayCamera
    warnings: list


def default_view(mesh, data: dict, width: int, height: int) -> FirstView:
    """A data file's view (the contract's keys and `render`), as Blender's first F12 after an import
    with the defaults into its factory scene: the look first_look gives the field's samples over
    the fitted range, the factory camera framed on the volume, the factory world behind, Classified
    at DEFAULT_STEPS_ACROSS steps across the volume; the warnings an import reports of the look (a
    field constant up to rounding)."""
    diagonal = mesh_diagonal(mesh)
    values, weights = field_samples(mesh, weights=True)
    look = first_look(values, weights=weights)
    rays, camera = factory_camera(framing_points(mesh), width, height)
    view = {"data": dict(data), "image": {"width": int(width), "height": int(height)}, "camera": camera,
            "transfer_function": look_transfer_function(look, diagonal).to_contract(),
            "background": list(FACTORY_WORLD),
            "render": {"method": "classified", "h": diagonal / DEFAULT_STEPS_ACROSS}}
    return FirstView(view, rays, [w for w in (look.warning,) if w])
