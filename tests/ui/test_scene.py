"""The bpy-free steps of the Blender render path (that they and the core import without bpy:
test_layers.py)."""
import dataclasses

import numpy as np
import pytest

from hovr_blender.ui.scene import combined_pass, render_background, transfer_function_from_ramp
from hovr_blender.io.sources import SourceError, VolumeSource, frame_path, load_volume
from hovr_blender.engine.transfer_function import TransferFunctionError
from hovr_blender.io import builtin
from hovr_blender.io.vtu.format import read_vtu_field
from tests.helpers import data_file as shared_file

from ..io.test_magnitude import kinked  # noqa: F401  (a fixture)

POS = [0.0, 0.25, 1.0]
RGBA = [(0.0, 0.0, 0.0, 0.0), (1.0, 0.5, 0.25, 1.0), (0.0, 1.0, 0.0, 0.5)]


def test_ramp_maps_positions_onto_value_range():
    tf = transfer_function_from_ramp("LINEAR", "RGB", POS, RGBA, 4.0, -2.0, 6.0)
    np.testing.assert_allclose(tf.color_s, [-2.0, 0.0, 6.0])
    np.testing.assert_allclose(tf.color([0.0, 6.0, 100.0]), [[1.0, 0.5, 0.25], [0, 1, 0], [0, 1, 0]])
    np.testing.assert_allclose(tf.density([-5.0, 0.0, 3.0]), [0.0, 4.0, 4.0 * 0.75])


@pytest.mark.parametrize("interp,mode,match", [
    ("EASE", "RGB", "Linear"), ("CONSTANT", "RGB", "Linear"), ("B_SPLINE", "RGB", "Linear"),
    ("LINEAR", "HSV", "RGB"),
])
def test_ramp_refuses_other_interpolations(interp, mode, match):
    with pytest.raises(TransferFunctionError, match=match):
        transfer_function_from_ramp(interp, mode, POS, RGBA, 1.0, 0.0, 1.0)


@pytest.mark.parametrize("vmin,vmax,scale", [(1.0, 1.0, 1.0), (2.0, 1.0, 1.0), (0.0, float("nan"), 1.0), (0.0, 1.0, -1.0)])
def test_ramp_refuses_bad_range_or_scale(vmin, vmax, scale):
    with pytest.raises(TransferFunctionError):
        transfer_function_from_ramp("LINEAR", "RGB", POS, RGBA, scale, vmin, vmax)


def test_combined_pass_flips_rows_and_sets_alpha():
    rng = np.random.default_rng(1)
    img = rng.random((3, 5, 4)).astype(np.float32)  # core image, row 0 at the top
    opaque = combined_pass(img, film_transparent=False).reshape(3, 5, 4)
    assert opaque.dtype == np.float32 and opaque.flags.c_contiguous
    np.testing.assert_array_equal(opaque[..., :3], img[::-1, :, :3])  # Blender: row 0 at the bottom
    np.testing.assert_array_equal(opaque[..., 3], 1.0)
    clear = combined_pass(img, film_transparent=True).reshape(3, 5, 4)
    np.testing.assert_array_equal(clear, img[::-1])
    np.testing.assert_array_equal(img, img.copy())  # input untouched


def test_background():
    np.testing.assert_array_equal(render_background((0.1, 0.2, 0.3), False), [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(render_background((0.1, 0.2, 0.3), True), [0, 0, 0])
    np.testing.assert_array_equal(render_background(None, False), [0, 0, 0])


def test_volume_sources():
    mesh = load_volume(VolumeSource.resolve("builtin:sphere"))
    np.testing.assert_array_equal(mesh.vertices, builtin.sphere().vertices)
    with pytest.raises(SourceError, match="unknown built-in"):
        load_volume(VolumeSource.resolve("builtin:teapot"))
    with pytest.raises(SourceError, match="unsupported"):
        load_volume(VolumeSource.resolve("/data/flow.cgns"))  # .vtu became a supported source with the VTU reader
    with pytest.raises(SourceError, match="not found: /nonexistent/flow.vtu"):
        load_volume(VolumeSource.resolve("/nonexistent/flow.vtu"))


# --- numbered series, passes, presets, histogram ------------------------------------------

from hovr_blender.engine.looks import TF_PRESETS, field_samples  # noqa: E402
from hovr_blender.ui.scene import depth_pass, flip_rows, value_histogram  # noqa: E402
from hovr_blender.engine.camera import RayCamera  # noqa: E402


@pytest.mark.parametrize("path,frame,want", [
    ("flow_####.vtu", 12, "flow_0012.vtu"), ("a#/b_##.fld", 7, "a#/b_07.fld"), ("x.fld", 5, "x.fld"),
    ("f_#.fld", 123, "f_123.fld"), ("f_###.fld", -4, "f_-004.fld"), ("", 3, ""),
])
def test_frame_path(path, frame, want):
    assert frame_path(path, frame) == want


def test_volume_source_key_follows_the_frames_file(tmp_path):
    for n in (1, 2):
        (tmp_path / f"s_{n:03d}.fld").write_text(f"frame {n}")
    (tmp_path / "m.xml").write_text("mesh")
    rel = lambda p: str(tmp_path / p[2:]) if p.startswith("//") else p  # Blender's '//' = the .blend's folder
    a1 = VolumeSource.resolve("//m.xml", "//s_###.fld", "p", 1, abspath=rel)
    a1b = VolumeSource.resolve("//m.xml", "//s_###.fld", "p", 1, abspath=rel)
    a2 = VolumeSource.resolve("//m.xml", "//s_###.fld", "p", 2, abspath=rel)
    assert a1.path == str(tmp_path / "m.xml") and a1.solution == str(tmp_path / "s_001.fld")
    assert a1.key == a1b.key and a1.key != a2.key  # same file: no re-read; next frame: re-read
    (tmp_path / "s_001.fld").write_text("frame 1, rewritten")
    assert VolumeSource.resolve("//m.xml", "//s_###.fld", "p", 1, abspath=rel).key != a1.key  # edited file
    assert VolumeSource.resolve("builtin:sphere", "x", "y", 9).key == ("builtin:sphere", "", "", ())
    with pytest.raises(SourceError, match="no data"):
        VolumeSource.resolve("  ", "", "", 1)


def test_depth_pass_converts_t_to_view_depth_and_far_where_opacity_stays_below_half():
    from hovr_blender.engine.camera_matrices import clipped

    cam = clipped(RayCamera.from_contract({"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0],
                                           "fov_y_deg": 60}, 4, 3, ), 0.1, 20.0)
    t = np.full((3, 4), 4.0)
    alpha = np.array([[0.9] * 4, [0.5, 0.49, 0.0, 1.0], [0.7] * 4])
    z = depth_pass(cam, t, alpha).reshape(3, 4)[::-1]  # back to rows from the top
    _, d = cam.rays()
    want = np.where(alpha >= 0.5, 4.0 * -d[..., 2], 20.0)
    np.testing.assert_allclose(z, want, atol=1e-6)
    assert np.all(z[alpha >= 0.5] < 4.0)  # off-axis: the view-axis distance is shorter than t
    np.testing.assert_array_equal(flip_rows(np.arange(6.0).reshape(2, 3)), [3, 4, 5, 0, 1, 2])


def test_presets_are_valid_linear_ramps():
    for key, (label, desc, stops) in TF_PRESETS.items():
        pos = [p for p, _ in stops]
        assert label and desc and pos == sorted(pos) and 0.0 <= pos[0] and pos[-1] <= 1.0, key
        tf = transfer_function_from_ramp("LINEAR", "RGB", pos, [c for _, c in stops], 1.0, 0.0, 1.0)
        assert tf.density_tau.max() > 0 and np.all(tf.density_tau >= 0)


def test_field_samples_and_histogram_on_the_sphere():
    mesh = builtin.sphere()
    values = field_samples(mesh, 9)
    corners = mesh.vertices[0]
    assert values.max() == pytest.approx(builtin.sphere_field(*corners.T).max())
    assert 0.0 <= values.min() < 0.5
    hist = value_histogram(values, values.min(), values.max(), 16)
    assert hist.shape == (16,) and hist.sum() == pytest.approx(1.0) and np.all(hist >= 0)
    half = value_histogram(values, values.min(), np.median(values), 4)
    assert half.sum() == pytest.approx(0.5, abs=0.05)  # values above the range are not counted
    assert np.all(value_histogram([], 0.0, 1.0, 5) == 0)


def test_value_range_of_a_field_constant_up_to_rounding():
    """Issue 30: round-off is not shown as structure, and a constant field gets a usable range."""
    from hovr_blender.engine.looks import value_range

    rng = np.random.default_rng(0)
    # Tet_channel_m3's u: zero up to +-1.7e-16
    lo, hi, warning = value_range(rng.uniform(-1.7e-16, 1.5e-16, 500))
    assert (lo, hi) == (-1.0, 1.0) and "zero up to rounding" in warning and "1.7e-16" in warning
    assert value_range(np.zeros(10))[:2] == (-1.0, 1.0)
    # wss_3D_periodic's rho: 0.0247601 everywhere, up to 1e-16
    lo, hi, warning = value_range(0.0247601 + rng.uniform(0, 1.1e-16, 500))
    assert lo < 0.0247601 < hi and np.isclose(0.5 * (lo + hi), 0.0247601) and np.float32(hi) > np.float32(lo)
    assert "constant up to rounding" in warning and "0.0247601 everywhere" in warning
    lo, hi, warning = value_range(np.full(7, -3.0))
    assert (lo, hi) == (-4.5, -1.5) and warning.startswith("the field is constant: -3 everywhere")
    # real variation keeps its exact range; one float32 cannot tell apart is widened by an ulp
    assert value_range(np.array([0.5, 2.0, 1.0])) == (0.5, 2.0, None)
    lo, hi, warning = value_range(np.array([1.0, 1.0 + 1e-9]))
    assert warning is None and np.float32(hi) > np.float32(lo) and hi - lo < 1e-6


# --- looks chosen from the data (issue 30) ------------------------------------------------

from hypothesis import given, settings, strategies as st  # noqa: E402

from hovr_blender.engine.looks import (  # noqa: E402
    FIRST_LOOK, FIRST_LOOKS, LOOK_MIN_GAP, SHELL_SHARE, look_quantile_tents, quantiles, ramp_positions, value_range,
)


def _peaks(stops):
    """(position, alpha, the tent's support) of each tent's peak, in ramp order."""
    pos = np.array([p for p, _ in stops])
    alpha = np.concatenate([[0.0], [c[3] for _, c in stops], [0.0]])
    return [(pos[k], alpha[k + 1], (pos[max(k - 1, 0)], pos[min(k + 1, len(pos) - 1)]))
            for k in range(len(pos)) if alpha[k + 1] > 0 and alpha[k + 1] >= alpha[k] and alpha[k + 1] >= alpha[k + 2]]


def test_quantile_tents_peak_at_the_fields_quantiles():
    """Values bunched low (x^1.5 of a uniform x): the 10/50/90 % shells sit where the values are
    (ramp 0.03, 0.35, 0.85), not at a fixed 20/50/80 % of the range; each holds about 6 % of the
    values (a shell holding more fades in proportion); the ramp's stops stay LOOK_MIN_GAP apart,
    so float32 resolves them."""
    values = np.linspace(0.0, 1.0, 10001) ** 1.5
    lo, hi, _ = value_range(values)
    stops, density = look_quantile_tents(values, lo, hi)
    peaks = _peaks(stops)
    np.testing.assert_allclose([p for p, _, _ in peaks], np.quantile(values, [0.1, 0.5, 0.9]), atol=1e-9)
    for (_, alpha, (a, b)), base in zip(peaks, (0.5, 0.5, 1.0)):
        share = ((values >= a) & (values <= b)).mean()
        assert alpha == pytest.approx(base * min(1.0, 2 * SHELL_SHARE / share)) and share < 0.2
    assert density > 4.0  # thin shells: denser than a fog
    pos = np.array([p for p, _ in stops])
    assert np.diff(pos).min() >= LOOK_MIN_GAP and pos[0] == 0.0 and pos[-1] == 1.0


def test_quantile_tents_are_quantiles_over_the_volume():
    """Issue 40, hump3D: fine elements near a wall outnumber the rest, so the samples' quantiles
    crowd the wall; weighted by the volume each sample stands for, the shells spread over the
    domain. A plateau of nearly equal values (a free stream over a tenth of the volume) makes its
    shell faint instead of a fog that hides the others."""
    rng = np.random.default_rng(3)
    z = np.concatenate([rng.uniform(0.0, 0.1, 9000), rng.uniform(0.1, 1.0, 1000)])  # 90 % of samples near z=0
    w = np.concatenate([np.full(9000, 0.1 / 9000), np.full(1000, 0.9 / 1000)])  # each stands for its volume
    values = np.minimum(z, 0.8)  # a plateau: the top fifth of the volume holds the same value
    lo, hi, _ = value_range(values)
    plain = [p for p, _, _ in _peaks(look_quantile_tents(values, lo, hi)[0])]
    weighted = _peaks(look_quantile_tents(values, lo, hi, w)[0])
    assert plain[1] < 0.1 and weighted[1][0] == pytest.approx(0.5 / 0.8, abs=0.03)  # the median: z 0.05 vs 0.5
    assert weighted[2][0] == pytest.approx(1.0) and weighted[2][1] < 0.5  # the plateau's shell fades
    assert quantiles(values, [0.5], w)[0] == pytest.approx(0.5, abs=0.02)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=2, max_size=200), st.sampled_from(sorted(FIRST_LOOKS)))
def test_every_first_look_is_a_valid_ramp_for_any_field(values, look):
    values = np.asarray(values)
    if not np.ptp(values) > 1e-9 * max(1.0, np.abs(values).max()):
        return  # a constant field keeps the smooth ramp (the import's rule)
    lo, hi, _ = value_range(values)
    stops, density = FIRST_LOOKS[look][2](values, lo, hi)
    pos = [p for p, _ in stops]
    assert pos[0] == 0.0 and pos[-1] == 1.0 and len(stops) <= 32  # a Blender ramp
    assert np.diff(pos).min() >= LOOK_MIN_GAP - 1e-12  # no feature float32 cannot resolve
    assert all(0.0 <= v <= 1.0 for _, c in stops for v in c) and density > 0
    tf = transfer_function_from_ramp("LINEAR", "RGB", pos, [c for _, c in stops], density, lo, hi)
    assert tf.density_tau.max() > 0


def test_the_import_look_is_one_of_the_first_looks_and_today_stays_a_preset():
    assert FIRST_LOOK in FIRST_LOOKS and "SMOOTH" in TF_PRESETS
    np.testing.assert_allclose(ramp_positions([0, 1, 2, 3, 4], 0.0, 8.0, [0.5]), [0.25])


def test_value_range_comes_from_the_true_magnitudes(kinked):
    """Issue 30: what Fit Value Range and the histogram read (engine/looks.field_samples) lies within
    the range of the exact magnitudes sampled while fitting, never at the fit's own dips."""
    from hovr_blender.engine.looks import field_samples

    _, mag = kinked
    true_min, true_max = mag.true_range
    assert 0 <= true_min == mag.derived_error["true_min"] < 0.05 and true_max >= mag.derived_error["max_value"]
    fitted = mag.field_samples(9)
    narrowed = dataclasses.replace(mag)
    narrowed.true_range = (float(np.percentile(fitted, 10)), float(np.percentile(fitted, 90)))
    samples = field_samples(narrowed, 9)
    assert samples.min() == narrowed.true_range[0] and samples.max() == narrowed.true_range[1]
    np.testing.assert_array_equal(field_samples(mag, 9), np.clip(fitted, true_min, true_max))


@pytest.mark.slow
def test_pyfr_velocity_magnitude_has_no_negative_value_min():
    """Issue 30's PyFR |Velocity|: the fit dips below zero near the velocity's zeros (Value Min
    was -0.0058); the range now comes from the true magnitudes, and the report says where the
    fit's error is."""
    from hovr_blender.engine.looks import field_samples, value_range

    mag = read_vtu_field(shared_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu"), "Velocity")
    assert mag.field_samples(9).min() < 0  # the fit's dip
    lo, hi, warning = value_range(field_samples(mag))
    assert 0 <= lo < 0.01 and hi > 1.0 and warning is None
    assert "the fit dips to" in mag.warnings[-1] and "the value range comes from the true magnitudes" in mag.warnings[-1]
