"""A CPU render's tiles over a thread a core (issue 37): one frame of each dataset at the defaults a
user gets, the audit's oblique view and tents, on one thread against every core this process may
use (Renderer.cpu_threads), the images checked identical bit for bit.

    python -m bench.cpu_threads --size 320x180 --out bench/results/cpu/issue37/cpu_threads_320x180.json

Best of --repeats after a first frame each (kernel load). Plain renders (the CLI, a first F12, an
animation's frames); a traced F12 runs its bands of rows over the same threads (bench.f12_reshade
times it inside Blender). On a shared machine the numbers are for regressions.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from bench.common import command_line, git, write_report

DATASETS = "ngsolve_ball,Hex_Mushroom,mfem_fichera,ngsolve_post,hump3D"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--datasets", default=DATASETS)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import warp as wp

    from hovr_blender.audit.datasets import load, transfer_function, views
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.limits import cpu_threads
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    threads = cpu_threads()
    rows = []
    for name in [d for d in args.datasets.split(",") if d]:
        mesh, _ = load(name)
        tf = transfer_function(mesh)
        view = views(mesh)["oblique"]
        camera = RayCamera.from_contract(view, W, H)
        renderer = Renderer(mesh, "cpu")
        opts = RenderOptions(device="cpu")
        renderer.render(RayCamera.from_contract(view, 16, 9), tf, np.zeros(3), opts)  # the kernels loaded
        row, images = {"dataset": name, "elements": int(mesh.num_elements)}, {}
        for n in (1, threads):
            renderer.cpu_threads = n
            best = None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                res = renderer.render(camera, tf, np.zeros(3), opts)
                best = min(best or 1e30, time.perf_counter() - t0)
            row[f"seconds_{n}_threads"] = round(best, 3)
            images[n] = res.rgba
        row["speedup"] = round(row["seconds_1_threads"] / row[f"seconds_{threads}_threads"], 2)
        row["identical"] = bool(np.array_equal(images[1], images[threads]))
        print(f"cpu_threads: {name}: 1 thread {row['seconds_1_threads']:.2f} s, {threads} threads "
              f"{row[f'seconds_{threads}_threads']:.2f} s ({row['speedup']}x), identical {row['identical']}", flush=True)
        rows.append(row)
    write_report({"command": command_line(), "git_commit": git("rev-parse", "HEAD"), "date": time.strftime("%Y-%m-%d"),
                  "size": [W, H], "threads": threads, "defaults": RenderOptions().as_dict(), "runs": rows}, args.out)


if __name__ == "__main__":
    main()
