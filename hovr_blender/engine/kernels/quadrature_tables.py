"""Gauss-Kronrod G7/K15 nodes and weights and the spectral integration matrix on them (numpy)."""
from __future__ import annotations

import numpy as np

# Kronrod nodes on [-1, 1] in ascending order; the Gauss (G7) nodes are the odd indices.
_XK_POS = [0.991455371120812639206854697526329, 0.949107912342758524526189684047851,
           0.864864423359769072789712788640926, 0.741531185599394439863864773280788,
           0.586087235467691130294144845693013, 0.405845151377397166906606412076961,
           0.207784955007898467600689403773245, 0.0]
_WK_POS = [0.022935322010529224963732008058970, 0.063092092629978553290700663189204,
           0.104790010322250183839876322541518, 0.140653259715525918745189590510238,
           0.169004726639267902826583426598550, 0.190350578064785409913256402421014,
           0.204432940075298892414161999234649, 0.209482141084727828012999174891714]
_WG_POS = [0.129484966168869693270611432679082, 0.279705391489276667901467771423780,
           0.381830050505118944950369775488975, 0.417959183673469387755102040816327]


def gauss_kronrod_15():
    """(nodes (15,), kronrod weights (15,), gauss weights (15,) zero at non-Gauss nodes)."""
    x = np.array([-v for v in _XK_POS[:-1]] + [0.0] + _XK_POS[:-1][::-1])
    wk = np.array(_WK_POS[:-1] + [_WK_POS[-1]] + _WK_POS[:-1][::-1])
    wg = np.zeros(15)
    gauss_idx = [1, 3, 5, 7, 9, 11, 13]
    wg_vals = _WG_POS[:-1] + [_WG_POS[-1]] + _WG_POS[:-1][::-1]
    wg[gauss_idx] = wg_vals
    return x, wk, wg


def integration_matrix(x: np.ndarray) -> np.ndarray:
    """S[j, i] = integral from -1 to x_j of the i-th Lagrange polynomial through nodes x.

    S @ g gives the running integral of the interpolant of g at each node (exact for
    polynomials of degree < len(x)): the 'spectral' inner integral of a smooth segment."""
    n = x.size
    V = np.vander(x, n, increasing=True)  # V[j, k] = x_j^k
    k = np.arange(n)
    P = (np.power.outer(x, k + 1) - (-1.0) ** (k + 1)) / (k + 1)  # integral of x^k from -1 to x_j
    return P @ np.linalg.inv(V)
