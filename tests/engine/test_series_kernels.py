"""The kernels' Chebyshev series routines (Clenshaw value, antiderivative, both in one pass)
against numpy.polynomial.chebyshev, over random series of every degree a segment can have;
and a Gauss-Kronrod panel over a segment one ulp long."""
import numpy as np
import numpy.polynomial.chebyshev as C
import warp as wp

from hovr_blender.engine.kernels import quadrature, restriction
from hovr_blender.engine.kernels.args import MAX_SAMPLES, QuadArgs, TransferArgs
from hovr_blender.engine.kernels.quadrature_tables import gauss_kronrod_15, integration_matrix


@wp.kernel
def _series(c: wp.array(dtype=wp.float32), deg: wp.array(dtype=wp.int32), s: wp.array(dtype=wp.float32),
            out: wp.array(dtype=wp.vec4)):
    i = wp.tid()
    cb = i * MAX_SAMPLES
    both = restriction.clenshaw_and_integral(c, cb, deg[i], s[i])
    out[i] = wp.vec4(restriction.clenshaw(c, cb, deg[i], s[i]), restriction.clenshaw_integral(c, cb, deg[i], s[i]),
                     both[0], both[1])


def test_value_and_antiderivative_match_numpy(device):
    rng = np.random.default_rng(7)
    n = 400
    degs = rng.integers(0, MAX_SAMPLES - 2, n).astype(np.int32)
    coeffs = np.zeros((n, MAX_SAMPLES), np.float32)
    for i, d in enumerate(degs):
        coeffs[i, : d + 1] = rng.uniform(-1, 1, d + 1) / (1.0 + np.arange(d + 1))
    s = rng.uniform(-1, 1, n).astype(np.float32)
    out = wp.zeros(n, dtype=wp.vec4, device=device)
    wp.launch(_series, dim=n, device=device,
              inputs=[wp.array(coeffs.ravel(), dtype=wp.float32, device=device),
                      wp.array(degs, dtype=wp.int32, device=device), wp.array(s, dtype=wp.float32, device=device), out])
    got = out.numpy().astype(np.float64)
    for i, d in enumerate(degs):
        c = coeffs[i, : d + 1].astype(np.float64)
        si = np.float64(s[i])
        value = C.chebval(si, c)
        # the kernels' antiderivative has no T_0 term; numpy's chebint with lbnd=0 differs from it
        # by a constant, so compare values relative to s = 0
        F = C.chebint(c)
        F[0] = 0.0
        integral = C.chebval(si, F)
        scale = np.abs(c).sum() + 1e-30
        assert abs(got[i, 0] - value) <= 4e-6 * scale, (d, got[i, 0], value)
        assert abs(got[i, 2] - value) <= 4e-6 * scale, (d, got[i, 2], value)
        assert abs(got[i, 1] - integral) <= 4e-6 * scale, (d, got[i, 1], integral)
        assert abs(got[i, 3] - integral) <= 4e-6 * scale, (d, got[i, 3], integral)


@wp.kernel
def _panel(tf: TransferArgs, q: QuadArgs, c: wp.array(dtype=wp.float32), deg: int, a: float, b: float,
           out: wp.array(dtype=wp.vec4)):
    st = quadrature.RayIntegral()
    st.transmittance = 1.0
    st.depth = -1.0
    st = quadrature.gauss_kronrod_smooth(tf, q, c, 0, deg, a, b, a, b, 1, st)
    out[0] = wp.vec4(st.color[0], st.color[1], st.color[2], st.transmittance)


def test_gauss_kronrod_on_a_one_ulp_segment_stays_finite(device):
    """A segment one float32 ulp long: its middle rounds onto an end, so an end's position in
    [-1, 1] computes as +-2, where a degree-30 series of rounding noise grows by 2^30 (found on
    the H100: an optical depth of -inf, a NaN pixel). Every evaluation is held to [-1, 1]."""
    a = np.float32(2.28241849)
    b = np.nextafter(a, np.float32(3))
    if np.float32(0.5) * (a + b) != b:  # the middle must round onto b for |s| = 2
        b, a = a, np.nextafter(a, np.float32(0))
    deg = 30
    rng = np.random.default_rng(3)
    c = np.zeros(MAX_SAMPLES, np.float32)
    c[0] = 0.807
    c[1:deg + 1] = rng.uniform(-1e-7, 1e-7, deg)
    c[deg + 1:deg + 3] = 1.0  # the weights after the series (restriction.series_weights): none, the exact-depth path
    x, wk, wg = gauss_kronrod_15()
    tf = TransferArgs()
    tf.color_s = wp.array([0.0, 2.0], dtype=wp.float32, device=device)
    tf.color_rgb = wp.array([[1.0, 0.5, 0.2], [0.2, 0.5, 1.0]], dtype=wp.vec3, device=device)
    tf.density_s = wp.array([0.0, 2.0], dtype=wp.float32, device=device)
    tf.density_tau = wp.array([0.0, 50.0], dtype=wp.float32, device=device)
    q = QuadArgs()
    q.tol = 1e-5
    q.min_transmittance = 0.0
    q.gk_x, q.gk_wk, q.gk_wg = (wp.array(v.astype(np.float32), dtype=wp.float32, device=device) for v in (x, wk, wg))
    q.gk_s = wp.array(integration_matrix(x).astype(np.float32), dtype=wp.float32, device=device)
    out = wp.zeros(1, dtype=wp.vec4, device=device)
    wp.launch(_panel, dim=1, device=device, inputs=[tf, q, wp.array(c, dtype=wp.float32, device=device), deg,
                                                   float(a), float(b), out])
    col_t = out.numpy()[0]
    assert np.isfinite(col_t).all(), col_t
    assert 0.0 <= col_t[3] <= 1.0 and abs(col_t[3] - 1.0) < 1e-4, col_t  # tau ~ 20 over 1e-7: T ~ 1
