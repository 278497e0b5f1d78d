"""The float64 reference integrator against closed forms and an independent brute-force integration."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hovr_blender.engine.expansions import fit_tensor_coefficients
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import VolumeMesh
from hovr_blender.engine.shapes import HEX, VERTICES
from hovr_blender.engine.reference import cheb_eval, cheb_integral, reference_render
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.io.builtin import SPHERE_LOWER, SPHERE_UPPER, box_vertices, sphere

FAST = settings(max_examples=25, deadline=None)


def camera(eye, target, n=4, fov=30.0, up=(0.0, 0.0, 1.0)):
    return RayCamera.from_contract({"eye": list(eye), "target": list(target), "up": list(up), "fov_y_deg": fov}, n, n)


def linear_field_mesh(vertices, grad, f0):
    """One affine hex with f(x) = grad . x + f0 (modes 2), fitted in reference coordinates."""
    x0 = vertices.mean(axis=0)
    J = 0.5 * np.stack([vertices[1] - vertices[0], vertices[3] - vertices[0], vertices[4] - vertices[0]], axis=1)

    def f(a, b, c):
        xi = np.stack([a, b, c], axis=-1)
        return (x0 + xi @ J.T) @ grad + f0

    c = fit_tensor_coefficients(f, (2, 2, 2))
    return VolumeMesh.from_affine_hexes(vertices[None], (2, 2, 2), [c])


def world_chord(vertices, o, d):
    """Chord of the ray o + t d (t >= 0) through a parallelepiped, from its six world-space face planes."""
    faces = [(0, 1, 2, 3), (0, 1, 5, 4), (1, 2, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4), (4, 5, 6, 7)]
    centre = vertices.mean(axis=0)
    t_in, t_out = 0.0, np.inf
    for f in faces:
        p = vertices[list(f)]
        n = np.cross(p[1] - p[0], p[3] - p[0])
        if np.dot(n, centre - p[0]) > 0:  # outward normal
            n = -n
        den, num = np.dot(n, d), np.dot(n, p[0] - o)
        if den == 0.0:
            if num < 0:
                return 0.0, 0.0
            continue
        t = num / den
        if den > 0:
            t_out = min(t_out, t)
        else:
            t_in = max(t_in, t)
    return (t_in, t_out) if t_out > t_in else (0.0, 0.0)


def random_parallelepiped(seed):
    rng = np.random.default_rng(seed)
    J = np.diag(rng.uniform(0.5, 1.5, 3)) + rng.uniform(-0.3, 0.3, (3, 3))
    return rng.uniform(-0.5, 0.5, 3) + VERTICES[HEX] @ J.T


def test_chebyshev_helpers_match_numpy():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(5, 7))
    s = rng.uniform(-1, 1, (5, 3))
    want = np.array([np.polynomial.chebyshev.chebval(s[i], c[i]) for i in range(5)])
    np.testing.assert_allclose(cheb_eval(c, s), want, rtol=0, atol=1e-13)
    G = cheb_integral(c)
    want = np.array([np.polynomial.chebyshev.chebint(c[i]) for i in range(5)])
    np.testing.assert_allclose(G[:, 1:], want[:, 1:], rtol=0, atol=1e-14)


def constant_field_mesh(vertices, values):
    """Constant field per element. Modified_A with one mode is (1 - x)/2, not 1, so a constant
    needs modes 2 with equal vertex coefficients (the vertex modes sum to 1)."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 8, 3)
    return VolumeMesh.from_affine_hexes(vertices, (2, 2, 2), [np.full(8, float(v)) for v in values])


# (a) constant field: T = exp(-tau L), C = kappa (1 - T) with L from the world-space face planes
@FAST
@given(seed=st.integers(0, 10_000), value=st.floats(-2.0, 2.0), az=st.floats(0, 2 * np.pi), el=st.floats(-1.2, 1.2))
def test_constant_field_is_beer_lambert(seed, value, az, el):
    v = random_parallelepiped(seed)
    mesh = constant_field_mesh(v, [value])
    tf = TransferFunction(np.array([-2.0, 2.0]), np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.25]]),
                          np.array([-2.0, 0.0, 2.0]), np.array([0.5, 3.0, 1.0]))
    eye = v.mean(axis=0) + 5.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    cam = camera(eye, v.mean(axis=0), n=5, fov=40.0, up=(0.3, 0.1, 1.0))
    img, info = reference_render(mesh, cam, tf, (0.0, 0.0, 0.0))
    o, d = cam.rays()
    for j in range(5):
        for i in range(5):
            t0, t1 = world_chord(v, o[j, i], d[j, i])
            T = np.exp(-tf.density(value) * (t1 - t0))
            np.testing.assert_allclose(img[j, i, :3], tf.color(value) * (1 - T), rtol=0, atol=1e-13)
            np.testing.assert_allclose(img[j, i, 3], 1 - T, rtol=0, atol=1e-13)


def test_two_elements_composite_front_to_back_across_a_shared_face():
    lo, mid, hi = np.array([-1.0, -1, -1]), np.array([1.0, 1, 0]), np.array([1.0, 1, 1])
    v = np.stack([box_vertices(lo, mid), box_vertices([-1.0, -1, 0], hi)])
    mesh = constant_field_mesh(v, [0.0, 1.0])
    tf = TransferFunction(np.array([0.0, 1.0]), np.array([[1.0, 0, 0], [0, 0, 1.0]]), np.array([0.0, 1.0]), np.array([0.7, 2.0]))
    cam = camera((0.3, 0.2, 6.0), (0.0, 0.0, 0.0), n=6, fov=20.0, up=(0.0, 1.0, 0.0))
    bg = np.array([0.2, 0.3, 0.4])
    img, _ = reference_render(mesh, cam, tf, bg)
    o, d = cam.rays()
    for j in range(6):
        for i in range(6):
            a0, a1 = world_chord(v[1], o[j, i], d[j, i])  # top element, seen first from z = 6
            b0, b1 = world_chord(v[0], o[j, i], d[j, i])
            T1, T0 = np.exp(-2.0 * (a1 - a0)), np.exp(-0.7 * (b1 - b0))
            C = np.array([0, 0, 1.0]) * (1 - T1) + T1 * np.array([1.0, 0, 0]) * (1 - T0)
            np.testing.assert_allclose(img[j, i, :3], C + T1 * T0 * bg, rtol=0, atol=1e-13)
            np.testing.assert_allclose(img[j, i, 3], 1 - T1 * T0, rtol=0, atol=1e-13)


# (b) linear field along the ray, one tent: closed forms
def tent_area(u, s1, w, height):
    """int_{-inf}^u of the tent height * max(0, 1 - |x - s1| / w)."""
    x = np.clip(u - (s1 - w), 0.0, 2 * w)
    return np.where(x <= w, 0.5 * height * x * x / w, height * w - 0.5 * height * (2 * w - x) ** 2 / w)


@FAST
@given(seed=st.integers(0, 10_000), s1=st.floats(-0.8, 0.8), w=st.floats(0.02, 0.6), height=st.floats(0.1, 30.0))
def test_linear_field_density_tent(seed, s1, w, height):
    rng = np.random.default_rng(seed)
    v = random_parallelepiped(seed)
    grad = rng.normal(size=3)
    grad /= np.linalg.norm(grad)
    f0 = -grad @ v.mean(axis=0)
    mesh = linear_field_mesh(v, grad, f0)
    kappa = np.array([0.3, 0.6, 0.9])
    tf = TransferFunction(np.array([0.0]), kappa[None], np.array([s1 - w, s1, s1 + w]), np.array([0.0, height, 0.0]))
    eye = v.mean(axis=0) + 4.0 * rng.normal(size=3) / np.sqrt(3)
    cam = camera(eye, v.mean(axis=0) + 0.2 * rng.normal(size=3), n=4, fov=35.0, up=rng.normal(size=3))
    img, info = reference_render(mesh, cam, tf)
    o, d = cam.rays()
    for j in range(4):
        for i in range(4):
            t0, t1 = world_chord(v, o[j, i], d[j, i])
            if t1 <= t0:
                T = 1.0
            else:
                fa, fb = sorted([grad @ (o[j, i] + t * d[j, i]) + f0 for t in (t0, t1)])
                slope = abs(grad @ d[j, i])
                depth = (tent_area(fb, s1, w, height) - tent_area(fa, s1, w, height)) / slope if slope > 1e-9 else None
                if depth is None:  # f constant along the ray
                    depth = tf.density(fa) * (t1 - t0)
                T = np.exp(-depth)
            np.testing.assert_allclose(img[j, i, 3], 1 - T, rtol=0, atol=1e-11)
            np.testing.assert_allclose(img[j, i, :3], kappa * (1 - T), rtol=0, atol=1e-11)
    assert info["error_estimate"] < 1e-9


@FAST
@given(seed=st.integers(0, 10_000), s1=st.floats(-0.8, 0.8), w=st.floats(0.02, 0.6), tau=st.floats(0.05, 20.0))
def test_linear_field_colour_tent(seed, s1, w, tau):
    """kappa is a tent, tau constant: on each piece kappa = p + q t, and
    int (p + q t) tau exp(-tau (t - t0)) dt = [-(p + q t + q / tau) exp(-tau (t - t0))]."""
    rng = np.random.default_rng(seed)
    v = random_parallelepiped(seed)
    grad = rng.normal(size=3)
    grad /= np.linalg.norm(grad)
    mesh = linear_field_mesh(v, grad, -grad @ v.mean(axis=0))
    base, peak = np.array([0.1, 0.2, 0.0]), np.array([1.0, 0.5, 2.0])
    tf = TransferFunction(np.array([s1 - w, s1, s1 + w]), np.stack([base, peak, base]), np.array([0.0]), np.array([tau]))
    eye = v.mean(axis=0) + 4.0 * rng.normal(size=3) / np.sqrt(3)
    cam = camera(eye, v.mean(axis=0) + 0.2 * rng.normal(size=3), n=4, fov=35.0, up=rng.normal(size=3))
    bg = np.array([0.5, 0.25, 0.125])
    img, info = reference_render(mesh, cam, tf, bg)
    o, d = cam.rays()
    f0 = -grad @ v.mean(axis=0)
    for j in range(4):
        for i in range(4):
            t0, t1 = world_chord(v, o[j, i], d[j, i])
            C = np.zeros(3)
            T = 1.0
            if t1 > t0:
                fs, fi = grad @ d[j, i], grad @ o[j, i] + f0  # f(t) = fi + fs t
                cuts = [t0, t1] + [(b - fi) / fs for b in tf.color_s if fs != 0]
                cuts = np.unique(np.clip(cuts, t0, t1))
                for a, b in zip(cuts[:-1], cuts[1:]):
                    ka, kb = tf.color(fi + fs * a), tf.color(fi + fs * b)
                    q = (kb - ka) / (b - a)
                    p = ka - q * a

                    def prim(t):
                        return -(p + q * t + q / tau) * np.exp(-tau * (t - t0))

                    C += prim(b) - prim(a)
                T = np.exp(-tau * (t1 - t0))
            np.testing.assert_allclose(img[j, i, :3], C + T * bg, rtol=0, atol=1e-11)
            np.testing.assert_allclose(img[j, i, 3], 1 - T, rtol=0, atol=1e-12)
    assert info["error_estimate"] < 1e-9


# (c) the sphere and a cubic field against brute force
def brute_force_ray(mesh, tf, o, d, lower, upper, n_grid=3001, subs=48, nodes=16):
    """Independent integration of one ray through the axis-aligned box element 0: chord by bisection on
    the inside test, field by mesh.evaluate, breakpoint crossings by bisection inside the monotone
    stretches between the field's extrema, depth and emission by nested composite Gauss-Legendre."""

    def inside(t):
        x = o + t * d
        return bool(np.all((x >= lower) & (x <= upper)))

    def bisect(g, a, b, it=80):  # g(a) != g(b): boolean or sign change
        ga = g(a)
        for _ in range(it):
            m = 0.5 * (a + b)
            if g(m) == ga:
                a = m
            else:
                b = m
        return 0.5 * (a + b)

    def field(t):
        return mesh.evaluate(0, o + np.asarray(t, dtype=float)[..., None] * d)

    far = np.linalg.norm(o - 0.5 * (lower + upper)) + np.linalg.norm(upper - lower)
    ts = np.linspace(0.0, far, n_grid)
    ins = np.array([inside(t) for t in ts])
    k = np.nonzero(ins)[0]
    if k.size == 0:
        return np.zeros(3), 1.0
    t_in = 0.0 if k[0] == 0 else bisect(inside, ts[k[0] - 1], ts[k[0]])
    t_out = bisect(inside, ts[k[-1]], ts[k[-1] + 1])

    tg = np.linspace(t_in, t_out, n_grid)
    df = np.diff(field(tg))
    splits = [t_in, t_out]
    for i in np.nonzero(np.sign(df[1:]) != np.sign(df[:-1]))[0] + 1:  # extremum near tg[i]
        a, b = tg[i - 1], tg[i + 1]
        sgn = np.sign(df[i - 1]) or 1.0
        for _ in range(100):  # ternary search for the extremum of sgn * f
            m1, m2 = a + (b - a) / 3, b - (b - a) / 3
            if sgn * field(m1) < sgn * field(m2):
                a = m1
            else:
                b = m2
        splits.append(0.5 * (a + b))
    splits = sorted(splits)
    cuts = list(splits)
    for a, b in zip(splits[:-1], splits[1:]):
        fa, fb = field(a), field(b)
        for beta in tf.breakpoints:
            if (fa - beta) * (fb - beta) < 0:
                cuts.append(bisect(lambda t: field(t) > beta, a, b))
    cuts = np.unique(cuts)

    x, w = np.polynomial.legendre.leggauss(nodes)
    depth, C = 0.0, np.zeros(3)
    for a, b in zip(cuts[:-1], cuts[1:]):
        e = np.linspace(a, b, subs + 1)
        lo, hi = e[:-1], e[1:]
        tn = lo[:, None] + 0.5 * (x + 1) * (hi - lo)[:, None]  # (subs, nodes)
        full = 0.5 * (hi - lo) * (tf.density(field(tn)) @ w)  # depth of each sub-interval
        before = depth + np.concatenate([[0.0], np.cumsum(full)[:-1]])
        inner = lo[:, None, None] + 0.5 * (x + 1) * (tn - lo[:, None])[..., None]  # [lo, node] rules
        part = 0.5 * (tn - lo[:, None]) * (tf.density(field(inner)) @ w)
        dn = before[:, None] + part
        fn = field(tn)
        integrand = tf.color(fn) * (tf.density(fn) * np.exp(-dn))[..., None]
        C += np.einsum("sn,snc,n->c", 0.5 * (hi - lo)[:, None] * np.ones_like(tn), integrand, w)
        depth += full.sum()
    return C, np.exp(-depth)


def spike_tf():
    dens = [(0.8, 0.0), (1.0, 10.0), (1.2, 0.0), (3.8, 0.0), (4.0, 20.0), (4.2, 0.0), (8.8, 0.0), (9.0, 30.0), (9.2, 0.0)]
    col = [(0.0, 1.0, 0.0, 0.0), (5.0, 0.0, 1.0, 0.0), (12.0, 0.0, 0.0, 1.0)]
    return TransferFunction.from_contract({"color": col, "density": dens})


SPHERE_CAMERA = {"eye": [4.0, 3.0, 9.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 1.0, 0.0], "fov_y_deg": 30.0}


def test_sphere_matches_brute_force():
    mesh = sphere()
    tf = spike_tf()
    n = 48
    cam = RayCamera.from_contract(SPHERE_CAMERA, n, n)
    bg = np.array([0.1, 0.2, 0.3])
    img, info = reference_render(mesh, cam, tf, bg)
    assert info["error_estimate"] < 1e-9  # (d)
    assert info["max_degree"] == 2  # the sphere's field is recognised as a quadratic
    o, d = cam.rays()
    # pixels that see some spike, partly or fully opaque, and one that misses the box
    rng = np.random.default_rng(1)
    partial = np.argwhere((img[..., 3] > 0.05) & (img[..., 3] < 0.95))
    opaque = np.argwhere(img[..., 3] >= 0.95)
    pixels = [*rng.choice(partial, 6, replace=False), *rng.choice(opaque, 2, replace=False), (0, 0)]
    for j, i in pixels:
        C, T = brute_force_ray(mesh, tf, o[j, i], d[j, i], SPHERE_LOWER, SPHERE_UPPER)
        np.testing.assert_allclose(img[j, i, :3], C + T * bg, rtol=0, atol=1e-8, err_msg=f"pixel {(j, i)}")
        np.testing.assert_allclose(img[j, i, 3], 1 - T, rtol=0, atol=1e-8, err_msg=f"pixel {(j, i)}")


def test_cubic_field_matches_brute_force():
    """Degree > 2 along rays: exercises the companion-matrix root path."""
    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.5, 0.5])
    half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)

    def f(a, b, c):
        x, y, z = mid[0] + half[0] * a, mid[1] + half[1] * b, mid[2] + half[2] * c
        return x**3 - 2 * x * y * z + 0.5 * y * y + z

    mesh = VolumeMesh.from_affine_hexes(box_vertices(lo, hi)[None], (4, 4, 4), [fit_tensor_coefficients(f, (4, 4, 4))])
    tf = TransferFunction.from_contract({
        "color": [(-1.0, 1.0, 0.2, 0.0), (0.0, 0.0, 1.0, 0.3), (1.0, 0.2, 0.0, 1.0)],
        "density": [(-0.6, 0.0), (-0.5, 15.0), (-0.4, 0.0), (0.2, 0.0), (0.3, 8.0), (0.45, 0.0), (1.0, 0.0), (1.1, 25.0)],
    })
    n = 24
    cam = camera((3.0, -2.5, 2.0), (0.0, 0.2, -0.2), n=n, fov=40.0)
    img, info = reference_render(mesh, cam, tf, (0.0, 0.0, 0.0))
    assert info["max_degree"] >= 3
    assert info["error_estimate"] < 1e-9
    o, d = cam.rays()
    for j, i in [(12, 12), (3, 20), (18, 7), (8, 9), (20, 16)]:
        C, T = brute_force_ray(mesh, tf, o[j, i], d[j, i], lo, hi)
        np.testing.assert_allclose(img[j, i, :3], C, rtol=0, atol=1e-8, err_msg=f"pixel {(j, i)}")
        np.testing.assert_allclose(img[j, i, 3], 1 - T, rtol=0, atol=1e-8, err_msg=f"pixel {(j, i)}")


@FAST
@given(seed=st.integers(0, 10_000), k=st.integers(1, 4))
def test_sphere_random_breakpoints_chunking_and_background(seed, k):
    """Random spikes: error estimate small, chunking does not change the image, RGB - T bg is bg-free."""
    rng = np.random.default_rng(seed)
    centres = np.sort(rng.uniform(0.5, 17.0, k))
    dens = []
    for c in centres:
        w = rng.uniform(0.01, 0.3)
        dens += [(c - w, 0.0), (c, rng.uniform(1.0, 60.0)), (c + w, 0.0)]
    dens = sorted({round(s, 9): t for s, t in dens}.items())
    if any(b[0] - a[0] <= 0 for a, b in zip(dens[:-1], dens[1:])):
        return
    col = [(0.0, *rng.uniform(0, 1, 3)), (float(rng.uniform(1, 17)), *rng.uniform(0, 1, 3)), (18.0, *rng.uniform(0, 1, 3))]
    col = sorted(col)
    tf = TransferFunction.from_contract({"color": col, "density": [list(p) for p in dens]})
    cam = RayCamera.from_contract(SPHERE_CAMERA, 7, 5)
    mesh = sphere()
    a, info = reference_render(mesh, cam, tf, (0.0, 0.0, 0.0), rays_per_chunk=64)
    b, _ = reference_render(mesh, cam, tf, (1.0, 0.5, 0.25), rays_per_chunk=6)
    assert info["error_estimate"] < 1e-9
    np.testing.assert_allclose(b[..., 3], a[..., 3], rtol=0, atol=1e-15)
    T = 1.0 - a[..., 3:4]
    np.testing.assert_allclose(b[..., :3] - T * np.array([1.0, 0.5, 0.25]), a[..., :3], rtol=0, atol=1e-14)


def test_rays_missing_everything_see_the_background():
    mesh = sphere()
    cam = camera((30.0, 0.0, 0.0), (31.0, 0.0, 0.0), n=3)  # looking away
    img, info = reference_render(mesh, cam, spike_tf(), (0.2, 0.4, 0.6))
    np.testing.assert_array_equal(img, np.broadcast_to([0.2, 0.4, 0.6, 0.0], img.shape))
    assert info["intervals"] == 0


def test_opaque_piece_is_cut_not_lost():
    """A huge density: T underflows to 0 and C reaches kappa without blowing up the sub-piece count."""
    mesh = sphere()
    tf = TransferFunction(np.array([0.0]), np.array([[0.25, 0.5, 1.0]]), np.array([0.0]), np.array([1e6]))
    cam = RayCamera.from_contract(SPHERE_CAMERA, 4, 4)
    img, info = reference_render(mesh, cam, tf)
    hit = img[..., 3] > 0
    assert hit.any()
    np.testing.assert_allclose(img[hit][:, :3], np.broadcast_to([0.25, 0.5, 1.0], (hit.sum(), 3)), rtol=0, atol=1e-12)
    assert info["subpieces"] <= 3 * 60 * hit.sum()
