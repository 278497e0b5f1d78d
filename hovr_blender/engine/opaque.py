"""Opaque surfaces in front of, inside and behind the volume: where a pixel's ray first hits one,
its volume integral ends, and what lies behind is the surface instead of the background.

For the pixel's ray x(t) = o + t d (contract §4, |d| = 1), let t_s be the first hit of an
opaque triangle with t in the camera's range (+inf where none). The volume is integrated over
[0, t_s] only (Renderer.render(surface_t=...): kernels/rays.py init_rays; a Frame's opaque
meshes, engine/frame.py), which gives
C and T of contract §3 with the upper limit t_s, and the pixel is

    no hit:                 RGB = C + T background,   alpha = 1 - T   (contract §3, unchanged)
    hit, shaded surface:    RGB = C + T S,            alpha = 1
    hit, holdout surface:   RGB = C,                  alpha = 1 - T

with the surface's shading S = base_colour |n . d| (a two-sided headlight: a light at the eye,
Lambert's cosine between the triangle's geometric normal n and the ray, no other light, no
ambient term). A holdout surface (Blender's holdout objects; every surface in the HOLDOUT
mode) stops the rays but leaves the film transparent there: the image is then the volume in
front of the surfaces, premultiplied, for compositing over another renderer's picture of them
(alpha over: result = HOVR + (1 - alpha_HOVR) other).

Warp is imported only when an OpaqueScene is uploaded and cast (as engine/reference.py imports
the renderer), so the module itself imports without it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import RayCamera

MODES = ("SHADED", "HOLDOUT")


class OpaqueError(ValueError):
    """Triangles the surface cast cannot take (wrong shapes, non-finite vertices, bad indices)."""


@dataclass
class OpaqueMesh:
    """One object's triangles in world space, its base colour (linear RGB) and whether it is a
    holdout."""

    vertices: np.ndarray  # (n, 3) float
    triangles: np.ndarray  # (m, 3) int, indices into vertices
    color: tuple = (0.8, 0.8, 0.8)
    holdout: bool = False
    name: str = ""

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(self.triangles, dtype=np.int64).reshape(-1, 3)
        if not np.all(np.isfinite(v)):
            raise OpaqueError(f"surface {self.name!r}: vertices are not finite")
        if t.size and (t.min() < 0 or t.max() >= len(v)):
            raise OpaqueError(f"surface {self.name!r}: a triangle indexes outside its {len(v)} vertices")
        c = np.asarray(self.color, dtype=np.float64).reshape(-1)[:3]
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise OpaqueError(f"surface {self.name!r}: colour must be three finite numbers")
        self.vertices, self.triangles, self.color = v, t, tuple(float(x) for x in c)


@dataclass
class OpaqueHits:
    """Per pixel (H, W, rows from the top) of one camera: the first hit's t (+inf where none),
    its surface (index into OpaqueScene.meshes, -1 where none), the triangle's unit normal and
    the shaded colour S (zero where none)."""

    t: np.ndarray
    surface: np.ndarray
    normal: np.ndarray
    shaded: np.ndarray
    holdout: np.ndarray  # (H, W) bool: the hit surface is a holdout

    @property
    def hit(self) -> np.ndarray:
        return self.surface >= 0


def shade(color, normal, direction) -> np.ndarray:
    """The documented surface shading: base colour times |n . d| (two-sided headlight)."""
    cos = np.abs(np.sum(np.asarray(normal) * np.asarray(direction), axis=-1))
    return np.asarray(color) * cos[..., None]


@dataclass
class OpaqueScene:
    """Triangle meshes merged into one and uploaded once to a Warp device (a wp.Mesh and its
    BVH); cast(camera) for any number of cameras."""

    meshes: list
    device: str = "cpu"
    _upload: object = field(default=None, repr=False)

    def __post_init__(self):
        self.meshes = [m for m in self.meshes if len(m.triangles)]
        counts = [len(m.triangles) for m in self.meshes]
        self.face_surface = np.repeat(np.arange(len(self.meshes), dtype=np.int64), counts)
        offsets = np.cumsum([0] + [len(m.vertices) for m in self.meshes])
        self.vertices = (np.concatenate([m.vertices for m in self.meshes]) if self.meshes else np.zeros((0, 3)))
        self.triangles = (np.concatenate([m.triangles + o for m, o in zip(self.meshes, offsets)])
                          if self.meshes else np.zeros((0, 3), dtype=np.int64))
        a, b, c = (self.vertices[self.triangles[:, k]] for k in range(3))
        n = np.cross(b - a, c - a)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.face_normal = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        self.colors = np.array([m.color for m in self.meshes]).reshape(-1, 3)
        self.holdouts = np.array([m.holdout for m in self.meshes], dtype=bool)

    @property
    def empty(self) -> bool:
        return len(self.triangles) == 0

    def _device_mesh(self):
        if self._upload is None:
            import warp as wp

            from .devices import resolve_device

            self.device = resolve_device(self.device)
            with wp.ScopedDevice(self.device):
                points = wp.array(self.vertices.astype(np.float32), dtype=wp.vec3)
                indices = wp.array(self.triangles.astype(np.int32).ravel(), dtype=wp.int32)
                self._upload = (points, indices, wp.Mesh(points=points, indices=indices))
        return self._upload[2]

    def cast(self, camera: RayCamera) -> OpaqueHits:
        """The camera's rays against the triangles (kernels/opaque_cast.py), shaded here in float64."""
        W, H = int(camera.width), int(camera.height)
        if self.empty:
            t = np.full((H, W), np.inf)
            face = np.full((H, W), -1, dtype=np.int64)
        else:
            import warp as wp

            from .kernels import opaque_cast
            from .kernels.precision import Precision
            from .launch_args import camera_args

            mesh = self._device_mesh()
            with wp.ScopedDevice(self.device):
                t_out = wp.zeros(W * H, dtype=wp.float32)
                face_out = wp.zeros(W * H, dtype=wp.int32)
                wp.launch(opaque_cast.cast_opaque, dim=W * H,
                          inputs=[mesh.id, camera_args(Precision.named("float32"), camera), t_out, face_out])
                t = t_out.numpy().astype(np.float64).reshape(H, W)
                face = face_out.numpy().astype(np.int64).reshape(H, W)
        hit = face >= 0
        surface = np.where(hit, self.face_surface[np.where(hit, face, 0)] if len(self.face_surface) else -1, -1)
        normal = np.where(hit[..., None], self.face_normal[np.where(hit, face, 0)] if hit.any() else 0.0, 0.0)
        _, d = camera.rays()
        color = self.colors[np.where(hit, surface, 0)] if hit.any() else np.zeros((H, W, 3))
        shaded = np.where(hit[..., None], shade(color, normal, d), 0.0)
        holdout = hit & (self.holdouts[np.where(hit, surface, 0)] if hit.any() else False)
        return OpaqueHits(t=np.where(hit, t, np.inf), surface=surface, normal=normal, shaded=shaded,
                           holdout=np.asarray(holdout, dtype=bool))


def composite(volume_rgba, hits: OpaqueHits, background, mode: str = "SHADED") -> np.ndarray:
    """The pixels of the module's docstring from the volume rendered up to the hits over a black
    background (RGB = C, alpha = 1 - T): (H, W, 4) float64."""
    if mode not in MODES:
        raise OpaqueError(f"surface mode must be one of {MODES}, got {mode!r}")
    v = np.asarray(volume_rgba, dtype=np.float64)
    T = 1.0 - v[..., 3:4]
    bg = np.asarray(background, dtype=np.float64).reshape(3)
    shaded = hits.hit & ~hits.holdout & (mode == "SHADED")
    holdout = hits.hit & ~shaded
    out = v.copy()
    out[..., :3] = v[..., :3] + T * np.where(shaded[..., None], hits.shaded, np.where(holdout[..., None], 0.0, bg))
    out[..., 3] = np.where(shaded, 1.0, v[..., 3])
    return out


def composite_hits(res, hits: OpaqueHits, background, mode: str, rows=None):
    """The volume's result (rendered up to the hits over black) with the opaque meshes composited in
    (composite); a band of `rows` takes its rows of the whole camera's hits."""
    if rows is not None:
        r0, r1 = int(rows[0]), int(rows[1])
        hits = OpaqueHits(*(a[r0:r1] for a in (hits.t, hits.surface, hits.normal, hits.shaded, hits.holdout)))
    res.rgba = composite(res.rgba, hits, background, mode).astype(res.rgba.dtype)
    res.stats["surface_pixels"] = int(hits.hit.sum())
    res.opaque_hits = hits
    return res
