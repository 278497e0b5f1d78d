"""The view file of render contract §1, and the project's own render options."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace

import numpy as np

from .camera import RayCamera
from .mesh import VolumeMesh
from .transfer_function import TransferFunction

METHODS = ("riemann", "trapezoid", "classified", "split")


class ViewError(ValueError):
    """A view file that cannot be rendered; the message names the key."""


@dataclass(frozen=True)
class RenderOptions:
    """Quadrature settings; optional keys of the view file ("render": {...})."""

    method: str = "classified"
    h: float = 0.01  # step (world units) of Riemann/trapezoid and of piecewise-smooth segments
    tolerance: float = 1e-5  # absolute error target of each adaptive Gauss-Kronrod panel
    min_transmittance: float = 1e-5  # early ray termination: stop once T falls below this
    inner: str = "spectral"  # smooth/smooth inner integral: "spectral" or the paper's "trapezoid"
    device: str = "cpu"
    precision: str = "float32"  # kernel arithmetic: "float32" or "float64" (same kernel source)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ViewError(f"unknown method {self.method!r}; one of {', '.join(METHODS)}")
        if not (np.isfinite(self.h) and self.h > 0):
            raise ViewError(f"h must be a positive step, got {self.h}")
        if not (np.isfinite(self.tolerance) and self.tolerance > 0):
            raise ViewError(f"tolerance must be positive, got {self.tolerance}")
        if not (0.0 <= self.min_transmittance < 1.0):
            raise ViewError(f"min_transmittance must be in [0, 1), got {self.min_transmittance}")
        if self.inner not in ("spectral", "trapezoid"):
            raise ViewError(f"inner must be 'spectral' or 'trapezoid', got {self.inner!r}")
        if self.precision not in ("float32", "float64"):
            raise ViewError(f"precision must be 'float32' or 'float64', got {self.precision!r}")

    def with_(self, **kw) -> "RenderOptions":
        return replace(self, **{k: v for k, v in kw.items() if v is not None})

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

    @classmethod
    def from_dict(cls, d: dict, base_dir: str = ".") -> "View":
        if not isinstance(d, dict):
            raise ViewError("a view is a JSON object")
        try:
            img = d["image"]
            w, h = int(img["width"]), int(img["height"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ViewError(f"view needs image.width and image.height: {exc}") from exc
        if not (1 <= w <= 32768 and 1 <= h <= 32768):
            raise ViewError(f"image size {w}x{h} out of range 1..32768")
        for key in ("camera", "transfer_function", "data"):
            if key not in d:
                raise ViewError(f"view needs '{key}'")
        bg = np.asarray(d.get("background", [0.0, 0.0, 0.0]), dtype=np.float64)
        if bg.shape != (3,) or not np.all(np.isfinite(bg)):
            raise ViewError("background must be [r, g, b]")
        opts = d.get("render", {})
        try:
            options = RenderOptions(**opts)
        except TypeError as exc:
            raise ViewError(f"render options: {exc}") from exc
        return cls(
            camera=RayCamera.from_contract(d["camera"], w, h),
            transfer_function=TransferFunction.from_contract(d["transfer_function"]),
            background=bg,
            data=dict(d["data"]),
            options=options,
            base_dir=base_dir,
        )

    @classmethod
    def load(cls, path: str) -> "View":
        try:
            with open(path, encoding="utf-8") as fh:
                d = json.load(fh)
        except OSError as exc:
            raise ViewError(f"cannot read view file {path}: {exc.strerror}") from exc
        except json.JSONDecodeError as exc:
            raise ViewError(f"{path}: not valid JSON ({exc})") from exc
        return cls.from_dict(d, base_dir=os.path.dirname(os.path.abspath(path)))

    def load_mesh(self) -> VolumeMesh:
        return load_data(self.data, self.base_dir)


def load_data(data: dict, base_dir: str = ".") -> VolumeMesh:
    """Resolve the view's ``data`` object to a mesh: {"builtin": name} or {"path": ..., ...}."""
    from ..io import builtin

    if "builtin" in data:
        name = data["builtin"]
        if name not in builtin.BUILTIN:
            raise ViewError(f"unknown built-in dataset {name!r}; one of {', '.join(builtin.BUILTIN)}")
        return builtin.BUILTIN[name]()
    if "path" not in data:
        raise ViewError("data needs 'path' (or 'builtin')")
    path = data["path"] if os.path.isabs(data["path"]) else os.path.join(base_dir, data["path"])
    sol = data.get("solution")
    if sol is not None and not os.path.isabs(sol):
        sol = os.path.join(base_dir, sol)
    for p in (path, sol):
        if p is not None and not os.path.exists(p):
            raise ViewError(f"data file not found: {p}")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".xml":
        from ..io import derived

        return derived.read_nektar_field(path, sol, field=data.get("field"))  # "|u,v,w|": the magnitude
    if ext == ".vtu":
        from ..io import derived

        # a vector's magnitude from its exact components, as in Blender (io/derived.py)
        return derived.read_vtu_field(path, field=data.get("field"), component=data.get("component"))
    raise ViewError(f"{path}: unsupported data format {ext!r} (Nektar++ .xml or VTK .vtu)")
