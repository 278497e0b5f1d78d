"""`python -m tests.hostile.table`: run every hostile case and print a markdown table per class
(cases, clear errors, worst time and peak memory) and one row per case; --json FILE saves it."""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import unittest
from pathlib import Path

from .cases import CASES as READER_CASES
from .harness import MAX_PEAK_MB, MAX_SECONDS, run_case
from .run_cases import BLENDER_RENDER_PEAK_MB, CLUSTER_SECONDS, RUN_CASES

CASES = READER_CASES + RUN_CASES  # the readers' inputs, then issue 29's runs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    rows = []
    for case in CASES:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                o, problems = run_case(case, Path(tmp))
            except unittest.SkipTest as why:  # a case that needs what this machine lacks (bpy)
                print(f"skip {case.klass:22s} {case.name:45s} {why}", file=sys.stderr, flush=True)
                continue
        rows.append({"class": case.klass, "case": case.name, "exit": o.returncode, "seconds": round(o.seconds, 2),
                     "peak_mb": round(o.peak_mb, 1), "passed": not problems, "problems": problems,
                     "message": o.stderr.strip()[:300]})
        print(f"{'ok  ' if not problems else 'FAIL'} {case.klass:22s} {case.name:45s} {o.seconds:5.2f} s "
              f"{o.peak_mb:6.0f} MB  {o.stderr.strip()[:110]}", file=sys.stderr, flush=True)
    print(f"\n| class | cases | passed | clear errors | legitimate, rendered | worst time | worst peak memory |")
    print("|---|---|---|---|---|---|---|")
    for klass in dict.fromkeys(r["class"] for r in rows):
        rs = [r for r in rows if r["class"] == klass]
        print(f"| {klass} | {len(rs)} | {sum(r['passed'] for r in rs)} | {sum(r['exit'] == 2 for r in rs)} | "
              f"{sum(r['exit'] == 0 for r in rs)} | {max(r['seconds'] for r in rs):.2f} s | "
              f"{max(r['peak_mb'] for r in rs):.0f} MB |")
    print(f"\nLimits: {MAX_SECONDS} s ({CLUSTER_SECONDS:g} s where a Dask cluster or Blender starts first), "
          f"{MAX_PEAK_MB:.0f} MB ({BLENDER_RENDER_PEAK_MB:.0f} MB where Blender renders a legitimate frame). {sum(r['passed'] for r in rows)} of {len(rows)} passed.")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0 if all(r["passed"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
