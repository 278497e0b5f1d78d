"""The kernels' Chebyshev series routines (Clenshaw value, antiderivative, both in one pass)
against numpy.polynomial.chebyshev, over random series of every degree a segment can have."""
import numpy as np
import numpy.polynomial.chebyshev as C
import warp as wp

from hovr_blender.engine.kernels import restriction
from hovr_blender.engine.kernels.args import MAX_SAMPLES


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
