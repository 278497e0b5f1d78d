"""Figs. 5-6 of Nelson, Kirby, Haimes (2014) for hovr: error against step, samples and time.

Renders the paper's sphere (one hexahedron, f = x^2 + y^2 + z^2) with each method over a
sweep of h (and of the Gauss-Kronrod tolerance for `split`), measures the largest RGB
difference against the float64 reference, and writes JSON (plots: bench/plot_convergence.py).

    python -m bench.convergence --device cpu --size 96x72 --out bench/results/cpu
    python -m bench.convergence --device cuda:0 --size 1900x950 --out $OUT/cuda   (GPU machine)

Two transfer functions:
- "spikes": several narrow tent pairs (breakpoints inside most segments: the piecewise-smooth
  case, where the trapezoid rule sets the order);
- "smooth": one linear ramp over the whole field range (no breakpoint on any segment: the
  Gauss-Kronrod outer-integral case).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.reference import reference_render
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.builtin import sphere

CAMERA = {"projection": "perspective", "eye": [7.0, 5.5, 8.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 0.0, 1.0],
          "fov_y_deg": 40.0}
TRANSFER_FUNCTIONS = {
    "spikes": {
        "color": [[1.0, 1.0, 0.9, 0.2], [4.0, 0.2, 1.0, 0.3], [9.0, 0.1, 0.4, 1.0], [16.0, 1.0, 0.2, 0.6]],
        "density": [[1.5, 0.0], [2.0, 2.0], [2.5, 0.0], [4.5, 0.0], [5.0, 1.5], [5.5, 0.0],
                    [8.5, 0.0], [9.0, 1.0], [9.5, 0.0], [15.0, 0.0], [16.0, 0.4], [17.0, 0.0]],
    },
    "smooth": {
        "color": [[-1.0, 0.2, 0.4, 1.0], [20.0, 1.0, 0.6, 0.1]],
        "density": [[-1.0, 0.05], [20.0, 0.6]],
    },
}
H_VALUES = [0.4, 0.2, 0.1, 0.05, 0.025, 0.0125, 0.00625, 0.003125]
TOLERANCES = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7]
BACKGROUND = [0.02, 0.02, 0.03]


def fitted_order(hs, errs):
    hs, errs = np.asarray(hs, float), np.asarray(errs, float)
    ok = (errs > 5e-6) & np.isfinite(errs)  # float32 floor: fit only above it
    if ok.sum() < 3:
        return None
    return float(np.polyfit(np.log(hs[ok]), np.log(errs[ok]), 1)[0])


def timed_render(r, cam, tf, opts, repeats):
    best, res = np.inf, None
    for _ in range(repeats):
        res = r.render(cam, tf, BACKGROUND, opts)
        best = min(best, res.stats["render_seconds"])
    return res, best


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="96x72")
    ap.add_argument("--out", default="bench/results/cpu")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args(argv)
    W, H = (int(v) for v in args.size.split("x"))
    os.makedirs(args.out, exist_ok=True)
    cam = RayCamera.from_contract(CAMERA, W, H)
    mesh = sphere()
    r = Renderer(mesh, args.device)
    import warp as wp

    dev = wp.get_device(r.device)
    out = {"device": r.device, "device_name": getattr(dev, "name", str(dev)), "size": [W, H],
           "date": time.strftime("%Y-%m-%d"), "host": platform.node(), "warp": wp.__version__,
           "camera": CAMERA, "background": BACKGROUND, "cases": {}}
    for tf_name, tf_dict in TRANSFER_FUNCTIONS.items():
        tf = TransferFunction.from_contract(tf_dict)
        t0 = time.perf_counter()
        ref, info = reference_render(mesh, cam, tf, BACKGROUND)
        ref_s = time.perf_counter() - t0
        print(f"[{tf_name}] reference {W}x{H} in {ref_s:.1f} s, certified error {info.get('error_estimate')}", flush=True)
        case = {"transfer_function": tf_dict, "reference_seconds": ref_s, "reference_info":
                {k: v for k, v in info.items() if isinstance(v, (int, float, str))}, "runs": []}
        r.render(cam, tf, BACKGROUND, RenderOptions(method="riemann", h=0.5))  # compile/warm up
        sweeps = [(m, dict(h=h)) for m in ("riemann", "trapezoid", "classified") for h in H_VALUES]
        sweeps += [("classified", dict(h=0.0125, tolerance=t)) for t in TOLERANCES]
        sweeps += [("split", dict(tolerance=t)) for t in TOLERANCES]
        for method, kw in sweeps:
            opts = RenderOptions(method=method, min_transmittance=0.0, device=args.device, **kw)
            res, secs = timed_render(r, cam, tf, opts, args.repeats)
            err = float(np.abs(res.rgba[..., :3].astype(np.float64) - ref[..., :3]).max())
            row = {"method": method, **kw, "max_error": err, "seconds": secs,
                   "samples_per_ray": res.stats["samples_per_ray"],
                   "field_evaluations": res.stats["field_evaluations"],
                   "restriction_evaluations": res.stats["restriction_evaluations"],
                   "segments_empty": res.stats["segments_empty"], "segments_smooth": res.stats["segments_smooth"],
                   "segments_piecewise_smooth": res.stats["segments_piecewise_smooth"]}
            case["runs"].append(row)
            print(f"  {method:10s} {kw}  err {err:.3e}  {secs * 1e3:8.2f} ms  {row['samples_per_ray']:8.1f} samples/ray", flush=True)
        case["fitted_order"] = {
            m: fitted_order([x["h"] for x in case["runs"] if x["method"] == m and "tolerance" not in x],
                            [x["max_error"] for x in case["runs"] if x["method"] == m and "tolerance" not in x])
            for m in ("riemann", "trapezoid", "classified")}
        print(f"  fitted orders: {case['fitted_order']}", flush=True)
        out["cases"][tf_name] = case
    path = os.path.join(args.out, "convergence.json")
    with open(path, "w") as fh:
        json.dump(out, fh, indent=1)
    print("wrote", path)


if __name__ == "__main__":
    main()
