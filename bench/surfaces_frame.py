"""Isosurface and plane frames against the volume frame of the same data (issue 31): per dataset,
the audit's volume render (three density tents, the audit's oblique view), an isosurface frame
(one opaque level at the field's 60th percentile, no volume), a plane frame (a plane through the
data's centre coloured by the field, no volume) and both surfaces over the volume; and, for the
CFD datasets, the derived-field frames (contract §8: Q of the velocity, sampled exactly at each
sample point): its volume (the audit's tents over Q's range) and the Q isosurface coloured by the
speed, no volume (audit/datasets.q_level's level). Each timed in one command on one device.

    python -m bench.surfaces_frame --device cuda:0 --size 1920x1080 --out $OUT/surfaces_frame.json
    python -m bench.surfaces_frame --device cpu --size 64x36 --datasets mfem_fichera --repeats 1 \\
        --out /tmp/surfaces_frame.json   (a small CPU check)

Per dataset and frame: render_seconds (the best of --repeats after a warm-up call: the renderer's
own timer, first launch to synchronize), wall_seconds (the same call timed around it), and the
per-ray counters of the stats (field and restriction evaluations, segments and their classes):
the deterministic work the timings come from. The isosurface and plane frames use the method the
volume frame uses (--method, default classified without a fixed step). The memory limit is raised
to --max-memory (default 64G) for the run (one 1920x1080 launch tile's buffers exceed the default).
A dataset whose file is missing is skipped and recorded so; the JSON is written after each dataset.
"""
from __future__ import annotations

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import numpy as np

from bench import common
from hovr_blender.audit import datasets, scenes  # the audit's datasets, views, transfer functions

DEFAULT_DATASETS = "ngsolve_ball,mfem_fichera,pyfr_tgv,hump3D"
COUNTERS = ("field_evaluations", "restriction_evaluations", "samples_per_ray", "segments", "segments_empty",
            "segments_smooth", "segments_piecewise_smooth")


def frames(mesh, tf):
    """{name: (transfer function, Surfaces)} of the four frames (the last: a half-opaque level and
    the plane clipping the volume above it, over the volume)."""
    from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, Surfaces
    from hovr_blender.engine.transfer_function import TransferFunction

    samples = mesh.field_samples(4)
    level = float(np.percentile(samples, 60))
    none = TransferFunction(tf.color_s, tf.color_rgb, tf.density_s, np.zeros_like(tf.density_tau))
    lo, hi = mesh.bounds()
    plane = CutPlane.through(0.5 * (lo.min(axis=0) + hi.max(axis=0)), (0.2, 0.3, 1.0))
    iso = Isosurface(level, (1.0, 0.85, 0.4), 1.0)
    clipping = CutPlane(plane.normal, plane.offset, 1.0, clip=1)
    return {"volume": (tf, Surfaces()), "isosurface": (none, Surfaces((iso,))), "plane": (none, Surfaces((), (plane,))),
            "volume_isosurface_clipping_plane": (tf, Surfaces((Isosurface(level, (1.0, 0.85, 0.4), 0.5),), (clipping,)))}


def derived_frames(mesh, name: str) -> dict:
    """{name: (transfer function, Surfaces)}: Q's volume, and its isosurface coloured by the speed."""
    from hovr_blender.engine.isosurfaces import Isosurface, Surfaces
    from hovr_blender.engine.transfer_function import TransferFunction

    tf = datasets.transfer_function(mesh)
    none = TransferFunction(tf.color_s, tf.color_rgb, tf.density_s, np.zeros_like(tf.density_tau))
    iso = Isosurface(datasets.q_level(mesh, name), (1.0, 1.0, 1.0), 1.0, color_by="speed",
                     color_ramp=datasets.speed_ramp(mesh))
    return {"derived_volume": (tf, Surfaces()), "derived_isosurface": (none, Surfaces((iso,)))}


def timed(r, cam, tf, surfaces, opts, repeats: int) -> dict:
    bg = scenes.BACKGROUND
    res = r.render(cam, tf, bg, opts, surfaces=surfaces)  # warm-up (compiles on first use)
    times, walls = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = r.render(cam, tf, bg, opts, surfaces=surfaces)
        walls.append(time.perf_counter() - t0)
        times.append(res.stats["render_seconds"])
    out = {"render_seconds": min(times), "wall_seconds": min(walls)}
    out.update({k: res.stats[k] for k in COUNTERS})
    out["covered_fraction"] = float((res.rgba[..., 3] > 0.5).mean())
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--datasets", default=DEFAULT_DATASETS)
    ap.add_argument("--method", default="classified")
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-memory", default="64G")
    ap.add_argument("--out", required=True, help="the JSON to write")
    args = ap.parse_args(argv)

    from hovr_blender.engine import limits
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    W, H = (int(v) for v in args.size.lower().split("x"))
    opts = RenderOptions(method=args.method, precision=args.precision, device=args.device)
    report = {"bench": "surfaces_frame", "date": datetime.date.today().isoformat(), "device": args.device,
              "host": platform.node(), "size": [W, H], "method": args.method, "precision": args.precision,
              "repeats": args.repeats, "commit": common.git("rev-parse", "HEAD"),
              "datasets": {}}
    lim = limits.ResourceLimits(limits.parse_size(args.max_memory), limits.current().max_samples_per_ray)
    with limits.using(lim):
        for name in args.datasets.split(","):
            try:
                mesh, _ = datasets.load(name)
            except FileNotFoundError as exc:
                report["datasets"][name] = {"skipped": str(exc)}
                continue
            tf = datasets.transfer_function(mesh)
            cam = RayCamera.from_contract(dict(datasets.views(mesh)["oblique"], projection="perspective"), W, H)
            r = Renderer(mesh, args.device)
            entry = {"elements": mesh.num_elements}
            for frame, (ftf, surfaces) in frames(mesh, tf).items():
                entry[frame] = timed(r, cam, ftf, surfaces, opts, args.repeats)
                print(f"{name} {frame}: {entry[frame]['render_seconds']:.4f} s", flush=True)
            if name in datasets.Q_FIELDS:
                t0 = time.perf_counter()
                derived = datasets.load_field(name, datasets.Q_FIELDS[name])
                entry["derived"] = {"field": datasets.Q_FIELDS[name], "load_seconds": time.perf_counter() - t0,
                                    "q_level": datasets.q_level(derived, name), "fit": derived.warnings[-1]}
                rd = Renderer(derived, args.device)
                for frame, (ftf, surfaces) in derived_frames(derived, name).items():
                    entry[frame] = timed(rd, cam, ftf, surfaces, opts, args.repeats)
                    print(f"{name} {frame}: {entry[frame]['render_seconds']:.4f} s", flush=True)
            v = entry["volume"]["render_seconds"]
            entry["isosurface_over_volume"] = entry["isosurface"]["render_seconds"] / v
            entry["plane_over_volume"] = entry["plane"]["render_seconds"] / v
            if name in datasets.Q_FIELDS:
                entry["derived_isosurface_over_volume"] = entry["derived_isosurface"]["render_seconds"] / v
            report["datasets"][name] = entry
            Path(args.out).write_text(json.dumps(report, indent=1, default=float))
    Path(args.out).write_text(json.dumps(report, indent=1, default=float))


if __name__ == "__main__":
    main()
