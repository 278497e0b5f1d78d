"""Evaluation error of the device expansions (float32 Warp, kernels/element.py) against the
float64 numpy oracle (core/expansions.py), every shape x order 1..14.

For each (family, shape, order) a few random fields are drawn, evaluated by a small Warp
kernel that calls element.eval_element (the renderer's own evaluator) at random reference
points inside the element plus points near the collapsed vertex/edges (distance 1e-6..1e-2
in the collapsed coordinate) and the vertices, and compared with the oracle:

- kernel error: the oracle at exactly the kernel's float32 inputs (rounded coefficients and
  points): the error of the float32 arithmetic alone;
- end-to-end error: the oracle at the float64 inputs: what a user sees (input rounding too).

Errors are given as max |error| and max |error| / (field range over the sampled points).

Families (the renderer only ever sees modal coefficients; importers convert nodal data to
the same polynomial in float64 before upload, io/nektar.py and io/vtu.py):
- modified:     Nektar++ Modified coefficients, uniform in [-1, 1] (unit max |coefficient|);
- gll_lagrange: Nektar++ GLL_Lagrange hexahedra, nodal values uniform in [-1, 1] at the GLL
                nodes, converted by expansions.gll_lagrange_hex_to_modal; oracle: the tensor
                Lagrange interpolant through the GLL nodes, in float64;
- vtk_lagrange: VTK Lagrange hex / tet / wedge cells, nodal values uniform in [-1, 1] at VTK's
                equispaced nodes, converted by io/vtu.conversion_matrix; oracle: vtu.cell_basis
                (the cell's own nodal basis) in float64.

    python bench/eval_table.py --device cpu --out bench/results/eval_table.json
    python bench/eval_table.py --device cuda:0 --out $OUT/eval_table_cuda.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import warp as wp  # noqa: E402

from hovr_blender.core import expansions as ex  # noqa: E402
from hovr_blender.core import shapes  # noqa: E402
from hovr_blender.core.expansions import gll_points  # noqa: E402
from hovr_blender.core.kernels import element as el_k  # noqa: E402

SHAPES = [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR]
FAMILIES = {"modified": SHAPES, "gll_lagrange": [shapes.HEX], "vtk_lagrange": [shapes.HEX, shapes.PRISM, shapes.TET]}
ORDERS = list(range(1, 15))

wp.set_module_options({"enable_backward": False})


@wp.kernel
def eval_points_kernel(shape: int, modes: wp.vec3i, coeffs: wp.array(dtype=wp.float32),
                       xi: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = el_k.eval_element(shape, coeffs, 0, modes, xi[i])


def device_eval(shape, modes, coeffs32, xi32, device):
    out = wp.zeros(len(xi32), dtype=wp.float32, device=device)
    wp.launch(eval_points_kernel, dim=len(xi32), device=device,
              inputs=[int(shape), wp.vec3i(*map(int, modes)), wp.array(coeffs32, dtype=wp.float32, device=device),
                      wp.array(xi32, dtype=wp.vec3, device=device), out])
    return out.numpy().astype(np.float64)


# ---------------------------------------------------------------------------- points


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
        near = ex._uncollapse(shape, eta)
    return pts, near, shapes.VERTICES[shape].copy()


# ---------------------------------------------------------------------------- families


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
        z = gll_points(n)
        grid = nodal.reshape(n, n, n)  # [k, j, i]

        def oracle(xi):
            x = xi.reshape(-1, 3)
            L0, L1, L2 = (_lagrange_1d(z, x[:, d]) for d in range(3))
            return np.einsum("kji,pi,pj,pk->p", grid, L0, L1, L2).reshape(xi.shape[:-1])

        return modes, c, oracle
    if family == "vtk_lagrange":
        from hovr_blender.io import vtu

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


# ---------------------------------------------------------------------------- comparison


def compare(family, shape, order, device="cpu", points=2000, trials=3, seed=0):
    """Max errors over `trials` random fields at `points` (+ near-collapse + vertex) points."""
    rng = np.random.default_rng([seed, order, shape, list(FAMILIES).index(family)])
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


def markdown(rows, key="max_rel", fmt="{:.1e}"):
    cols = [(f, s) for f, shapes in FAMILIES.items() for s in shapes]
    head = "| order | " + " | ".join(f"{f} {shapes.NAMES[s][:4]}" for f, s in cols) + " |"
    out = [head, "|" + "---|" * (len(cols) + 1)]
    look = {(r["family"], r["shape"], r["order"]): r for r in rows}
    for o in sorted({r["order"] for r in rows}):
        cells = []
        for f, s in cols:
            r = look.get((f, shapes.NAMES[s], o))
            cells.append("" if r is None else fmt.format(r[key]))
        out.append(f"| {o} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--max-order", type=int, default=14)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "eval_table.json"))
    args = ap.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = str(wp.get_device(args.device))
    rows = []
    t0 = time.perf_counter()
    for fam in args.families.split(","):
        for shape in FAMILIES[fam]:
            for order in range(1, args.max_order + 1):
                r = compare(fam, shape, order, device, args.points, args.trials)
                rows.append(r)
                print(f"{fam:13s} {r['shape']:12s} order {order:2d}: max abs {r['max_abs']:.2e} rel {r['max_rel']:.2e} "
                      f"(kernel {r['max_rel_kernel']:.2e}; near collapse {r['max_rel_near_collapse']:.2e}, "
                      f"nonfinite {r['nonfinite']} + {r['nonfinite_near_collapse']} near collapse)", flush=True)
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=os.path.dirname(os.path.abspath(__file__))).stdout.strip()
    except OSError:
        commit = ""
    cpu = platform.processor() or platform.machine()
    result = {
        "what": "float32 device expansions (kernels/element.eval_element) vs float64 numpy oracle",
        "date": datetime.date.today().isoformat(),
        "device": device if device != "cpu" else f"cpu ({cpu})",
        "device_name": wp.get_device(device).name,
        "warp": wp.config.version,
        "commit": commit,
        "command": "python bench/eval_table.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "seconds": round(time.perf_counter() - t0, 1),
        "rows": rows,
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=1)
    print(markdown(rows))
    print(markdown(rows, "max_rel_near_collapse"))
    print("written", args.out)


if __name__ == "__main__":
    main()
