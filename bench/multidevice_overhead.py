"""Where a frame split over several devices (engine/multi_device.py) spends its time outside the
devices' renders, on any host (CPU devices work: `--devices cpu,cpu`): a cheap mesh (io/synthetic
mixed cube) at --size, one frame on one device and over --devices, best of --repeats after a
first frame. Prints per frame: the one-device render's own seconds and its wall time, the split
frame's seconds, each device's render seconds (and its worker's wall time round Renderer.render,
where reported) and the overhead = split seconds - the slowest device's render seconds.

    python -m bench.multidevice_overhead --devices cpu,cpu --size 1920x1080
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from hovr_blender.audit import scenes


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--devices", default="cpu,cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--cells", type=int, default=2, help="mixed_cube cells a side")
    ap.add_argument("--modes", type=int, default=3)
    ap.add_argument("--h-div", type=float, default=8.0, help="classified, h = diagonal / this")
    ap.add_argument("--distance", type=float, default=20.0, help="the camera's distance in bounding radii (far: most rays miss)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    from hovr_blender.engine.multi_device import MultiDeviceRenderer
    from hovr_blender.engine.devices import expand_devices
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.io import synthetic

    W, H = (int(v) for v in args.size.split("x"))
    devices = expand_devices(args.devices)
    mesh = synthetic.mixed_cube(args.cells, args.modes, synthetic.cube_field)
    lo, hi = np.percentile(mesh.field_samples(3), [2, 98])
    tf = scenes.tents(lo, hi, scenes.COLORS, 6.0)
    blo, bhi = scenes.mesh_bounds(mesh)
    opts = RenderOptions(method="classified", h=float(np.linalg.norm(bhi - blo)) / args.h_div)
    cam = scenes.framing(mesh, W, H, distance=args.distance)
    # the one-device frame from a process started like the split's (tests/engine/test_multi_device.py)
    with MultiDeviceRenderer(mesh, devices[:1]) as one:
        one.render(cam, tf, scenes.BACKGROUND, opts)
        single, single_wall = None, None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = one.render(cam, tf, scenes.BACKGROUND, opts)
            wall = time.perf_counter() - t0
            if single is None or wall < single_wall:
                single, single_wall = res, wall
    with MultiDeviceRenderer(mesh, devices) as md:
        md.render(cam, tf, scenes.BACKGROUND, opts)
        best = None
        for _ in range(args.repeats):
            res = md.render(cam, tf, scenes.BACKGROUND, opts)
            if best is None or res.stats["render_seconds"] < best.stats["render_seconds"]:
                best = res
    one_dev = single.stats["devices"][0]["render_seconds"]
    per = [d["render_seconds"] for d in best.stats["devices"]]
    walls = [d.get("wall_seconds") for d in best.stats["devices"]]
    multi = best.stats["render_seconds"]
    print(f"{W}x{H} {mesh.num_elements} elements on {','.join(devices)}: one device {one_dev:.3f} s "
          f"(its process's frame {single.stats['render_seconds']:.3f} s); split {multi:.3f} s; per device "
          f"{', '.join(f'{s:.3f}' for s in per)} s"
          + (f" (worker wall {', '.join(f'{w:.3f}' for w in walls)} s)" if None not in walls else "")
          + f"; overhead {multi - max(per):.3f} s; bands {[d['rows'] for d in best.stats['devices']]}; "
          f"identical {bool(np.array_equal(best.rgba, single.rgba))}", flush=True)


if __name__ == "__main__":
    main()
