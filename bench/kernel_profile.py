"""Per-kernel GPU time of one frame (Warp's kernel timing), classified and split at the defaults,
pyfr_tgv and paper_scale at 1920x1080 from the audit's oblique view and tents, and each kernel's
local-memory depot in the PTX Warp writes (a kernel that spills or keeps arrays on its stack).
It profiles the hovr_blender it imports; for another tree, put the tree first on PYTHONPATH and run
the file from outside any checkout:

    cd /tmp && PYTHONPATH=TREE python REPO/bench/kernel_profile.py OUT.json

KPROF_DEVICE (default cuda:0) and KPROF_SIZE (default 1920x1080) change the device and size; on the
CPU Warp times no kernels.
"""
import glob
import json
import os
import re
import sys
import time

import numpy as np
import warp as wp

import hovr_blender
from hovr_blender.audit.datasets import load, transfer_function, views
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.view import RenderOptions

DATASETS = ("pyfr_tgv", "paper_scale")
METHODS = ("classified", "split")


def frame_profile(name, device, W, H) -> dict:
    """Per method: one frame's wall time (after a warm-up) and each kernel's summed time and launches."""
    mesh, _ = load(name)
    tf = transfer_function(mesh)
    cam = RayCamera.from_contract(views(mesh)["oblique"], W, H)
    r = Renderer(mesh, device)
    out = {}
    for method in METHODS:
        opts = RenderOptions(method=method, device=device)
        r.render(cam, tf, np.zeros(3), opts)
        wp.synchronize()
        t0 = time.perf_counter()
        r.render(cam, tf, np.zeros(3), opts)
        wp.synchronize()
        wall = time.perf_counter() - t0
        wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
        r.render(cam, tf, np.zeros(3), opts)
        wp.synchronize()
        kernels = {}
        for x in wp.timing_end():
            k = kernels.setdefault(x.name, [0.0, 0])
            k[0] += x.elapsed
            k[1] += 1
        out[method] = {"wall_ms": round(wall * 1e3, 1), "tolerance": opts.tolerance,
                       "kernels_ms": {k: [round(v[0], 2), v[1]] for k, v in sorted(kernels.items(), key=lambda kv: -kv[1][0])}}
    return out


def local_depots() -> dict:
    """Each kernel in Warp's kernel cache: its PTX local-memory depot (bytes) and declared registers."""
    found = {}
    for f in glob.glob(os.path.join(wp.config.kernel_cache_dir, "**", "*.ptx"), recursive=True):
        with open(f, errors="replace") as fh:
            text = fh.read()
        for m in re.finditer(r"\.entry\s+(\w+)\((.*?)\n\}", text, re.S):
            body = m.group(0)
            depot = re.search(r"__local_depot\d*\[(\d+)\]", body)
            regs = sum(int(n) for n in re.findall(r"\.reg \.\w+ \s*%\w+<(\d+)>", body))
            found[m.group(1)[:120]] = {"local_bytes": int(depot.group(1)) if depot else 0, "virtual_regs": regs}
    return dict(sorted(found.items(), key=lambda kv: -kv[1]["local_bytes"]))


def main(out_path):
    wp.config.quiet = True
    wp.config.cuda_output = "ptx"  # the local-memory depots, below
    device = os.environ.get("KPROF_DEVICE", "cuda:0")
    W, H = map(int, os.environ.get("KPROF_SIZE", "1920x1080").split("x"))
    out = {"hovr_blender": os.path.dirname(hovr_blender.__file__), "device": device, "size": [W, H]}
    for name in DATASETS:
        for method, entry in frame_profile(name, device, W, H).items():
            out[f"{name}-{method}"] = entry
            print(name, method, entry["wall_ms"], list(entry["kernels_ms"].items())[:6], flush=True)
    out["ptx_local_depots"] = local_depots()
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1])
