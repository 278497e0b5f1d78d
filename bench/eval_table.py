"""Evaluation error of the device expansions (float32 Warp, kernels/element.py) against the
float64 numpy oracle (engine/expansions.py), every shape x order 1..14.

The comparison (random fields of each family at random reference points, near the collapsed
vertex/edges and at the vertices; kernel error and end-to-end error against the float64 oracle)
is hovr_blender/audit/evaluation.eval_compare, which tests/engine/test_stress.py runs on fewer points; this script
runs it on every (family, shape, order) and writes the table.

    python -m bench.eval_table --device cpu --out bench/results/eval_table.json
    python -m bench.eval_table --device cuda:0 --out $OUT/eval_table_cuda.json
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time

import warp as wp

from bench import common
from hovr_blender.audit.evaluation import EVAL_FAMILIES, eval_compare
from hovr_blender.engine import shapes

def markdown(rows, key="max_rel", fmt="{:.1e}"):
    cols = [(f, s) for f, shapes in EVAL_FAMILIES.items() for s in shapes]
    head = "| order | " + " | ".join(f"{f} {shapes.NAMES[s][:4]}" for f, s in cols) + " |"
    out = [head, "|" + "---|" * (len(cols) + 1)]
    look = {(r["family"], r["shape"], r["order"]): r for r in rows}
    for o in sorted({r["order"] for r in rows}):
        cells = []
        for f, s in cols:
            r = look.get((f, shapes.NAMES[s], o))
            cells.append("" if r is None else fmt.format(r[key]))
        out.append(f"| {o} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--families", default=",".join(EVAL_FAMILIES))
    ap.add_argument("--max-order", type=int, default=14)
    ap.add_argument("--out", default=str(common.RESULTS / "eval_table.json"))
    args = ap.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = str(wp.get_device(args.device))
    rows = []
    t0 = time.perf_counter()
    for fam in args.families.split(","):
        for shape in EVAL_FAMILIES[fam]:
            for order in range(1, args.max_order + 1):
                r = eval_compare(fam, shape, order, device, args.points, args.trials)
                rows.append(r)
                print(f"{fam:13s} {r['shape']:12s} order {order:2d}: max abs {r['max_abs']:.2e} rel {r['max_rel']:.2e} "
                      f"(kernel {r['max_rel_kernel']:.2e}; near collapse {r['max_rel_near_collapse']:.2e}, "
                      f"nonfinite {r['nonfinite']} + {r['nonfinite_near_collapse']} near collapse)", flush=True)
    commit = common.git("rev-parse", "--short", "HEAD") or ""
    cpu = platform.processor() or platform.machine()
    result = {
        "what": "float32 device expansions (kernels/element.eval_element) vs float64 numpy oracle",
        "date": datetime.date.today().isoformat(),
        "device": device if device != "cpu" else f"cpu ({cpu})",
        "device_name": wp.get_device(device).name,
        "warp": wp.config.version,
        "commit": commit,
        "command": "python -m bench.eval_table " + " ".join(argv if argv is not None else sys.argv[1:]),
        "seconds": round(time.perf_counter() - t0, 1),
        "rows": rows,
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=1)
    print(markdown(rows))
    print(markdown(rows, "max_rel_near_collapse"))
    print("written", args.out)


if __name__ == "__main__":
    main()
