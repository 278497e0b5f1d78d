"""Fields far from zero (docs/methods.md, "Precision"): the float32 image depends on the field's
variation around its transfer function, not on its offset or units. The renderer maps the field
and the transfer function into one frame on the host (engine/field_frame.py), so rendering f
and a f + b (transfer function mapped the same way) must give the same image."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.field_frame import mapped
from hovr_blender.engine.mesh import concatenate
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import mixed_cube
from tests.helpers import BACKGROUND, COLORS, data_file, framing, pascals, tents

W, H = 32, 24


def polynomial(rng):
    """A random cubic in x, y, z (its monomials' coefficients uniform in [-1, 1])."""
    powers = [(i, j, k) for i in range(4) for j in range(4) for k in range(4) if i + j + k <= 3]
    c = rng.uniform(-1, 1, len(powers))
    return lambda x, y, z: sum(ci * x**i * y**j * z**k for ci, (i, j, k) in zip(c, powers))


def image(mesh, tf, camera, method, precision="float32", device="cpu"):
    opts = RenderOptions(method=method, precision=precision, min_transmittance=0.0, tolerance=1e-5)
    return Renderer(mesh, device).render(camera, tf, BACKGROUND, opts)


@settings(max_examples=12, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), log_a=st.floats(-6, 6), ratio=st.floats(-1e6, 1e6),
       method=st.sampled_from(["split", "classified"]))
def test_offset_and_units_do_not_change_the_float32_image(seed, log_a, ratio, method):
    """f and g = a f + b, b up to 1e6 times g's span, a over 1e-6..1e6: the same image to 1e-4."""
    rng = np.random.default_rng(seed)
    f = polynomial(rng)
    mesh_f = mixed_cube(2, 4, f)
    lo, hi = np.percentile(mesh_f.field_samples(4), [2, 98])
    a = 10.0**log_a
    b = ratio * a * (hi - lo)
    mesh_g = mixed_cube(2, 4, lambda x, y, z: a * f(x, y, z) + b)  # fitted on its own, in float64
    tf = tents(lo, hi, COLORS, float(rng.uniform(2, 12)))
    theta = rng.uniform(0, 2 * np.pi)
    camera = framing(mesh_f, W, H, direction=(np.cos(theta), np.sin(theta), rng.uniform(-0.7, 0.7)))
    img_f = image(mesh_f, tf, camera, method)
    img_g = image(mesh_g, mapped(tf, a, b), camera, method)
    assert img_f.rgba[..., 3].max() > 0.05  # the image shows something
    assert np.abs(img_f.rgba - img_g.rgba).max() < 1e-4
    assert img_g.stats["warnings"] == []


@pytest.mark.parametrize("method", ["split", "classified"])
def test_pressure_in_pascals_renders_in_float32_within_1e3_of_float64(method):
    mesh = mixed_cube(2, 5, pascals)
    lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
    tf = tents(lo, hi, COLORS, 8.0)
    camera = framing(mesh, W, H)
    img32 = image(mesh, tf, camera, method)
    img64 = image(mesh, tf, camera, method, "float64")
    assert img64.rgba[..., 3].max() > 0.05
    assert np.abs(img32.rgba - img64.rgba).max() < 1e-3
    assert img32.stats["warnings"] == []


def test_float32_that_cannot_resolve_the_transfer_function_warns():
    """A field steep across a band a millionth of its own size: float32 cannot resolve it even in
    the band's frame; the render says so and names float64 (float64 does not warn)."""
    mesh = mixed_cube(2, 3, lambda x, y, z: 1e6 * x)
    tf = tents(5e5, 5e5 + 1e-3, COLORS, 4.0)
    camera = framing(mesh, 8, 6)
    warnings = image(mesh, tf, camera, "split").stats["warnings"]
    assert len(warnings) == 1 and "float64" in warnings[0]
    assert image(mesh, tf, camera, "split", "float64").stats["warnings"] == []


def test_two_volumes_render_through_their_own_transfer_functions():
    """Two cubes side by side, one in pascals and one near zero, merged into one mesh and
    rendered in one pass each through its own transfer function: every pixel equals the render
    of the cube it sees, alone (the cubes do not overlap on screen from the front)."""
    left = mixed_cube(2, 4, pascals, lower=(0.0, 0.0, 0.0))
    right = mixed_cube(2, 4, lambda x, y, z: np.sin(4 * x) * y, lower=(1.5, 0.0, 0.0))
    tfs = []
    for m in (left, right):
        lo, hi = np.percentile(m.field_samples(4), [2, 98])
        tfs.append(tents(lo, hi, COLORS, 8.0))
    both = concatenate([left, right])
    camera = RayCamera.from_contract({"eye": [1.25, -6.0, 0.5], "target": [1.25, 0.5, 0.5], "up": [0, 0, 1],
                                      "fov_y_deg": 30}, 48, 24)
    merged = image(both, tfs, camera, "split")
    alone = [image(m, tf, camera, "split").rgba for m, tf in zip((left, right), tfs)]
    o, d = camera.rays()
    hits_left = (o + d * (-o[..., 1:2] / d[..., 1:2]))[..., 0] < 1.25  # where each ray meets y = 0
    expect = np.where(hits_left[..., None], alone[0], alone[1])
    assert min(a[..., 3].max() for a in alone) > 0.05
    assert np.abs(merged.rgba - expect).max() < 1e-4
    with pytest.raises(Exception, match="2 volumes"):
        Renderer(both, "cpu").render(camera, tfs[0], BACKGROUND, RenderOptions())


@pytest.mark.slow
@pytest.mark.parametrize("method", ["split", "classified"])
def test_pyfr_pressure_float32_within_1e3_of_float64(method):
    """PyFR's Taylor-Green pressure (values 71.05 to 72.01: an offset 70 times its variation),
    three tents over its range: float32 against float64 (issue 20's case, at 96x54 on the CPU)."""
    from hovr_blender.io.vtu import read_vtu

    mesh = read_vtu(data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu"), "Pressure")
    lo, hi = np.percentile(mesh.field_samples(3), [0, 100])
    tf = tents(lo, hi, COLORS, 4.0)
    camera = framing(mesh, 96, 54)
    img32 = image(mesh, tf, camera, method)
    img64 = image(mesh, tf, camera, method, "float64")
    assert np.abs(img32.rgba - img64.rgba).max() < 1e-3
