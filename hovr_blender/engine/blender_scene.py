"""Plain-data steps of a Blender render that need no bpy: ramp -> transfer function,
volume source -> mesh, core image -> Blender's Combined pass. Tested without Blender."""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

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


def frame_path(path: str, frame: int) -> str:
    """Blender's numbered-file convention: the last run of '#' becomes the frame number,
    zero-padded to the run's length ("flow_####.fld", 12 -> "flow_0012.fld")."""
    if not path:
        return path
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    m = runs[-1]
    number = f"{abs(int(frame)):0{len(m.group())}d}"
    return path[: m.start()] + ("-" if frame < 0 else "") + number + path[m.end():]


@dataclass(frozen=True)
class VolumeSource:
    """One frame's data: what to read, and a key that changes exactly when the bytes may.

    `path` is "builtin:NAME" or an absolute file path (placeholders already substituted)."""

    path: str
    solution: str = ""
    field: str = ""
    stamps: tuple = ()  # (mtime_ns, size) of each file when the source was resolved

    @property
    def key(self) -> tuple:
        return (self.path, self.solution, self.field, self.stamps)


def _stamps(*paths) -> tuple:
    out = []
    for p in paths:
        if p:
            try:
                st = os.stat(p)
                out.append((st.st_mtime_ns, st.st_size))
            except OSError:
                out.append(None)  # missing: load_volume_source reports it
    return tuple(out)


def volume_source(source: str, solution: str = "", field: str = "", frame: int = 1, abspath=None) -> VolumeSource:
    """Object.hovr (source, solution, field) at a frame; `abspath` resolves Blender's '//'."""
    source, solution, field = source.strip(), solution.strip(), field.strip()
    if source.startswith("builtin:"):
        return VolumeSource(source, "", "")
    if not source:
        raise SourceError("the HOVR volume has no source: set Object > HOVR Volume > Source")
    resolve = abspath or (lambda p: p)
    path = os.path.abspath(resolve(frame_path(source, frame)))
    sol = os.path.abspath(resolve(frame_path(solution, frame))) if solution else ""
    return VolumeSource(path, sol, field, _stamps(path, sol))


def load_volume_source(source, solution: str = "", field: str = "") -> VolumeMesh:
    """Object.hovr.source -> mesh in object space: "builtin:NAME" for the shipped datasets,
    a Nektar++ .xml (with `solution`, the .fld/.chk beside it) or a .vtu file."""
    from ..io import builtin

    if isinstance(source, VolumeSource):
        source, solution, field = source.path, source.solution, source.field
    kind, _, name = source.partition(":")
    if kind == "builtin":
        if name not in builtin.BUILTIN:
            raise SourceError(f"unknown built-in dataset {name!r}; one of {', '.join(builtin.BUILTIN)}")
        return builtin.BUILTIN[name]()
    ext = os.path.splitext(source)[1].lower()
    if ext not in (".xml", ".vtu"):
        raise SourceError(f"unsupported volume source {source!r} (use builtin:NAME, a Nektar++ .xml or a .vtu file)")
    for p in (source, solution):
        if p and not os.path.exists(p):
            raise SourceError(f"data file not found: {p}")
    if ext == ".xml":
        from ..io import nektar

        return nektar.read_nektar(source, solution or None, field=field or None)
    try:
        from ..io.vtu import read_vtu
    except ImportError as exc:
        raise SourceError(f"{source}: this build has no VTU reader ({exc})") from exc
    return read_vtu(source, field or None)


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


# Transfer-function presets: (name, description, [(ramp position, (r, g, b, alpha))]).
# Colours are scene-linear; alpha x density scale is the extinction.
def _tents(spec, width):
    stops = [(0.0, (0.0, 0.0, 0.0, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
    for centre, rgb in spec:
        stops += [(centre - width, (*rgb, 0.0)), (centre, (*rgb, 1.0)), (centre + width, (*rgb, 0.0))]
    return sorted(stops, key=lambda s: s[0])


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
    return values[np.isfinite(values)]


def value_histogram(values, value_min: float, value_max: float, bins: int = 16) -> np.ndarray:
    """Fraction of the samples in each of `bins` equal bins of [value_min, value_max]."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0 or not value_max > value_min:
        return np.zeros(bins)
    counts, _ = np.histogram(values, bins=bins, range=(value_min, value_max))
    return counts / values.size
