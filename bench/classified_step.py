"""classified's step (issue 20, docs/methods.md "classified's step"): error against the exact
image and cost, for the paper's fixed step h (absolute, and relative to the data's box diagonal)
against the step each piecewise-smooth segment chooses without h (kernels/quadrature.auto_steps),
with split beside them.

    python -m bench.classified_step --size 192x108 --out bench/results/cpu/classified_step.json
    python -m bench.classified_step --size 1920x1080 --rows 0:216 --datasets pyfr_tgv_pressure --only auto --repeats 1
    python -m bench.classified_step --size 320x180 --datasets paper_scale --only auto --step-errors 1e-3,5e-4,2.5e-4 --repeats 1

Scenes: bench/offset.py's (PyFR's Taylor-Green pressure; pascals on the curved mixed cube),
bench/convergence.py's sphere with its spikes, and the paper-scale channel in the audit's oblique
view with its transfer function (hovr_blender/audit/datasets.py; rays through seven or eight curved elements).
--step-errors runs the "auto" setting at each of these per-segment error bounds instead of the
default (engine/view.AUTO_STEP_ERROR). The exact image is split in float64 at tolerance
1e-9 without early termination (engine/reference.pixel_exact_reference's settings); every render
here also runs to T = 0. --rows renders only those rows of the image (a full-size image in bands,
one process each); --only picks the runs (fixed, diagonal, auto, split). Per run: max |image - exact| over RGBA, pixels above 1e-3, samples per ray
(element and restriction evaluations), seconds (best of --repeats; the CPU is shared, so compare
samples first).
"""
from __future__ import annotations

import argparse
import datetime
import time

import numpy as np

from bench import common, convergence  # convergence: the paper's sphere scene
from bench import offset  # issue 20's scenes
from hovr_blender.audit import datasets  # the paper-scale channel's view and transfer function
from hovr_blender.audit.scenes import BACKGROUND

FIXED_H = [0.01, 0.005, 0.0025]
DIAGONAL_DIVISIONS = [1000, 2000, 4000]


def scenes(W, H, names):
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.transfer_function import TransferFunction
    from hovr_blender.io.builtin import sphere

    out = {}
    for name, mesh in offset.datasets().items():
        tf, camera, _ = offset.scene(mesh, W, H)
        out[name] = (mesh, tf, camera, BACKGROUND)
    out["sphere_spikes"] = (sphere(), TransferFunction.from_contract(convergence.TRANSFER_FUNCTIONS["spikes"]),
                            RayCamera.from_contract(convergence.CAMERA, W, H), convergence.BACKGROUND)
    if "paper_scale" in names:  # built only when asked for (seconds)
        mesh, _ = datasets.load("paper_scale")
        out["paper_scale"] = (mesh, datasets.transfer_function(mesh),
                              RayCamera.from_contract(datasets.views(mesh)["oblique"], W, H), np.zeros(3))
    return {k: v for k, v in out.items() if not names or k in names}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="192x108")
    ap.add_argument("--rows", default=None, help="first:end rows of the image to render (default all)")
    ap.add_argument("--datasets", default="", help="comma-separated (default all)")
    ap.add_argument("--only", default="fixed,diagonal,auto,split", help="which runs (comma-separated)")
    ap.add_argument("--repeats", type=int, default=2, help="timed renders per run (beyond 1: after one untimed)")
    ap.add_argument("--step-errors", default="", help="per-segment error bounds for the auto run (default: AUTO_STEP_ERROR)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    from hovr_blender.engine import launch_args
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import AUTO_STEP_ERROR, RenderOptions

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    rows = tuple(int(v) for v in args.rows.split(":")) if args.rows else (0, H)
    commit = common.git("rev-parse", "--short", "HEAD")
    report = {"device": args.device, "device_name": wp.get_device(args.device).name, "size": [W, H], "rows": list(rows),
              "date": datetime.date.today().isoformat(), "commit": commit, "auto_step_error": AUTO_STEP_ERROR,
              "cases": {}}
    for name, (mesh, tf, camera, bg) in scenes(W, H, args.datasets.split(",") if args.datasets else []).items():
        renderer = Renderer(mesh, args.device)

        def render(**kw):
            opts = RenderOptions(min_transmittance=0.0, device=args.device, **kw)
            if args.repeats > 1:
                renderer.render(camera, tf, bg, opts, rows=rows)  # compile, upload
            secs = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                res = renderer.render(camera, tf, bg, opts, rows=rows)
                secs.append(time.perf_counter() - t0)
            return res.rgba.astype(np.float64), res.stats, min(secs)  # the rows asked for only

        exact_opts = RenderOptions.pixel_exact(args.device)
        exact, _, exact_s = render(method=exact_opts.method, tolerance=exact_opts.tolerance, precision=exact_opts.precision)
        diag = renderer.data_diagonal
        only = args.only.split(",")
        runs = [("classified", {"h": h}, f"h = {h:g}") for h in FIXED_H if "fixed" in only]
        runs += [("classified", {"h": diag / n}, f"h = diagonal / {n}") for n in DIAGONAL_DIVISIONS if "diagonal" in only]
        bounds = [float(v) for v in args.step_errors.split(",")] if args.step_errors else [AUTO_STEP_ERROR]
        runs += [("classified", {"step_error": e}, f"no h (each segment's own step, {e:g} a segment)")
                 for e in bounds if "auto" in only]
        runs += [("split", {"tolerance": 1e-5}, "tolerance 1e-5")] * ("split" in only)
        case = {"elements": int(mesh.num_elements), "diagonal": diag, "exact_seconds": exact_s,
                "max_alpha": float(exact[..., 3].max()), "runs": []}
        for method, kw, label in runs:
            row = {"method": method, "setting": label, **kw}
            imgs = {}
            opts_kw = {k: v for k, v in kw.items() if k != "step_error"}
            # the renderer reads the bound from launch_args when it sets up a render's quadrature
            launch_args.AUTO_STEP_ERROR = kw.get("step_error", AUTO_STEP_ERROR)
            for precision in ("float32", "float64"):
                img, stats, secs = render(method=method, precision=precision, **opts_kw)
                imgs[precision] = img
                err = np.abs(img - exact).max(axis=-1)
                j, i = np.unravel_index(int(np.argmax(err)), err.shape)
                row[precision] = {"max_error": float(err.max()), "worst_pixel": [int(j) + rows[0], int(i)],
                                  "pixels_over_1e-3": int((err > 1e-3).sum()),
                                  "samples_per_ray": float(stats["samples_per_ray"]), "seconds": secs}
            row["float32_vs_float64"] = float(np.abs(imgs["float32"] - imgs["float64"]).max())
            case["runs"].append(row)
            print(f"{name:20s} {method:10s} {label:32s} " + "  ".join(
                f"{p}: {row[p]['max_error']:.2e} ({row[p]['pixels_over_1e-3']} > 1e-3), "
                f"{row[p]['samples_per_ray']:.0f} samples/ray, {row[p]['seconds']:.2f} s" for p in ("float32", "float64"))
                + f"  f32-f64 {row['float32_vs_float64']:.2e}", flush=True)
        report["cases"][name] = case
    common.write_report(report, args.out)


if __name__ == "__main__":
    main()
