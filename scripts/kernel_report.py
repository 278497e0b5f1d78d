"""Compile the render kernels for a CUDA architecture without a GPU (Warp's NVRTC), time the
compile, and report each kernel's registers, stack frame and spills.

    python -m scripts.kernel_report                              # sm_90, float32, report only
    python -m scripts.kernel_report --cache .gpu/kcache          # also fill a Warp kernel cache
    python -m scripts.kernel_report --precision float64 --arch 90
    python -m scripts.kernel_report --modes 0,2,3,4,5,6,7,8,9,10,11   # every sample specialisation
    python -m scripts.kernel_report --only integrate,shade       # those kernels alone (both variants)

--cache writes the compiled modules (PTX and CUBIN) where Warp looks for them when
WARP_CACHE_PATH points there, so a GPU machine given that folder loads the kernels instead of
compiling them (the module hash is the same on any machine with the same source and Warp).
The register report needs ptxas from CUDA 13.x or newer (NVRTC here writes PTX 9.x): set
PTXAS=/path/to/ptxas, or put it on PATH (pip's nvidia-cuda-nvcc wheel carries one).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import tempfile
import time



def run_ptxas(ptxas: str, arch: int, ptx: str):
    """ptxas -v on the PTX file; where this ptxas is older than the PTX's .version (CUDA 13.0's
    reads PTX 9.0, Warp's NVRTC 13.4 writes 9.4), again with the header lowered to the version
    ptxas names (the kernels use nothing newer)."""
    r = subprocess.run([ptxas, f"-arch=sm_{arch}", "-v", ptx, "-o", os.devnull], capture_output=True, text=True)
    m = re.search(r"Unsupported \.version (\S+); current version is '(\S+)'", r.stderr)
    if m:
        with open(ptx, "rb") as f:
            text = f.read()
        with open(ptx, "wb") as f:
            f.write(text.replace(f".version {m.group(1)}".encode(), f".version {m.group(2)}".encode(), 1))
        r = subprocess.run([ptxas, f"-arch=sm_{arch}", "-v", ptx, "-o", os.devnull], capture_output=True, text=True)
    if r.returncode != 0:
        print("    ptxas failed:", r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode)
    return r


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--arch", type=int, default=90)
    ap.add_argument("--precision", default="float32", choices=["float32", "float64"])
    ap.add_argument("--cache", default=None, help="a Warp kernel cache folder to fill (WARP_CACHE_PATH)")
    ap.add_argument("--modes", default="0,7", type=lambda v: [int(x) for x in v.split(",")],
                    help="sample kernels to build: 0 generic, N unrolled for N modes (7: order 6, the paper's)")
    ap.add_argument("--only", default=None, type=lambda v: v.split(","),
                    help="report only kernels whose names start with one of these (e.g. integrate,shade)")
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
        kernels.append((f"sample ({kind}, a derived field)", raycast.walk_kernels(kind == "curved", 0, True)[2]))
    for iso in (False, True):
        integrate, shade = raycast.integrate_kernels(iso)
        with_iso = " with isosurfaces and planes" if iso else ""
        kernels.append((f"integrate{with_iso}", integrate))
        kernels.append((f"shade{with_iso} (transfer-function edits from a segment cache)", shade))
    # the module's own kernels: init_rays, refine, coefficients, finalize, trace_*, sum_counts
    kernels.append(("init_rays, refine, coefficients, finalize, trace_reserve, trace_write, trace_ends, sum_counts",
                    raycast.finalize))
    kernels.append(("step_terms", raycast.step_terms))
    if args.only:
        kernels = [(name, kern) for name, kern in kernels if name.startswith(tuple(args.only))]
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
            r = run_ptxas(ptxas, args.arch, clean)
            for line in r.stderr.splitlines():
                line = line.strip()
                if "Compiling entry" in line:
                    print("   ", line.split("'")[1].split("_cuda_kernel")[0].split("__locals__")[-1])
                elif "registers" in line or "spill" in line:
                    print("       ", line.replace("ptxas info    : ", ""))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
