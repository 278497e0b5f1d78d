"""Front-to-back traversal over many elements: chord lengths and watertight shared faces."""
import numpy as np
import pytest

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.builtin import SPHERE_LOWER, SPHERE_UPPER, sphere, sphere_field
from hovr_blender.io.synthetic import brick

from ..helpers import box_chord

TAU = 0.7


@pytest.mark.parametrize("method", ["riemann", "trapezoid", "classified", "split"])
def test_constant_density_chords_over_many_elements(device, method):
    # 5 x 4 x 12 elements: rays cross up to ~20 of them, more than one traversal window
    lo, hi = np.array([-1.0, -0.8, -3.0]), np.array([1.5, 1.2, 3.0])
    mesh = brick(lo, hi, (5, 4, 12), 2, lambda x, y, z: 0.0 * x + 1.0)  # exactly constant (modes 2)
    tf = TransferFunction.from_contract({"color": [[0, 0.3, 0.6, 0.9], [2, 0.3, 0.6, 0.9]],
                                         "density": [[0, TAU], [2, TAU]]})
    cam = RayCamera.from_contract({"eye": [7.0, 2.5, 9.0], "target": [0.1, 0.2, 0.0], "up": [0, 0, 1],
                                   "fov_y_deg": 40}, 48, 40)
    res = Renderer(mesh, device).render(cam, tf, [0.1, 0.1, 0.1], RenderOptions(method=method, h=0.05, min_transmittance=0.0))
    o, d = cam.rays()
    L = box_chord(o, d, lo, hi)
    T = np.exp(-TAU * L)
    assert (L > 3.0).sum() > 100  # many rays really cross long stacks of elements
    np.testing.assert_allclose(1.0 - res.rgba[..., 3], T, rtol=2e-5, atol=2e-6)
    # the optical depth of a constant field is exact for every rule; the emission integral only
    # for the Gauss-Kronrod methods (the baselines' O(h) / O(h^2) error on exp is their nature)
    atol = {"riemann": 0.02, "trapezoid": 2e-4}.get(method, 2e-6)
    np.testing.assert_allclose(res.rgba[..., 2], 0.9 * (1 - T) + 0.1 * T, rtol=2e-5, atol=atol)


def test_split_brick_equals_single_element(device):
    """The sphere cut into 3 x 3 x 6 elements renders as the single-element sphere."""
    tf = TransferFunction.from_contract({"color": [[2, 1, 0.5, 0], [9, 0, 0.5, 1]],
                                         "density": [[2, 0], [3, 2], [4, 0], [8, 0], [9, 1.5], [10, 0]]})
    cam = RayCamera.from_contract({"eye": [6, 5, 8], "target": [0, 0, 1], "up": [0, 0, 1], "fov_y_deg": 35}, 40, 30)
    opts = RenderOptions(method="split", tolerance=1e-7)
    one = Renderer(sphere(), device).render(cam, tf, [0, 0, 0], opts)
    many = Renderer(brick(SPHERE_LOWER, SPHERE_UPPER, (3, 3, 6), 3, sphere_field), device).render(cam, tf, [0, 0, 0], opts)
    assert one.rgba[..., 3].max() > 0.3
    np.testing.assert_allclose(many.rgba, one.rgba, atol=2e-5)
    assert many.stats["segments"] > 3 * one.stats["segments"]


@pytest.mark.parametrize("method", ["trapezoid", "split"])
def test_depth_pass_constant_density(device, method):
    """Depth = where 1 - T first reaches 0.5: t_in + ln 2 / tau for a constant field, else far."""
    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    mesh = brick(lo, hi, (2, 2, 2), 2, lambda x, y, z: 0.0 * x + 1.0)
    tau = 1.5
    tf = TransferFunction.from_contract({"color": [[0, 1, 1, 1], [2, 1, 1, 1]], "density": [[0, tau], [2, tau]]})
    cam = RayCamera.from_contract({"eye": [4.0, 1.0, 3.0], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": 40}, 40, 30)
    res = Renderer(mesh, device).render(cam, tf, [0, 0, 0], RenderOptions(method=method, h=0.01, min_transmittance=0))
    o, d = cam.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    t_in = np.nanmax(np.minimum(ta, tb), axis=-1)
    L = box_chord(o, d, lo, hi)
    reaches = L > np.log(2) / tau + 1e-3
    assert reaches.sum() > 100 and (~reaches).sum() > 100
    np.testing.assert_allclose(res.depth[reaches], (t_in + np.log(2) / tau)[reaches], atol=2e-4)
    assert np.all(res.depth[~reaches & (L == 0)] >= 1e29)
    assert np.all(res.error >= 0) and res.error.max() < 1e-3


def test_tiled_render_progress_and_cancel(device):
    mesh = sphere()
    tf = TransferFunction.from_contract({"color": [[2, 1, 0.5, 0], [9, 0, 0.5, 1]], "density": [[2, 0], [3, 2], [4, 0]]})
    cam = RayCamera.from_contract({"eye": [6, 5, 8], "target": [0, 0, 1], "up": [0, 0, 1], "fov_y_deg": 35}, 40, 30)
    r = Renderer(mesh, device)
    whole = r.render(cam, tf, [0, 0, 0], RenderOptions(method="split"))
    seen = []
    tiled = r.render(cam, tf, [0, 0, 0], RenderOptions(method="split"), progress=seen.append, tile_pixels=256)
    assert len(seen) == -(-40 * 30 // 256) and seen[-1] == 1.0 and not tiled.cancelled
    np.testing.assert_array_equal(tiled.rgba, whole.rgba)
    calls = []
    cancelled = r.render(cam, tf, [0, 0, 0], RenderOptions(method="split"),
                         progress=lambda f: calls.append(f) or False, tile_pixels=256)
    assert cancelled.cancelled and len(calls) == 1
    assert np.all(cancelled.rgba.reshape(-1, 4)[256:] == 0)


def test_clip_planes_along_the_view_axis(device):
    """Blender-style clip start/end along the axis: per ray t in [near/c, far/c]."""
    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    mesh = brick(lo, hi, (1, 1, 1), 2, lambda x, y, z: 0.0 * x + 1.0)
    tf = TransferFunction.from_contract({"color": [[0, 1, 1, 1], [2, 1, 1, 1]], "density": [[0, 0.8], [2, 0.8]]})
    base = {"eye": [0.0, 0.0, 5.0], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40}
    cam = RayCamera.from_contract(base, 24, 24)
    near, far = 4.5, 5.5  # planes z = 0.5 and z = -0.5
    import dataclasses

    clipped = dataclasses.replace(cam, clip_axis=(0.0, 0.0, -1.0), clip_near=near, clip_far=far)
    res = Renderer(mesh, device).render(clipped, tf, [0, 0, 0], RenderOptions(method="split", min_transmittance=0))
    o, d = cam.rays()
    c = -d[..., 2]
    t0 = np.maximum(near / c, np.nanmax(np.minimum((lo - o) / d, (hi - o) / d), axis=-1))
    t1 = np.minimum(far / c, np.nanmin(np.maximum((lo - o) / d, (hi - o) / d), axis=-1))
    L = np.clip(t1 - t0, 0, None)
    np.testing.assert_allclose(-np.log(1 - res.rgba[..., 3]), 0.8 * L, atol=1e-5)
    assert L.max() > 0.9 and L.max() < 1.2  # the slab, not the whole cube
