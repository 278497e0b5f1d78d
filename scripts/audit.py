"""Audit of the renderer against the independent reference (issue 15), in two stages.

    python scripts/audit.py render --device cuda:0 --size 1920x1080 --out audit.json [--datasets a,b]
        renders every dataset from three views (oblique, along the mesh lines, grazing) in
        float32 and float64 and keeps, per view, every pixel where the two differ by more than
        1e-4 (up to --max-gap) and a random sample of --sample others where the volume shows
        (seeded), with both values. Only that list leaves the GPU machine.
    python scripts/audit.py check audit.json --out bench/results/audit [--jobs 2]
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
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

SHARED = Path(os.environ.get("HOVR_DATA", REPO.parent / "shared" / "data"))  # HOVR_DATA: elsewhere (GPU machine)
GAP = 1e-4  # float32 against float64: pixels listed for checking
WRONG = 1e-3  # against the reference: a wrong pixel (the project's target)

DATASETS = {
    "hump3D": {"path": "nektar/hump3D_GLL.xml", "solution": "nektar/hump3D.rst", "field": "rho"},
    "Hex_CurvedFace": {"path": "nektar/Hex_CurvedFace.xml", "solution": "nektar/Hex_CurvedFace.fld", "field": "u"},
    "Hex_Mushroom": {"path": "nektar/Hex_Mushroom.xml", "solution": "nektar/Hex_Mushroom.fld", "field": "u"},
    "RotPerBcs3D_Annulus": {"path": "nektar/RotPerBcs3D_Annulus.xml"},
    "Pyr_channel_m6": {"path": "nektar/Pyr_channel_m6.xml"},
    "scaleHO": {"path": "nektar/scaleHO.xml"},
    "ngsolve_ball": {"path": "vtu/ngsolve_ball_poisson_hex_p6.vtu", "field": "u"},
    "mfem_fichera": {"path": "vtu/mfem_fichera_poisson_mixed_p4.vtu", "field": "u"},
    "ngsolve_post": {"path": "vtu/ngsolve_post_heat_tetprism_p4.vtu", "field": "temperature"},
    "pyfr_tgv": {"path": "vtu/pyfr_tgv_hexprism_p4_t4.vtu", "field": "Pressure"},
    "paper_scale": {"synthetic": "paper_scale"},
    "curved_mixed_cube": {"synthetic": "curved_mixed_cube"},
}


def load(name):
    """(VolumeMesh, data spec or None) of a dataset."""
    spec = DATASETS[name]
    if "synthetic" in spec:
        if spec["synthetic"] == "paper_scale":
            from hovr_blender.io.paper_scale import paper_scale_mesh

            return paper_scale_mesh(), None
        from hovr_blender.io.synthetic import curved_cube

        return curved_cube(4), None  # the benchmark suite's curved mixed cube (full size)
    from hovr_blender.io.sources import VolumeSource, load_volume

    data = {k: str(SHARED / v) if k in ("path", "solution") else v for k, v in spec.items()}
    for k in ("path", "solution"):
        if k in data and not os.path.exists(data[k]):
            raise FileNotFoundError(data[k])
    return load_volume(VolumeSource.from_view_data(data)), data


def framing(mesh):
    lo, hi = mesh.vertices.reshape(-1, 3).min(0), mesh.vertices.reshape(-1, 3).max(0)
    return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)), lo, hi


def views(mesh):
    """Three cameras (render contract): oblique (the benchmark suite's direction and distance);
    along the x axis (the mesh lines of axis-aligned meshes); grazing the top of the bounding box."""
    c, r, lo, hi = framing(mesh)
    d = np.array([1.0, -0.8, 0.7]) / np.linalg.norm([1.0, -0.8, 0.7])
    top = np.array([c[0], c[1], hi[2]])
    return {
        "oblique": {"eye": (c + 2.6 * r * d).tolist(), "target": c.tolist(), "up": [0, 0, 1], "fov_y_deg": 30.0},
        "along_x": {"eye": (c + np.array([2.6 * r, 1e-3 * r, 0.0])).tolist(), "target": c.tolist(), "up": [0, 0, 1],
                    "fov_y_deg": 45.0},
        "grazing": {"eye": (top + np.array([0.0, -2.6 * r, 0.02 * r])).tolist(), "target": top.tolist(),
                    "up": [0, 0, 1], "fov_y_deg": 30.0},
    }


def transfer_function(mesh):
    """Three tents over the field's range with an optical depth of a few across the data; a
    constant density where the field is constant (then the image measures the geometry)."""
    from hovr_blender.engine.transfer_function import TransferFunction

    c, r, lo, hi = framing(mesh)
    vals = mesh.field_samples(4)
    a, b = (float(v) for v in np.percentile(vals, [2, 98]))
    if b - a <= 1e-12 * max(1.0, abs(a)):
        return TransferFunction.from_contract({"color": [[a - 1, 0.2, 0.5, 1.0], [a + 1, 0.2, 0.5, 1.0]],
                                               "density": [[a - 1, 1.0 / r], [a + 1, 1.0 / r]]})
    q = [a + (b - a) * t for t in (0.2, 0.3, 0.4, 0.6, 0.7, 0.8)]
    return TransferFunction.from_contract({
        "color": [[a, 0.1, 0.2, 1.0], [0.5 * (a + b), 0.2, 1.0, 0.3], [b, 1.0, 0.3, 0.1]],
        "density": [[a, 0.0], [q[0], 0.0], [q[1], 3.0 / r], [q[2], 0.0], [q[3], 0.0], [q[4], 6.0 / r], [q[5], 0.0], [b, 0.0]]})


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
    from hovr_blender.audit import reference as R
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
    c.add_argument("--out", default=str(REPO / "bench" / "results" / "audit"))
    c.add_argument("--datasets", default="")
    c.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    render_stage(args) if args.stage == "render" else check_stage(args)


if __name__ == "__main__":
    main()
