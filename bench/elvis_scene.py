"""ElVis's Nektar++ volume-rendering regression scene, ours beside its two baselines.

Scene (docs/spec/formats.md, "ElVis test scene"): one hexahedron [-1,1]x[-1,1]x[-4,-2] read from
Hex_01_01_01_03Modes_x2_Offset3.{xml,fld}, p = x^2+y^2+z^2, 1024x1024, eye at the origin
looking down -z, three tent spikes. Writes ours (npy/png), the float64 reference, the
error against it, and a side-by-side figure with ElVis's baselines.

    python -m bench.elvis_scene --device cpu --out bench/results/elvis
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from bench import common
from hovr_blender.engine.image_io import to_png_bytes_rgba, write_png
from hovr_blender.engine.reference import reference_render
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.view import View
from hovr_blender.io import load_view_data

VIEW = str(common.REPO / "examples" / "elvis_sphere.json")
DATA = str(common.DATA / "nektar")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--out", default=str(common.RESULTS / "elvis"))
    ap.add_argument("--no-reference", action="store_true")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    view = View.load(VIEW)
    view.camera = type(view.camera)(**{**view.camera.__dict__, "width": args.size, "height": args.size})
    mesh = load_view_data(view)
    r = Renderer(mesh, args.device)
    summary = {"device": r.device, "size": args.size, "date": time.strftime("%Y-%m-%d"), "runs": {}}
    images = {}
    for name, opts in {"split": view.options.with_(method="split", tolerance=1e-6),
                       "classified_h0.01": view.options.with_(method="classified", h=0.01),
                       "trapezoid_h0.01": view.options.with_(method="trapezoid", h=0.01),
                       "riemann_h0.1": view.options.with_(method="riemann", h=0.1)}.items():
        r.render(view.camera, view.transfer_function, view.background, opts)  # warm
        res = r.render(view.camera, view.transfer_function, view.background, opts)
        images[name] = res.rgba
        summary["runs"][name] = {k: res.stats[k] for k in ("render_seconds", "samples_per_ray", "field_evaluations",
                                                            "restriction_evaluations")}
        np.save(os.path.join(args.out, f"ours_{name}.npy"), res.rgba) if name == "split" else None
        write_png(os.path.join(args.out, f"ours_{name}.png"), res.rgba, alpha=False)
        print(name, summary["runs"][name], flush=True)
    if not args.no_reference:
        t0 = time.perf_counter()
        ref, info = reference_render(mesh, view.camera, view.transfer_function, view.background)
        summary["reference_seconds"] = time.perf_counter() - t0
        summary["reference_error_estimate"] = info.get("error_estimate")
        for name, img in images.items():
            err = float(np.abs(img[..., :3].astype(np.float64) - ref[..., :3]).max())
            summary["runs"][name]["max_error_vs_reference"] = err
            summary["runs"][name]["pixel_exact"] = err < 1.0 / 255.0
            print(name, "max error vs reference", err, flush=True)
    with open(os.path.join(args.out, "elvis_summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    figure(images["split"], args.out)


def figure(ours, out):
    """Ours | ElVis h=0.1 | ElVis h=0.01, plus ours shown with ElVis's colour inversion."""
    from PIL import Image

    base = [os.path.join(DATA, f"NektarPlusPlusVolumeRenderSphere_Type1_h{h}Baseline.png") for h in (".1", ".01")]
    if not all(os.path.exists(b) for b in base):
        print("ElVis baselines not found; figure skipped")
        return
    ours_px = to_png_bytes_rgba(ours.astype(np.float64))[..., :3]
    tiles = [ours_px] + [np.asarray(Image.open(b).convert("RGB")) for b in base]
    h = min(t.shape[0] for t in tiles)
    tiles = [np.asarray(Image.fromarray(t).resize((h, h))) for t in tiles]
    Image.fromarray(np.concatenate(tiles, axis=1)).save(os.path.join(out, "elvis_side_by_side.png"))


if __name__ == "__main__":
    main()
