"""The isosurface tangency band at full size (issue 36, contract §7 "Near tangency"): the sphere
scene (audit/scenes.ball_mesh: f = |x - C|^2 on curved elements of all four shapes, the level
R^2 at opacity 0.5, no volume) rendered from the framing view in float32 and float64, every pixel
against its exact ray (audit/isosurface_band.py): outside the band a ray that misses draws
nothing, one that crosses meets the sphere twice, its depth at the first crossing within the
stated tolerance. One device call:

    python -m bench.isosurface_band --device cuda:0 --size 1920x1080 --out $OUT/isosurface_band.json
    python -m bench.isosurface_band --device cpu --size 1920x1080 --rows 325:843 --out /tmp/band.json
        (the rows the sphere covers, on the CPU: minutes)

Prints per precision the pixels outside the band (0 is the claim) and the band measured (the
widest |delta| where a pixel inside it came out otherwise than the exact ray); the JSON has the
counts and every failing pixel with its ray. Exit status 1 where any pixel lies outside the band.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

import numpy as np

from bench import common
from hovr_blender.audit import isosurface_band, scenes

ALPHA = 0.5  # the level's opacity: a ray that crosses the sphere shows 1 - (1 - ALPHA)^2


def clear_tf():
    """No volume: colour black, density 0 (its frame is the identity: the band is in f's units)."""
    from hovr_blender.engine.transfer_function import TransferFunction

    return TransferFunction(np.array([0.0, 1.0]), np.zeros((2, 3)), np.array([0.0, 1.0]), np.zeros(2))


def run(device: str, width: int, height: int, precisions, rows=None) -> dict:
    from hovr_blender.engine.isosurfaces import Isosurface, Surfaces
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    mesh = scenes.ball_mesh()
    cam = scenes.framing(mesh, width, height)
    level = scenes.BALL_RADIUS ** 2
    surfaces = Surfaces((Isosurface(level, (1.0, 1.0, 1.0), ALPHA),))
    r = Renderer(mesh, device)
    o, d = cam.rays()
    centre, radius = scenes.BALL_CENTRE, scenes.BALL_RADIUS
    map_error = isosurface_band.device_map_error(mesh, isosurface_band.near_sphere(centre, radius))
    row0, row1 = rows if rows is not None else (0, height)
    out = {}
    for prec in precisions:
        res = r.render(cam, clear_tf(), np.zeros(3), RenderOptions(precision=prec, device=device), surfaces=surfaces,
                       rows=rows)
        eps = isosurface_band.level_rounding(r, prec, level, 2.0 * radius, map_error)
        got = isosurface_band.classify(res.rgba, res.depth, o[row0:row1], d[row0:row1], centre, radius, eps, prec,
                                       ALPHA)
        for f in got["failures"]:
            f["pixel"][1] += row0
        got.update(eps=eps, device_map_error=map_error, render_seconds=res.stats["render_seconds"])
        out[prec] = got
        print(f"{prec}: {got['outside_band']} pixels outside the band (eta <= {got['eta_max']:.2e}): "
              f"{got['drawn_outside_band']} drawn off the sphere, {got['wrong_meetings']} not meeting it twice, "
              f"{got['depth_beyond_tolerance']} deeper than the tolerance; in the band {got['in_band']} pixels, "
              f"{got['in_band_disagreeing']} otherwise than exact (|delta| <= {got['measured_band']:.2e})", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--precisions", default="float32,float64")
    ap.add_argument("--rows", default=None, help="first:end, the image rows to render (default all)")
    ap.add_argument("--max-memory", default="64G", help="the memory limit for the run (a 1920x1080 tile's buffers)")
    ap.add_argument("--out", required=True, help="the JSON to write")
    args = ap.parse_args(argv)
    from hovr_blender.engine import limits

    W, H = (int(v) for v in args.size.lower().split("x"))
    rows = None if args.rows is None else tuple(int(v) for v in args.rows.split(":"))
    report = {"bench": "isosurface_band", "date": datetime.date.today().isoformat(), "device": args.device,
              "size": [W, H], "rows": rows, "commit": common.git("rev-parse", "HEAD"), "command": common.command_line()}
    lim = limits.ResourceLimits(limits.parse_size(args.max_memory), limits.current().max_samples_per_ray)
    with limits.using(lim):
        report["precisions"] = run(args.device, W, H, args.precisions.split(","), rows)
    Path(args.out).write_text(json.dumps(report, indent=1, default=common.jsonable))
    return 1 if any(v["outside_band"] for v in report["precisions"].values()) else 0


if __name__ == "__main__":
    sys.exit(main())
