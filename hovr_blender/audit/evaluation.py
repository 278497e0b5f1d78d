"""The float32 device evaluation against the float64 oracle: the renderer's own element
evaluator (engine/kernels/element.py) run on a device at random reference points and compared
with engine/expansions. tests/engine/test_stress.py runs it on few points; bench/eval_table.py
writes the full table.

For each (family, shape, order) a few random fields are drawn, evaluated by a small Warp kernel
that calls element.eval_element (the renderer's own evaluator) at random reference points
inside the element plus points near the collapsed vertex/edges (distance 1e-6..1e-2 in the
collapsed coordinate) and the vertices, and compared with the oracle:
- kernel error: the oracle at exactly the kernel's float32 inputs (rounded coefficients and
  points): the error of the float32 arithmetic alone;
- end-to-end error: the oracle at the float64 inputs: what a user sees (input rounding too).
Families (the renderer only ever sees modal coefficients; importers convert nodal data to the
same polynomial in float64 before upload, io/nektar.py and io/vtu.py):
- modified:     Nektar++ Modified coefficients, uniform in [-1, 1] (unit max |coefficient|);
- gll_lagrange: Nektar++ GLL_Lagrange hexahedra, nodal values uniform in [-1, 1] at the GLL
                nodes, converted by expansions.gll_lagrange_hex_to_modal; oracle: the tensor
                Lagrange interpolant through the GLL nodes, in float64;
- vtk_lagrange: VTK Lagrange hex / tet / wedge cells, nodal values uniform in [-1, 1] at VTK's
                equispaced nodes, converted by io/vtu.conversion_matrix; oracle: vtu.cell_basis
                (the cell's own nodal basis) in float64.
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..engine import expansions as ex
from ..engine import shapes
from ..engine.kernels import element as element_kernels

EVAL_SHAPES = [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR]
EVAL_FAMILIES = {"modified": EVAL_SHAPES, "gll_lagrange": [shapes.HEX],
                 "vtk_lagrange": [shapes.HEX, shapes.PRISM, shapes.TET]}


wp.set_module_options({"enable_backward": False})


@wp.kernel
def _eval_points_kernel(shape: int, modes: wp.vec3i, coeffs: wp.array(dtype=wp.float32),
                        xi: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = element_kernels.eval_element(shape, coeffs, 0, modes, xi[i])


def device_eval(shape, modes, coeffs32, xi32, device):
    """One element's float32 expansion at float32 reference points, on `device`, as the renderer evaluates it."""
    out = wp.zeros(len(xi32), dtype=wp.float32, device=device)
    wp.launch(_eval_points_kernel, dim=len(xi32), device=device,
              inputs=[int(shape), wp.vec3i(*map(int, modes)), wp.array(coeffs32, dtype=wp.float32, device=device),
                      wp.array(xi32, dtype=wp.vec3, device=device), out])
    return out.numpy().astype(np.float64)


def sample_points(shape, n, rng):
    """n uniform points inside the reference element, n // 4 near the collapse, the vertices."""
    pts = np.empty((0, 3))
    while len(pts) < n:
        p = rng.uniform(-1, 1, (4 * n, 3))
        pts = np.concatenate([pts, p[ex.inside(shape, p, tol=0.0)]])
    pts = pts[:n]
    near = np.empty((0, 3))
    if shape != shapes.HEX:
        m = max(n // 4, 4)
        eta = np.stack([rng.uniform(-1, 1, m), rng.uniform(-1, 1, m), 1.0 - 10.0 ** rng.uniform(-6, -2, m)], axis=1)
        if shape == shapes.TET:  # half of them near the first collapse's edge instead
            h = m // 2
            eta[:h, 1] = 1.0 - 10.0 ** rng.uniform(-6, -2, h)
            eta[:h, 2] = rng.uniform(-1, 1, h)
        near = ex.uncollapse(shape, eta)
    return pts, near, shapes.VERTICES[shape].copy()


def _lagrange_1d(nodes, x):
    """(M, n) Lagrange basis through `nodes` at x (product formula, float64)."""
    out = np.ones((x.size, nodes.size))
    for a in range(nodes.size):
        for b in range(nodes.size):
            if b != a:
                out[:, a] *= (x - nodes[b]) / (nodes[a] - nodes[b])
    return out


def family_field(family, shape, order, rng):
    """(modes, float64 modal coefficients, oracle(xi) -> float64 values)."""
    if family == "modified":
        modes = (order + 1,) * 3
        c = rng.uniform(-1.0, 1.0, ex.num_coeffs(shape, modes))
        return modes, c, lambda xi: ex.eval_modal(shape, modes, c, xi)
    if family == "gll_lagrange":
        n = order + 1
        modes = (n, n, n)
        nodal = rng.uniform(-1.0, 1.0, n**3)  # node (i, j, k), i fastest
        c = ex.gll_lagrange_hex_to_modal(modes, nodal)
        z = ex.gll_points(n)
        grid = nodal.reshape(n, n, n)  # [k, j, i]

        def oracle(xi):
            x = xi.reshape(-1, 3)
            L0, L1, L2 = (_lagrange_1d(z, x[:, d]) for d in range(3))
            return np.einsum("kji,pi,pj,pk->p", grid, L0, L1, L2).reshape(xi.shape[:-1])

        return modes, c, oracle
    if family == "vtk_lagrange":
        from ..io import vtu

        degs = (order,) * 3
        T = vtu.conversion_matrix(shape, "lagrange", degs)
        modes = vtu.modes_for(shape, degs)
        nodal = rng.uniform(-1.0, 1.0, T.shape[1])
        c = T @ nodal

        def oracle(xi):
            x = xi.reshape(-1, 3)
            return (vtu.cell_basis(shape, "lagrange", degs, vtu.xi_to_vtk(shape, x)) @ nodal).reshape(xi.shape[:-1])

        return modes, c, oracle
    raise ValueError(family)


def eval_compare(family, shape, order, device="cpu", points=2000, trials=3, seed=0) -> dict:
    """Max errors over `trials` random fields at `points` (+ near-collapse + vertex) points."""
    rng = np.random.default_rng([seed, order, shape, list(EVAL_FAMILIES).index(family)])
    worst = dict(max_abs_kernel=0.0, max_rel_kernel=0.0, max_abs=0.0, max_rel=0.0, max_rel_near_collapse=0.0,
                 nonfinite=0, nonfinite_near_collapse=0, min_range=np.inf, max_abs_coeff=0.0)
    for _ in range(trials):
        modes, c, oracle = family_field(family, shape, order, rng)
        pts, near, verts = sample_points(shape, points, rng)
        xi = np.concatenate([pts, verts, near])
        xi32 = xi.astype(np.float32)
        c32 = c.astype(np.float32)
        got = device_eval(shape, modes, c32, xi32, device)
        want_e2e = oracle(xi)
        want_k = ex.eval_modal(shape, modes, c32.astype(np.float64), xi32.astype(np.float64))
        m = len(pts) + len(verts)  # interior points and vertices first, near-collapse points after
        rng_f = float(want_e2e[:m].max() - want_e2e[:m].min())
        ek = np.abs(got - want_k)[:m]
        ee = np.abs(got - want_e2e)
        fin = np.isfinite(got)
        worst["nonfinite"] += int((~fin[:m]).sum())
        worst["nonfinite_near_collapse"] += int((~fin[m:]).sum())
        worst["max_abs_kernel"] = max(worst["max_abs_kernel"], float(np.nanmax(ek)))
        worst["max_rel_kernel"] = max(worst["max_rel_kernel"], float(np.nanmax(ek)) / rng_f)
        worst["max_abs"] = max(worst["max_abs"], float(np.nanmax(ee[:m])))
        worst["max_rel"] = max(worst["max_rel"], float(np.nanmax(ee[:m])) / rng_f)
        if len(near):
            worst["max_rel_near_collapse"] = max(worst["max_rel_near_collapse"], float(np.nanmax(ee[m:])) / rng_f)
        worst["min_range"] = min(worst["min_range"], rng_f)
        worst["max_abs_coeff"] = max(worst["max_abs_coeff"], float(np.abs(c).max()))
    worst.update(family=family, shape=shapes.NAMES[shape], order=order, modes=list(modes),
                 coefficients=int(len(c)), points_per_trial=int(len(xi)), trials=trials)
    return worst
