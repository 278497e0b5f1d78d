"""Where float32 and the float64 reference disagree on one of the suite's datasets: the count of
pixels over 1e-3 and 1e-2 and the worst pixels (row, column, error, float32 and float64 RGBA),
per setting. The probe that found the search's located-list bug (commit 2a0230f); the suite's
methods section only reports the largest error.

    python -m bench.precision_gap --device cuda:0 --dataset curved_mixed --sizes 1920x1080
    python -m bench.precision_gap --device cpu --config small --sizes 64x48         (CPU check)
"""
from __future__ import annotations

import argparse
import datetime
import json

import numpy as np

from bench import common, suite
from hovr_blender.audit import scenes
from hovr_blender.engine.reference import pixel_exact_reference
from hovr_blender.engine.view import RenderOptions


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--dataset", default="curved_mixed", choices=["sphere", "curved_mixed", "paper_scale"])
    ap.add_argument("--config", default="full", choices=sorted(suite.CONFIG))
    ap.add_argument("--sizes", default="1920x1080")
    ap.add_argument("--tolerances", default="1e-2,1e-5")
    ap.add_argument("--worst", type=int, default=8)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    mesh, tf, camera, desc = suite.dataset(args.dataset, suite.CONFIG[args.config])
    r, _ = common.compiled_renderer(mesh, args.device)
    out = {"device": args.device, "device_name": wp.get_device(args.device).name,
           "date": datetime.datetime.now().isoformat(timespec="seconds"), "git_commit": common.git("rev-parse", "HEAD"),
           "command": common.command_line(),
           "dataset": desc, "cases": []}
    for size in args.sizes.split(","):
        W, H = (int(v) for v in size.split("x"))
        cam = camera(W, H)
        ref, _ = pixel_exact_reference(mesh, cam, tf, scenes.BACKGROUND, args.device, renderer=r)
        for tol in (float(v) for v in args.tolerances.split(",")):
            res = r.render(cam, tf, scenes.BACKGROUND, RenderOptions(method="split", tolerance=tol, device=args.device))
            got = res.rgba.astype(np.float64)
            err = np.abs(got[..., :3] - ref[..., :3]).max(axis=-1)
            order = np.argsort(err.ravel())[::-1][: args.worst]
            case = {"size": [W, H], "tolerance": tol, "max_error": float(err.max()),
                    "pixels_over_1e-3": int((err > 1e-3).sum()), "pixels_over_1e-2": int((err > 1e-2).sum()),
                    "worst": [{"row": int(i // W), "col": int(i % W), "error": float(err.ravel()[i]),
                               "float32": got.reshape(-1, 4)[i].tolist(), "float64": ref.reshape(-1, 4)[i].tolist()}
                              for i in order]}
            out["cases"].append(case)
            print(f"{W}x{H} split {tol:g}: max {case['max_error']:.2e}, {case['pixels_over_1e-3']} pixels over 1e-3, "
                  f"{case['pixels_over_1e-2']} over 1e-2; worst at row {case['worst'][0]['row']}, col "
                  f"{case['worst'][0]['col']}", flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
