"""Load time and memory of the real Nektar++ and VTU files (issue: open real data).

    python -m bench.load [--out bench/results/cpu/load.json] [--repeats 3] [--cases hump3D,ngsolve_ball]
                         [--package-root DIR]

Each file is read in a fresh subprocess through the loader every front end uses
(io/sources.load_volume), --repeats times, and the run of least CPU time is kept: the read's
wall and CPU seconds (CPU time is what a busy shared machine disturbs least), the CPU seconds
spent certifying the elements (engine/validity.check_elements, None for a package without it),
the process's peak resident memory growth during the read (ru_maxrss), and the bytes of the
arrays the VolumeMesh keeps (what the renderer uploads from).
--package-root loads through another checkout's hovr_blender (to compare two commits on one
machine: run both, alternating, on a quiet machine).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time

from bench import common

# name: (file under ../shared/data, solution file or "", field or "")
CASES = {
    "hump3D": ("nektar/hump3D_GLL.xml", "nektar/hump3D.rst", "rho"),
    "scaleHO": ("nektar/scaleHO.xml", "", ""),
    "ngsolve_ball": ("vtu/ngsolve_ball_poisson_hex_p6.vtu", "", "u"),
    "mfem_fichera": ("vtu/mfem_fichera_poisson_mixed_p4.vtu", "", "u"),
    "pyfr_tgv": ("vtu/pyfr_tgv_hexprism_p4_t4.vtu", "", "Density"),
    "ngsolve_post": ("vtu/ngsolve_post_heat_tetprism_p4.vtu", "", "temperature"),
}

CHILD = r"""
import json, resource, time
import numpy as np
from hovr_blender.io.sources import VolumeSource, load_volume
try:
    from hovr_blender.engine import validity
except ImportError:
    validity = None
spent = [0.0]
if validity is not None:
    check = validity.check_elements

    def timed(*args, **kwargs):
        t = time.process_time()
        try:
            return check(*args, **kwargs)
        finally:
            spent[0] += time.process_time() - t

    validity.check_elements = timed
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0, c0 = time.perf_counter(), time.process_time()
m = load_volume(VolumeSource.resolve({path!r}, {solution!r}, {field!r}))
dt, cpu = time.perf_counter() - t0, time.process_time() - c0
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
kept = sum(v.nbytes for v in vars(m).values() if isinstance(v, np.ndarray))
print(json.dumps({{"seconds": dt, "cpu_seconds": cpu, "validity_cpu_seconds": spent[0] if validity is not None else None,
                  "peak_rss_growth_MB": (after - before) / 1024.0, "mesh_arrays_MB": kept / 2**20,
                  "elements": int(m.num_elements), "curved": int((~m.affine).sum())}}))
"""


def measure(name, repeats, root):
    path, solution, field = CASES[name]
    code = CHILD.format(path=str(common.DATA / path), solution=str(common.DATA / solution) if solution else "",
                        field=field)
    env = dict(os.environ, PYTHONPATH=str(root))
    runs = []
    for _ in range(repeats):
        res = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True,
                             check=True)
        runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
    best = min(runs, key=lambda r: r["cpu_seconds"])
    best["all_cpu_seconds"] = [round(r["cpu_seconds"], 3) for r in runs]
    return best


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(common.RESULTS / "cpu" / "load.json"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--package-root", default=str(common.REPO))
    args = ap.parse_args(argv)
    root = os.path.abspath(args.package_root)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.processor() or platform.machine()}, "
           f"{os.cpu_count()} cores", "command": common.command_line(),
           "commit": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                    text=True).stdout.strip() or None,
           "repeats": args.repeats, "files": {}}
    for name in args.cases.split(","):
        out["files"][name] = measure(name, args.repeats, root)
        print(name, out["files"][name], flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
