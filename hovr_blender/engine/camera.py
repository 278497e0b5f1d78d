"""Pixel rays (render contract §4) as one affine model shared by every camera source.

For pixel (i, j) (row 0 at the top) with u = (2(i+0.5)/W - 1) W/H and v = 1 - 2(j+0.5)/H:

    origin(u, v)    = o0 + u ou + v ov
    direction(u, v) = normalize(d0 + u du + v dv)

Perspective cameras have ou = ov = 0; orthographic ones du = dv = 0. Blender's camera
(sensor fit, shift, pixel aspect) also reduces to this form, so the kernel has one path.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .strict_json import as_number, as_object, as_string, as_vector3


class CameraError(ValueError):
    """A camera the contract cannot describe (zero direction, bad size, unknown projection)."""


def _unit(v, what):
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if not np.isfinite(n) or n < 1e-300:
        raise CameraError(f"camera: {what} has zero length")
    return v / n


@dataclass(frozen=True)
class RayCamera:
    width: int
    height: int
    o0: np.ndarray
    ou: np.ndarray
    ov: np.ndarray
    d0: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    t_min: float = 0.0
    t_max: float = float("inf")
    projection: str = "perspective"
    # optional clip planes along a view axis (Blender's clip start/end for perspective
    # cameras): a ray d keeps t in [clip_near / c, clip_far / c], c = d . clip_axis
    clip_axis: tuple = (0.0, 0.0, 0.0)
    clip_near: float = 0.0
    clip_far: float = float("inf")
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise CameraError(f"image size must be positive, got {self.width}x{self.height}")
        for name in ("o0", "ou", "ov", "d0", "du", "dv"):
            a = np.asarray(getattr(self, name), dtype=np.float64).reshape(3)
            if not np.all(np.isfinite(a)):
                raise CameraError(f"camera: {name} is not finite")
            object.__setattr__(self, name, a)

    @classmethod
    def from_contract(cls, camera: dict, width: int, height: int) -> "RayCamera":
        camera = as_object(camera, "camera", CameraError)
        for key in ("eye", "target", "up"):
            if key not in camera:
                raise CameraError(f"camera needs eye, target and up: '{key}' is missing")
        proj = as_string(camera.get("projection", "perspective"), "camera.projection", CameraError)
        eye = as_vector3(camera["eye"], "camera.eye", CameraError)
        target = as_vector3(camera["target"], "camera.target", CameraError)
        up = as_vector3(camera["up"], "camera.up", CameraError)
        forward = _unit(target - eye, "target - eye")
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-12:
            raise CameraError("camera: up is parallel to the viewing direction")
        right = _unit(right, "right")
        up2 = np.cross(right, forward)
        zero = np.zeros(3)
        if proj == "perspective":
            if "fov_y_deg" not in camera:
                raise CameraError("perspective camera needs fov_y_deg")
            fov = as_number(camera["fov_y_deg"], "camera.fov_y_deg", CameraError)
            if not 0.0 < fov < 180.0:
                raise CameraError(f"fov_y_deg must be in (0, 180), got {fov}")
            t = np.tan(np.radians(fov) / 2.0)
            return cls(width, height, eye, zero, zero, forward, t * right, t * up2, projection=proj)
        if proj == "orthographic":
            if "height" not in camera:
                raise CameraError("orthographic camera needs height")
            h = as_number(camera["height"], "camera.height", CameraError)
            if not h > 0.0:
                raise CameraError(f"orthographic height must be > 0, got {h}")
            return cls(width, height, eye, 0.5 * h * right, 0.5 * h * up2, forward, zero, zero, projection=proj)
        raise CameraError(f"unknown camera projection {proj!r} (perspective or orthographic)")

    def uv(self):
        """(H, W) arrays of the contract's u, v at pixel centres, row 0 at the top."""
        w, h = int(self.width), int(self.height)
        i = np.arange(w, dtype=np.float64)
        j = np.arange(h, dtype=np.float64)
        u = (2.0 * (i + 0.5) / w - 1.0) * (w / h)
        v = 1.0 - 2.0 * (j + 0.5) / h
        return np.meshgrid(u, v)

    def rays(self):
        """float64 (H, W, 3) origins and unit directions; the reference integrator's rays."""
        u, v = self.uv()
        o = self.o0 + u[..., None] * self.ou + v[..., None] * self.ov
        d = self.d0 + u[..., None] * self.du + v[..., None] * self.dv
        return o, d / np.linalg.norm(d, axis=-1, keepdims=True)
