"""Per-kernel GPU time of one frame of each tree's renderer (Warp's kernel timing), classified and split at
the defaults, pyfr_tgv and paper_scale at 1920x1080 from the audit's oblique view and tents, and each
kernel's local-memory depot in the PTX Warp writes (a kernel that spills or keeps arrays on its stack):

    python bench/kernel_profile.py OUT.json TREE     (TREE: a folder holding hovr_blender; one tree a process)

KPROF_DEVICE (default cuda:0) and KPROF_SIZE (default 1920x1080) change the device and size; on the CPU
Warp times no kernels.
"""
import json
import os
import sys
import time

import numpy as np
out = {}
DEV = os.environ.get("KPROF_DEVICE", "cuda:0")
W, H = map(int, os.environ.get("KPROF_SIZE", "1920x1080").split("x"))
for tree in sys.argv[2:]:
    for m in [k for k in sys.modules if k.startswith("hovr_blender")]:
        del sys.modules[m]
    sys.path.insert(0, tree)
    import warp as wp
    wp.config.quiet = True
    wp.config.cuda_output = "ptx"  # the local-memory depots of each kernel, below
    from hovr_blender.audit.datasets import load, transfer_function, views
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    import hovr_blender
    print("tree", tree, hovr_blender.__file__, flush=True)
    for name in ("pyfr_tgv", "paper_scale"):
        mesh, _ = load(name)
        tf = transfer_function(mesh); cam = RayCamera.from_contract(views(mesh)["oblique"], W, H)
        r = Renderer(mesh, DEV)
        for method in ("classified", "split"):
            opts = RenderOptions(method=method, device=DEV)
            r.render(cam, tf, np.zeros(3), opts)
            wp.synchronize()
            t0 = time.perf_counter(); r.render(cam, tf, np.zeros(3), opts); wp.synchronize(); wall = time.perf_counter() - t0
            wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
            res = r.render(cam, tf, np.zeros(3), opts); wp.synchronize()
            rows = wp.timing_end()
            agg = {}
            for x in rows:
                a = agg.setdefault(x.name, [0.0, 0]); a[0] += x.elapsed; a[1] += 1
            key = f"{os.path.basename(tree.rstrip('/'))}-{name}-{method}"
            out[key] = {"wall_ms": round(wall * 1e3, 1), "tolerance": opts.tolerance,
                        "kernels_ms": {k: [round(v[0], 2), v[1]] for k, v in sorted(agg.items(), key=lambda kv: -kv[1][0])}}
            print(key, out[key]["wall_ms"], list(out[key]["kernels_ms"].items())[:6], flush=True)
        del r
    sys.path.remove(tree)
import glob, re
import warp as wp
depots = {}
for f in glob.glob(os.path.join(wp.config.kernel_cache_dir, "**", "*.ptx"), recursive=True):
    text = open(f, errors="replace").read()
    for m in re.finditer(r"\.entry\s+(\w+)\((.*?)\n\}", text, re.S):
        body = m.group(0)
        d = re.search(r"__local_depot\d*\[(\d+)\]", body)
        regs = sum(int(n) for n in re.findall(r"\.reg \.\w+ \s*%\w+<(\d+)>", body))
        depots[m.group(1)[:120]] = {"local_bytes": int(d.group(1)) if d else 0, "virtual_regs": regs}
out["ptx_local_depots"] = dict(sorted(depots.items(), key=lambda kv: -kv[1]["local_bytes"])[:60])
print(json.dumps(dict(list(out["ptx_local_depots"].items())[:25]), indent=0), flush=True)
json.dump(out, open(sys.argv[1], "w"), indent=1)
