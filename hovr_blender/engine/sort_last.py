"""Meshes larger than one device: the elements partitioned over devices, each device integrating
its own part of every ray, the partial images composited front to back (sort-last).

Why slabs. Emission-absorption composes exactly front to back over consecutive pieces of a ray:
if the ray's [0, inf) is cut at t1 < t2 < ... into intervals I_1, I_2, ..., and piece k gives
C_k = int_{I_k} kappa tau exp(-int_{I_k, u < t} tau) dt and T_k = exp(-int_{I_k} tau), then

    C = C_1 + T_1 C_2 + T_1 T_2 C_3 + ...        T = T_1 T_2 T_3 ...

(contract §3 split at the cuts). This needs each device's share of a ray to be one interval, in
a known order. Element sets do not give that (elements of two parts interleave along a ray), so
the parts are slabs: planes a . x = w_k across a unit axis a cut space into slabs S_1, S_2, ...;
a line meets a slab in one interval, and a ray with d . a > 0 meets them in the order of k.
Device k holds every element whose box reaches into S_k (an element astride a plane goes to both
sides) and integrates only t where the ray is inside S_k: the camera's clip planes along `a`
(RayCamera.clip_axis, clip_near, clip_far; kernel init_rays), which keep t with
near <= t (d . a) <= far, i.e. the slab, measured from the camera's origin plane. Neighbouring
slabs compute the cut t = w / (d . a) from the same numbers, so the pieces meet without a gap or
an overlap; inside a slab the kernel integrates the elements' segments clipped at the planes,
each exactly as in one device's render, so the composite differs from the single-device image
only by the quadrature's splitting of the two segments at a cut (within the method's tolerance:
<= 1e-6 for the pixel-exact settings, tests/engine/test_multi_device.py) and by rounding.

The axis is the camera's forward direction when the partition is made, and a partition serves
every later camera whose rays all have d . a > 0 (a perspective camera's four corner rays say so)
and, for orthographic cameras, whose origin plane is perpendicular to a; any other camera gets a
new partition. Early ray termination acts per part (each part stops once its own transmittance
is below min_transmittance), so the composite's early-termination error keeps the single
device's bound. Parts are balanced by element count.
"""
from __future__ import annotations

import time

import numpy as np

from .mesh import element_boxes, subset
from .devices import expand_devices
from .kernel_loading import kernel_variant
from .render_result import RenderResult
from .renderer import Renderer

FAR = 1.0e30  # the open ends of the first and last slab (the kernel's float32 infinity stand-in)


def camera_axis(camera) -> np.ndarray:
    """The partition axis a camera asks for: its clip axis if it has one, else its forward direction."""
    axis = np.asarray(camera.clip_axis, dtype=np.float64)
    if not np.any(axis):
        axis = np.asarray(camera.d0, dtype=np.float64)
    return axis / np.linalg.norm(axis)


def serves(axis, camera) -> bool:
    """Whether slabs across `axis` compose front to back for every ray of `camera` (module doc)."""
    axis = np.asarray(axis, dtype=np.float64)
    if np.any(camera.clip_axis) and not np.allclose(np.asarray(camera.clip_axis) / np.linalg.norm(camera.clip_axis),
                                                    axis, atol=1e-12):
        return False
    if np.any(camera.ou) or np.any(camera.ov):  # orthographic: origins on a plane, which must face `axis`
        if abs(np.dot(camera.ou, axis)) > 1e-12 * np.linalg.norm(camera.ou) or \
                abs(np.dot(camera.ov, axis)) > 1e-12 * np.linalg.norm(camera.ov):
            return False
    ar = camera.width / camera.height
    corners = [camera.d0 + u * camera.du + v * camera.dv for u in (-ar, ar) for v in (-1.0, 1.0)]
    return all(np.dot(d, axis) > 1e-9 * np.linalg.norm(d) for d in corners)


def slab_partition(mesh, axis, parts: int):
    """(planes w_1 < ... < w_{parts-1} along the unit `axis`, element indices of each slab): cuts
    at quantiles of the elements' box centres (equal element counts), each slab holding every
    element whose box reaches into it."""
    axis = np.asarray(axis, dtype=np.float64)
    lo, hi = element_boxes(mesh)
    lo_a = np.where(axis > 0, lo, hi) @ axis
    hi_a = np.where(axis > 0, hi, lo) @ axis
    pad = 1e-6 * max(float(np.abs(np.concatenate([lo_a, hi_a])).max()), float((hi_a - lo_a).max()), 1e-300)
    lo_a, hi_a = lo_a - pad, hi_a + pad
    centre = 0.5 * (lo_a + hi_a)
    planes = np.quantile(centre, np.arange(1, parts) / parts)
    edges = np.concatenate([[-np.inf], planes, [np.inf]])
    elements = [np.flatnonzero((hi_a >= edges[k]) & (lo_a <= edges[k + 1])) for k in range(parts)]
    keep = [k for k, e in enumerate(elements) if e.size]  # a slab with no element adds nothing
    edges_kept = [edges[0]] + [edges[k + 1] for k in keep[:-1]] + [edges[-1]]
    return np.asarray(edges_kept[1:-1]), [elements[k] for k in keep]


def slab_cameras(camera, axis, planes):
    """One camera per slab: `camera` clipped to it along `axis` (clip planes measured from the
    camera's origin plane), each within the camera's own clip range."""
    from dataclasses import replace

    offset = float(np.dot(camera.o0, axis))
    near0 = camera.clip_near if np.any(camera.clip_axis) else -FAR
    far0 = min(camera.clip_far, FAR) if np.any(camera.clip_axis) else FAR
    cuts = [near0] + [min(max(float(w) - offset, near0), far0) for w in planes] + [far0]
    return [replace(camera, clip_axis=tuple(map(float, axis)), clip_near=cuts[k], clip_far=cuts[k + 1])
            for k in range(len(planes) + 1)]


def composite(partials, background) -> np.ndarray:
    """Front-to-back composite of partial images rendered with a black background (rgb = C_k,
    alpha = 1 - T_k), front first: RGB = sum_k (prod_{j<k} T_j) C_k + T background, alpha = 1 - T."""
    shape = partials[0].shape
    C = np.zeros(shape[:-1] + (3,), np.float64)
    T = np.ones(shape[:-1] + (1,), np.float64)
    for p in partials:
        p = p.astype(np.float64)
        C += T * p[..., :3]
        T *= 1.0 - p[..., 3:4]
    bg = np.asarray(background, dtype=np.float64).reshape(3)
    return np.concatenate([C + T * bg, 1.0 - T], axis=-1)


class SortLastRenderer:
    """Renderer.render() with the mesh's elements split over `devices` in slabs, one part a
    device; with `processes` (the default) each part lives in its own process (engine/multi_device.py),
    rendered at once, else one after the other in this process (tests; a single device). Of a
    Frame it draws the volume alone (engine/frame.py)."""

    capabilities = frozenset()
    kind = "sort-last over several devices"

    def __init__(self, mesh, devices, processes: bool = True, max_tile_rays: int | None = None):
        self.mesh = mesh
        self.kernel_variant = kernel_variant([mesh])  # every part's kernels (a part's may need fewer)
        self.devices = expand_devices(devices)
        self.device = ",".join(self.devices)
        self.processes = processes
        self.max_tile_rays = max_tile_rays
        self.axis = None
        self._parts = []
        self.upload_seconds = 0.0

    def partition(self, axis):
        """Slabs across `axis`, each part uploaded to its device (the previous parts released)."""
        self.close()
        t0 = time.perf_counter()
        self.axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
        self.planes, elements = slab_partition(self.mesh, self.axis, len(self.devices))
        meshes = [subset(self.mesh, e) for e in elements]
        self.part_elements = [len(e) for e in elements]
        ranges = Renderer.volume_ranges(self.mesh)
        if self.processes:
            from .multi_device import start_processes

            self._parts = start_processes(meshes, self.devices, self.max_tile_rays)
            for p in self._parts:  # the whole mesh's field frame on every part (equal rounding)
                p.send("data_ranges", ranges)
            for p in self._parts:
                p.reply()
        else:
            self._parts = [Renderer(m, d, max_tile_rays=self.max_tile_rays) for m, d in zip(meshes, self.devices)]
            for r in self._parts:
                r.data_ranges = ranges
        self.upload_seconds = time.perf_counter() - t0

    def render(self, camera, tf, background, options, progress=None, tile_pixels=None, profile=False) -> RenderResult:
        if self.axis is None or not serves(self.axis, camera):
            self.partition(camera_axis(camera))
        cams = slab_cameras(camera, self.axis, self.planes)
        black = np.zeros(3)
        t0 = time.perf_counter()
        if self.processes:
            for p, cam in zip(self._parts, cams):
                p.send("render", cam, tf, black, options, None, None, None)
            results = [p.reply() for p in self._parts]
        else:
            results = [r.render(cam, tf, black, options.with_(device=r.device)) for r, cam in zip(self._parts, cams)]
        rgba = composite([r.rgba for r in results], background)
        seconds = time.perf_counter() - t0
        stats = dict(results[0].stats)
        for k in ("field_evaluations", "restriction_evaluations", "segments", "curved_locates"):
            stats[k] = int(sum(r.stats[k] for r in results))
        stats.update(render_seconds=seconds, device=self.device, elements=self.mesh.num_elements,
                     sort_last=[{"device": d, "elements": n, "render_seconds": r.stats["render_seconds"]}
                                for d, n, r in zip(self.devices, self.part_elements, results)])
        if progress is not None:
            progress(1.0)
        error = np.sum([r.error for r in results], axis=0)
        return RenderResult(rgba=rgba.astype(results[0].rgba.dtype), stats=stats, error=error)

    def close(self):
        if self.processes:
            for p in self._parts:
                p.close()
        self._parts = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
