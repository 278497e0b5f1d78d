"""Transfer-function edits re-rendered from cached segments (issue 21): per dataset and method
setting, a full render, the trace that keeps every ray's segments and series
(Renderer.trace), and the shade of N different transfer-function edits from that cache
(Renderer.shade), each against a fresh render of the same edit.

    python -m bench.tf_edit --device cuda:0 --size 1920x1080 --out $OUT/tf_edit.json
    python -m bench.tf_edit --device cpu --size 96x54 --paper 48,96 --edits 4 --repeats 2 \\
        --datasets paper_scale,paper_scale_straight,hump3D --out /tmp/tf_edit.json   (a small CPU check)

Datasets, cameras and transfer functions are the audit's (hovr_blender/audit/datasets.py: the oblique view,
three density tents over the field's 2..98 % range); paper_scale_straight is the paper-scale
channel with straight sides. A dataset whose file is missing is skipped and recorded so. The
edits keep the transfer function's breakpoint band (its lowest and highest breakpoint), so the
field's frame and with it the cache stay valid (engine/field_frame.py): inner breakpoints moved,
densities scaled, colours replaced, one tent emptied; edit 0 is the original.

Per setting (bench/frame.py's names; default split-1e-3 and classified-d1600):
- render_seconds / trace_seconds / shade_seconds: the best of --repeats after a warm-up call,
  from the first launch to wp.synchronize (the renderer's own timers: device work and launch
  overhead, without allocation and the copy of the image back to the host); shade per edit, and
  its min / median / max over the edits;
- *_wall_seconds: the same calls timed around them (allocation, transfer-function upload, the
  image's copy back to the host and the stats included);
- cache: bytes in all, per ray and per segment (a segment's record, its series and its share of
  the chunks), segments per ray, coefficients per segment;
- max_abs_difference: the largest |shaded - fresh| over RGBA, depth and error of every edit
  (0 where they are bitwise equal; see tests/engine/test_segment_cache.py for why).

The memory limit is raised to --max-memory (default 64G) for the run: at 1920x1080 one launch
tile's buffers alone are ~7.7 GiB in float32 (Renderer.check_limits), more than the default 4 GiB.
Writes the JSON after every dataset (--datasets takes a subset, so a time-limited machine can run
them over several calls; each dataset costs 1 + repeats + edits full renders and 1 + repeats traces
per setting, and (1 + repeats) shades per edit); --png writes each dataset's last shaded edit beside it.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time

import numpy as np

from bench import common
from bench.frame import SETTINGS  # the method settings' names
from hovr_blender.audit import datasets, scenes  # the audit's datasets, views, transfer functions

DEFAULT_DATASETS = "paper_scale,paper_scale_straight,hump3D,ngsolve_ball,mfem_fichera,ngsolve_post,pyfr_tgv"


def load(name: str, paper: tuple[int, int]):
    """(mesh, transfer function, camera contract) of a dataset: the audit's, with the paper-scale
    channel at the requested size and its straight-sided twin."""
    if name in ("paper_scale", "paper_scale_straight"):
        from hovr_blender.io.paper_scale import paper_scale_mesh

        mesh = paper_scale_mesh(*paper, curved=name == "paper_scale")
    else:
        mesh, _ = datasets.load(name)
    return mesh, datasets.transfer_function(mesh), dict(datasets.views(mesh)["oblique"], projection="perspective")


def edits(tf, n: int, seed: int = 21) -> list:
    """n transfer functions with tf's lowest and highest breakpoints (so its field frame): tf
    itself first, then inner breakpoints moved (their order kept), densities scaled, colours
    replaced at random, and every other one with its largest-density tent emptied."""
    from hovr_blender.engine.transfer_function import TransferFunction

    rng = np.random.default_rng(seed)
    out = [tf]
    for k in range(1, n):
        ds = tf.density_s.copy()
        if len(ds) > 2:
            gaps = np.diff(ds)
            ds[1:-1] += rng.uniform(-0.3, 0.3, len(ds) - 2) * np.minimum(gaps[:-1], gaps[1:])
        tau = tf.density_tau * np.exp(rng.uniform(-1.0, 1.5))
        if k % 2 == 0:
            tau[max(int(np.argmax(tau)) - 1, 0):int(np.argmax(tau)) + 2] = 0.0
        rgb = rng.uniform(0.0, 1.0, tf.color_rgb.shape)
        out.append(TransferFunction(tf.color_s, rgb, ds, tau))
    return out


def best(call, repeats: int, key: str):
    """(best stats[key], best wall seconds, last result) over `repeats` calls (after a warm-up call)."""
    res = call()
    times, walls = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = call()
        walls.append(time.perf_counter() - t0)
        times.append(res.stats[key])
    return min(times), min(walls), res


def difference(a, b) -> float:
    return float(max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64)).max()
                     for x, y in ((a.rgba, b.rgba), (a.depth, b.depth), (a.error, b.error))))


def run_setting(r, cam, tfs, opts, args) -> dict:
    bg = scenes.BACKGROUND
    render_s, render_wall, fresh0 = best(lambda: r.render(cam, tfs[0], bg, opts), args.repeats, "render_seconds")
    trace_s, trace_wall, cache = best(lambda: r.trace(cam, tfs[0], opts), args.repeats, "trace_seconds")
    shade, shade_wall, diffs, shaded = [], [], [], None
    for tf in tfs:
        if r.frame_key(tf) != cache.frame_key:
            raise RuntimeError("an edit left the transfer function's frame: bench/tf_edit.py's edits are wrong")
        s, w, shaded = best(lambda: r.shade(cache, tf, bg, opts), args.repeats, "render_seconds")
        shade.append(s)
        shade_wall.append(w)
        diffs.append(difference(shaded, r.render(cam, tf, bg, opts)))
    return {"render_seconds": render_s, "render_wall_seconds": render_wall, "trace_seconds": trace_s,
            "trace_wall_seconds": trace_wall, "shade_seconds": shade, "shade_wall_seconds": shade_wall,
            "shade_seconds_min_median_max": [min(shade), float(np.median(shade)), max(shade)],
            "shade_wall_seconds_min_median_max": [min(shade_wall), float(np.median(shade_wall)), max(shade_wall)],
            "max_abs_difference": max(diffs), "max_abs_difference_per_edit": diffs,
            "cache": cache.describe(), "trace_rounds": cache.stats["rounds"],
            "render_segments_per_ray": fresh0.stats["segments"] / (cam.width * cam.height),
            "render_empty_fraction": fresh0.stats["segments_empty"] / max(fresh0.stats["segments"], 1)}, shaded


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--datasets", default=DEFAULT_DATASETS)
    ap.add_argument("--settings", default="split-1e-3,classified-d1600")
    ap.add_argument("--precision", default="float32")
    ap.add_argument("--edits", type=int, default=8,
                    help="transfer functions shaded from one cache (the first: the original)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--paper", default="3400,7600", help="the paper-scale channel's requested hexahedra,prisms")
    ap.add_argument("--max-memory", default="64G", help="the memory limit for the run (engine/limits.py)")
    ap.add_argument("--png", action="store_true", help="each dataset's last shaded edit as a PNG beside --out")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    unknown = [n for n in args.datasets.split(",") if n not in datasets.DATASETS and n != "paper_scale_straight"]
    if unknown:
        known = ", ".join([*datasets.DATASETS, "paper_scale_straight"])
        ap.error(f"unknown dataset(s) {', '.join(unknown)}; known: {known}")
    unknown = [s for s in args.settings.split(",") if s not in SETTINGS]
    if unknown:
        ap.error(f"unknown setting(s) {', '.join(unknown)}; known: {', '.join(SETTINGS)}")
    import warp as wp

    from hovr_blender.engine import limits
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.image_io import write_png
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    wp.config.quiet = True
    wp.init()
    W, H = (int(v) for v in args.size.split("x"))
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    paper = tuple(int(v) for v in args.paper.split(","))
    out = {"device": args.device, "device_name": wp.get_device(args.device).name, "host": platform.node(),
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "size": [W, H], "precision": args.precision,
           "edits": args.edits, "repeats": args.repeats, "max_memory": args.max_memory, "datasets": {}}
    with limits.using(limits.ResourceLimits(max_memory=limits.parse_size(args.max_memory))):
        for name in args.datasets.split(","):
            try:
                t0 = time.perf_counter()
                mesh, tf, contract = load(name, paper)
                load_s = time.perf_counter() - t0
            except FileNotFoundError as exc:
                print(f"{name}: skipped, missing {exc}", flush=True)
                out["datasets"][name] = {"skipped": f"missing {exc}"}
                continue
            cam = RayCamera.from_contract(contract, W, H)
            r = Renderer(mesh, args.device)
            diag = float(np.linalg.norm(np.ptp(mesh.vertices.reshape(-1, 3), axis=0)))
            tfs = edits(tf, args.edits)
            entry = {"elements": mesh.num_elements, "affine": int(mesh.affine.sum()), "load_seconds": load_s,
                     "settings": {}}
            shaded = None
            for setting in args.settings.split(","):
                kw = dict(SETTINGS[setting])
                if "h_div" in kw:
                    kw["h"] = diag / kw.pop("h_div")
                opts = RenderOptions(device=args.device, precision=args.precision, **kw)
                row, shaded = run_setting(r, cam, tfs, opts, args)
                row["parameters"] = kw
                entry["settings"][setting] = row
                c = row["cache"]
                shade_ms = row["shade_seconds_min_median_max"][1] * 1e3
                wall_ms = row["shade_wall_seconds_min_median_max"][1] * 1e3
                print(f"{name:22s} {setting:16s} render {row['render_seconds'] * 1e3:9.2f} ms  trace "
                      f"{row['trace_seconds'] * 1e3:9.2f} ms  shade {shade_ms:8.2f} ms (wall {wall_ms:8.2f} ms)  "
                      f"cache {c['bytes'] / 2**20:8.1f} MiB = {c['bytes_per_ray']:7.1f} B/ray, "
                      f"{c['bytes_per_segment']:6.1f} B/seg, {c['segments_per_ray']:5.2f} seg/ray  "
                      f"max diff {row['max_abs_difference']:.2g}", flush=True)
            if args.png and args.out and shaded is not None:
                write_png(os.path.join(os.path.dirname(os.path.abspath(args.out)), f"tf_edit_{name}.png"), shaded.rgba,
                          alpha=False)
            out["datasets"][name] = entry
            if args.out:
                with open(args.out, "w") as fh:
                    json.dump(out, fh, indent=1, default=common.jsonable)
            del r
    return out


if __name__ == "__main__":
    main()
