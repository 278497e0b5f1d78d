"""Host side of a render: upload a VolumeMesh once per device, launch the ray kernel, gather stats."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .camera import RayCamera
from .mesh import VolumeMesh
from .transfer_function import TransferFunction
from .view import RenderOptions, View

_METHOD_IDS = {"riemann": 0, "trapezoid": 1, "classified": 2, "split": 3}
_INNER_IDS = {"spectral": 0, "trapezoid": 1}


class RenderError(RuntimeError):
    """A render that could not run (device unavailable, out of memory); the message says why."""


@dataclass
class RenderResult:
    rgba: np.ndarray  # (H, W, 4) float32, RGB = C + T*background, A = 1 - T; row 0 at the top
    stats: dict
    depth: np.ndarray | None = None  # (H, W) t where 1 - T first reaches 0.5, else the far value
    error: np.ndarray | None = None  # (H, W) sum of the Gauss-Kronrod panel error estimates
    cancelled: bool = False


def _warp():
    """Import and initialise Warp on first use (device probing deferred until a render needs it)."""
    import warp as wp

    wp.config.quiet = True
    wp.init()
    return wp


def resolve_device(device: str) -> str:
    wp = _warp()
    try:
        return str(wp.get_device(device))
    except (RuntimeError, ValueError) as exc:
        avail = ", ".join(str(d) for d in wp.get_devices())
        raise RenderError(f"Warp device {device!r} is not available here (available: {avail})") from exc


class Renderer:
    """Holds one mesh uploaded to one Warp device (BVH included); render() many views with it."""

    def __init__(self, mesh: VolumeMesh, device: str = "cpu"):
        wp = _warp()
        from .kernels import raycast, quadrature_tables

        self.device = resolve_device(device)
        self.mesh = mesh
        self._k = raycast
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            from .mesh import element_boxes, element_field_ranges

            lowers, uppers = element_boxes(mesh)
            pad = 1e-5 * np.maximum(np.abs(lowers).max(axis=1, keepdims=True), np.abs(uppers - lowers).max(axis=1, keepdims=True))
            self._lowers = wp.array((lowers - pad).astype(np.float32), dtype=wp.vec3)
            self._uppers = wp.array((uppers + pad).astype(np.float32), dtype=wp.vec3)
            self._bvh = wp.Bvh(self._lowers, self._uppers)
            m = raycast.MeshArgs()
            m.bvh = self._bvh.id
            m.shape = wp.array(mesh.shape.astype(np.int32), dtype=wp.int32)
            m.ref_a = wp.array(mesh.ref_from_world[:, :, :3].astype(np.float32), dtype=wp.mat33)
            m.ref_b = wp.array(mesh.ref_from_world[:, :, 3].astype(np.float32), dtype=wp.vec3)
            m.modes = wp.array(mesh.modes.astype(np.int32), dtype=wp.vec3i)
            m.basis = wp.array(mesh.basis.astype(np.int32), dtype=wp.int32)
            if mesh.coeffs.size >= 2**31:
                raise RenderError("field too large for 32-bit coefficient offsets")
            m.coeff_offset = wp.array(mesh.coeff_offset.astype(np.int32), dtype=wp.int32)
            m.coeffs = wp.array(mesh.coeffs.astype(np.float32), dtype=wp.float32)
            flo, fhi = element_field_ranges(mesh)
            m.field_lo = wp.array(flo.astype(np.float32), dtype=wp.float32)
            m.field_hi = wp.array(fhi.astype(np.float32), dtype=wp.float32)
            n = mesh.num_elements
            affine = np.ones(n, np.int32) if mesh.affine is None else mesh.affine.astype(np.int32)
            m.affine = wp.array(affine, dtype=wp.int32)
            from .tensor_geometry import mesh_tensor_geometry

            gdeg, goff, gco, gcen = mesh_tensor_geometry(mesh)
            if gco.shape[0] >= 2**31:
                raise RenderError("curved geometry too large for 32-bit offsets")
            m.geo_degree = wp.array(gdeg.astype(np.int32), dtype=wp.int32)
            m.geo_offset = wp.array(goff.astype(np.int32), dtype=wp.int32)
            m.geo_coeffs = wp.array(gco.astype(np.float32), dtype=wp.vec3)
            m.geo_centre = wp.array(gcen.astype(np.float32), dtype=wp.vec3)
            # affine-only meshes get the kernel without the curved machinery
            self._kernel = raycast.render_kernel(curved=not bool(affine.all()))
            m.box_lo = self._lowers
            m.box_hi = self._uppers
            self._mesh_args = m
            x, wk, wg = quadrature_tables.gauss_kronrod_15()
            S = quadrature_tables.integration_matrix(x)
            self._gk = [wp.array(a.astype(np.float32), dtype=wp.float32) for a in (x, wk, wg)]
            self._gk_s = wp.array(S.astype(np.float32), dtype=wp.float32)
        self.upload_seconds = time.perf_counter() - t0

    def render(self, camera: RayCamera, tf: TransferFunction, background, options: RenderOptions,
               progress=None, tile_pixels: int | None = None) -> RenderResult:
        """Render one image. With `progress`, the image is launched in tiles of `tile_pixels`
        pixels and progress(fraction_done) is called after each; returning False cancels
        (the result then has cancelled=True and only the finished tiles filled in)."""
        wp = _warp()
        k = self._k
        W, H = int(camera.width), int(camera.height)
        bg = np.asarray(background, dtype=np.float64).reshape(3)
        with wp.ScopedDevice(self.device):
            cam = k.CameraArgs()
            for name in ("o0", "ou", "ov", "d0", "du", "dv"):
                setattr(cam, name, wp.vec3(*map(float, getattr(camera, name))))
            cam.width, cam.height = W, H
            cam.t_min = float(camera.t_min)
            cam.t_max = float(min(camera.t_max, 1e30))
            cam.clip_axis = wp.vec3(*map(float, camera.clip_axis))
            cam.clip_near = float(camera.clip_near)
            cam.clip_far = float(min(camera.clip_far, 1e30))
            t = k.TransferArgs()
            t.color_s = wp.array(tf.color_s.astype(np.float32), dtype=wp.float32)
            t.color_rgb = wp.array(tf.color_rgb.astype(np.float32), dtype=wp.vec3)
            t.density_s = wp.array(tf.density_s.astype(np.float32), dtype=wp.float32)
            t.density_tau = wp.array(tf.density_tau.astype(np.float32), dtype=wp.float32)
            q = k.QuadArgs()
            q.method = _METHOD_IDS[options.method]
            q.inner = _INNER_IDS[options.inner]
            q.h = float(options.h)
            q.tol = float(options.tolerance)
            q.min_transmittance = float(options.min_transmittance)
            q.background = wp.vec3(*map(float, bg))
            q.gk_x, q.gk_wk, q.gk_wg = self._gk
            q.gk_s = self._gk_s
            try:
                rgba = wp.zeros(W * H, dtype=wp.vec4)
                aux = wp.zeros(W * H, dtype=wp.vec2)
                stats = wp.zeros((W * H, k.NUM_STATS), dtype=wp.int32)
            except RuntimeError as exc:  # allocation failure on the device
                raise RenderError(f"cannot allocate a {W}x{H} image on {self.device}: {exc}") from exc
            wp.load_module(self._kernel.module, device=self.device)  # compile outside the timed region
            wp.synchronize_device(self.device)
            t0 = time.perf_counter()
            total = W * H
            step = total if progress is None else max(1, int(tile_pixels or 65536))
            cancelled = False
            for start in range(0, total, step):
                n = min(step, total - start)
                wp.launch(self._kernel, dim=n, inputs=[self._mesh_args, cam, t, q, start, rgba, aux, stats])
                if progress is not None:
                    wp.synchronize_device(self.device)
                    if progress((start + n) / total) is False:
                        cancelled = True
                        break
            wp.synchronize_device(self.device)
            seconds = time.perf_counter() - t0
            img = rgba.numpy().reshape(H, W, 4)
            depth_err = aux.numpy().reshape(H, W, 2)
            st = stats.numpy().astype(np.int64)
        if not np.all(np.isfinite(img)):
            raise RenderError("the render produced non-finite pixels (NaN/Inf in the data or transfer function?)")
        tot = st.sum(axis=0)
        return RenderResult(
            depth=depth_err[..., 0],
            error=depth_err[..., 1],
            cancelled=cancelled,
            rgba=img,
            stats={
                "device": self.device,
                "render_seconds": seconds,
                "width": W,
                "height": H,
                "method": options.method,
                "parameters": options.as_dict(),
                "field_evaluations": int(tot[k.STAT_FIELD_EVALS]),
                "restriction_evaluations": int(tot[k.STAT_RESTRICTION_EVALS]),
                "samples_per_ray": float((tot[k.STAT_FIELD_EVALS] + tot[k.STAT_RESTRICTION_EVALS]) / (W * H)),
                "segments": int(tot[k.STAT_SEGMENTS]),
                "segments_empty": int(tot[k.STAT_EMPTY]),
                "segments_smooth": int(tot[k.STAT_SMOOTH]),
                "segments_piecewise_smooth": int(tot[k.STAT_PIECEWISE]),
                "curved_locates": int(tot[k.STAT_LOCATES]),
                "elements": self.mesh.num_elements,
                "precision": "float32",
            },
        )


def render_view(view: View, mesh: VolumeMesh | None = None) -> RenderResult:
    mesh = view.load_mesh() if mesh is None else mesh
    return Renderer(mesh, view.options.device).render(view.camera, view.transfer_function, view.background, view.options)
