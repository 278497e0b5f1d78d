"""PyFR's pressure (issue 20) against the independent reference at its worst pixels.

    python -m bench.offset_audit --size 480x270 --out bench/results/cpu/offset_audit.json

bench/offset.py's scene of PyFR's Taylor-Green pressure (three tents over its 2..98 % band,
optical depth 8 across the half diagonal) is rendered with split and classified, each in float32
and float64 at bench/offset.py's settings (tolerance 1e-5 in float32, 1e-9 in float64, no early
termination; classified without h). The pixels checked: the --worst with the largest
|classified - split float64| (either precision), the --worst with the largest |float32 - float64|
(either method) and a seeded --sample of others where the volume shows. Each is integrated by
hovr_blender/audit's independent reference (VTK's cells read from the file, float64, its own
rays from the contract's camera, tolerance 1e-10, about a second a pixel), and the four renders'
errors against it are reported, with the reference's own error estimate.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench import common, offset  # offset: the scene
from hovr_blender.audit.scenes import BACKGROUND
from hovr_blender.audit.scenes import framing_contract  # the scene's camera as the contract writes it

PYFR = common.DATA / "vtu" / "pyfr_tgv_hexprism_p4_t4.vtu"
RENDERS = [(method, precision) for method in ("split", "classified") for precision in ("float32", "float64")]
WRONG = 1e-3


def top(err, k, exclude=()):
    """The k pixels (j, i) of largest err, none of `exclude`."""
    order = np.argsort(-err, axis=None)
    out = []
    for flat in order:
        p = tuple(int(v) for v in np.unravel_index(flat, err.shape))
        if p not in exclude:
            out.append(p)
        if len(out) == k:
            break
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--worst", type=int, default=20)
    ap.add_argument("--sample", type=int, default=10)
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if not PYFR.exists():
        sys.exit(f"missing {PYFR}")
    import warp as wp

    from hovr_blender.audit import vtk_reference as R
    from hovr_blender.audit import vtk_volume
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.io.vtu import read_vtu

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    mesh = read_vtu(str(PYFR), "Pressure")
    tf, _, band = offset.scene(mesh, W, H)
    contract = framing_contract(mesh)
    camera = RayCamera.from_contract(contract, W, H)
    renderer = Renderer(mesh, "cpu")
    images, seconds = {}, {}
    for method, precision in RENDERS:
        opts = RenderOptions(method=method, precision=precision, tolerance=1e-5 if precision == "float32" else 1e-9,
                             min_transmittance=0.0)
        t0 = time.perf_counter()
        images[method, precision] = renderer.render(camera, tf, BACKGROUND, opts).rgba.astype(np.float64)
        seconds[f"{method} {precision}"] = time.perf_counter() - t0
    exact = images["split", "float64"]
    step_gap = np.maximum(*(np.abs(images["classified", p] - exact).max(axis=-1) for p in ("float32", "float64")))
    precision_gap = np.maximum(*(np.abs(images[m, "float32"] - images[m, "float64"]).max(axis=-1)
                                 for m in ("split", "classified")))
    picked = {p: "classified vs split" for p in top(step_gap, args.worst)}
    picked.update({p: "float32 vs float64" for p in top(precision_gap, args.worst, picked)})
    visible = np.argwhere(exact[..., 3] > 0.002)
    rng = np.random.default_rng(args.seed)
    for k in rng.choice(len(visible), min(args.sample, len(visible)), replace=False):
        p = tuple(int(v) for v in visible[k])
        picked.setdefault(p, "sample")

    grid = vtk_volume.read_vtu(str(PYFR), "Pressure")
    ref = R.IndependentReference(grid, tf.color_s, tf.color_rgb, tf.density_s, tf.density_tau, tol=1e-10)
    rows = []
    t_ref = time.perf_counter()
    for (j, i), why in picked.items():
        o, d = R.contract_ray(contract, W, H, i, j)
        r = ref.pixel(o, d, BACKGROUND)
        row = {"i": i, "j": j, "why": why, "reference": r.rgba.tolist(), "reference_error": r.error,
               "classified_vs_split": float(step_gap[j, i]), "float32_vs_float64": float(precision_gap[j, i])}
        for method, precision in RENDERS:
            row[f"error_{method}_{precision}"] = float(np.abs(images[method, precision][j, i] - r.rgba).max())
        rows.append(row)
        print(f"({i:3d}, {j:3d}) {why:20s} " + " ".join(f"{m[:5]} {p[5:]}: {row[f'error_{m}_{p}']:.1e}"
                                                        for m, p in RENDERS) + f"  ref err {r.error:.0e}", flush=True)
    commit = common.git("rev-parse", "--short", "HEAD")
    summary = {f"max_error_{m}_{p}": max(r[f"error_{m}_{p}"] for r in rows) for m, p in RENDERS}
    summary.update({f"wrong_{m}_{p}": sum(r[f"error_{m}_{p}"] > WRONG for r in rows) for m, p in RENDERS})
    report = {"date": datetime.date.today().isoformat(), "commit": commit, "device": "cpu", "size": [W, H],
              "data": str(PYFR.name), "value_band": list(band), "camera": contract,
              "render_seconds": seconds, "reference_seconds": time.perf_counter() - t_ref,
              "image_max_classified_vs_split": float(step_gap.max()), "image_max_float32_vs_float64": float(precision_gap.max()),
              "checked": len(rows), "max_reference_error": max(r["reference_error"] for r in rows), **summary, "pixels": rows}
    print(json.dumps({k: v for k, v in report.items() if k != "pixels"}, indent=1), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
