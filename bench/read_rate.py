"""How long the reader process takes a MB of each shared dataset (processor and wall time), and its
longest stretch without progress: the numbers behind the read time limit (engine/limits.py
READ_SECONDS_PER_MB, processor time, and READ_STALL_SECONDS; issue 41).

    python -m bench.read_rate [--out bench/results/cpu/read_rate.json] [--repeat 3] [--only NAME ...]

Each dataset is read by io.sources.load_volume in a fresh reader process (its parsed-geometry cache
cold, as a first import), under a flat limit so that nothing is stopped. For each read: the seconds
from the reader's start of reading to its reply, the processor time the reader last reported (what
the time limit measures), the MB of the files it opened (what the limit allows for), processor
seconds a MB, and the longest gap between two of its progress reports, in wall time and in the
reader's processor time (the stall check's clock; the reply counts as the last report). The worst of --repeat runs
is kept: the limit must hold for the slowest honest read on a loaded machine.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

from bench import common
from bench.load import DATASETS
from hovr_blender.engine import limits
from hovr_blender.io import isolation
from hovr_blender.io.sources import VolumeSource


def read_once(source) -> dict:
    """One cold read in a fresh reader process: seconds, MB opened, longest gap between reports."""
    isolation.shutdown()  # a fresh reader: the mesh cache is cold
    request = isolation.read_volume_request(source)
    times, cpus = [], []

    def timed():
        times.append(time.monotonic())
        cpus.append(request.reader_cpu_seconds())

    request.on_message = timed
    isolation.wait(request)
    seconds = times[-1] - times[0]
    gaps = [b - a for a, b in zip(times, times[1:])]
    cpu_gaps = [b - a for a, b in zip(cpus, cpus[1:]) if a is not None and b is not None]
    mb = request.opened_bytes / 1e6
    cpu = cpus[-1] - cpus[0] if cpus and None not in (cpus[0], cpus[-1]) else request.cpu_seconds
    return {"seconds": seconds, "cpu_seconds": cpu, "mb": mb, "cpu_seconds_per_mb": cpu / mb if mb else None, "longest_gap": max(gaps, default=0.0),
            "longest_cpu_gap": max(cpu_gaps, default=0.0), "reports": len(times)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", nargs="*")
    args = ap.parse_args(argv)
    rows = {}
    with limits.using(limits.ResourceLimits(max_read_seconds=3600.0)):
        for name, (path, solution, field) in DATASETS.items():
            if args.only and name not in args.only:
                continue
            source = VolumeSource.resolve(str(common.DATA / path), str(common.DATA / solution) if solution else "",
                                          field or "")
            runs = [read_once(source) for _ in range(args.repeat)]
            worst = {k: max(r[k] for r in runs if r[k] is not None) if any(r[k] is not None for r in runs) else None
                     for k in runs[0]}
            rows[name] = worst
            print(f"{name:22s} {worst['mb']:7.3f} MB {worst['seconds']:6.2f} s, processor {worst['cpu_seconds']:6.2f} s "
                  f"{(worst['cpu_seconds_per_mb'] or 0):6.2f} s/MB  longest gap {worst['longest_gap']:5.2f} s, "
                  f"processor {worst['longest_cpu_gap']:5.2f} s", flush=True)
    print(f"limits: {limits.READ_BASE_SECONDS:g} s + {limits.READ_SECONDS_PER_MB:g} s/MB of processor time, "
          f"stall {limits.READ_STALL_SECONDS:g} s")
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"machine": platform.node(), "load_average": os.getloadavg(), "command": common.command_line(),
                   "commit": common.git("rev-parse", "HEAD"), "datasets": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
