"""Compile the render kernels for a CUDA architecture without a GPU (Warp's NVRTC), time each
module's compile, PTX and CUBIN apart (Warp compiles CUBIN where the GPU's driver is older than its
NVRTC, as on this project's H200, PTX otherwise), and report each kernel's registers, stack frame
and spills, and with --inlining what its compile is made of.

    python -m scripts.kernel_report                              # sm_90, float32, report only
    python -m scripts.kernel_report --cache .gpu/kcache          # also fill a Warp kernel cache
    python -m scripts.kernel_report --precision float64 --arch 90
    python -m scripts.kernel_report --modes 0,2,3,4,5,6,7,8,9,10,11   # every sample specialisation
    python -m scripts.kernel_report --only integrate,shade       # those kernels alone (both variants)
    python -m scripts.kernel_report --only "search (curved)" --inlining            # the largest compile, taken apart
    python -m scripts.kernel_report --only "search (curved)" --noinline missed_entry,polish   # ... with those out of line

Warp is started as a render starts it (engine/devices.py: its CPU flags are part of every module's
hash), so --cache writes the compiled modules (PTX and CUBIN) under the very names a render looks
for when WARP_CACHE_PATH points there: a GPU machine given that folder loads the kernels instead
of compiling them (the module hash is the same on any machine with the same source and Warp).
The register report needs ptxas from CUDA 13.x or newer (NVRTC here writes PTX 9.x): set
PTXAS=/path/to/ptxas, or put it on PATH (pip's nvidia-cuda-nvcc wheel carries one).

--inlining: Warp writes every Warp function of a module as a static function of one CUDA
translation unit, and NVRTC inlines each at every call site. From the generated source, the report
counts how many copies of each function the kernel holds (its call sites, through every caller)
and the lines those copies make, the function's own and all it inlines; ranked by the share of the
kernel that is repeated copies of a function (all but one of them): the few functions at the top
are what its compile time is spent on, and one call site each (or --noinline) would save that. --noinline NAMES compiles
with those Warp functions kept out of line (what @wp.func(inline=False), CUDA's __noinline__,
would do: one copy, called from each site), without editing the source: its times beside the
default's show what the decorator would save (its cost at run time is the GPU's to measure).
--out FILE writes the times and the inlining as JSON, after each module. --jobs N compiles N
modules at once (a thread each; NVRTC uses one core), each still timed on its own: on a machine of
many cores the whole table in about its largest module's time.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor

FUNCTION = re.compile(r'^(?:static (?:WP_\w+ )?CUDA_CALLABLE|extern "C" __global__)(?:[^(]*WP_MAXNREG\(\d+\))?[^(]*?\b(\w+)\(', re.M)


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


def inlining(cuda_source: str, noinline=()) -> dict:
    """What the kernels of a module's generated CUDA source are made of once NVRTC inlines every
    function at every call site: {"lines": the kernels' lines with every copy, "source_lines": the
    functions' own lines, once each, "functions": [{name, copies, own_lines, lines (its copies with
    all they inline), repeated_share (of "lines": all copies but one), called_from}], the largest
    repeated share first}. Functions named in `noinline` (Warp's names, without the "_0" suffix)
    count once, as out-of-line code."""
    starts = [(m.start(), m.group(1)) for m in FUNCTION.finditer(cuda_source)]
    body = {name: cuda_source[a:b] for (a, name), (b, _) in zip(starts, starts[1:] + [(len(cuda_source), "")])}
    kernels = [n for n in body if n.endswith("_cuda_kernel_forward")]
    funcs = [n for n in body if not n.startswith("adj_")]  # the reverse functions: empty without backward
    own = {n: sum(1 for ln in body[n].splitlines() if ln.strip() and not ln.strip().startswith("//")) for n in funcs}
    calls = {g: {f: c for f in funcs if f != g and (c := len(re.findall(rf"\b{re.escape(f)}\(", body[g])))}
             for g in funcs}
    out_of_line = {f"{n}_0" for n in noinline} | set(noinline)
    copies = defaultdict(int)

    def visit(g, k):
        copies[g] += k
        for f, c in calls[g].items():
            if f not in out_of_line:
                visit(f, k * c)
            elif copies[f] == 0:  # out of line: one copy, whoever calls it
                visit(f, 1)

    for kernel in kernels:
        visit(kernel, 1)
    expanded = {}

    def lines(g):  # g's code with all it inlines, once
        if g not in expanded:
            expanded[g] = own[g] + sum(c * lines(f) for f, c in calls[g].items() if f not in out_of_line)
        return expanded[g]

    reached = [f for f in copies if copies[f]]
    total = sum(lines(k) for k in kernels) + sum(lines(f) for f in reached if f in out_of_line)

    def named(f):
        return f.removesuffix("_cuda_kernel_forward").removesuffix("_0")

    rows = [{"name": named(f), "copies": copies[f], "own_lines": own[f], "lines": copies[f] * lines(f),
             "repeated_share": (copies[f] - 1) * lines(f) / total,
             "called_from": {named(g): calls[g][f] for g in reached if f in calls[g]}}
            for f in reached if f not in kernels]
    return {"lines": total, "source_lines": sum(own[f] for f in reached),
            "functions": sorted(rows, key=lambda r: -r["repeated_share"])}


def _keep_out_of_line(names, package: str) -> list[str]:
    """Mark the Warp functions `names` of the kernel modules of `package` out of line (Warp's
    inline_hint, as @wp.func(inline=False) sets it). Returns the names found."""
    import warp as wp

    found = []
    for modname, mod in list(sys.modules.items()):
        if not modname.startswith(package + ".") or mod is None:
            continue
        for name in names:
            func = getattr(mod, name, None)
            if isinstance(func, wp.Function):
                for f in [func, *func.user_overloads.values(), *func.user_templates.values()]:
                    f.inline_hint = "noinline"
                found.append(name)
    return sorted(set(found))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--arch", type=int, default=90)
    ap.add_argument("--precision", default="float32", choices=["float32", "float64"])
    ap.add_argument("--cache", default=None, help="a Warp kernel cache folder to fill (WARP_CACHE_PATH)")
    ap.add_argument("--modes", default="0,7", type=lambda v: [int(x) for x in v.split(",")],
                    help="sample kernels to build: 0 generic, N unrolled for N modes (7: order 6, the paper's)")
    ap.add_argument("--only", default=None, type=lambda v: v.split(","),
                    help="report only kernels whose names start with one of these (e.g. integrate,shade)")
    ap.add_argument("--formats", default="ptx,cubin", type=lambda v: v.split(","), help="ptx and/or cubin, each timed")
    ap.add_argument("--inlining", action="store_true", help="what each kernel inlines (see the module's docstring)")
    ap.add_argument("--noinline", default="", type=lambda v: [x for x in v.split(",") if x],
                    help="Warp functions to compile out of line (names, comma-separated)")
    ap.add_argument("--out", default=None, help="write the times (and the inlining) as JSON")
    ap.add_argument("--jobs", type=int, default=1,
                    help="modules compiled at once, each timed on its own (NVRTC is one thread: up to a core each)")
    args = ap.parse_args(argv)
    if args.cache and args.noinline:
        ap.error("--noinline compiles other code than the source: not into a kernel cache")
    if args.cache:
        os.environ["WARP_CACHE_PATH"] = os.path.abspath(args.cache)
    from hovr_blender.engine.devices import resolve_device

    resolve_device("cpu")  # Warp started as a render starts it: the same module hashes
    import warp as wp

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
    if args.noinline:
        found = _keep_out_of_line(args.noinline, raycast.__name__.rpartition(".")[0])
        missing = sorted(set(args.noinline) - set(found))
        if missing:
            ap.error(f"no Warp function named {', '.join(missing)} in the kernels")
        for _, kern in kernels:
            kern.module.mark_modified()  # the hint is part of the hash and the code
        print(f"out of line: {', '.join(found)}")
    ptxas = os.environ.get("PTXAS") or shutil.which("ptxas")
    tmp = tempfile.mkdtemp()
    report = {"arch": args.arch, "precision": args.precision, "noinline": args.noinline, "modules": []}
    def compile_module(name, kern):
        """One module compiled in each format, timed; its generated source and PTX kept."""
        row = {"kernels": name, "module": kern.module.name}
        folder = None if args.cache else tempfile.mkdtemp(dir=tmp)
        for fmt in args.formats:
            t0 = time.perf_counter()
            paths = wp.compile_aot_module(kern.module, arch=args.arch, use_ptx=fmt == "ptx", module_dir=folder)
            row[f"{fmt}_seconds"] = time.perf_counter() - t0
            row[f"{fmt}_bytes"] = os.path.getsize(paths[0])
            row[f"{fmt}_path"] = str(paths[0])
        return row

    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        for (name, kern), row in zip(kernels, pool.map(lambda nk: compile_module(*nk), kernels)):
            ptx = row.pop("ptx_path", None)
            binary = row.pop("cubin_path", None) or ptx
            print(f"{name}: NVRTC " + ", ".join(f"{fmt.upper()} {row[f'{fmt}_seconds']:.1f} s" for fmt in args.formats))
            if args.inlining:
                source = os.path.join(os.path.dirname(binary), kern.module.get_module_identifier() + ".cu")
                if os.path.exists(source):
                    with open(source, encoding="utf-8") as f:
                        row["inlining"] = inlining(f.read(), args.noinline)
                    _print_inlining(row["inlining"])
            if ptxas and ptx:
                r = _ptxas(ptxas, ptx, args.arch, tmp)
                if r.returncode != 0:
                    print("    ptxas:", r.stderr.strip().splitlines()[0] if r.stderr.strip() else f"exit {r.returncode}")
                for line in r.stderr.splitlines():
                    line = line.strip()
                    if "Compiling entry" in line:
                        print("   ", line.split("'")[1].split("_cuda_kernel")[0].split("__locals__")[-1])
                    elif "registers" in line or "spill" in line:
                        print("       ", line.replace("ptxas info    : ", ""))
            report["modules"].append(row)
            if args.out:  # after each module: a run cut short keeps what it measured
                with open(args.out, "w", encoding="utf-8") as f:
                    json.dump(report, f, indent=1)
    shutil.rmtree(tmp, ignore_errors=True)
    if report["modules"]:
        slowest = max(report["modules"], key=lambda r: max(r.get(f"{fmt}_seconds", 0.0) for fmt in args.formats))
        print(f"largest compile: {slowest['kernels']} (" + ", ".join(
            f"{fmt.upper()} {slowest[f'{fmt}_seconds']:.1f} s" for fmt in args.formats) + ")")


def _print_inlining(info: dict, top: int = 8):
    print(f"    {info['lines']:,} lines once every function is inlined, from {info['source_lines']:,} of source "
          f"({info['lines'] / max(1, info['source_lines']):.1f}x); the largest shares of repeated copies:")
    for r in info["functions"][:top]:
        callers = ", ".join(f"{g} {c}x" for g, c in r["called_from"].items())
        print(f"    {100 * r['repeated_share']:5.1f}% repeated: {r['name']}, {r['copies']} copies of "
              f"{r['lines'] // r['copies']:,} lines (called from {callers})")


if __name__ == "__main__":
    main()
