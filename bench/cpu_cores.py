"""The CPU fallback over every core (issue 21): one frame on one CPU device (Warp runs a CPU
launch on one thread) against `cpu:all` (engine/multi_device.py: one process a core, the frame's
rows split over them), on hump3D at the size of a first F12 (480x270).

    python -m bench.cpu_cores --out bench/results/cpu/cpu_cores.json

Best of --repeats after a first frame each (kernel load, and the rows' costs the split uses);
the images must be identical (checked). On a shared machine the numbers are for regressions.
"""
from __future__ import annotations

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import numpy as np

from bench.common import DATA
from hovr_blender.audit.scenes import BACKGROUND, COLORS, framing, tents  # the tests' scenes


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    from hovr_blender.engine.multi_device import make_renderer
    from hovr_blender.engine.limits import cpu_cores
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.io.nektar import read_nektar

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    mesh = read_nektar(str(DATA / "nektar" / "hump3D_GLL.xml"), str(DATA / "nektar" / "hump3D.rst"), field="rho")
    lo, hi = (float(v) for v in np.percentile(mesh.field_samples(4), [2, 98]))
    diag = float(np.linalg.norm(np.ptp(mesh.vertices.reshape(-1, 3), axis=0)))
    tf = tents(lo, hi, COLORS, 16.0 / diag)
    camera = framing(mesh, W, H)
    opts = RenderOptions(method="split", tolerance=1e-5)
    report = {"date": datetime.date.today().isoformat(), "cpu": cpu_name(), "cores": cpu_cores(), "size": [W, H],
              "dataset": "hump3D (rho)", "elements": int(mesh.num_elements), "runs": {}}
    images = {}
    for device in ("cpu", "cpu:all"):
        renderer = make_renderer(mesh, device)
        try:
            first = time.perf_counter()
            renderer.render(camera, tf, BACKGROUND, opts)
            first = time.perf_counter() - first
            secs = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                res = renderer.render(camera, tf, BACKGROUND, opts)
                secs.append(time.perf_counter() - t0)
        finally:
            close = getattr(renderer, "close", None)
            if close:
                close()
        images[device] = res.rgba
        report["runs"][device] = {"first_seconds": first, "seconds": min(secs), "all_seconds": secs}
        print(f"{device}: {min(secs):.2f} s (first {first:.2f} s)", flush=True)
    one, all_ = report["runs"]["cpu"]["seconds"], report["runs"]["cpu:all"]["seconds"]
    report["speedup"] = one / all_
    report["speedup_per_core"] = one / all_ / report["cores"]
    report["identical_images"] = bool(np.array_equal(images["cpu"], images["cpu:all"]))
    print(f"speed-up {report['speedup']:.2f}x on {report['cores']} cores ({report['speedup_per_core']:.2f} a core), "
          f"identical {report['identical_images']}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
