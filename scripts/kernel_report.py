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



def _ptxas(ptxas: str, ptx: str, arch: int, tmp: str):
    """ptxas -v on the module's PTX. An older ptxas refuses a newer PTX ISA version by name even
    where the code uses nothing newer (NVRTC 13.4 writes 9.4, CUDA 13.0's ptxas reads 9.0): the
    version line is lowered to the one it names and the PTX assembled again, saying so."""
    clean = os.path.join(tmp, "clean.ptx")
    with open(ptx, "rb") as src:
        text = src.read().replace(b"\x00", b"")
    for attempt in range(2):
        with open(clean, "wb") as dst:
            dst.write(text)
        r = subprocess.run([ptxas, f"-arch=sm_{arch}", "-v", clean, "-o", os.devnull], capture_output=True, text=True)
        m = re.search(r"Unsupported \.version (\S+); current version is '(\S+)'", r.stderr)
        if r.returncode == 0 or not m or attempt:
            return r
        print(f"    (ptxas reads PTX {m.group(2)}: the module's .version {m.group(1)} lowered to it)")
        text = text.replace(f".version {m.group(1)}".encode(), f".version {m.group(2)}".encode(), 1)
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
    # every Warp module of the kernel table (kernels/raycast.kernel_table), once, named by its kernels:
    # each walk variant, a derived field's sample kernel, integrate and shade with and without surfaces
    modules = {}
    variants = [(kind, m, False, iso) for kind in ("curved", "affine") for m in args.modes for iso in (False, True)]
    variants += [(kind, 0, True, False) for kind in ("curved", "affine")]
    for kind, m, derived, iso in variants:
        with_iso = " with isosurfaces and planes" if iso else ""
        sampled = "a derived field" if derived else f"modes {m or 'generic'}"
        for name, kern in raycast.kernel_table(kind == "curved", m, derived, iso).named().items():
            label = {"search": f"search ({kind})", "traverse": f"traverse ({kind})",
                     "sample": f"sample ({kind}, {sampled})", "integrate": f"integrate{with_iso}",
                     "shade": f"shade{with_iso}"}.get(name, name)
            labels = modules.setdefault(id(kern.module), (kern, []))[1]
            if label not in labels:
                labels.append(label)
    kernels = [(", ".join(labels), kern) for kern, labels in modules.values()]
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
            r = _ptxas(ptxas, ptx, args.arch, tmp)
            if r.returncode != 0:
                print("    ptxas:", r.stderr.strip().splitlines()[0] if r.stderr.strip() else f"exit {r.returncode}")
            for line in r.stderr.splitlines():
                line = line.strip()
                if "Compiling entry" in line:
                    print("   ", line.split("'")[1].split("_cuda_kernel")[0].split("__locals__")[-1])
                elif "registers" in line or "spill" in line:
                    print("       ", line.replace("ptxas info    : ", ""))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
