"""The resample-and-trilinear baseline (bench/resample_baseline.py): grid size and memory,
grid values, an exact case for the march, and convergence to the reference as h_g shrinks.

A check of bench code, so it lives in bench/ (tests/ never import bench): the baseline the
suite times against. pytest collects it with tests/ (pyproject testpaths);
the device fixture is the repository's conftest.py."""
import math

import numpy as np
import pytest

from bench import resample_baseline as rb
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.reference import reference_render
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.io import paper_scale as ps
from hovr_blender.io.builtin import SPHERE_LOWER, SPHERE_UPPER, sphere, sphere_field

CAM = {"eye": [7.0, 5.5, 8.0], "target": [0.0, 0.0, 1.0], "up": [0, 0, 1], "fov_y_deg": 40.0}
BG = [0.02, 0.02, 0.03]


@pytest.mark.parametrize("h", [0.3, 0.25, 0.07])
def test_grid_covers_the_box_and_memory_is_four_bytes_a_point(h):
    g = rb.resample(sphere(), h)
    L = SPHERE_UPPER - SPHERE_LOWER
    want = [math.ceil(v / h - 1e-9) + 1 for v in L]
    assert list(g.values.shape) == want
    assert g.nbytes == 4 * int(np.prod(want)) == rb.grid_memory_bytes(SPHERE_LOWER, SPHERE_UPPER, h)
    assert g.values.dtype == np.float32
    assert np.all(g.upper >= SPHERE_UPPER - 1e-12) and np.all(g.upper - h < SPHERE_UPPER)
    np.testing.assert_allclose(g.lower, SPHERE_LOWER)


def test_sphere_grid_values_are_the_field():
    g = rb.resample(sphere(), 0.25)
    idx = np.indices(g.values.shape).reshape(3, -1).T
    X = g.lower + 0.25 * idx
    inside = np.all(X <= SPHERE_UPPER + 1e-9, axis=1)
    v = g.values.reshape(-1)
    assert np.all(np.isnan(v[~inside])) and np.all(np.isfinite(v[inside]))
    np.testing.assert_allclose(v[inside], sphere_field(*X[inside].T), rtol=1e-6, atol=1e-6)


def test_curved_grid_values_and_the_hole():
    """Curved mixed mesh: located by Newton, values within the data set's stated error of the
    analytic flow; the block's hole and the outside of the bent channel stay empty; one
    process or two give the same grid."""
    mesh = ps.paper_scale_mesh(n_hex=48, n_prism=96, order=4)
    src = mesh.paper_scale["source"]
    g = rb.resample(mesh, 0.25, workers=1)
    v = g.values.reshape(-1)
    X = g.lower + 0.25 * np.indices(g.values.shape).reshape(3, -1).T
    fin = np.isfinite(v)
    assert 0.3 < fin.mean() < 0.95  # the bounding box of a bent channel has empty corners
    rel = np.abs(v[fin] - src(*X[fin].T)).max() / np.ptp(src(*X[fin].T))
    assert rel < 0.15
    cx, cy = src.centre
    hole = (np.abs(X[:, 0] - cx) < 0.3) & (np.abs(X[:, 1] - cy) < 0.3) & (X[:, 2] > 0.1) & (X[:, 2] < 1.9)
    assert hole.any() and np.all(np.isnan(v[hole]))
    assert g.newton_unconverged == 0
    g2 = rb.resample(mesh, 0.25, workers=2, pair_chunk=4096)
    np.testing.assert_array_equal(g.values, g2.values)


def test_march_is_exact_where_trilinear_and_steps_are(device):
    """Constant tau and colour over the whole range: the image depends only on the chord
    through the box, which the march integrates exactly at any step."""
    cam = RayCamera.from_contract(CAM, 24, 18)
    tf = TransferFunction.from_contract({"color": [[-1, 0.8, 0.5, 0.2], [40, 0.8, 0.5, 0.2]],
                                         "density": [[-1, 0.35], [40, 0.35]]})
    mesh = sphere()
    ref, _ = reference_render(mesh, cam, tf, BG)
    img, st = rb.march(rb.resample(mesh, 0.5), cam, tf, BG, step=0.37, device=device)
    assert ref[..., 3].max() > 0.5 and ref[..., 3].min() == 0.0
    np.testing.assert_allclose(img, ref, atol=2e-5)
    assert st["samples_per_ray"] > 0


def test_baseline_converges_to_the_reference(device):
    cam = RayCamera.from_contract(CAM, 32, 24)
    tf = TransferFunction.from_contract({"color": [[1.0, 1.0, 0.9, 0.2], [16.0, 1.0, 0.2, 0.6]],
                                         "density": [[1.5, 0.0], [2.0, 2.0], [2.5, 0.0], [8.5, 0.0], [9.0, 1.0],
                                                     [9.5, 0.0]]})
    mesh = sphere()
    ref, _ = reference_render(mesh, cam, tf, BG)
    rows = rb.compare(mesh, cam, tf, BG, [0.4, 0.2, 0.1], ref, device=device, log=lambda *a: None)
    errs = [r["max_error"] for r in rows]
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 0.25 * errs[0]  # trilinear + midpoint steps: second order, 1/16 ideally
    assert errs[0] > 1e-3  # coarse grids are visibly wrong: the comparison measures something
    assert [r["grid_bytes"] for r in rows] == [rb.grid_memory_bytes(SPHERE_LOWER, SPHERE_UPPER, h) for h in (0.4, 0.2, 0.1)]


def test_skipped_when_over_budget():
    cam = RayCamera.from_contract(CAM, 8, 6)
    tf = TransferFunction.from_contract({"color": [[0, 1, 1, 1], [1, 1, 1, 1]], "density": [[0, 1], [1, 1]]})
    rows = rb.compare(sphere(), cam, tf, BG, [0.5, 0.05], np.zeros((6, 8, 4)), max_pairs=1e4, log=lambda *a: None)
    assert "skipped" not in rows[0] and "skipped" in rows[1]
    assert rows[1]["candidate_pairs"] > 1e4
