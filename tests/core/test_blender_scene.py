"""The bpy-free steps of the Blender render path, and that the core never imports bpy."""
import subprocess
import sys

import numpy as np
import pytest

from hovr_blender.engine.blender_scene import (
    SourceError, combined_pass, load_volume_source, render_background, transfer_function_from_ramp,
)
from hovr_blender.engine.transfer_function import TransferFunctionError
from hovr_blender.io import builtin

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
    mesh = load_volume_source("builtin:sphere")
    np.testing.assert_array_equal(mesh.vertices, builtin.sphere().vertices)
    with pytest.raises(SourceError, match="unknown built-in"):
        load_volume_source("builtin:teapot")
    with pytest.raises(SourceError, match="unsupported"):
        load_volume_source("/data/flow.vtu")


def test_core_and_addon_package_import_without_bpy():
    code = (
        "import sys, hovr_blender, hovr_blender.engine.blender_camera, hovr_blender.engine.blender_scene, "
        "hovr_blender.engine.renderer, hovr_blender.io.builtin, hovr_blender.ui; "
        "assert 'bpy' not in sys.modules, 'bpy imported'; "
        "assert callable(hovr_blender.register) and hovr_blender.bl_info['name'] == 'HOVR'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
