"""io/synthetic: the vectorised brick is the per-element fit, bit for bit."""
import numpy as np
import pytest

from hovr_blender.engine.expansions import fit_tensor_coefficients
from hovr_blender.engine.mesh import MeshError, VolumeMesh
from hovr_blender.io.builtin import box_vertices
from hovr_blender.io.synthetic import brick


def brick_one_element_at_a_time(lower, upper, cells, modes, func):
    """The brick as it was built before it was vectorised: every element fitted on its own."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    nx, ny, nz = cells
    edges = [np.linspace(lower[k], upper[k], n + 1) for k, n in enumerate((nx, ny, nz))]
    verts, coeffs = [], []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                lo = np.array([edges[0][i], edges[1][j], edges[2][k]])
                hi = np.array([edges[0][i + 1], edges[1][j + 1], edges[2][k + 1]])
                mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
                verts.append(box_vertices(lo, hi))
                coeffs.append(fit_tensor_coefficients(
                    lambda a, b, c, mid=mid, half=half: func(mid[0] + half[0] * a, mid[1] + half[1] * b, mid[2] + half[2] * c),
                    (modes,) * 3))
    return VolumeMesh.from_affine_hexes(np.array(verts), (modes,) * 3, coeffs, source=f"synthetic:brick{nx}x{ny}x{nz}")


FIELDS = {
    "smooth": lambda x, y, z: np.sin(2 * np.pi * x) * np.cos(y) + z ** 2,
    "constant": lambda x, y, z: 0 * x + 1.0,
    "cubic": lambda x, y, z: x * y * z - 3.1 * x,
}


@pytest.mark.parametrize("field", sorted(FIELDS))
@pytest.mark.parametrize("lower,upper,cells,modes", [
    ([0, 0, 0], [1, 1, 1], (3, 3, 3), 2),
    ([0, 0, 0], [3, 2, 1], (3, 2, 1), 4),
    ([-1.3, 0.2, 5], [2.7, 0.9, 5.5], (5, 4, 7), 9),
    ([0, 0, 0], [1, 1, 1], (2, 2, 1), 15),
    ([1e4, 0, 0], [1e4 + 1e-3, 1, 1], (2, 3, 4), 3),
])
def test_brick_is_the_per_element_fit_exactly(lower, upper, cells, modes, field):
    want = brick_one_element_at_a_time(lower, upper, cells, modes, FIELDS[field])
    got = brick(lower, upper, cells, modes, FIELDS[field], chunk=7)  # several chunks
    for name in ("shape", "vertices", "ref_from_world", "modes", "basis", "coeff_offset", "coeffs"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert (got.field_name, got.source) == (want.field_name, want.source)
    assert got.geom_coeffs is None and want.geom_coeffs is None


def test_brick_refuses_an_empty_box():
    with pytest.raises(MeshError, match="must exceed lower"):
        brick([0, 0, 0], [1, 0, 1], (1, 1, 1), 2, FIELDS["constant"])
