"""Compile the render kernels for a CUDA architecture without a GPU (Warp's NVRTC), time the
compile, and report each kernel's registers, stack frame and spills.

    python -m scripts.kernel_report                              # sm_90, float32, report only
    python -m scripts.kernel_report --cache .gpu/kcache          # also fill a Warp kernel cache
    python -m scripts.kernel_report --precision float64 --arch 90
    python -m scripts.kernel_report --modes 0,2,3,4,5,6,7,8,9,10,11   # every sample specialisation

--cache writes the compiled modules (PTX and CUBIN) where Warp looks for them when
WARP_CACHE_PATH points there, so a GPU machine given that folder loads the kernels instead of
compiling them (the module hash is the same on any machine with the same source and Warp).
The register report needs ptxas from CUDA 13.x or newer (NVRTC here writes PTX 9.x): set
PTXAS=/path/to/ptxas, or put it on PATH (pip's nvidia-cuda-nvcc wheel carries one).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import tempfile
import time



def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--arch", type=int, default=90)
    ap.add_argument("--precision", default="float32", choices=["float32", "float64"])
    ap.add_argument("--cache", default=None, help="a Warp kernel cache folder to fill (WARP_CACHE_PATH)")
    ap.add_argument("--modes", default="0,7", type=lambda v: [int(x) for x in v.split(",")],
                    help="sample kernels to build: 0 generic, N unrolled for N modes (7: order 6, the paper's)")
    args = ap.parse_args(argv)
    if args.cache:
        os.environ["WARP_CACHE_PATH"] = os.path.abspath(args.cache)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    from hovr_blender.engine.kernels.precision import Precision

    raycast = Precision.named(args.precision).kernels
    kernels = []
    for kind in ("curved", "affine"):
        search, traverse, _ = raycast.walk_kernels(kind == "curved")
        kernels += [(f"search ({kind})", search), (f"traverse ({kind})", traverse)]
        kernels += [(f"sample ({kind}, modes {m or 'generic'})", raycast.walk_kernels(kind == "curved", m)[2])
                    for m in args.modes]
    kernels.append(("integrate", raycast.integrate))
    kernels.append(("shade (transfer-function edits from a segment cache)", raycast.shade))
    # the module's own kernels: init_rays, refine, coefficients, finalize, trace_*, sum_counts
    kernels.append(("init_rays, refine, coefficients, finalize, trace_reserve, trace_write, trace_ends, sum_counts",
                    raycast.finalize))
    kernels.append(("step_terms", raycast.step_terms))
    ptxas = os.environ.get("PTXAS") or shutil.which("ptxas")
    tmp = tempfile.mkdtemp()
    for name, kern in kernels:
        t0 = time.perf_counter()
        for use_ptx in (True, False):
            paths = wp.compile_aot_module(kern.module, arch=args.arch, use_ptx=use_ptx,
                                          module_dir=None if args.cache else tmp)
            if use_ptx:
                ptx = str(paths[0])
        secs = time.perf_counter() - t0
        print(f"{name}: NVRTC {secs:.1f} s (PTX and CUBIN)")
        if ptxas:
            clean = os.path.join(tmp, "clean.ptx")
            with open(ptx, "rb") as src, open(clean, "wb") as dst:
                dst.write(src.read().replace(b"\x00", b""))
            r = subprocess.run([ptxas, f"-arch=sm_{args.arch}", "-v", clean, "-o", os.devnull],
                               capture_output=True, text=True)
            for line in r.stderr.splitlines():
                line = line.strip()
                if "Compiling entry" in line:
                    print("   ", line.split("'")[1].split("_cuda_kernel")[0].split("__locals__")[-1])
                elif "registers" in line or "spill" in line:
                    print("       ", line.replace("ptxas info    : ", ""))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
