"""The kernels' element evaluation against the independent numpy implementation."""
import numpy as np
import pytest
import warp as wp

from hovr_blender.engine.expansions import eval_tensor
from hovr_blender.engine.kernels import args, restriction
from hovr_blender.engine.renderer import Renderer
from hovr_blender.io.builtin import box_vertices
from hovr_blender.engine.mesh import VolumeMesh


@wp.kernel
def _eval_points(mesh: args.MeshArgs, elem: wp.array(dtype=wp.int32), xi: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = restriction.eval_field(mesh, elem[i], xi[i])


def test_modified_a_tensor_all_orders(device):
    rng = np.random.default_rng(1)
    orders = [(n, n, n) for n in range(1, 16)] + [(1, 7, 15), (15, 2, 5)]
    verts = [box_vertices([0, 0, 0], [1, 1, 1])] * len(orders)
    coeffs = [rng.uniform(-1, 1, int(np.prod(m))) / np.sqrt(np.prod(m)) for m in orders]
    mesh = VolumeMesh.from_affine_hexes(verts, np.array(orders), coeffs)
    r = Renderer(mesh, device)
    npts = 64
    elem = np.repeat(np.arange(len(orders), dtype=np.int32), npts)
    xi = rng.uniform(-1, 1, (elem.size, 3))
    out = wp.zeros(elem.size, dtype=wp.float32, device=r.device)
    wp.launch(_eval_points, dim=elem.size, device=r.device,
              inputs=[r.mesh_args(), wp.array(elem, dtype=wp.int32, device=r.device),
                      wp.array(xi.astype(np.float32), dtype=wp.vec3, device=r.device), out])
    got = out.numpy()
    worst = 0.0
    for e, m in enumerate(orders):
        sel = elem == e
        ref = eval_tensor(coeffs[e], m, xi[sel].astype(np.float32).astype(np.float64))
        err = np.abs(got[sel] - ref).max()
        worst = max(worst, err)
        assert err < 2e-5, f"modes {m}: max error {err:.3g}"
    assert worst > 0.0  # float32 kernel vs float64 numpy: the comparison is real
