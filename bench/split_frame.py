"""Issue 42: one frame over N devices against one device of the same host, in one call, on the
audit's datasets (hovr_blender/audit/datasets.py: the oblique view and three-tent transfer
function bench.commits' views use).

    python -m bench.split_frame --devices cuda:0,cuda:1 --size 1920x1080 \\
        --datasets paper_scale,hump3D,ngsolve_ball --out $OUT/split_frame.json     (2 or 4 GPUs)
    python -m bench.split_frame --devices cpu,cpu --size 192x108 --repeats 2       (any host)

Per dataset:
- one device: `Renderer.render` on the first device in this process (what a user with one device
  gets), a warm-up frame then the best of --repeats, by its wall time round render();
- set-up, once: `MultiDeviceRenderer(mesh, devices)`'s start (processes, each device's mesh upload
  and kernel load: `setup`);
- the first frame over the N devices (rows split by a pre-pass at 1/--prepass-scale of the size),
  the same first frame split into equal rows (`reset_split`, pre-pass off), and the best of
  --repeats frames split by the previous frame's row costs: each frame's seconds, speed-up
  against the one device's wall time (target >= 0.9 N), the per-device render seconds and their
  spread ((max - min) / min, target <= 0.10), the pre-pass's seconds, and whether the image
  equals the one device's bit for bit;
- the split strategies on the cost model: from the one-device frame's exact cost per row
  (work counts, engine/work_counts.ray_cost), the balance (mean / max of the devices' costs; 1 is
  perfect) each strategy would give for 2, 4 and 8 devices: equal rows, a pre-pass at 1/4, 1/8
  and 1/16 of the size (each pre-pass rendered here on the one device, its seconds as a fraction
  of the frame), interleaved tiles of k rows dealt round-robin, and the frame's own costs (the
  previous frame of a still view: the best contiguous bands can do). Tiles need a render call
  per tile (Renderer.render traces one range of rows): `tile_calls` times the one device's frame
  in --tile-calls calls of equal bands against one call, the cost of a call.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import time

import numpy as np

from bench import common

PREPASS_SCALES = (4, 8, 16)
TILE_ROWS = (1, 8, 32)
DEVICE_COUNTS = (2, 4, 8)


def band_balance(row_cost, bands) -> float:
    """mean / max of the bands' summed costs (1: every device has the same work)."""
    c = np.array([float(np.sum(row_cost[a:b])) for a, b in bands])
    return float(c.mean() / c.max())


def tiles_balance(row_cost, devices: int, rows: int) -> float:
    """The balance of tiles of `rows` rows dealt round-robin to `devices` devices."""
    tile = np.arange(len(row_cost)) // rows
    c = np.bincount(tile % devices, weights=row_cost, minlength=devices)
    return float(c.mean() / c.max())


def strategies(renderer, cam, tf, opts, frame_cost, frame_seconds, calls: int) -> dict:
    """The cost model's balance of each strategy (module docstring), each pre-pass's seconds on
    `renderer`'s device as a fraction of `frame_seconds`, and the frame's wall time in `calls`
    render calls of equal bands."""
    from hovr_blender.engine.multi_device import balanced_rows, prepass_camera, upsampled_rows

    H = len(frame_cost)
    out = {"equal_rows": {}, "previous_frame": {}, "prepass": {}, "tiles": {}}
    estimates = {}
    for s in PREPASS_SCALES:
        low = prepass_camera(cam, s)
        res = renderer.render(low, tf, common.BACKGROUND, opts)
        estimates[s] = upsampled_rows(res.row_cost, H)
        out["prepass"][f"1/{s}"] = {"size": [int(low.width), int(low.height)],
                                    "seconds": res.stats["render_seconds"],
                                    "fraction_of_frame": res.stats["render_seconds"] / frame_seconds}
    for n in DEVICE_COUNTS:
        ones = np.ones(n)
        out["equal_rows"][n] = band_balance(frame_cost, balanced_rows(np.ones(H), ones))
        out["previous_frame"][n] = band_balance(frame_cost, balanced_rows(frame_cost, ones))
        for s in PREPASS_SCALES:
            out["prepass"][f"1/{s}"][n] = band_balance(frame_cost, balanced_rows(estimates[s], ones))
        for k in TILE_ROWS:
            out["tiles"].setdefault(f"{k} rows", {})[n] = tiles_balance(frame_cost, n, k)
    t0 = time.perf_counter()
    for band in balanced_rows(np.ones(H), np.ones(calls)):
        renderer.render(cam, tf, common.BACKGROUND, opts, rows=band)
    wall = time.perf_counter() - t0
    out["tile_calls"] = {"calls": calls, "wall_seconds": wall, "one_call_wall_seconds": frame_seconds,
                         "seconds_per_call": (wall - frame_seconds) / max(calls - 1, 1)}
    return out


def split_frame_row(md, res, one, one_wall, n) -> dict:
    """A split frame's measures against the one-device frame `one` (wall time `one_wall`)."""
    per = res.stats["devices"]
    seconds = res.stats["render_seconds"]
    return {"seconds": seconds, "speedup": one_wall / seconds, "target_speedup": 0.9 * n,
            "split_by": res.stats["split_by"], "prepass_seconds": res.stats["prepass_seconds"],
            "device_spread": res.stats["device_spread"], "device_balance": res.stats["device_balance"],
            "per_device": [{**d, "cost_per_second": d["cost"] / max(d["render_seconds"], 1e-12)} for d in per],
            "identical": bool(np.array_equal(res.rgba, one.rgba)),
            "max_abs_difference": float(np.abs(res.rgba.astype(np.float64) - one.rgba).max())}


def bench_dataset(name, devices, W, H, repeats, prepass_scale, opts, tile_calls) -> dict:
    from hovr_blender.audit import datasets
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.multi_device import MultiDeviceRenderer
    from hovr_blender.engine.renderer import Renderer

    t0 = time.perf_counter()
    mesh, _ = datasets.load(name)
    load = time.perf_counter() - t0
    tf = datasets.transfer_function(mesh)
    cam = RayCamera.from_contract(datasets.views(mesh)["oblique"], W, H)
    opts = opts.with_(device=devices[0])
    row = {"dataset": name, "elements": int(mesh.num_elements), "size": [W, H], "load_seconds": load,
           "parameters": opts.as_dict(), "devices": devices}

    r = Renderer(mesh, devices[0])
    r.render(cam, tf, common.BACKGROUND, opts)  # kernels loaded, buffers sized
    one, one_wall = None, None
    for _ in range(repeats):
        t1 = time.perf_counter()
        res = r.render(cam, tf, common.BACKGROUND, opts)
        wall = time.perf_counter() - t1
        if one is None or wall < one_wall:
            one, one_wall = res, wall
    row.update(one_device=devices[0], one_seconds=one.stats["render_seconds"], one_wall_seconds=one_wall)
    row["strategies"] = strategies(r, cam, tf, opts, one.row_cost, one_wall, tile_calls)
    del r

    t1 = time.perf_counter()
    md = MultiDeviceRenderer(mesh, devices, precision=opts.precision, prepass_scale=prepass_scale)
    try:
        row["setup"] = {**md.setup, "wall_seconds": time.perf_counter() - t1}
        row["first_frame"] = split_frame_row(md, md.render(cam, tf, common.BACKGROUND, opts), one, one_wall,
                                             len(devices))
        best = None
        for _ in range(repeats):
            res = md.render(cam, tf, common.BACKGROUND, opts)
            if best is None or res.stats["render_seconds"] < best.stats["render_seconds"]:
                best = res
        row["steady_frame"] = split_frame_row(md, best, one, one_wall, len(devices))
        md.reset_split()
        md.prepass_scale = 0
        row["first_frame_equal_rows"] = split_frame_row(md, md.render(cam, tf, common.BACKGROUND, opts), one,
                                                        one_wall, len(devices))
    finally:
        md.close()
    return row


def report(row) -> str:
    def frame(f):
        return (f"{f['seconds']:.3f} s ({f['speedup']:.2f}x, spread {100 * f['device_spread']:.0f} %, "
                f"identical {f['identical']})")

    st = row["strategies"]
    pre = ", ".join(f"{k} {v['fraction_of_frame']:.3f}" for k, v in st["prepass"].items())
    tc = st["tile_calls"]
    bal = "; ".join(f"{n}: equal {st['equal_rows'][n]:.2f}, pre-pass 1/8 {st['prepass']['1/8'][n]:.2f}, "
                    f"tiles 8 rows {st['tiles']['8 rows'][n]:.2f}, previous {st['previous_frame'][n]:.2f}"
                    for n in DEVICE_COUNTS)
    return (f"{row['dataset']} {row['size'][0]}x{row['size'][1]} on {','.join(row['devices'])}: one device "
            f"{row['one_wall_seconds']:.3f} s; set-up {row['setup']['seconds']:.2f} s; first frame "
            f"{frame(row['first_frame'])} (pre-pass {row['first_frame']['prepass_seconds']:.3f} s), equal rows "
            f"{frame(row['first_frame_equal_rows'])}, steady {frame(row['steady_frame'])}\n"
            f"  pre-pass seconds / frame on one device: {pre}; the frame in {tc['calls']} calls "
            f"{tc['wall_seconds']:.3f} s ({tc['seconds_per_call']:.4f} s a call)\n"
            f"  cost-model balance by devices: {bal}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", default="cuda:all", help="the split frame's devices (cuda:all, cpu,cpu, cpu:all...)")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--datasets", default="paper_scale,hump3D,ngsolve_ball",
                    help="names of hovr_blender/audit/datasets.py (HOVR_DATA: where the shared data is)")
    ap.add_argument("--method", default="split", help="the render method (the defaults' tolerance and step)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--prepass-scale", type=int, default=None, help="the first frame's pre-pass (default the engine's)")
    ap.add_argument("--tile-calls", type=int, default=16, help="the one device's frame in this many calls")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    from hovr_blender.engine.devices import expand_devices
    from hovr_blender.engine.multi_device import PREPASS_SCALE
    from hovr_blender.engine.view import RenderOptions

    devices = expand_devices(args.devices)
    if len(devices) < 2:
        ap.error("--devices: name at least two devices")
    W, H = (int(v) for v in args.size.lower().split("x"))
    scale = PREPASS_SCALE if args.prepass_scale is None else args.prepass_scale
    out = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "devices": devices, "prepass_scale": scale, "rows": []}
    for name in args.datasets.split(","):
        try:
            row = bench_dataset(name.strip(), devices, W, H, args.repeats, scale, RenderOptions(method=args.method),
                                args.tile_calls)
        except FileNotFoundError as exc:
            print(f"{name}: skipped, no {exc}", flush=True)
            continue
        out["rows"].append(row)
        print(report(row), flush=True)
        if args.out:
            os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
            common.write_report(json.loads(json.dumps(out, default=common.jsonable)), args.out)
    if not args.out:
        print(json.dumps(out, default=common.jsonable)[:2000])


if __name__ == "__main__":
    main()
