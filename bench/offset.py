"""Fields far from zero (issue 20, docs/methods.md "The field's frame"): the float32 image
against the float64 image of the same frame, with the field's frame (the renderer's default)
and without it (the field and transfer function handed to the kernels in their own units, as
before the frame existed), for data whose values sit far from zero:

- PyFR's Taylor-Green pressure (71.05 .. 72.01: offset / span about 74);
- a synthetic pressure in pascals, 101,325 +- 5 Pa, on the mixed cube (straight, all four shapes; offset / span
  about 10^4).

    python -m bench.offset --device cuda:0 --size 1920x1080 --out $OUT/offset.json

Each case gives, per method (split, classified), the max |float32 - float64| over the image's
RGBA with and without the frame, both renders' seconds (best of --repeats), the warnings the
renderer reported and the float32 render's options. Classified runs at its default: without h,
each piecewise-smooth segment's own step (until 2026-11-26 the default was the fixed h = 0.01).
"""
from __future__ import annotations

import argparse
import datetime
import time

import numpy as np

from bench import common
from bench.common import DATA
from hovr_blender.audit.scenes import BACKGROUND, COLORS, framing, pascals, tents  # the tests' scenes
from hovr_blender.engine import field_frame


def datasets():
    from hovr_blender.io.synthetic import mixed_cube

    out = {}
    pyfr = DATA / "vtu" / "pyfr_tgv_hexprism_p4_t4.vtu"
    if pyfr.exists():
        from hovr_blender.io.vtu import read_vtu

        out["pyfr_tgv_pressure"] = read_vtu(str(pyfr), "Pressure")
    else:
        print(f"pyfr_tgv_pressure: skipped, missing {pyfr}", flush=True)
    out["pascals_mixed_cube"] = mixed_cube(4, 5, pascals)
    return out


def scene(mesh, W, H):
    """(transfer function, camera, value band): three tents over the field's 2..98 % band, an optical
    depth of 8 across the data's half diagonal, the tests' framing."""
    lo, hi = (float(v) for v in np.percentile(mesh.field_samples(4), [2, 98]))
    tf = tents(lo, hi, COLORS, 8.0 / (0.5 * float(np.linalg.norm(np.ptp(mesh.vertices.reshape(-1, 3), axis=0)))))
    return tf, framing(mesh, W, H), (lo, hi)


def own_units(tfs, data_ranges):
    """field_frame.frame's stand-in for the baseline: the identity frame (one volume)."""
    tfs = list(tfs)
    return field_frame.FieldFrame(np.ones(1), np.zeros(1)), tfs[0]


def best(renderer, camera, tf, opts, repeats):
    secs, res = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = renderer.render(camera, tf, BACKGROUND, opts)
        secs.append(time.perf_counter() - t0)
    return res, min(secs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    report = {"device": args.device, "device_name": wp.get_device(args.device).name, "size": [W, H],
              "date": datetime.date.today().isoformat(), "cases": {}}
    frame = field_frame.frame
    for name, mesh in datasets().items():
        tf, camera, (lo, hi) = scene(mesh, W, H)
        renderer = Renderer(mesh, args.device)
        case = {"elements": int(mesh.num_elements), "value_band": [lo, hi], "offset_over_span": 0.5 * (lo + hi) / (hi - lo)}
        for method in ("split", "classified"):
            row = {}
            for precision in ("float64", "float32"):
                opts = RenderOptions(method=method, precision=precision, tolerance=1e-5 if precision == "float32" else 1e-9,
                                     min_transmittance=0.0, device=args.device)
                renderer.render(camera, tf, BACKGROUND, opts)  # compile, upload
                res, secs = best(renderer, camera, tf, opts, args.repeats)
                row[precision] = {"seconds": secs, "rgba": res.rgba.astype(np.float64), "warnings": res.stats["warnings"]}
                if precision == "float32":
                    field_frame.frame = own_units
                    try:
                        renderer.render(camera, tf, BACKGROUND, opts)
                        base, base_secs = best(renderer, camera, tf, opts, args.repeats)
                    finally:
                        field_frame.frame = frame
                    row["float32_own_units"] = {"seconds": base_secs, "rgba": base.rgba.astype(np.float64)}
            ref = row["float64"]["rgba"]
            alpha = float(ref[..., 3].max())
            case[method] = {
                "max_alpha": alpha,
                "max_error_float32_frame": float(np.abs(row["float32"]["rgba"] - ref).max()),
                "max_error_float32_own_units": float(np.abs(row["float32_own_units"]["rgba"] - ref).max()),
                "seconds_float32_frame": row["float32"]["seconds"],
                "seconds_float32_own_units": row["float32_own_units"]["seconds"],
                "seconds_float64": row["float64"]["seconds"],
                "warnings_float32": row["float32"]["warnings"],
                "options_float32": opts.as_dict()}
            print(f"{name} {method}: float32 vs float64 max {case[method]['max_error_float32_frame']:.2e} with the "
                  f"frame, {case[method]['max_error_float32_own_units']:.2e} in its own units; "
                  f"{row['float32']['seconds']:.3f} / {row['float32_own_units']['seconds']:.3f} s", flush=True)
        report["cases"][name] = case
    common.write_report(report, args.out)


if __name__ == "__main__":
    main()
