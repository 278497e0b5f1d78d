"""Stress tests through the Renderer: large coordinate offsets, tiny and flat elements, order-14
fields, grazing rays along faces and edges and through vertices (collapsed ones included), and
the float32 evaluation of every shape against the float64 oracle (tests/helpers.eval_compare, whose
full table is bench/eval_table.py).

Every image is small (at most 24 x 16 pixels; the one non-affine case 7 x 7) and is checked for
finite pixels and against an independent answer: the float64 reference (engine/reference.py,
hexahedra) or, for constant density, T = exp(-tau L) with the chord L computed here from the
element vertices (half-spaces from vertex triplets, no engine code).
"""
import itertools

import numpy as np
import pytest
from numpy.polynomial import chebyshev

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import VolumeMesh
from hovr_blender.engine.reference import reference_render
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import brick, mixed_cube, straight_geometry, with_field

from ..helpers import EVAL_FAMILIES, device_eval, eval_compare, jittered_trilinear_brick, sample_points

EPS32 = float(np.finfo(np.float32).eps)
TAU = 1.3


def constant_tf(tau=TAU):
    return TransferFunction.from_contract({"color": [[-9, 0.2, 0.5, 0.8], [9, 0.2, 0.5, 0.8]],
                                           "density": [[-9, tau], [9, tau]]})


def spiky_tf(scale=1.0):
    """Breakpoints throughout [-1, 1] (split cuts every segment many times); densities per
    world unit divided by `scale` so that tau L stays ~1 whatever the element size."""
    return TransferFunction.from_contract({
        "color": [[-1, 1.0, 0.2, 0.1], [-0.2, 0.2, 1.0, 0.3], [0.5, 0.1, 0.3, 1.0], [1, 0.9, 0.9, 0.2]],
        "density": [[-1, 0.0], [-0.6, 2.0 / scale], [-0.1, 0.3 / scale], [0.3, 3.0 / scale], [0.7, 0.2 / scale],
                    [1.0, 1.0 / scale]]})


def split_opts(**kw):
    return RenderOptions(method="split", tolerance=1e-7, min_transmittance=0.0, **kw)


# ------------------------------------------------------------------- independent chords


def halfspaces(V):
    """(normals (F, 3), offsets (F,)) of the convex hull of the vertices V (n . x <= c inside):
    every plane through three vertices with all vertices on one side."""
    V = np.unique(np.asarray(V, dtype=np.float64), axis=0)
    scale = np.abs(V - V.mean(axis=0)).max()
    N, c = [], []
    for i, j, k in itertools.combinations(range(len(V)), 3):
        n = np.cross(V[j] - V[i], V[k] - V[i])
        if np.linalg.norm(n) <= 1e-12 * scale**2:
            continue
        n = n / np.linalg.norm(n)
        s = (V - V[i]) @ n
        tol = 1e-10 * scale
        if np.all(s <= tol):
            N.append(n), c.append(n @ V[i])
        elif np.all(s >= -tol):
            N.append(-n), c.append(-n @ V[i])
    return np.array(N), np.array(c)


def convex_chord(V, o, d):
    """Length of {t >= 0: o + t d inside hull(V)} for rays o, d (..., 3), float64."""
    N, c = halfspaces(V)
    o = np.asarray(o, np.float64)[..., None, :]
    d = np.asarray(d, np.float64)[..., None, :]
    num = c - (o * N).sum(-1)
    den = (d * N).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    enter = np.where(den < 0, t, -np.inf).max(-1)
    leave = np.where(den > 0, t, np.inf).min(-1)
    blocked = ((den == 0) & (num < 0)).any(-1)
    L = np.clip(leave - np.maximum(enter, 0.0), 0.0, None)
    return np.where(blocked, 0.0, L)


UNIT_CUBE = 0.5 * (shapes.VERTICES[shapes.HEX] + 1.0)


def mesh_chord(mesh, o, d):
    """Sum of the elements' chords: only for rays that do not run inside a shared face (there
    every element holding the face would count it)."""
    nv = np.array([8, 6, 4, 5])[mesh.shape]
    return sum(convex_chord(mesh.vertices[e, :nv[e]], o, d) for e in range(mesh.num_elements))


def assert_transmittance(res, L, tau=TAU, rtol=1e-4):
    assert np.all(np.isfinite(res.rgba))
    T = 1.0 - res.rgba[..., 3].astype(np.float64)
    want = np.exp(-tau * L)
    rel = np.abs(T - want) / want
    assert rel.max() <= rtol, f"max relative error of T {rel.max():.3g} at pixel {np.unravel_index(rel.argmax(), rel.shape)}"


# ----------------------------------------------------- float32 evaluation vs the oracle


@pytest.mark.parametrize("family,shapes,max_order", [
    ("modified", EVAL_FAMILIES["modified"], 14),
    ("gll_lagrange", EVAL_FAMILIES["gll_lagrange"], 14),
    # VTK hexes/prisms of degree > 8 need a large float64 pseudo-inverse for the conversion
    # (38 s for degree 14); bench/eval_table.py runs them all
    ("vtk_lagrange", [shapes.TET], 14),
    ("vtk_lagrange", [shapes.HEX, shapes.PRISM], 8),
])
def test_float32_expansions_match_oracle_cpu(family, shapes, max_order):
    """The comparison of bench/eval_table.py (tests/helpers.eval_compare) on the CPU with fewer
    points: inside every element (uniform points and the vertices) the float32 kernel is within
    1e-4 of the field's range of the float64 oracle at every order (measured: <= 2.1e-6,
    bench/results/eval_table.json)."""
    worst = []
    for shape in shapes:
        for order in range(1, max_order + 1):
            r = eval_compare(family, shape, order, "cpu", points=300, trials=1, seed=1)
            assert r["nonfinite"] == 0, r
            worst.append((r["max_rel"], r["shape"], order))
    assert max(worst)[0] < 1e-4, f"{family}: worst {max(worst)}"


@pytest.mark.parametrize("order", [4, 14])
@pytest.mark.parametrize("shape", [shapes.PRISM, shapes.TET, shapes.PYR])
def test_float32_expansion_one_ulp_off_the_collapse(shape, order):
    """Points one float32 ulp in xi0 off the collapsed vertex / edge, as the render kernel's
    clipped entry points land for rays through them, against the oracle at the collapsed point
    itself (the field is continuous there: grad * 1e-7 apart). Regression: collapse_ratio once
    let eta reach ~1e5 here (tet order 4: 1.7e-3 of the range; order >= 9: NaN)."""
    rng = np.random.default_rng(order)
    modes = (order + 1,) * 3
    c = rng.uniform(-1, 1, ex.num_coeffs(shape, modes))
    s = np.linspace(-0.9, 0.9, 7)
    if shape == shapes.PRISM:  # the collapsed edge xi0 = -1, xi2 = 1 (any xi1)
        on = np.stack([-np.ones_like(s), s, np.ones_like(s)], axis=1)
    elif shape == shapes.TET:  # the collapsed edge of the first collapse: xi0 = -1, xi1 = -xi2
        on = np.stack([-np.ones_like(s), -s, s], axis=1)
    else:  # the apex
        on = np.array([[-1.0, -1.0, 1.0]])
    off = on.astype(np.float32)
    off[:, 0] = np.nextafter(np.float32(-1.0), np.float32(0.0))
    got = device_eval(shape, modes, c.astype(np.float32), off, "cpu")
    want = ex.eval_modal(shape, modes, c.astype(np.float32).astype(np.float64), on)
    pts = sample_points(shape, 2000, rng)[0]
    f = ex.eval_modal(shape, modes, c, pts)
    span = f.max() - f.min()
    assert np.all(np.isfinite(got)), f"non-finite at {off[~np.isfinite(got)].tolist()}"
    assert np.abs(got - want).max() <= 1e-4 * span, f"error {np.abs(got - want).max() / span:.3g} of the range"


# --------------------------------------------------- offsets, tiny elements, order 14


def cheb14(lo, hi):
    """A degree-14 field on the box [lo, hi]: T14(x') + T13(y') + z'^14 over 3, x' in [-1, 1]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)

    def f(x, y, z):
        u = [2.0 * (v - a) / (b - a) - 1.0 for v, a, b in zip((x, y, z), lo, hi)]
        return (chebyshev.chebval(u[0], [0] * 14 + [1]) + chebyshev.chebval(u[1], [0] * 13 + [1]) + u[2] ** 14) / 3.0

    return f


@pytest.mark.parametrize("offset,size", [(0.0, 1.0), (1e5, 1.0), (0.0, 1e-6), (1.0, 1e-6)])
def test_order14_offset_and_tiny_bricks_against_reference(device, offset, size):
    """Order-14 hexahedra (2 x 2 x 1) far from the origin and/or tiny, against the float64
    reference. float64 kernels: 1e-6 in every case. float32: a world position carries
    eps32 * |x| of rounding, so the stated budget is max(1e-5, 20 eps32 |offset| / size)
    (measured: 1.8e-6 at the origin, 8.4e-2 at 1e5 with unit elements, 0.37 for 1e-6
    elements at 1.0: float32 cannot locate them; the host could rebase coordinates)."""
    lo = np.full(3, offset)
    hi = lo + size * np.array([2.0, 1.5, 1.0])
    mesh = brick(lo, hi, (2, 2, 1), 15, cheb14(lo, hi))
    tf = spiky_tf(size)
    cam = RayCamera.from_contract({"eye": (lo + size * np.array([4.0, 3.2, 2.5])).tolist(),
                                   "target": (lo + size * np.array([1.0, 0.75, 0.5])).tolist(),
                                   "up": [0, 0, 1], "fov_y_deg": 40}, 24, 16)
    ref, info = reference_render(mesh, cam, tf)
    assert info["error_estimate"] < 1e-9 and ref[..., 3].max() > 0.5
    r = Renderer(mesh, device)
    res64 = r.render(cam, tf, [0, 0, 0], split_opts(precision="float64"))
    assert np.abs(res64.rgba - ref).max() <= 1e-6
    res32 = r.render(cam, tf, [0, 0, 0], split_opts())
    assert np.all(np.isfinite(res32.rgba))
    budget = max(1e-5, 20 * EPS32 * offset / size)
    assert np.abs(res32.rgba - ref).max() <= budget


# ------------------------------------------------------------ grazing rays, vertices


def grid_field(x, y, z):
    """Degree 8 (exact in every shape with 9 modes), values in about [-0.5, 1.3]."""
    return 0.5 * (2 * x - 1) ** 8 + 0.4 * (2 * y - 1) ** 3 * (2 * z - 1) ** 4 + 0.2 * z + 0.3


GRID_TF = TransferFunction.from_contract({"color": [[0, 1, 0.2, 0.1], [0.5, 0.2, 1, 0.3], [1, 0.1, 0.3, 1]],
                                          "density": [[0, 0.5], [0.3, 2.0], [0.5, 0.3], [0.7, 3.0], [1.0, 0.5]]})


def grazing_cameras(n):
    """Cameras over the unit cube cut n times per axis: orthographic along x, pixel spacing
    1/(4n), so rays run along every grid line and in every grid plane inside the cube (none on
    its surface); orthographic along (1, 1, 0), rays in the planes x - y = k/(4n), every other
    one grazing the vertical grid edges; perspective with its centre ray on the cube's
    diagonal, through every diagonal grid vertex (and the pyramids' apex of mixed_cube)."""
    s = 1.0 / (4 * n)
    W = 4 * n - 1
    s2 = s / np.sqrt(2.0)  # along (1, -1, 0)/sqrt2 a step s2 changes x - y by s
    return {
        "along_x": RayCamera.from_contract({"projection": "orthographic", "eye": [-1.0, 0.5, 0.5], "target": [0, 0.5, 0.5],
                                            "up": [0, 0, 1], "height": W * s}, W, W),
        "along_xy": RayCamera.from_contract({"projection": "orthographic", "eye": [-0.5, -0.5, 0.5],
                                             "target": [0.5, 0.5, 0.5], "up": [0, 0, 1], "height": 5 * s2}, 8 * n - 1, 5),
        "diagonal": RayCamera.from_contract({"eye": [-0.5, -0.5, -0.5], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1],
                                             "fov_y_deg": 50}, 9, 9),
    }


@pytest.mark.parametrize("camera", ["along_x", "along_xy", "diagonal"])
def test_grazing_rays_hex_brick(device, camera):
    """A 3 x 3 x 3 brick: constant density along grid lines and faces gives exp(-tau L), and an
    order-8 field matches the float64 reference, on rays along shared faces and edges and
    through shared vertices."""
    cam = grazing_cameras(3)[camera]
    o, d = cam.rays()
    const = brick([0, 0, 0], [1, 1, 1], (3, 3, 3), 2, lambda x, y, z: 0 * x + 1.0)
    assert_transmittance(Renderer(const, device).render(cam, constant_tf(), [0, 0, 0], split_opts()),
                         convex_chord(UNIT_CUBE, o, d))
    mesh = brick([0, 0, 0], [1, 1, 1], (3, 3, 3), 9, grid_field)
    ref, _ = reference_render(mesh, cam, GRID_TF)
    assert ref[..., 3].max() > 0.5
    res = Renderer(mesh, device).render(cam, GRID_TF, [0, 0, 0], split_opts())
    assert np.all(np.isfinite(res.rgba))
    assert np.abs(res.rgba - ref).max() <= 5e-6


@pytest.mark.parametrize("camera", ["along_x", "along_xy", "diagonal"])
def test_grazing_rays_mixed_cube(device, camera):
    """mixed_cube(2): hexes, prisms, tets and pyramids sharing faces; the diagonal's centre ray
    runs along the tets' shared edges and through the pyramids' apex. Constant density:
    exp(-tau L); an order-8 field against the float64 reference of the same field on hexes.
    Budget 1e-5 (measured <= 2.5e-6; 7.6e-5 on the pixels through the apex before pyramid
    segments were cut near it, see test_pyramid_apex_rays_float32_restriction)."""
    cam = grazing_cameras(2)[camera]
    o, d = cam.rays()
    const = mixed_cube(2, 2, lambda x, y, z: 0 * x + 1.0)
    assert_transmittance(Renderer(const, device).render(cam, constant_tf(), [0, 0, 0], split_opts()),
                         convex_chord(UNIT_CUBE, o, d))
    mesh = mixed_cube(2, 9, grid_field)
    ref, _ = reference_render(brick([0, 0, 0], [1, 1, 1], (2, 2, 2), 9, grid_field), cam, GRID_TF)
    assert ref[..., 3].max() > 0.5
    res = Renderer(mesh, device).render(cam, GRID_TF, [0, 0, 0], split_opts())
    assert np.all(np.isfinite(res.rgba))
    assert np.abs(res.rgba - ref).max() <= 1e-5


# ------------------------------------------------------- collapsed vertices, flat elements


def single_element(shape, vertices, modes, func):
    m = VolumeMesh.from_elements([shape], (2, 2, 2), [np.zeros(ex.num_coeffs(shape, (2, 2, 2)))], (2, 2, 2),
                                 [straight_geometry(shape, vertices)])
    return with_field(m, func, modes)


def apex_camera(shape, vertices, width=24, height=16, spread=1e-7):
    """Orthographic rays within `spread` of the shape's last vertex (tet/pyramid apex, the
    prism's collapsed edge end), heading into the element towards its centroid."""
    V = np.asarray(vertices, float)
    apex = V[-1]
    d = V.mean(axis=0) - apex
    d /= np.linalg.norm(d)
    up = np.cross(d, [0.3, 0.5, 0.8])
    return RayCamera.from_contract({"projection": "orthographic", "eye": (apex - 2 * d).tolist(),
                                    "target": apex.tolist(), "up": up.tolist(), "height": spread}, width, height)


@pytest.mark.parametrize("shape", [shapes.PRISM, shapes.TET, shapes.PYR])
def test_rays_through_collapsed_vertex_low_order(device, shape):
    """Rays within 1e-7 of the collapsed vertex of an order-2 element (and of a sheared one):
    constant density gives exp(-tau L) with L from the vertices."""
    for V in (shapes.VERTICES[shape], shapes.VERTICES[shape] @ np.array([[1, 0.3, 0], [0, 1, 0.2], [0.1, 0, 2]])):
        mesh = single_element(shape, V, 3, lambda x, y, z: 0 * x + 1.0)
        cam = apex_camera(shape, V)
        o, d = cam.rays()
        L = convex_chord(V, o, d)
        assert L.min() > 0.5
        for method in ("split", "trapezoid"):
            assert_transmittance(Renderer(mesh, device).render(cam, constant_tf(), [0, 0, 0],
                                                               RenderOptions(method=method, h=0.01, min_transmittance=0.0)), L)


@pytest.mark.slow
@pytest.mark.parametrize("shape", [shapes.PRISM, shapes.TET, shapes.PYR])
def test_rays_through_collapsed_vertex_order14(device, shape):
    """As the low-order test, order 14 (a constant field: all higher coefficients zero).
    Regression: these rays once gave NaN pixels (Renderer raised 'non-finite pixels')."""
    V = shapes.VERTICES[shape]
    mesh = single_element(shape, V, 15, lambda x, y, z: 0 * x + 1.0)
    cam = apex_camera(shape, V)
    o, d = cam.rays()
    res = Renderer(mesh, device).render(cam, constant_tf(), [0, 0, 0], split_opts())
    assert_transmittance(res, convex_chord(V, o, d))


def interval(V, o, d):
    """(t_enter, t_exit) of one ray in hull(V), float64."""
    N, c = halfspaces(V)
    num, den = c - N @ o, N @ d
    with np.errstate(divide="ignore"):
        t = num / den
    return max(0.0, t[den < 0].max()), t[den > 0].min()


@pytest.mark.slow
def test_pyramid_apex_rays_float32_restriction(device):
    """Rays within `spread` of a pyramid's apex, order 8 field, density linear in the field (no
    breakpoint: one smooth segment); T against the float64 oracle integrated per ray (32 panels
    of 64-point Gauss-Legendre). Target: 1e-5, what every other ray reaches with margin.
    Regression: the pyramid's restriction g = f w^2 divided by w^2 again amplified g's float32
    rounding by 1/w^2 near the apex (T off by 4-7e-5 within 2e-3 of it); segments are now cut
    where w changes by more than a factor 2 (kernels/raycast.pyramid_piece_end)."""
    V = shapes.VERTICES[shapes.PYR]
    mesh = single_element(shapes.PYR, V, 9, lambda x, y, z: 0.5 * (x + 0.3) ** 8 + 0.4 * y**3 * z**4 + 0.2 * z + 0.8)
    tf = TransferFunction.from_contract({"color": [[-5, 1, 1, 1], [5, 1, 1, 1]], "density": [[-5, 0.0], [5, 2.0]]})
    gx, gw = np.polynomial.legendre.leggauss(64)

    def exact_T(o, d):
        t0, t1 = interval(V, o, d)
        edges = np.linspace(t0, t1, 33)
        depth = 0.0
        for a, b in zip(edges[:-1], edges[1:]):
            t = 0.5 * (a + b) + 0.5 * (b - a) * gx
            f = ex.eval_modal(shapes.PYR, mesh.modes[0], mesh.element_coeffs(0), o + t[:, None] * d)
            depth += 0.5 * (b - a) * (gw @ (0.2 * (f + 5.0)))
        return np.exp(-depth)

    r = Renderer(mesh, device)
    errors = {}
    for spread in (2e-7, 2e-5, 2e-3):
        cam = apex_camera(shapes.PYR, V, 12, 8, spread=spread)
        o, d = cam.rays()
        want = np.array([[exact_T(o[i, j], d[i, j]) for j in range(cam.width)] for i in range(cam.height)])
        for method in ("split", "classified", "trapezoid"):
            res = r.render(cam, tf, [0, 0, 0], RenderOptions(method=method, h=1e-3, tolerance=1e-7, min_transmittance=0))
            errors[(spread, method)] = float(np.abs(1.0 - res.rgba[..., 3] - want).max())
    assert max(errors.values()) <= 1e-5, errors


@pytest.mark.parametrize("thickness", [1e-3, 1e-5])
@pytest.mark.parametrize("shape", [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR])
def test_flat_elements(device, shape, thickness):
    """Nearly singular elements: each shape squashed to `thickness` along a tilted axis (aspect
    ratio up to 1e5), rays crossing it obliquely, constant density scaled so that tau L ~ 1;
    L from the vertices. float64 kernels: exp(-tau L) to 1e-6. float32: t along the ray carries
    eps32 * t of rounding, so T's stated budget is max(1e-4, 4 eps32 tau t_exit) relative
    (measured 3.3e-4 at thickness 1e-3 and 4.6e-2 at 1e-5, with t_exit ~ 3.5)."""
    Q, _ = np.linalg.qr(np.array([[1.0, 0.2, 0.1], [0.3, 1.0, 0.2], [0.1, 0.4, 1.0]]))
    V = (shapes.VERTICES[shape] * np.array([1.0, 1.0, thickness])) @ Q.T + np.array([0.3, -0.2, 0.1])
    tau = 1.0 / thickness
    mesh = single_element(shape, V, 2, lambda x, y, z: 0 * x + 1.0)
    normal = Q[:, 2]
    eye = V.mean(axis=0) + 3.0 * (normal + 0.4 * Q[:, 0])
    cam = RayCamera.from_contract({"eye": eye.tolist(), "target": V.mean(axis=0).tolist(), "up": Q[:, 1].tolist(),
                                   "fov_y_deg": 30}, 24, 16)
    o, d = cam.rays()
    L = convex_chord(V, o, d)
    assert (L > 0).sum() > 50 and (L == 0).sum() > 10
    r = Renderer(mesh, device)
    assert_transmittance(r.render(cam, constant_tf(tau), [0, 0, 0], split_opts(precision="float64")), L, tau=tau, rtol=1e-6)
    t_exit = np.linalg.norm(V - eye, axis=1).max()
    budget = max(1e-4, 4 * EPS32 * tau * t_exit)
    assert_transmittance(r.render(cam, constant_tf(tau), [0, 0, 0], split_opts()), L, tau=tau, rtol=budget)


def test_stack_of_thin_layers(device):
    """100 hex layers 1e-4 thick (aspect 1e4) crossed by rays along and across them: the window
    of 8 intervals per BVH pass is refilled ~13 times per ray; exp(-tau L)."""
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.01])
    mesh = brick(lo, hi, (1, 1, 100), 2, lambda x, y, z: 0 * x + 1.0)
    for eye, target in (([0.5, 0.5, 1.0], [0.5, 0.5, 0.0]), ([-1.0, 0.45, 0.006], [0.5, 0.5, 0.005])):
        cam = RayCamera.from_contract({"eye": eye, "target": target, "up": [0, 1, 0] if eye[2] == 1.0 else [0, 0, 1],
                                       "fov_y_deg": 20 if eye[2] == 1.0 else 0.5}, 24, 16)
        o, d = cam.rays()
        L = mesh_chord(mesh, o, d)
        assert L.max() > 0.009
        tau = 1.0 / L.max()
        assert_transmittance(Renderer(mesh, device).render(cam, constant_tf(tau), [0, 0, 0], split_opts()), L, tau=tau)


# ------------------------------------------------------------------- non-affine, tiny


def test_rays_through_trilinear_brick_vertices(device):
    """The jittered trilinear brick (non-affine: the curved path) at 7 x 7 pixels, the centre
    ray through an interior node where 8 bilinear-faced hexes meet: constant density gives
    exp(-tau L) of the unit cube, its outer surface."""
    mesh = jittered_trilinear_brick(2, 0.25)
    assert not mesh.affine.any()
    node = mesh.vertices[0, 6]  # element 0's far corner: the brick's one interior node
    assert np.all(np.abs(node - 0.5) < 0.2)
    cam = RayCamera.from_contract({"eye": (node + [-1.5, -1.0, -0.8]).tolist(), "target": node.tolist(), "up": [0, 0, 1],
                                   "fov_y_deg": 30}, 7, 7)
    o, d = cam.rays()
    L = convex_chord(shapes.VERTICES[shapes.HEX] * 0.5 + 0.5, o, d)
    mesh = with_field(mesh, lambda x, y, z: 0 * x + 1.0, 2)
    assert_transmittance(Renderer(mesh, device).render(cam, constant_tf(), [0, 0, 0], split_opts()), L)
