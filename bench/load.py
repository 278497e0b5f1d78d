"""Load time of every shared dataset, read in this process and in the reader process (issue 29).

    python -m bench.load [--out bench/results/cpu/load.json] [--repeat 3] [--only NAME ...] [--package-root DIR]

Each (dataset, mode) runs in a fresh subprocess that loads the data twice with
io.sources.load_volume: `first` is what a `hovr` command or Blender's first import pays (with
the reader process: starting it, its imports included), `again` a second load of the same source
in the same session (the warm reader process; in both modes Nektar++'s parsed-geometry cache
holds the mesh). Modes: HOVR_ISOLATION=0 (read here) and the default (the reader process). The
best of --repeat runs is kept; first_cpu_seconds is the first load's CPU time in this process
(what a busy shared machine disturbs least; in the reader mode the reader's work is not in it),
validity_cpu_seconds the part of it spent certifying elements (engine/validity.check_elements;
in process only, None where the package has no such check); peak_rss_growth_MB is this
process's (in the reader mode the reader process's memory is not in it), mesh_arrays_MB what
the VolumeMesh keeps. --package-root loads through another checkout's hovr_blender (two
commits on one machine: run both, alternating).
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

SHARED = str(common.DATA)
REPO = str(common.REPO)
# name -> (path, solution or None, field or None) under ../shared/data
DATASETS = {
    "hump3D": ("nektar/hump3D_GLL.xml", "nektar/hump3D.rst", "rho"),
    "scaleHO": ("nektar/scaleHO.xml", None, None),
    "Tet_channel_m3": ("nektar/Tet_channel_m3.xml", "nektar/Tet_channel_m3.fld", "w"),
    "wss_3D_periodic": ("nektar/wss_3D_periodic.xml", "nektar/wss_3D_periodic.fld", "rho"),
    "Hex_Mushroom": ("nektar/Hex_Mushroom.xml", "nektar/Hex_Mushroom.fld", "u"),
    "Womersley_PipeFlow": ("nektar/Womersley_PipeFlow.xml", None, None),
    "RotPerBcs3D_Annulus": ("nektar/RotPerBcs3D_Annulus.xml", None, None),
    "CubeAllElements": ("nektar/CubeAllElements.xml", None, None),
    "mfem_fichera": ("vtu/mfem_fichera_poisson_mixed_p4.vtu", None, None),
    "ngsolve_ball": ("vtu/ngsolve_ball_poisson_hex_p6.vtu", None, None),
    "ngsolve_tetprism": ("vtu/ngsolve_post_heat_tetprism_p4.vtu", None, None),
    "pyfr_tgv": ("vtu/pyfr_tgv_hexprism_p4_t4.vtu", None, None),
}

CHILD = r"""
import json, resource, sys, time
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
source = VolumeSource.resolve({path!r}, {sol!r} or "", {field!r} or "")
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0, c0 = time.perf_counter(), time.process_time()
m = load_volume(source)
first, first_cpu = time.perf_counter() - t0, time.process_time() - c0
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
load_volume(source)
again = time.perf_counter() - t0
kept = sum(v.nbytes for v in vars(m).values() if isinstance(v, np.ndarray))
print(json.dumps({{"first_seconds": first, "again_seconds": again, "first_cpu_seconds": first_cpu,
                  "validity_cpu_seconds": spent[0] if validity is not None and spent[0] > 0 else None,
                  "peak_rss_growth_MB": (after - before) / 1024.0,
                  "mesh_arrays_MB": kept / 2**20, "elements": int(m.num_elements)}}))
"""


def measure(name, isolated: bool, repeat: int, root: str = REPO) -> dict:
    path, sol, field = DATASETS[name]
    code = CHILD.format(path=os.path.join(SHARED, path), sol=os.path.join(SHARED, sol) if sol else None, field=field)
    env = dict(os.environ, PYTHONPATH=root, HOVR_ISOLATION="1" if isolated else "0")
    runs = []
    for _ in range(repeat):
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
        runs.append(json.loads(res.stdout.strip().splitlines()[-1]))
    best = {k: min(r[k] for r in runs) for k in ("first_seconds", "again_seconds", "first_cpu_seconds")}
    return {**runs[0], **best}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(common.RESULTS / "cpu" / "load.json"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--package-root", default=REPO)
    args = ap.parse_args(argv)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.processor() or platform.machine()}, "
           f"{os.cpu_count()} cores", "command": common.command_line(),
           "load_average_at_start": os.getloadavg()[0] if hasattr(os, "getloadavg") else None, "datasets": {}}
    for name in args.only or DATASETS:
        if not os.path.exists(os.path.join(SHARED, DATASETS[name][0])):
            print(name, "missing: skipped", flush=True)
            continue
        root = os.path.abspath(args.package_root)
        here, there = measure(name, False, args.repeat, root), measure(name, True, args.repeat, root)
        row = {"in_process": here, "reader_process": there,
               "first_extra_seconds": round(there["first_seconds"] - here["first_seconds"], 3),
               "again_ratio": round(there["again_seconds"] / max(here["again_seconds"], 1e-9), 3)}
        out["datasets"][name] = row
        print(name, json.dumps({k: row[k] for k in ("first_extra_seconds", "again_ratio")}),
              f"first {here['first_seconds']:.3f} -> {there['first_seconds']:.3f} s, again {here['again_seconds']:.3f}"
              f" -> {there['again_seconds']:.3f} s", flush=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
