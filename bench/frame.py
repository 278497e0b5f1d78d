"""One frame, looked at closely: the paper-scale channel (curved and straight), at chosen image
sizes and method settings, with the kernel's counters per ray and the error against a
converged render of the same frame. The quick probe for performance work; bench/suite.py
is the full benchmark.

    python -m bench.frame --device cuda:0 --sizes 1920x1080,512x512 --out $OUT/frame.json
    python -m bench.frame --device cpu --paper 48,96 --sizes 64x48          (a small CPU check)

Each case: the build time, the first render (kernel compile or cache load), then per setting
the best of --repeats renders: seconds, element segments, curved locations, field and
restriction evaluations per ray, the empty/smooth/piecewise counts, and the max RGB error
against engine/reference.pixel_exact_reference (float64, split at tolerance 1e-9, no early
termination; --no-reference skips it).
"""
from __future__ import annotations

import argparse
import datetime
import json
import time

import numpy as np

from bench import common
from hovr_blender.audit import scenes  # framing and transfer functions: the suite's own
from hovr_blender.engine.reference import pixel_exact_reference  # every benchmark's reference
from hovr_blender.engine.view import RenderOptions

SETTINGS = {
    "split-1e-5": dict(method="split", tolerance=1e-5),
    "split-1e-3": dict(method="split", tolerance=1e-3),
    "classified-d400": dict(method="classified", h_div=400),
    "classified-d800": dict(method="classified", h_div=800),
    "classified-d1600": dict(method="classified", h_div=1600),
    "classified-d2400": dict(method="classified", h_div=2400),
    "trapezoid-d400": dict(method="trapezoid", h_div=400),
    "trapezoid-d3200": dict(method="trapezoid", h_div=3200),
}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--sizes", default="1920x1080")
    ap.add_argument("--paper", default="3400,7600", help="requested hexahedra,prisms")
    ap.add_argument("--variants", default="curved,straight")
    ap.add_argument("--settings", default="split-1e-5,split-1e-3,classified-d400,trapezoid-d400")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-reference", action="store_true")
    ap.add_argument("--profile", action="store_true", help="one more render per setting, each kernel waited for and timed")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    n_hex, n_prism = (int(v) for v in args.paper.split(","))
    out = {"device": args.device, "device_name": wp.get_device(args.device).name,
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "cases": []}
    from hovr_blender.io.paper_scale import paper_scale_mesh

    for variant in args.variants.split(","):
        t0 = time.perf_counter()
        mesh = paper_scale_mesh(n_hex, n_prism, curved=(variant == "curved"))
        build = time.perf_counter() - t0
        tf = scenes.tents(0.25, 1.55, scenes.COLORS, 3.0)
        r, first = common.compiled_renderer(mesh, args.device)
        lo, hi = scenes.mesh_bounds(mesh)
        diag = float(np.linalg.norm(hi - lo))
        print(f"{variant}: {mesh.num_elements} elements ({int(mesh.affine.sum())} affine), build {build:.1f} s, "
              f"upload {r.upload_seconds:.2f} s, first render {first:.1f} s", flush=True)
        for size in args.sizes.split(","):
            W, H = (int(v) for v in size.split("x"))
            cam = scenes.framing(mesh, W, H, direction=(0.3, -1.0, 1.2))
            case = {"variant": variant, "elements": mesh.num_elements, "affine": int(mesh.affine.sum()),
                    "size": [W, H], "build_seconds": build, "first_render_seconds": first, "runs": []}
            ref = None
            if not args.no_reference:
                ref, ref_stats = pixel_exact_reference(mesh, cam, tf, scenes.BACKGROUND, args.device, renderer=r)
                case["reference_seconds"] = ref_stats["render_seconds"]
            for name in args.settings.split(","):
                kw = dict(SETTINGS[name])
                if "h_div" in kw:
                    kw["h"] = diag / kw.pop("h_div")
                res = common.timed(r, cam, tf, RenderOptions(device=args.device, **kw), args.repeats)
                row = common.row_of(res, setting=name, **kw)
                px = W * H
                row.update(segments_per_ray=row["segments"] / px, locates_per_ray=row["curved_locates"] / px,
                           field_evals_per_ray=row["field_evaluations"] / px,
                           restriction_evals_per_ray=row["restriction_evaluations"] / px)
                row["rounds"] = res.stats.get("rounds")
                if args.profile:
                    prof = r.render(cam, tf, scenes.BACKGROUND, RenderOptions(device=args.device, **kw), profile=True)
                    row["kernel_seconds"] = prof.stats["kernel_seconds"]
                if ref is not None:
                    row["max_error"] = common.rgb_error(res.rgba, ref)
                    err = np.abs(res.rgba[..., :3].astype(np.float64) - ref[..., :3]).max(axis=-1)
                    worst = np.unravel_index(int(err.argmax()), err.shape)
                    row["worst_pixel"] = {"row": int(worst[0]), "col": int(worst[1]),
                                          "got": res.rgba[worst].tolist(), "reference": ref[worst].tolist()}
                    row["pixels_over"] = {f"{v:g}": int((err > v).sum()) for v in (1e-5, 1e-4, 1e-3, 1 / 255)}
                case["runs"].append(row)
                print(f"  {W}x{H} {name:16s} {row['seconds'] * 1e3:9.1f} ms  err {row.get('max_error', float('nan')):.1e}  "
                      f"seg/ray {row['segments_per_ray']:.2f} loc/ray {row['locates_per_ray']:.2f} "
                      f"field/ray {row['field_evals_per_ray']:.1f} restr/ray {row['restriction_evals_per_ray']:.1f} "
                      f"empty {row['empty_fraction']:.2f}" + (f" kernels {row['kernel_seconds']}" if args.profile else ""),
                      flush=True)
            out["cases"].append(case)
            if args.out:
                with open(args.out, "w") as fh:
                    json.dump(out, fh, indent=1, default=common.jsonable)
        del r


if __name__ == "__main__":
    main()
