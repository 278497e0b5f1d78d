"""Load time and memory of the real Nektar++ files (issue: open real data).

    python -m bench.load [--out bench/results/cpu/load.json]

Each file is read in a fresh subprocess: wall time of read_nektar, the process's peak
resident memory growth during the read (ru_maxrss), and the bytes of the arrays the
VolumeMesh keeps (what the renderer uploads from).
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

DATA = str(common.DATA / "nektar")
CASES = {"hump3D": ("hump3D_GLL.xml", "hump3D.rst", "rho"), "scaleHO": ("scaleHO.xml", None, None)}

CHILD = r"""
import json, resource, time
import numpy as np
from hovr_blender.io.nektar import read_nektar
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
m = read_nektar({mesh!r}, {sol!r}, field={field!r})
dt = time.perf_counter() - t0
after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
kept = sum(v.nbytes for v in vars(m).values() if isinstance(v, np.ndarray))
print(json.dumps({{"seconds": dt, "peak_rss_growth_MB": (after - before) / 1024.0, "mesh_arrays_MB": kept / 2**20,
                  "elements": int(m.num_elements), "curved": int((~m.affine).sum())}}))
"""


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(common.RESULTS / "cpu" / "load.json"))
    args = ap.parse_args(argv)
    out = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.processor() or platform.machine()}, "
           f"{os.cpu_count()} cores", "command": "python -m bench.load", "files": {}}
    for name, (mesh, sol, field) in CASES.items():
        code = CHILD.format(mesh=os.path.join(DATA, mesh), sol=os.path.join(DATA, sol) if sol else None,
                            field=field)
        res = subprocess.run([sys.executable, "-c", code], cwd=common.REPO, capture_output=True, text=True, check=True)
        out["files"][name] = json.loads(res.stdout.strip().splitlines()[-1])
        print(name, out["files"][name], flush=True)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
