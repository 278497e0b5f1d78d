"""All four shapes on the device: expansions against the numpy oracle, traversal across shapes."""
import numpy as np
import pytest
import warp as wp

ex = pytest.importorskip("hovr_blender.engine.expansions")
if not hasattr(ex, "eval_modal"):
    pytest.skip("engine/expansions.py not implemented yet", allow_module_level=True)

from hovr_blender.engine import shapes  # noqa: E402
from hovr_blender.engine.camera import RayCamera  # noqa: E402
from hovr_blender.engine.kernels import args, restriction  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.engine.view import RenderOptions  # noqa: E402
from hovr_blender.io.synthetic import brick, mixed_cube, straight_geometry  # noqa: E402
from hovr_blender.engine.mesh import VolumeMesh  # noqa: E402

from ..helpers import UNIT_CUBE_CAM, box_chord  # noqa: E402


@wp.kernel
def _eval_points(mesh: args.MeshArgs, elem: wp.array(dtype=wp.int32), xi: wp.array(dtype=wp.vec3),
                 out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = restriction.eval_field(mesh, elem[i], xi[i])


def random_inside(shape, n, rng):
    pts = []
    while len(pts) < n:
        p = rng.uniform(-1, 1, (4 * n, 3))
        pts.extend(p[ex.inside(shape, p, tol=-1e-3)])
    return np.array(pts[:n])


@pytest.mark.parametrize("shape", [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR])
def test_kernel_expansion_matches_numpy(device, shape):
    rng = np.random.default_rng(7 + shape)
    orders = [(n, n, n) for n in range(2, 16)] + [(3, 4, 5), (2, 6, 6)]  # collapsed direction carries the top order
    ref_v = shapes.VERTICES[shape]
    geoms, coeffs = [], []
    for m in orders:
        k = ex.num_coeffs(shape, m)
        coeffs.append(rng.uniform(-1, 1, k) / np.sqrt(k))
        geoms.append(straight_geometry(shape, ref_v))  # identity map
    mesh = VolumeMesh.from_elements([shape] * len(orders), np.array(orders), coeffs, (2, 2, 2), geoms)
    r = Renderer(mesh, device)
    npts = 48
    elem = np.repeat(np.arange(len(orders), dtype=np.int32), npts)
    xi = np.concatenate([random_inside(shape, npts, rng) for _ in orders])
    out = wp.zeros(elem.size, dtype=wp.float32, device=r.device)
    wp.launch(_eval_points, dim=elem.size, device=r.device,
              inputs=[r.mesh_args(), wp.array(elem, dtype=wp.int32, device=r.device),
                      wp.array(xi.astype(np.float32), dtype=wp.vec3, device=r.device), out])
    got = out.numpy()
    for e, m in enumerate(orders):
        sel = elem == e
        want = ex.eval_modal(shape, m, coeffs[e], xi[sel].astype(np.float32).astype(np.float64))
        err = np.abs(got[sel] - want).max()
        assert err < 5e-5 * max(1.0, np.abs(want).max()), f"{shapes.NAMES[shape]} modes {m}: {err:.3g}"


@pytest.mark.parametrize("method", ["trapezoid", "split"])
def test_mixed_shapes_are_watertight(device, method):
    """Constant density over a cube cut into hexes, prisms, tets and pyramids: T = exp(-tau L)."""
    mesh = mixed_cube(3, 2, lambda x, y, z: 0 * x + 1.0)
    assert set(mesh.shape.tolist()) == {shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR}
    assert mesh.affine.all()
    tf = TransferFunction.from_contract({"color": [[0, 0.2, 0.5, 0.8], [2, 0.2, 0.5, 0.8]], "density": [[0, 1.3], [2, 1.3]]})
    cam = RayCamera.from_contract(UNIT_CUBE_CAM, 64, 48)
    res = Renderer(mesh, device).render(cam, tf, [0, 0, 0], RenderOptions(method=method, h=0.02, min_transmittance=0))
    o, d = cam.rays()
    L = box_chord(o, d, np.zeros(3), np.ones(3))
    assert (L > 0.5).sum() > 300
    np.testing.assert_allclose(1 - res.rgba[..., 3], np.exp(-1.3 * L), rtol=1e-4, atol=2e-6)


def test_mixed_shapes_render_like_hexes(device):
    """A degree-2 field on the mixed cube renders as the same field on a hex brick (all shapes,
    their corrections and the pyramid's rational restriction agree with the tensor hexes)."""
    f = lambda x, y, z: 3 * x * x + 2 * y * z - x + 1.0  # noqa: E731
    mixed = mixed_cube(3, 3, f)
    hexes = brick([0, 0, 0], [1, 1, 1], (2, 2, 2), 3, f)
    tf = TransferFunction.from_contract({"color": [[1.0, 1, 0.3, 0], [3.0, 0, 0.4, 1]],
                                         "density": [[1.2, 0], [1.6, 4], [2.0, 0], [2.5, 0], [2.8, 3], [3.1, 0]]})
    cam = RayCamera.from_contract(UNIT_CUBE_CAM, 48, 36)
    opts = RenderOptions(method="split", tolerance=1e-7)
    a = Renderer(mixed, device).render(cam, tf, [0, 0, 0], opts)
    b = Renderer(hexes, device).render(cam, tf, [0, 0, 0], opts)
    assert b.rgba[..., 3].max() > 0.3
    np.testing.assert_allclose(a.rgba, b.rgba, atol=5e-5)


def test_transformed_general_mesh_moves_geometry_and_field():
    """Object transforms on any mesh (all shapes): vertices move by the matrix and the field
    travels with the element (f'(M x) = f(x))."""
    f = lambda x, y, z: x + 2 * y - z * z  # noqa: E731
    mesh = mixed_cube(2, 3, f)
    M = np.eye(4)
    M[:3, :3] = [[0, -2.0, 0], [1.5, 0, 0], [0, 0, 0.5]]
    M[:3, 3] = [1.0, -2.0, 3.0]
    moved = mesh.transformed(M)
    np.testing.assert_allclose(moved.vertices, mesh.vertices @ M[:3, :3].T + M[:3, 3], atol=1e-12)
    assert moved.affine.all()
    for e in range(mesh.num_elements):
        x = mesh.vertices[e, :4].mean(axis=0)  # an interior point
        xi = mesh.reference_coords(e, x)
        xi2 = moved.reference_coords(e, x @ M[:3, :3].T + M[:3, 3])
        np.testing.assert_allclose(xi2, xi, atol=1e-12)


def test_mesh_evaluate_and_samples_for_every_shape():
    """VolumeMesh.evaluate and field_samples (value range, histogram) hold for all shapes."""
    f = lambda x, y, z: 1.0 + x * y - 2 * z  # noqa: E731
    mesh = mixed_cube(2, 3, f)
    rng = np.random.default_rng(5)
    for e in range(0, mesh.num_elements, 3):
        nv = {shapes.HEX: 8, shapes.PRISM: 6, shapes.TET: 4, shapes.PYR: 5}[int(mesh.shape[e])]
        w = rng.dirichlet(np.ones(nv), 4)  # convex combinations of the vertices: inside
        x = w @ mesh.vertices[e, :nv]
        np.testing.assert_allclose(mesh.evaluate(e, x), f(*x.T), atol=1e-12)
    v = mesh.field_samples(5)
    assert v.size > 5 * mesh.num_elements
    assert v.min() >= 1.0 - 2.0 - 1e-9 and v.max() <= 1.0 + 1.0 + 1e-9  # f's range on the unit cube


_STATIC_KERNELS = {}


def _static_eval_kernel(N):
    """A kernel evaluating through element.static_evaluator(N), as the sample kernel does."""
    from hovr_blender.engine.kernels import element

    if N not in _STATIC_KERNELS:
        evaluate = element.static_evaluator(N)

        @wp.kernel(enable_backward=False, module="unique", module_options={"max_unroll": N})
        def eval_static(mesh: args.MeshArgs, elem: wp.array(dtype=wp.int32), xi: wp.array(dtype=wp.vec3),
                        out: wp.array(dtype=wp.float32)):
            i = wp.tid()
            e = elem[i]
            out[i] = wp.static(evaluate)(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi[i])

        _STATIC_KERNELS[N] = eval_static
    return _STATIC_KERNELS[N]


@pytest.mark.parametrize("N", [2, 3, 7])
def test_static_evaluator_matches_numpy(device, N):
    """The unrolled evaluators (hexahedra and prisms of N modes) against the numpy oracle, in a
    mesh that also holds every shape at other modes (those take the generic path)."""
    rng = np.random.default_rng(N)
    elems = [(shapes.HEX, (N, N, N)), (shapes.PRISM, (N, N, N)), (shapes.HEX, (N + 1,) * 3), (shapes.PRISM, (3, 4, 5)),
             (shapes.TET, (N, N, N)), (shapes.PYR, (N, N, N))]
    kinds = [s for s, _ in elems]
    coeffs = [rng.uniform(-1, 1, ex.num_coeffs(s, m)) for s, m in elems]
    geoms = [straight_geometry(s, shapes.VERTICES[s]) for s in kinds]
    mesh = VolumeMesh.from_elements(kinds, np.array([m for _, m in elems]), coeffs, (2, 2, 2), geoms)
    r = Renderer(mesh, device)
    npts = 40
    elem = np.repeat(np.arange(len(elems), dtype=np.int32), npts)
    xi = np.concatenate([random_inside(s, npts, rng) for s in kinds])
    out = wp.zeros(elem.size, dtype=wp.float32, device=r.device)
    wp.launch(_static_eval_kernel(N), dim=elem.size, device=r.device,
              inputs=[r.mesh_args(), wp.array(elem, dtype=wp.int32, device=r.device),
                      wp.array(xi.astype(np.float32), dtype=wp.vec3, device=r.device), out])
    got = out.numpy()
    for e, (s, m) in enumerate(elems):
        sel = elem == e
        want = ex.eval_modal(s, m, coeffs[e], xi[sel].astype(np.float32).astype(np.float64))
        err = np.abs(got[sel] - want).max()
        assert err < 5e-5 * max(1.0, np.abs(want).max()), f"{shapes.NAMES[s]} modes {m}: {err:.3g}"


def test_static_modes_picks_one_order_or_none():
    from hovr_blender.engine.kernels.element import static_modes

    H, P, T = shapes.HEX, shapes.PRISM, shapes.TET
    assert static_modes([H, P, T], [(7, 7, 7), (7, 7, 7), (3, 3, 3)]) == 7  # tets go generic anyway
    assert static_modes([H, P], [(7, 7, 7), (6, 6, 6)]) == 0  # two orders: no single specialisation
    assert static_modes([H], [(3, 4, 5)]) == 0  # anisotropic
    assert static_modes([T, T], [(4, 4, 4), (4, 4, 4)]) == 0  # no hexahedra or prisms
    assert static_modes([H], [(16, 16, 16)]) == 0  # beyond STATIC_MODES
