"""Property tests of the bounds the renderer relies on, every shape, orders 1..14.

(a) element_field_ranges(mesh) (engine/mesh.py) must enclose the field everywhere in the
    element: checked against the float64 numpy oracle at random points inside it.
(b) the per-segment bound of the classified/split methods on affine elements (Chebyshev
    restriction of f w^2 along the segment, |g - c0| <= sum |c_k|, then the pyramid's w^2
    divided out by interval division; kernels/restriction.py) must enclose the field along
    the segment: a tiny Warp kernel calls the kernels' own functions, the oracle samples the
    segment.

Hypothesis draws the shape, the modes (2..15 per direction, anisotropic within each shape's
constraints), the kind of coefficients and a seed. Hexahedra and prisms are capped at
MAX_COEFFS coefficients: mode_bounds' fit-point pseudo-inverse costs 38 s for a 15^3 hex on
this machine, so a 15^3 hex is not drawn (every per-direction order up to 14 still is).

Two engine bugs these tests found are fixed: mode_bounds sampled |phi_m| at random points
with a 5 % margin (single high modes exceeded it by up to ~40 %; now certified by
expansions.mode_max_bounds), and collapse_ratio let one rounding error next to a collapsed
vertex give eta ~ 1e5, overflowing float32 into NaN at order >= ~9 (now held to [-1, 1]).
"""
import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.kernels import args
from hovr_blender.engine.kernels import restriction
from hovr_blender.engine.mesh import VolumeMesh, element_field_ranges
from hovr_blender.engine.renderer import Renderer
from hovr_blender.io.synthetic import straight_geometry

SHAPES = [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR]
MAX_COEFFS = 1300
# the top orders of every shape, run on top of the drawn cases
TOP_ORDERS = [(shapes.HEX, (15, 5, 15), "dense", 1), (shapes.HEX, (2, 15, 2), "decaying", 2),
              (shapes.PRISM, (15, 10, 15), "dense", 3), (shapes.PRISM, (2, 15, 15), "offset", 4),
              (shapes.TET, (15, 15, 15), "dense", 5), (shapes.TET, (2, 3, 15), "decaying", 6),
              (shapes.PYR, (15, 15, 15), "dense", 7), (shapes.PYR, (2, 2, 15), "offset", 8)]
SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow],
                print_blob=True)


# ------------------------------------------------------------------------- strategies


def top_examples(f):
    for case in TOP_ORDERS:
        f = example(case)(f)
    return f


@st.composite
def element_cases(draw):
    """(shape, modes, coefficient kind, seed) within the shape's mode constraints."""
    shape = draw(st.sampled_from(SHAPES))
    m2 = draw(st.integers(2, 15))
    if shape == shapes.HEX:
        m0 = draw(st.integers(2, 15))
        m1 = draw(st.integers(2, min(15, MAX_COEFFS // (m0 * m2))))
    elif shape == shapes.PRISM:  # m0 <= m2 (the collapsed direction carries the top order)
        m0 = draw(st.integers(2, m2))
        tri = m0 * (m0 + 1) // 2 + m0 * (m2 - m0)
        m1 = draw(st.integers(2, min(15, MAX_COEFFS // tri)))
    else:  # tet and pyramid: m0, m1 <= m2 (a 15^3 tet has 680 coefficients, a pyramid 1240)
        m0 = draw(st.integers(2, m2))
        m1 = draw(st.integers(2, m2))
    kind = draw(st.sampled_from(["dense", "decaying", "offset"]))
    seed = draw(st.integers(0, 2**31 - 1))
    return shape, (m0, m1, m2), kind, seed


def make_coeffs(shape, modes, kind, rng):
    k = ex.num_coeffs(shape, modes)
    t = ex.mode_triples(shape, modes)
    if kind == "dense":  # unit max |coefficient|, no structure
        return rng.uniform(-1.0, 1.0, k)
    if kind == "decaying":  # a smooth field: spectral decay with the mode's total order
        return rng.uniform(-1.0, 1.0, k) * 0.5 ** t.sum(axis=1)
    c = 0.05 * rng.uniform(-1.0, 1.0, k)  # large mean, small variation
    c[ex.vertex_mode_indices(shape, modes)] = 3.0 + rng.uniform(-0.5, 0.5, len(shapes.VERTICES[shape]))
    return c


def identity_mesh(shape, modes, coeffs):
    """One straight element whose world coordinates are its reference coordinates."""
    return VolumeMesh.from_elements([shape], modes, [coeffs], (2, 2, 2),
                                    [straight_geometry(shape, shapes.VERTICES[shape])])


def random_inside(shape, n, rng):
    out = np.empty((0, 3))
    while len(out) < n:
        p = rng.uniform(-1, 1, (4 * n, 3))
        out = np.concatenate([out, p[ex.inside(shape, p, tol=0.0)]])
    return out[:n]


def near_collapse(shape, n, rng):
    """Points close to the collapsed vertex / edges (inside), where the collapsed coordinates
    divide by a small number."""
    if shape == shapes.HEX:
        return np.empty((0, 3))
    eps = 10.0 ** rng.uniform(-7, -2, n)
    eta = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), 1.0 - eps], axis=1)
    if shape == shapes.TET:  # also near the collapsed edge of the first collapse (eta2 -> 1)
        half = n // 2
        eta[:half, 1] = 1.0 - 10.0 ** rng.uniform(-7, -2, half)
        eta[:half, 2] = rng.uniform(-1, 1, half)
    return ex.uncollapse(shape, eta)


# -------------------------------------------------------------- (a) element field ranges


@settings(max_examples=24, **SETTINGS)
@given(element_cases())
@top_examples
def test_element_field_ranges_enclose_sampled_field(case):
    shape, modes, kind, seed = case
    rng = np.random.default_rng(seed)
    c = make_coeffs(shape, modes, kind, rng)
    lo, hi = element_field_ranges(identity_mesh(shape, modes, c))
    pts = np.concatenate([random_inside(shape, 600, rng), near_collapse(shape, 100, rng),
                          shapes.VERTICES[shape], ex.fit_points(shape, (2, 2, 2))])
    f = ex.eval_modal(shape, modes, c, pts)
    slack = 1e-12 * np.abs(c).sum()  # float64 rounding of the sums
    assert lo[0] <= hi[0]
    assert f.min() >= lo[0] - slack, f"{shapes.NAMES[shape]} {modes} {kind}: min {f.min():.6g} < lo {lo[0]:.6g}"
    assert f.max() <= hi[0] + slack, f"{shapes.NAMES[shape]} {modes} {kind}: max {f.max():.6g} > hi {hi[0]:.6g}"


@pytest.mark.parametrize("shape", SHAPES)
def test_element_field_ranges_enclose_single_modes(shape):
    """One-hot coefficients on every mode of a degree-5 element: the range must enclose the
    mode's values. Found by dense sampling (not hard-coded): the worst mode is searched at
    60 000 random points inside the element."""
    modes = (6, 6, 6)
    rng = np.random.default_rng(11)
    pts = np.concatenate([random_inside(shape, 60000, rng), near_collapse(shape, 2000, rng)])
    B = np.abs(ex.basis_matrix(shape, modes, pts))  # (n, K)
    k = ex.num_coeffs(shape, modes)
    worst = []
    for m in range(k):
        c = np.zeros(k)
        c[m] = 1.0
        lo, hi = element_field_ranges(identity_mesh(shape, modes, c))
        worst.append((B[:, m].max() - hi[0], m))
    excess, m = max(worst)
    assert excess <= 0.0, f"{shapes.NAMES[shape]} {modes}: mode {m} reaches {excess:.3g} above its range"


# ------------------------------------------------------------ (b) per-segment bounds


@wp.kernel
def _segment_bounds(mesh: args.MeshArgs, xo: wp.array(dtype=wp.vec3), xd: wp.array(dtype=wp.vec3),
                    ab: wp.array(dtype=wp.vec2), segs: args.Segments, out: wp.array(dtype=wp.vec2)):
    # what the kernels do for a segment of affine element 0 (its map the identity, so the ray
    # in world space is the segment in reference space): the traverse kernel writes the
    # samples, the integrate kernel turns them into the series and bounds it
    i = wp.tid()
    segs.element[i] = 0
    segs.t0[i] = ab[i][0]
    segs.t1[i] = ab[i][1]
    deg = restriction.restriction_degree(mesh, 0)
    for j in range(deg + 1):
        segs.samples[i * args.MAX_SAMPLES + j] = restriction.sample_at(mesh, xo[i], xd[i], segs, i, j, deg, 0)
    w = restriction.end_weights(mesh, xo[i], xd[i], segs, i, 0)
    segs.samples[i * args.MAX_SAMPLES + args.MAX_SAMPLES - 2] = w[0]
    segs.samples[i * args.MAX_SAMPLES + args.MAX_SAMPLES - 1] = w[1]
    for k in range(deg + 1):
        segs.coeffs[i * args.MAX_SAMPLES + k] = restriction.chebyshev_coefficient(segs, i, k, deg)
    segs.coeffs[i * args.MAX_SAMPLES + deg + 1] = w[0]  # the weights after the series (restriction.series_weights)
    segs.coeffs[i * args.MAX_SAMPLES + deg + 2] = w[1]
    out[i] = restriction.segment_bounds(segs.coeffs, i * args.MAX_SAMPLES, deg, mesh.field_err[0])


def segment_bounds(mesh_args, xo, xd, ab):
    n = len(xo)
    segs = args.Segments()
    segs.samples = wp.zeros(n * args.MAX_SAMPLES, dtype=wp.float32, device="cpu")
    segs.coeffs = wp.zeros(n * args.MAX_SAMPLES, dtype=wp.float32, device="cpu")
    segs.element = wp.zeros(n, dtype=wp.int32, device="cpu")
    segs.t0 = wp.zeros(n, dtype=wp.float32, device="cpu")
    segs.t1 = wp.zeros(n, dtype=wp.float32, device="cpu")
    out = wp.zeros(n, dtype=wp.vec2, device="cpu")
    wp.launch(_segment_bounds, dim=n, device="cpu",
              inputs=[mesh_args, wp.array(np.asarray(xo, np.float32), dtype=wp.vec3, device="cpu"),
                      wp.array(np.asarray(xd, np.float32), dtype=wp.vec3, device="cpu"),
                      wp.array(np.asarray(ab, np.float32), dtype=wp.vec2, device="cpu"), segs, out])
    return out.numpy().astype(np.float64)


def random_segments(shape, n, rng):
    """(P, Q): segments inside the (convex) reference element; some end at a vertex (the
    pyramid's and tet's apex among them) or run along an edge."""
    V = shapes.VERTICES[shape]
    P = random_inside(shape, n, rng)
    Q = random_inside(shape, n, rng)
    k = n // 4
    P[:k] = V[rng.integers(0, len(V), k)]  # from a vertex
    Q[k:2 * k] = V[-1]  # to the last vertex (the apex of tets and pyramids)
    e = V[rng.integers(0, len(V), (2, 4))]
    P[2 * k:2 * k + 4], Q[2 * k:2 * k + 4] = e[0], e[1]  # vertex to vertex: edges, face diagonals
    P[-4:] = near_collapse(shape, 4, rng) if shape != shapes.HEX else P[-4:]
    return P, Q  # ends exactly at vertices too, collapsed ones included


@settings(max_examples=24, **SETTINGS)
@given(element_cases())
@top_examples
def test_segment_bounds_enclose_field_along_segments(case):
    shape, modes, kind, seed = case
    rng = np.random.default_rng(seed)
    c = make_coeffs(shape, modes, kind, rng)
    mesh = identity_mesh(shape, modes, c)
    r = Renderer(mesh, "cpu")
    n = 24
    P, Q = random_segments(shape, n, rng)
    xo = P.astype(np.float32)
    xd = (Q - P).astype(np.float32)
    a = np.zeros(n, np.float32)
    b = np.ones(n, np.float32)
    sub = rng.integers(0, 3, n) == 0  # some sub-segments, as a ray's segment of an element
    a[sub] = rng.uniform(0.0, 0.5, sub.sum())
    b[sub] = rng.uniform(0.5, 1.0, sub.sum())
    lohi = segment_bounds(r.mesh_args(), xo, xd, np.stack([a, b], 1))
    # the oracle at exactly the segment the kernel saw (float32 inputs, float32 coefficients)
    c32 = c.astype(np.float32).astype(np.float64)
    s = np.concatenate([np.linspace(0.0, 1.0, 41), rng.uniform(0, 1, 40)])
    t = a[:, None].astype(np.float64) + s[None, :] * (b - a)[:, None].astype(np.float64)
    xi = xo[:, None, :].astype(np.float64) + t[..., None] * xd[:, None, :].astype(np.float64)
    inside = ex.inside(shape, xi, tol=1e-6)  # float32 rounding of a vertex may step just outside
    f = ex.eval_modal(shape, modes, c32, xi)
    assert np.all(np.isfinite(lohi))
    for i in range(n):
        fi = f[i][inside[i]]
        assert fi.min() >= lohi[i, 0] and fi.max() <= lohi[i, 1], (
            f"{shapes.NAMES[shape]} {modes} {kind} segment {i} {P[i]}->{Q[i]} on [{a[i]}, {b[i]}]: "
            f"field in [{fi.min():.7g}, {fi.max():.7g}], bound [{lohi[i, 0]:.7g}, {lohi[i, 1]:.7g}]")


@pytest.mark.parametrize("shape", [shapes.PRISM, shapes.TET, shapes.PYR])
def test_segment_bounds_finite_next_to_collapsed_vertices(shape):
    """Segments of an order-14 element that start one float32 ulp (2^-23) off the collapsed
    vertex (prism: a point of the collapsed edge), where the render kernel's clipped entry point
    lands for a ray through that vertex, and run to the centroid."""
    modes = (15, 15, 15)
    rng = np.random.default_rng(5)
    c = rng.uniform(-1, 1, ex.num_coeffs(shape, modes))
    r = Renderer(identity_mesh(shape, modes, c), "cpu")
    ulp = 2.0 ** -23
    start = np.array([-1.0, -1.0, 1.0]) if shape != shapes.PRISM else np.array([-1.0, 0.25, 1.0])
    P = start + np.array([[ulp, 0, 0], [0, 0, 0], [ulp, ulp, 0], [0, 0, -ulp]])
    n = len(P)
    lohi = segment_bounds(r.mesh_args(), P, shapes.CENTROIDS[shape] - P, np.tile([0.0, 1.0], (n, 1)))
    bad = ~np.isfinite(lohi).all(axis=1)
    assert not bad.any(), f"{shapes.NAMES[shape]}: non-finite bounds on segments from {P[bad].tolist()}"
