"""Audit of the renderer against the independent reference (issue 15), in two stages.

    python -m scripts.audit render --device cuda:0 --size 1920x1080 --out audit.json [--datasets a,b]
        renders every dataset from three views (oblique, along the mesh lines, grazing) in
        float32 and float64 and keeps, per view, every pixel where the two differ by more than
        1e-4 (up to --max-gap) and a random sample of --sample others where the volume shows
        (seeded), with both values. Only that list leaves the GPU machine.
    python -m scripts.audit check audit.json --out bench/results/audit [--jobs 2]
        runs the independent reference (hovr_blender/audit, VTK, float64, ~1 s a pixel) on every
        listed pixel and writes one report per dataset: each pixel's float32 and float64 error,
        which side is wrong (> 1e-3), the reference's own error estimate and the cells the ray
        crosses; a summary per dataset and view.

Rays that cross a pyramid cannot be checked (VTK has no cell in the same space); they are
counted as such. The datasets are those of ../shared/data (skipped where absent) and the two
synthetic benchmark meshes.
"""
from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bench.common import RESULTS
from hovr_blender.audit.datasets import DATASETS, load, transfer_function, views

GAP = 1e-4  # float32 against float64: pixels listed for checking
WRONG = 1e-3  # against the reference: a wrong pixel (the project's target)


def render_stage(args):
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    W, H = map(int, args.size.split("x"))
    out = {"size": [W, H], "device": args.device, "gap": GAP, "datasets": {}}
    rng = np.random.default_rng(args.seed)
    for name in args.datasets.split(","):
        try:
            mesh, data = load(name)
        except FileNotFoundError as exc:
            print(f"{name}: skipped, missing {exc}", flush=True)
            continue
        tf = transfer_function(mesh)
        renderer = Renderer(mesh, args.device)
        entry = {"data": data, "transfer_function": tf.to_contract(), "elements": mesh.num_elements, "views": {}}
        for vname, cam in views(mesh).items():
            camera = RayCamera.from_contract(cam, W, H)
            imgs, secs = {}, {}
            for precision, tol in (("float32", 1e-5), ("float64", 1e-9)):
                t0 = time.perf_counter()
                res = renderer.render(camera, tf, np.zeros(3), RenderOptions(method="split", precision=precision,
                                                                              tolerance=tol, min_transmittance=0.0,
                                                                              device=args.device))
                secs[precision] = time.perf_counter() - t0
                imgs[precision] = res.rgba.astype(np.float64)
            gap = np.abs(imgs["float32"] - imgs["float64"]).max(axis=2)
            gj, gi = np.nonzero(gap > GAP)
            order = np.argsort(-gap[gj, gi])[:args.max_gap]
            visible = np.nonzero((imgs["float64"][..., 3] > 0.002) & (gap <= GAP))
            pick = rng.choice(len(visible[0]), min(args.sample, len(visible[0])), replace=False)
            pixels = [(int(gi[k]), int(gj[k]), "gap") for k in order]
            pixels += [(int(visible[1][k]), int(visible[0][k]), "sample") for k in pick]
            entry["views"][vname] = {
                "camera": cam, "gap_pixels": int(len(gj)), "max_gap": float(gap.max()),
                "visible_pixels": int((imgs["float64"][..., 3] > 0.002).sum()), "seconds": secs,
                "pixels": [{"i": i, "j": j, "why": why, "float32": imgs["float32"][j, i].tolist(),
                            "float64": imgs["float64"][j, i].tolist()} for i, j, why in pixels]}
            print(f"{name} {vname}: {len(gj)} pixels differ by > {GAP} (max {gap.max():.2e}); "
                  f"{len(pixels)} listed; {secs['float32']:.2f} / {secs['float64']:.2f} s", flush=True)
        out["datasets"][name] = entry
        Path(args.out).write_text(json.dumps(out) + "\n")  # after each dataset: a cut-off run keeps what it did


def _pyramid_boxes(mesh):
    from hovr_blender.engine import shapes

    sel = mesh.shape == shapes.PYR
    return mesh.vertices[sel].min(axis=1), mesh.vertices[sel].max(axis=1)


def _check_dataset(job):
    """One dataset's report (a worker process: VTK objects stay in it)."""
    name, entry, size = job
    from hovr_blender.audit import vtk_reference as R
    from hovr_blender.audit import vtk_volume
    from hovr_blender.engine import shapes

    mesh, data = load(name)
    tf = entry["transfer_function"]
    color = np.asarray(tf["color"], float)
    density = np.asarray(tf["density"], float)
    if data is not None and data["path"].endswith(".vtu"):
        grid = vtk_volume.read_vtu(data["path"], data["field"])
    else:
        keep = mesh.shape != shapes.PYR
        grid = vtk_volume.from_mesh(_without(mesh, keep)) if not keep.all() else vtk_volume.from_mesh(mesh)
    pyr_lo, pyr_hi = _pyramid_boxes(mesh)
    ref = R.IndependentReference(grid, color[:, 0], color[:, 1:], density[:, 0], density[:, 1], tol=1e-10)
    W, H = size
    report = {"dataset": name, "elements": entry["elements"], "views": {}}
    for vname, v in entry["views"].items():
        rows = []
        for p in v["pixels"]:
            o, d = R.contract_ray(v["camera"], W, H, p["i"], p["j"])
            if len(pyr_lo) and _ray_meets_boxes(o, d, pyr_lo, pyr_hi):
                rows.append({**p, "checkable": False})
                continue
            t0 = time.perf_counter()
            r = ref.pixel(o, d, np.zeros(3))
            e32 = float(np.abs(np.asarray(p["float32"]) - r.rgba).max())
            e64 = float(np.abs(np.asarray(p["float64"]) - r.rgba).max())
            rows.append({**p, "checkable": True, "reference": r.rgba.tolist(), "reference_error": r.error,
                         "error_float32": e32, "error_float64": e64,
                         "wrong": [s for s, e in (("float32", e32), ("float64", e64)) if e > WRONG],
                         "cells": sorted({c for _, _, c in r.stretches}), "notes": r.notes,
                         "seconds": round(time.perf_counter() - t0, 2)})
        checked = [r for r in rows if r["checkable"]]
        report["views"][vname] = {
            "gap_pixels": v["gap_pixels"], "max_gap": v["max_gap"], "listed": len(rows), "checked": len(checked),
            "not_checkable_pyramids": len(rows) - len(checked),
            "wrong_float32": sum("float32" in r["wrong"] for r in checked),
            "wrong_float64": sum("float64" in r["wrong"] for r in checked),
            "max_error_float32": max((r["error_float32"] for r in checked), default=None),
            "max_error_float64": max((r["error_float64"] for r in checked), default=None),
            "max_reference_error": max((r["reference_error"] for r in checked), default=None),
            "pixels": rows}
        print(f"{name} {vname}: {len(checked)} checked, wrong f32 {report['views'][vname]['wrong_float32']}, "
              f"f64 {report['views'][vname]['wrong_float64']}", flush=True)
    return name, report


def _without(mesh, keep):
    from hovr_blender.engine.mesh import VolumeMesh

    idx = np.nonzero(keep)[0]
    return VolumeMesh.from_elements(mesh.shape[idx], mesh.modes[idx], [mesh.element_coeffs(e) for e in idx],
                                    mesh.geom_modes[idx],
                                    [mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] +
                                                      _num_geom(mesh, e)] for e in idx])


def _num_geom(mesh, e):
    from hovr_blender.engine import expansions

    return expansions.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e])


def _ray_meets_boxes(o, d, lo, hi):
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    tmin = np.nanmax(np.minimum(ta, tb), axis=1)
    tmax = np.nanmin(np.maximum(ta, tb), axis=1)
    return bool(np.any(tmax >= np.maximum(tmin, 0.0)))


def check_stage(args):
    audit = json.loads(Path(args.audit).read_text())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # one job per dataset and view: the views of a large dataset check side by side
    jobs = [(name, {**entry, "views": {vname: view}}, audit["size"]) for name, entry in audit["datasets"].items()
            if not args.datasets or name in args.datasets.split(",") for vname, view in entry["views"].items()]
    summary = {"size": audit["size"], "device": audit["device"], "datasets": {}}
    reports = {}
    with ProcessPoolExecutor(args.jobs) as pool:
        for name, report in pool.map(_check_dataset, jobs):
            if name in reports:
                reports[name]["views"].update(report["views"])
            else:
                reports[name] = report
    for name, report in reports.items():
        (out / f"{name}.json").write_text(json.dumps(report, indent=1) + "\n")
        summary["datasets"][name] = {v: {k: x for k, x in r.items() if k != "pixels"}
                                     for v, r in report["views"].items()}
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="stage", required=True)
    r = sub.add_parser("render")
    r.add_argument("--device", default="cuda:0")
    r.add_argument("--size", default="1920x1080")
    r.add_argument("--datasets", default=",".join(DATASETS))
    r.add_argument("--sample", type=int, default=70, help="random pixels per view (3 views: >= 200 a dataset)")
    r.add_argument("--max-gap", type=int, default=400)
    r.add_argument("--seed", type=int, default=15)
    r.add_argument("--out", required=True)
    c = sub.add_parser("check")
    c.add_argument("audit")
    c.add_argument("--out", default=str(RESULTS / "audit"))
    c.add_argument("--datasets", default="")
    c.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    render_stage(args) if args.stage == "render" else check_stage(args)


if __name__ == "__main__":
    main()
