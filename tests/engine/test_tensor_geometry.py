"""The device's curved maps (engine/tensor_geometry.py): the tensor Legendre re-expression of each
curved element's map is the same polynomial over the whole reference element, at rounding, for
every shape (issue 36: a degree-8 pyramid interpolated on the box [-1, 0]^3 alone was 3e-5 of its
map off at its base corners, where the Chebyshev polynomials grow outside the box)."""
import numpy as np
import pytest

from hovr_blender.audit import scenes
from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.tensor_geometry import fit_tensor_geometry, tensor_matrix, weight


@pytest.mark.parametrize("shape", [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR])
def test_re_expression_holds_over_the_whole_element(shape):
    mesh = scenes.ball_mesh()  # curved elements of all four shapes, the pyramids of degree 8 in x w^2
    rng = np.random.default_rng(7)
    eta = rng.uniform(-1.0, 1.0, (3000, 3))
    eta[:, 2] = rng.uniform(-1.0, 0.97, 3000)  # up to near the collapsed end
    xi = ex.uncollapse(shape, eta)
    elems = np.nonzero(mesh.shape == shape)[0]
    assert elems.size
    for e in elems[:8]:
        gm = tuple(int(v) for v in mesh.geom_modes[e])
        G = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(shape, gm)]
        D, C = fit_tensor_geometry(shape, gm, G[None])
        got = (tensor_matrix(D, xi) @ C[0]) / weight(shape, xi)[:, None] ** 2
        err = np.abs(got - ex.eval_modal(shape, gm, G, xi)).max() / np.abs(G).max()
        assert err < 1e-10, f"{shapes.NAMES[shape]} element {e}: {err:.2e} of the map's size"
