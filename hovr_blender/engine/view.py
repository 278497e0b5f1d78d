"""The view file of render contract §1, and the project's own render options."""
from __future__ import annotations

import numbers
import os
from dataclasses import dataclass, field, replace

import numpy as np

from .camera import RayCamera
from . import limits
from .isosurfaces import Surfaces, surfaces_from_view
from .limits import read_regular
from .methods import METHODS, needs_step, takes_step
from .strict_json import as_integer, as_object, as_string, as_vector3, loads
from .transfer_function import TransferFunction

# classified without h: each piecewise-smooth segment's trapezoid step is the largest whose error
# bound on the segment is at most this (kernels/quadrature.auto_steps). A quarter of the contract's
# aim for a whole image (§6): a ray's errors add up over the segments it marches (the paper-scale
# channel at 1e-3 a segment: 1.6e-3 at its worst pixel; docs/methods.md, "classified's step")
AUTO_STEP_ERROR = 2.5e-4
# A fixed step h resolves the data when one step absorbs at most 1 - 1/e of the light: the largest
# density over the field's values times h is at most this (render contract §3, "Fixed steps").
# The sums then keep C <= kappa_max (1 - T) within the factor x / (1 - e^-x) at x = tau_max h
# (Riemann: 1.58 at most) or (x / 2) coth(x / 2) (trapezoid: 1.08); a longer step is shortened to
# it (h = 1e6 gave RGB 5.04 at alpha 0.99 with kappa <= 1).
MAX_STEP_OPTICAL_DEPTH = 1.0


MAX_IMAGE_SIDE = 32768
MAX_VIEW_BYTES = 1 << 20


class ViewError(ValueError):
    """A view file that cannot be rendered; the message names the key."""


def data_spec(data) -> dict:
    """The view's ``data`` object, its keys type-checked: {"builtin": name} or {"path": ...,
    "solution": ..., "field": ..., "component": index or "magnitude"}."""
    data = as_object(data, "data", ViewError)
    for key in ("builtin", "path", "solution", "field"):
        if key in data and data[key] is not None:
            as_string(data[key], f"data.{key}", ViewError)
    comp = data.get("component")
    if comp is not None and comp != "magnitude":
        as_integer(comp, "data.component (an index or \"magnitude\")", ViewError, 0)
    return dict(data)


def device_processes(device: str) -> int:
    """The processes a device list starts, as far as its names say without asking Warp: one a
    name, a core for "cpu:all" ("cuda:all" counts one here; its devices are counted when they start)."""
    names = [d.strip() for d in device.split(",") if d.strip()]
    return sum(limits.cpu_cores() if d == "cpu:all" else 1 for d in names)


@dataclass(frozen=True)
class RenderOptions:
    """Quadrature settings; optional keys of the view file ("render": {...})."""

    method: str = "classified"
    # fixed step (world units) of Riemann/trapezoid and of classified's piecewise-smooth segments;
    # None: classified chooses each segment's step from its error bound (AUTO_STEP_ERROR)
    h: float | None = None
    tolerance: float = 1e-5  # absolute error target of each adaptive Gauss-Kronrod panel
    min_transmittance: float = 1e-5  # early ray termination: stop once T falls below this
    inner: str = "spectral"  # smooth/smooth inner integral: "spectral" or the paper's "trapezoid"
    device: str = "cpu"
    precision: str = "float32"  # kernel arithmetic: "float32" or "float64" (same kernel source)

    def __post_init__(self):
        for name in ("method", "inner", "device", "precision"):
            if not isinstance(getattr(self, name), str):
                raise ViewError(f"render option {name} must be a string, got {getattr(self, name)!r}")
        for name in ("h", "tolerance", "min_transmittance"):
            v = getattr(self, name)
            if name == "h" and v is None:
                continue
            if not isinstance(v, numbers.Real) or isinstance(v, bool):
                raise ViewError(f"render option {name} must be a number, got {v!r}")
        if self.method not in METHODS:
            raise ViewError(f"unknown method {self.method!r}; one of {', '.join(METHODS)}")
        if self.h is None:
            if needs_step(self.method):
                raise ViewError(f"method {self.method} marches with a fixed step: give h in world units "
                                f"(--h, or \"render\": {{\"h\": ...}} in the view file)")
        elif not (np.isfinite(self.h) and self.h > 0):
            raise ViewError(f"h must be a positive step, got {self.h}")
        if not (np.isfinite(self.tolerance) and self.tolerance > 0):
            raise ViewError(f"tolerance must be positive, got {self.tolerance}")
        if not (0.0 <= self.min_transmittance < 1.0):
            raise ViewError(f"min_transmittance must be in [0, 1), got {self.min_transmittance}")
        if self.inner not in ("spectral", "trapezoid"):
            raise ViewError(f"inner must be 'spectral' or 'trapezoid', got {self.inner!r}")
        if self.precision not in ("float32", "float64"):
            raise ViewError(f"precision must be 'float32' or 'float64', got {self.precision!r}")
        processes = device_processes(self.device)
        if processes > 1:  # refused here, before the data is read (start_processes checks the final count)
            limits.check_processes(processes, f"device {self.device[:80]!r}")

    @classmethod
    def pixel_exact(cls, device: str = "cpu") -> "RenderOptions":
        """The settings of the pixel-exact reference image (engine/reference.pixel_exact_reference):
        the breakpoint-split method in float64, Gauss-Kronrod panels to 1e-9 (curved interpolants
        to a tail of 1e-12), no early ray termination. Independent of the float32 kernels'
        rounding and of their tolerance, so an error measured against it includes both."""
        return cls(method="split", tolerance=1e-9, min_transmittance=0.0, precision="float64", device=device)

    def with_(self, **kw) -> "RenderOptions":
        return replace(self, **{k: v for k, v in kw.items() if v is not None})

    @property
    def fixed_step(self) -> bool:
        """Whether rays march with the fixed step h (the samples-per-ray limit applies)."""
        return takes_step(self.method) and self.h is not None

    def check_steps(self, data_diagonal: float):
        """A fixed step against the samples-per-ray limit across the data (engine/limits.py)."""
        if self.fixed_step:
            limits.check_samples_per_ray(self.h, data_diagonal)

    def image_bytes(self, width: int, height: int, num_stats: int = 0) -> int:
        """Bytes of a render's per-pixel buffers: RGBA and depth/error on the device and their
        host copies in this precision, num_stats counters (device int32, host int64) and 16
        bytes more a pixel. Renderer.check_limits adds its launch tiles' ray buffers; without
        Warp (num_stats 0) it is a lower bound, for refusing before Warp loads."""
        itemsize = np.dtype(self.precision).itemsize
        return int(width) * int(height) * ((4 + 2) * itemsize * 2 + 4 * num_stats + 8 * num_stats + 16)

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("method", "h", "tolerance", "min_transmittance", "inner", "device", "precision")}


@dataclass
class View:
    camera: RayCamera
    transfer_function: TransferFunction
    background: np.ndarray
    data: dict
    options: RenderOptions = field(default_factory=RenderOptions)
    base_dir: str = "."
    surfaces: Surfaces = field(default_factory=Surfaces)  # contract §7: isosurfaces and planes

    @classmethod
    def from_dict(cls, d: dict, base_dir: str = ".") -> "View":
        d = as_object(d, "a view", ViewError)
        for key in ("image", "camera", "transfer_function", "data"):
            if key not in d:
                raise ViewError(f"view needs '{key}'")
        img = as_object(d["image"], "image", ViewError)
        if "width" not in img or "height" not in img:
            raise ViewError("view needs image.width and image.height")
        w = as_integer(img["width"], "image size: width", ViewError, 1, MAX_IMAGE_SIDE)
        h = as_integer(img["height"], "image size: height", ViewError, 1, MAX_IMAGE_SIDE)
        bg = as_vector3(d.get("background", [0.0, 0.0, 0.0]), "background [r, g, b]", ViewError)
        opts = as_object(d.get("render", {}), "render", ViewError)
        try:
            options = RenderOptions(**opts)
        except TypeError as exc:
            raise ViewError(f"render options: {exc}") from exc
        return cls(
            camera=RayCamera.from_contract(d["camera"], w, h),
            transfer_function=TransferFunction.from_contract(d["transfer_function"]),
            background=bg,
            data=data_spec(d["data"]),
            options=options,
            base_dir=base_dir,
            surfaces=surfaces_from_view(d, ViewError),
        )

    @classmethod
    def load(cls, path: str) -> "View":
        # a view is a small JSON object: its size is checked on the open file before it is read
        raw = read_regular(path, "view file", max_bytes=MAX_VIEW_BYTES)
        return cls.from_dict(loads(raw, str(path), ViewError), base_dir=os.path.dirname(os.path.abspath(path)))


def resolving_step(options: RenderOptions, tfs, value_ranges) -> tuple[RenderOptions, list[str]]:
    """(options, warnings): a fixed step h (riemann, trapezoid, classified with h) that cannot resolve
    the data, tau_max h > MAX_STEP_OPTICAL_DEPTH, shortened to MAX_STEP_OPTICAL_DEPTH / tau_max,
    with a warning that says so; tau_max is the largest density of each volume's transfer function
    (`tfs`: one, or one per volume) over that volume's field values (`value_ranges`: (lo, hi) per
    volume). Other options come back as they are."""
    if options.h is None or not takes_step(options.method):
        return options, []
    tfs = [tfs] if isinstance(tfs, TransferFunction) else list(tfs)
    tau = max(tf.max_density(lo, hi) for tf, (lo, hi) in zip(tfs, value_ranges))
    if not tau * options.h > MAX_STEP_OPTICAL_DEPTH:
        return options, []
    h = MAX_STEP_OPTICAL_DEPTH / tau
    return options.with_(h=h), [
        f"step h = {options.h:g} cannot resolve the data (the density reaches {tau:.4g} per world unit, "
        f"{tau * options.h:.3g} e-foldings of the light a step): {options.method} stepped h = {h:.4g} "
        f"(render contract §3, fixed steps)"]
