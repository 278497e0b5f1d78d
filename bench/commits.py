"""The same frames at several commits, each commit's package in its own process: the baseline
beside the change, on one machine, in one run (issue 28's rule for quoting a speed-up).

    python -m bench.commits views --size 1920x1080 --out .gpu/bench/views      (here: the view files)
    python -m bench.commits time --views DIR --tree NAME=PATH [--tree ...] --device cuda:0 \\
        --methods split,classified --repeats 5 --out $OUT/commits.json          (there: the timings)
    python -m bench.commits table RUN.json [RUN.json ...]                   (the docs' table)

`views` writes one view file per dataset: the audit's oblique camera and three-tent transfer
function (hovr_blender/audit/datasets.py), the data path relative to the view file as
`../data/<kind>/<file>`, so that the folder works wherever a `data` folder (the shared data's
copy, or a link to it) sits beside it. The paper-scale channel has no
file: its view names `{"synthetic": "paper_scale"}`, which the timing process builds itself.

`time` runs, for each tree (a plain copy of a commit's files, `git archive COMMIT | tar -x`),
a fresh Python with PYTHONPATH=tree that imports only what every commit since c91ea4a has: the
view file's loader (`View.load`, then `load_mesh()` or `io.load_view_data`), `Renderer(mesh,
device).render(camera, tf, background, options)` and `options.with_(method=...)`. Each commit
renders at its own defaults for the method (what its user gets). Per frame: one warm-up render
(kernels loaded, buffers sized), then the best of --repeats, from the commit's own
`stats["render_seconds"]`, and the image's digest and its max difference from the first tree's.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile

_CHILD = r"""
import hashlib, json, os, sys, time
import numpy as np

spec = json.loads(sys.argv[1])
try:
    from hovr_blender.engine.view import View
    from hovr_blender.engine import renderer as renderer_module
    pkg = "hovr_blender.engine"
except ImportError:
    from hovr_blender.core.view import View
    from hovr_blender.core import renderer as renderer_module
    pkg = "hovr_blender.core"


def load(view, doc):
    if doc.get("data", {}).get("synthetic") == "paper_scale":
        from hovr_blender.io.paper_scale import paper_scale_mesh
        return paper_scale_mesh()
    if hasattr(view, "load_mesh"):
        return view.load_mesh()
    from hovr_blender.io import load_view_data
    return load_view_data(view)


rows = []
for path in spec["views"]:
    name = os.path.splitext(os.path.basename(path))[0]
    doc = json.load(open(path))
    if doc["data"].get("synthetic"):
        doc = dict(doc, data={"builtin": "sphere"})  # a loadable stand-in; the mesh is built in load()
        tmp = path + ".loadable.json"
        json.dump(doc, open(tmp, "w"))
        view = View.load(tmp)
        os.unlink(tmp)
        doc = json.load(open(path))
    else:
        view = View.load(path)
    try:
        t0 = time.perf_counter()
        mesh = load(view, doc)
        load_s = time.perf_counter() - t0
        r = renderer_module.Renderer(mesh, spec["device"])
    except Exception as exc:
        rows.append({"dataset": name, "error": f"{type(exc).__name__}: {exc}"})
        continue
    for method in spec["methods"]:
        row = {"dataset": name, "method": method, "elements": int(mesh.num_elements), "load_seconds": load_s}
        try:
            opts = view.options.with_(method=method, device=spec["device"])
            t0 = time.perf_counter()
            r.render(view.camera, view.transfer_function, view.background, opts)
            row["first_render_seconds"] = time.perf_counter() - t0
            best = None
            for _ in range(spec["repeats"]):
                res = r.render(view.camera, view.transfer_function, view.background, opts)
                if best is None or res.stats["render_seconds"] < best.stats["render_seconds"]:
                    best = res
            s = best.stats
            rgba = np.ascontiguousarray(best.rgba, dtype=np.float32)
            row.update(seconds=s["render_seconds"], options=opts.as_dict(),
                       stats={k: v for k, v in s.items() if isinstance(v, (int, float, str))},
                       digest=hashlib.sha256(rgba.tobytes()).hexdigest()[:16])
            np.save(os.path.join(spec["images"], f"{name}-{method}.npy"), rgba)
        except Exception as exc:
            row["error"] = f"{type(exc).__name__}: {exc}"
        rows.append(row)
        print(json.dumps(row)[:300], flush=True)
print("HOVR-COMMITS " + json.dumps({"package": pkg, "rows": rows}))
"""


def write_views(size: str, out: str) -> list[str]:
    """One view file per audit dataset whose files exist (and the paper-scale channel)."""
    import numpy as np

    from hovr_blender.audit import datasets as audit

    W, H = map(int, size.split("x"))
    os.makedirs(out, exist_ok=True)
    written = []
    for name in audit.SHARED_DATASETS:
        try:
            mesh, data = audit.load(name)
        except FileNotFoundError as exc:
            print(f"{name}: skipped, no {exc}")
            continue
        if data is None:
            data = {"synthetic": "paper_scale"}
        else:
            data = {k: ("../data/" + os.path.relpath(v, audit.SHARED) if k in ("path", "solution") else v)
                    for k, v in data.items()}
        tf = audit.transfer_function(mesh)
        doc = {"data": data, "camera": audit.views(mesh)["oblique"], "image": {"width": W, "height": H},
               "transfer_function": tf.to_contract(), "background": [0.0, 0.0, 0.0]}
        path = os.path.join(out, f"{name}.json")
        with open(path, "w") as f:
            json.dump(doc, f, indent=1, default=lambda v: np.asarray(v).tolist())
        written.append(path)
        print(f"{name}: {path}")
    return written


def time_trees(trees: list[tuple[str, str]], views: list[str], device: str, methods: list[str], repeats: int,
               images: str, progress=lambda partial: None) -> dict:
    """{tree name: that tree's rows}; progress(partial) after each tree (a long run keeps what it has)."""
    out = {}
    for name, tree in trees:
        img_dir = os.path.join(images, name)
        os.makedirs(img_dir, exist_ok=True)
        spec = {"views": views, "device": device, "methods": methods, "repeats": repeats, "images": img_dir}
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.abspath(tree)] + [p for p in os.environ.get(
            "PYTHONPATH", "").split(os.pathsep) if p]))
        proc = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(spec)], env=env, cwd=tempfile.gettempdir(),
                              capture_output=True, text=True)
        sys.stdout.write(f"== {name} ({tree})\n" + proc.stdout[-4000:] + proc.stderr[-2000:])
        line = [ln for ln in proc.stdout.splitlines() if ln.startswith("HOVR-COMMITS ")]
        out[name] = json.loads(line[-1][len("HOVR-COMMITS "):]) if line else {"error": proc.stderr[-2000:]}
        progress(out)
    first = trees[0][0]
    import numpy as np

    for name, _ in trees[1:]:
        for row in out[name].get("rows", []):
            a = os.path.join(images, first, f"{row['dataset']}-{row.get('method')}.npy")
            b = os.path.join(images, name, f"{row['dataset']}-{row.get('method')}.npy")
            if os.path.exists(a) and os.path.exists(b):
                row[f"max_abs_difference_vs_{first}"] = float(np.abs(np.load(a).astype(np.float64) - np.load(b)).max())
    return out


def table(runs: list[dict], labels: list[str]) -> str:
    """A markdown table, one row per dataset and method, one column per (run, tree) in milliseconds
    per frame (the best of the run's repeats); a tree missing a frame shows why in a footnote."""
    columns, cells, notes = [], {}, []
    for run, label in zip(runs, labels):
        for tree, res in run["results"].items():
            col = f"{tree} ({label})"
            columns.append(col)
            if "error" in res:
                notes.append(f"{col}: {res['error'].strip().splitlines()[-1][:160]}")
            for row in res.get("rows", []):
                if "seconds" in row:
                    cells[(row["dataset"], row["method"]), col] = f"{1000 * row['seconds']:.0f}"
                else:  # the dataset failed to load at that commit: no frame of either method
                    notes.append(f"{col}, {row['dataset']}: {row.get('error', '?')[:160]}")
    keys = sorted({k for k, _ in cells})
    lines = ["| data | method | " + " | ".join(columns) + " |", "|---|---|" + "---|" * len(columns)]
    lines += [f"| {d} | {m} | " + " | ".join(cells.get(((d, m), c), "") for c in columns) + " |" for d, m in keys]
    return "\n".join(lines + [""] + [f"- {n}" for n in notes])


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m bench.commits", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    v = sub.add_parser("views", help="write the view files")
    v.add_argument("--size", default="1920x1080")
    v.add_argument("--out", required=True)
    t = sub.add_parser("time", help="time the views at each tree")
    t.add_argument("--views", required=True, help="a folder of view files (from `views`)")
    t.add_argument("--only", default="", help="dataset names, comma-separated (default: every view)")
    t.add_argument("--tree", action="append", required=True, help="NAME=PATH of a commit's files; the first is the baseline")
    t.add_argument("--device", default="cuda:0")
    t.add_argument("--methods", default="split,classified")
    t.add_argument("--repeats", type=int, default=5)
    t.add_argument("--images", default=os.path.join(tempfile.gettempdir(), "hovr-commits"))
    t.add_argument("--out", required=True)
    r = sub.add_parser("table", help="print the markdown table of one or more runs' JSON")
    r.add_argument("runs", nargs="+")
    args = ap.parse_args(argv)
    if args.command == "table":
        runs = []
        for path in args.runs:
            with open(path) as f:
                runs.append(json.load(f))
        print(table(runs, [os.path.splitext(os.path.basename(p))[0] for p in args.runs]))
        return 0
    if args.command == "views":
        write_views(args.size, args.out)
        return 0
    names = [n for n in args.only.split(",") if n]
    views = sorted(os.path.abspath(os.path.join(args.views, f)) for f in os.listdir(args.views) if f.endswith(".json")
                   and (not names or f[:-5] in names))
    trees = [tuple(s.split("=", 1)) for s in args.tree]
    from bench.common import command_line

    result = {"date": datetime.date.today().isoformat(), "command": command_line(), "device": args.device,
              "trees": dict(trees), "methods": args.methods.split(","), "repeats": args.repeats}

    def save(partial):
        result["results"] = partial
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)

    save(time_trees(trees, views, args.device, args.methods.split(","), args.repeats, args.images, progress=save))
    return 0


if __name__ == "__main__":
    sys.exit(main())
