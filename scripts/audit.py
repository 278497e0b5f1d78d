"""Audit of the renderer against the independent reference (issues 15 and 36).

    python -m scripts.audit gpu --device cuda:0 --size 1920x1080 --out audit_gpu.json [--datasets a,b]
        issue 36: everything in one device command of at most 10 minutes. Every shared dataset
        (datasets.SHARED_DATASETS) from the audit's oblique view with its three tents, in
        float32 and float64, split and classified, at the options a user gets, beside the base
        (float64 split, tolerance 1e-7, no early termination). Decided by the independent
        reference, in a pool of --jobs processes beside the GPU work: every pixel where an
        image differs from the base by more than 1e-3 (at most --max-gap), each image's --top
        largest differences, and --sample random pixels whose rays pass through the domain (by
        the exact chords of audit/chords.py, which also show the reference where the ray is
        inside; a pixel the reference cannot decide is listed as reference_failed and another
        drawn in its place, up to REDRAWS_MAX a dataset). One JSON, rewritten after each dataset
        and every 30 s, cut at --deadline: every decided pixel over 1e-3 (any image against the reference) with its ray, the
        images' values and the reference; per dataset and image, pixels over 1e-3 against the
        base and against the reference and the largest errors. docs/benchmarks.md (issue 36)
        gives the device commands that carry Warp, VTK and the data there.
    python -m scripts.audit recheck audit_gpu.json --out audit_gpu-rechecked.json
        decides again, with this tree's reference, every pixel a gpu JSON lists over 1e-3 (against
        the images' values it kept): for a reference mended since the GPU run.
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

Rays through pyramids: VTK has no cell in the pyramid's (rational) space; affine pyramids are
decided by audit/pyramids.py (their exact inverse, the element's own expansion, the reference's
quadrature); rays that meet a curved pyramid cannot be checked and are counted as such. The
datasets are those of ../shared/data (or HOVR_DATA; skipped where absent) and the synthetic
benchmark meshes.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import shutil
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bench.common import RESULTS, jsonable
from hovr_blender.audit.datasets import DATASETS, SHARED_DATASETS, load, transfer_function, views

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


def reference_parts(mesh, data, tf: dict, grid=None):
    """(IndependentReference, unchecked lo, unchecked hi) of a dataset and its transfer function
    (contract dict): VTK's cells (a .vtu read by VTK; a project mesh converted, `grid` if given)
    and the affine pyramids (audit/pyramids.py); a ray that meets a box of `unchecked` (a curved
    pyramid) cannot be decided."""
    from hovr_blender.audit import vtk_reference as R
    from hovr_blender.audit import vtk_volume
    from hovr_blender.audit.pyramids import AffinePyramids
    from hovr_blender.engine import shapes

    color = np.asarray(tf["color"], float)
    density = np.asarray(tf["density"], float)
    pyramids = None
    if grid is None and data is not None and data["path"].endswith(".vtu"):
        grid = vtk_volume.read_vtu(data["path"], data["field"])
    elif grid is None:
        grid = vtk_grid(mesh)
    if data is None or not data["path"].endswith(".vtu"):
        pyr = np.nonzero(mesh.shape == shapes.PYR)[0]
        pyramids = AffinePyramids(mesh, pyr) if len(pyr) else None
    ref = R.IndependentReference(grid, color[:, 0], color[:, 1:], density[:, 0], density[:, 1], tol=1e-10,
                                 pyramids=pyramids)
    if pyramids is None:
        return ref, np.zeros((0, 3)), np.zeros((0, 3))
    return ref, pyramids.curved_lo, pyramids.curved_hi


def vtk_grid(mesh):
    """VTK's cells of a project mesh, its pyramids left out (None: none left)."""
    from hovr_blender.audit import vtk_volume
    from hovr_blender.engine import shapes
    from hovr_blender.engine.mesh import subset

    keep = mesh.shape != shapes.PYR
    if not keep.any():
        return None
    return vtk_volume.from_mesh(mesh if keep.all() else subset(mesh, np.nonzero(keep)[0]))


def _check_dataset(job):
    """One dataset's report (a worker process: VTK objects stay in it)."""
    name, entry, size = job
    from hovr_blender.audit import chords
    from hovr_blender.audit import vtk_reference as R

    mesh, data = load(name)
    ref, pyr_lo, pyr_hi = reference_parts(mesh, data, entry["transfer_function"])
    boundary = chords.Boundary(mesh)
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
            cover = chords.intervals(boundary, o[None], d[None])[0]
            r = ref.pixel(o, d, np.zeros(3), cover=cover)
            if r.failed:  # not decided: listed, never counted as checked
                rows.append({**p, "checkable": False, "reference_failed": r.failed})
                continue
            e32 = float(np.abs(np.asarray(p["float32"]) - r.rgba).max())
            e64 = float(np.abs(np.asarray(p["float64"]) - r.rgba).max())
            rows.append({**p, "checkable": True, "reference": r.rgba.tolist(), "reference_error": r.error,
                         "error_float32": e32, "error_float64": e64,
                         "wrong": [s for s, e in (("float32", e32), ("float64", e64)) if e > WRONG],
                         "cells": sorted({c for _, _, c in r.stretches}), "notes": r.notes,
                         "exact_chord": None if cover is None else sum(b - a for a, b in cover),
                         "reference_inside": _inside_length(r.stretches),
                         "seconds": round(time.perf_counter() - t0, 2)})
        checked = [r for r in rows if r["checkable"]]
        report["views"][vname] = {
            "gap_pixels": v["gap_pixels"], "max_gap": v["max_gap"], "listed": len(rows), "checked": len(checked),
            "not_checkable_curved_pyramids": sum(not r["checkable"] and "reference_failed" not in r for r in rows),
            "reference_failed": [r for r in rows if "reference_failed" in r],
            "wrong_float32": sum("float32" in r["wrong"] for r in checked),
            "wrong_float64": sum("float64" in r["wrong"] for r in checked),
            "max_error_float32": max((r["error_float32"] for r in checked), default=None),
            "max_error_float64": max((r["error_float64"] for r in checked), default=None),
            "max_reference_error": max((r["reference_error"] for r in checked), default=None),
            "pixels": rows}
        print(f"{name} {vname}: {len(checked)} checked, wrong f32 {report['views'][vname]['wrong_float32']}, "
              f"f64 {report['views'][vname]['wrong_float64']}", flush=True)
    return name, report


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
    with spawned_executor(args.jobs) as pool:
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


# ------------------------------------------------------------------ gpu: the whole audit, one call
# Issue 36: every shared dataset at full HD on the GPU, every disputed pixel and a random sample
# decided by the independent reference in a process pool beside it, one JSON, within one device
# command. The images: the defaults a user gets, and the comparison base.
IMAGES = {"float32-split": ("split", "float32"), "float32-classified": ("classified", "float32"),
          "float64-split": ("split", "float64"), "float64-classified": ("classified", "float64")}
BASE = "float64-split-1e-7"  # split, float64, tolerance 1e-7, no early ray termination
ALL_IMAGES = (*IMAGES, BASE)
PRIORITY_PREPARE, PRIORITY_GAP, PRIORITY_SAMPLE = (0, 0), 1, 2  # heap keys: (kind, rank)
SAMPLE_CHUNK = 4  # random pixels per pool job
# random pixels drawn again per dataset in place of those the reference could not decide (a cell
# whose map folds, a curved pyramid), so that the random pixels decided still reach --sample
REDRAWS_MAX = 64
GAP_CHUNK = 4
LOST = 1e-4  # of the diagonal: the reference's inside length short of the exact chord by more
PIXEL_KEYS = ("i", "j", "why", "exact_chord", "reference_inside", "reference_missed_chord", "reference",
              "reference_error", "errors", "seconds")  # what the JSON keeps of each decided pixel


def _image_options(name, device):
    from hovr_blender.engine.view import RenderOptions

    if name == BASE:
        return RenderOptions(method="split", precision="float64", tolerance=1e-7, min_transmittance=0.0, device=device)
    method, precision = IMAGES[name]
    return RenderOptions(method=method, precision=precision, device=device)


def _cache_files(cache, name):
    return os.path.join(cache, f"{name}.vtu"), os.path.join(cache, f"{name}.pkl")


def _prepare(name, cache, size):
    """A dataset's worker state, built once (its VTK grid written as .vtu, the rest pickled, for
    the other workers to read instead of converting the mesh again): the camera and tents of
    datasets.views / transfer_function, the exact chords' boundary and the pyramids."""
    import pickle

    from hovr_blender.audit import chords, vtk_volume
    from hovr_blender.audit.pyramids import AffinePyramids
    from hovr_blender.engine import shapes

    t0 = time.perf_counter()
    mesh, data = load(name)
    vtu, pkl = _cache_files(cache, name)
    grid = None
    if data is None or not data["path"].endswith(".vtu"):
        grid = vtk_grid(mesh)
        if grid is not None:
            vtk = vtk_volume.import_vtk()
            w = vtk.vtkXMLUnstructuredGridWriter()
            w.SetFileName(vtu + ".part")
            w.SetInputData(grid)
            w.SetDataModeToAppended()
            w.EncodeAppendedDataOff()
            w.Write()
            os.replace(vtu + ".part", vtu)
    pyr = np.nonzero(mesh.shape == shapes.PYR)[0]
    state = {"camera": views(mesh)["oblique"], "transfer_function": transfer_function(mesh).to_contract(),
             "size": size, "data": data, "boundary": chords.Boundary(mesh),
             "pyramids": AffinePyramids(mesh, pyr) if len(pyr) and (data is None or not data["path"].endswith(".vtu"))
             else None, "elements": int(mesh.num_elements),
             # for the rays the default search leaves undecided (_covers): built here once, not in each worker
             "dense": chords.dense_boundary(mesh)}
    with open(pkl + ".part", "wb") as f:
        pickle.dump(state, f)
    os.replace(pkl + ".part", pkl)
    return {"camera": state["camera"], "transfer_function": state["transfer_function"],
            "boundary_faces": len(state["boundary"].faces), "seconds": round(time.perf_counter() - t0, 1)}


@contextlib.contextmanager
def one_blas_thread():
    """Processes started inside start with one BLAS thread each (io/isolation.py's variables):
    the reference's products (a cell's shape functions times its nodes) are one thread's work,
    and a pool of 15 workers of 16 threads each oversubscribes the host. This process's own
    BLAS, already loaded, keeps its threads (so a forked worker would too: spawn)."""
    from hovr_blender.io.isolation import BLAS_THREADS

    saved = {k: os.environ.get(k) for k in BLAS_THREADS}
    os.environ.update(dict.fromkeys(BLAS_THREADS, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def spawned_executor(jobs):
    """A ProcessPoolExecutor of `jobs` spawned workers with one BLAS thread each (one_blas_thread: a
    forked worker would keep this process's threads). It starts its workers as work is submitted,
    so the variables stay set while it is open."""
    with one_blas_thread(), ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        yield pool


_STATE = {}


def _state(name, cache):
    """A worker's reference for a dataset, from _prepare's files (built once per worker)."""
    if name not in _STATE:
        import pickle

        from hovr_blender.audit import vtk_reference as R
        from hovr_blender.audit import vtk_volume

        vtu, pkl = _cache_files(cache, name)
        with open(pkl, "rb") as f:  # _prepare's own state, in this run's private mkdtemp folder: no outside bytes
            st = pickle.load(f)
        grid = None
        if st["data"] is not None and st["data"]["path"].endswith(".vtu"):
            grid = vtk_volume.read_vtu(st["data"]["path"], st["data"]["field"])
        elif os.path.exists(vtu):
            vtk = vtk_volume.import_vtk()
            r = vtk.vtkXMLUnstructuredGridReader()
            r.SetFileName(vtu)
            r.Update()
            grid = r.GetOutput()
        tf = st["transfer_function"]
        color, density = np.asarray(tf["color"], float), np.asarray(tf["density"], float)
        st["reference"] = R.IndependentReference(grid, color[:, 0], color[:, 1:], density[:, 0], density[:, 1],
                                                 tol=1e-10, pyramids=st["pyramids"])
        st["unchecked"] = ((st["pyramids"].curved_lo, st["pyramids"].curved_hi) if st["pyramids"] is not None
                           else (np.zeros((0, 3)), np.zeros((0, 3))))
        _STATE[name] = st
    return _STATE[name]


def _inside_length(stretches):
    """Length of the union of the reference's stretches (they may overlap)."""
    total, end = 0.0, -np.inf
    for a, b, _ in sorted(stretches):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def _covers(st, r):
    """Where each ray (r: (n, 6)) is inside the mesh, by the exact chords; rays their default
    search leaves undecided (odd crossings: mostly grazing a fold of the boundary) are searched
    again densely, so that the reference is told of a sliver it would step over. None where
    both leave it undecided."""
    from hovr_blender.audit import chords

    cover = chords.intervals(st["boundary"], r[:, :3], r[:, 3:]) if len(r) else []
    again = [k for k, iv in enumerate(cover) if iv is None]
    if again:
        redone = chords.intervals(st["dense"], r[again, :3], r[again, 3:], chords.dense_starts())
        for k, iv in zip(again, redone):
            cover[k] = iv
    return cover


def _decide(name, cache, kind, pixels, seed=0):
    """Reference rows for `pixels` [(i, j)] or, for kind "sample", for len(pixels) random pixels
    whose rays pass through the domain (exact chord > 0, or undecided), drawn from seed."""
    from hovr_blender.audit import vtk_reference as R

    st = _state(name, cache)
    W, H = st["size"]
    cam, boundary = st["camera"], st["boundary"]
    rays = lambda ij: np.array([np.concatenate(R.contract_ray(cam, W, H, i, j)) for i, j in ij]).reshape(-1, 6)
    if kind == "sample":
        rng = np.random.default_rng(seed)
        want, pixels, cover = len(pixels), [], []
        batch = max(8, 2 * want)  # the chords cost ~0.05 s a ray here: draw about what is needed
        while len(pixels) < want:
            ij = np.stack([rng.integers(0, W, batch), rng.integers(0, H, batch)], axis=1)
            r = rays(ij)
            for p, iv in zip(ij, _covers(st, r)):
                if iv is None or iv:  # through the domain, or undecided
                    pixels.append(tuple(map(int, p)))
                    cover.append(iv)
        pixels, cover = pixels[:want], cover[:want]
    else:
        r = rays(pixels)
        cover = _covers(st, r)
    rows = []
    for (i, j), iv in zip(pixels, cover):
        o, d = R.contract_ray(cam, W, H, i, j)
        chord = None if iv is None else sum(b - a for a, b in iv)
        row = {"i": int(i), "j": int(j), "why": kind, "origin": o.tolist(), "direction": d.tolist(),
               "exact_chord": chord}
        lo, hi = st["unchecked"]
        if len(lo) and _ray_meets_boxes(o, d, lo, hi):
            rows.append({**row, "checkable": False})
            continue
        t0 = time.perf_counter()
        res = st["reference"].pixel(o, d, np.zeros(3), cover=iv)
        if res.failed:  # not decided: listed, never counted as checked
            rows.append({**row, "checkable": False, "reference_failed": res.failed,
                         "seconds": round(time.perf_counter() - t0, 2)})
            continue
        inside = _inside_length(res.stretches)
        row.update(checkable=True, reference=res.rgba.tolist(), reference_error=res.error, notes=res.notes,
                   reference_inside=inside, seconds=round(time.perf_counter() - t0, 2),
                   reference_missed_chord=bool(chord is not None and abs(inside - chord) > LOST * boundary.scale))
        rows.append(row)
    return rows


def _worker(job):
    """One pool job: ("prepare", name) or (kind, name, pixels, seed); (job, result or error)."""
    import traceback

    try:
        if job[0] == "prepare":
            return job, _prepare(job[1], job[2], job[3])
        kind, name, cache, pixels, seed = job
        return job, _decide(name, cache, kind, pixels, seed)
    except Exception:  # reported in the JSON; the pool goes on with the rest
        return job, {"error": traceback.format_exc()[-2000:]}


class _Checker:
    """The process pool and its queue: jobs by priority (a dataset's preparation, then its
    disputed pixels largest first, then random pixels round-robin over the datasets), at most
    two per worker in flight; pixel jobs of a dataset wait for its preparation."""

    def __init__(self, jobs, cache):
        import heapq
        import itertools

        self.heapq, self.order, self.lock = heapq, itertools.count(), threading.Lock()
        self.jobs, self.cache = jobs, cache
        with one_blas_thread():  # a Pool starts its workers here
            self.pool = multiprocessing.get_context("spawn").Pool(jobs)  # spawn: no CUDA state is forked
        self.heap, self.inflight, self.waiting = [], {}, {}
        self.prepared, self.results, self.errors, self.redrawn = {}, {}, {}, {}

    def push(self, priority, job):
        with self.lock:
            name = job[1]
            if job[0] != "prepare" and name not in self.prepared:
                self.waiting.setdefault(name, []).append((priority, job))
            else:
                self.heapq.heappush(self.heap, (priority, next(self.order), job))
            self._pump()

    def _pump(self):
        while len(self.inflight) < 2 * self.jobs and self.heap:
            _, key, job = self.heapq.heappop(self.heap)
            self.inflight[key] = job
            self.pool.apply_async(_worker, (job,), callback=lambda res, key=key: self._done(key, res))

    def _done(self, key, res):
        job, out = res
        with self.lock:
            self.inflight.pop(key, None)
            name = job[1]
            if isinstance(out, dict) and "error" in out:
                self.errors.setdefault(name, []).append(out["error"])
                if job[0] == "prepare":
                    self.waiting.pop(name, None)
            elif job[0] == "prepare":
                self.prepared[name] = out
                for priority, waiting in self.waiting.pop(name, []):
                    self.heapq.heappush(self.heap, (priority, next(self.order), waiting))
            else:
                self.results.setdefault(name, []).extend(out)
                if job[0] == "sample":
                    self._redraw(job, sum(not row.get("checkable") for row in out))
            self._pump()

    def _redraw(self, job, undecided):
        """A sample job for as many new random pixels as `job` left undecided (its seed extended by
        the count so far), while the dataset's REDRAWS_MAX lasts; called with the lock held."""
        name = job[1]
        done = self.redrawn.get(name, 0)
        k = min(undecided, REDRAWS_MAX - done)
        if k > 0:
            self.redrawn[name] = done + k
            again = ("sample", name, job[2], [None] * k, [*job[4], done])
            self.heapq.heappush(self.heap, ((PRIORITY_SAMPLE, 1 << 30), next(self.order), again))

    def busy(self):
        with self.lock:
            return bool(self.heap or self.inflight or self.waiting)

    def pending_pixels(self, name):
        """Pixels of `name` not decided yet (queued, waiting or in flight)."""
        with self.lock:
            jobs = [j for _, _, j in self.heap] + list(self.inflight.values()) + \
                [j for _, j in self.waiting.get(name, [])]
            return sum(len(j[3]) for j in jobs if j[0] != "prepare" and j[1] == name)

    def stop(self):
        self.pool.terminate()


def _select(images, top, max_gap):
    """(pixels [(i, j)] to decide, largest first; per image its count and largest difference
    against the base): every pixel where an image differs from the base by more than WRONG (at
    most max_gap of them) and each image's `top` largest differences."""
    base = images[BASE]
    score = np.zeros(base.shape[:2])
    stats, picked = {}, set()
    for name in IMAGES:
        diff = np.abs(images[name] - base).max(axis=2)
        stats[name] = {"pixels_over": int((diff > WRONG).sum()), "max_difference": float(diff.max()),
                       "at": [int(v) for v in np.unravel_index(int(diff.argmax()), diff.shape)[::-1]]}
        score = np.maximum(score, diff)
        for k in np.argsort(diff, axis=None)[::-1][:top]:
            if diff.flat[k] > 0.0:
                picked.add(tuple(int(v) for v in np.unravel_index(int(k), diff.shape)[::-1]))
    jj, ii = np.nonzero(score > WRONG)
    for k in np.argsort(-score[jj, ii])[:max_gap]:
        picked.add((int(ii[k]), int(jj[k])))
    return sorted(picked, key=lambda p: -score[p[1], p[0]]), stats, int(len(jj))


# the tents come from field_samples' matrix products, which a worker's one BLAS thread rounds
# otherwise than this process's many: they may differ in their last bits (6e-16 seen), which moves
# no pixel by more than its own rounding
FLOAT_RTOL = 1e-12


def _first_difference(a, b, path="") -> str | None:
    """Where a and b (dicts, lists, numbers, strings) first differ, and by how much; None: equal
    (numbers within FLOAT_RTOL)."""
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return f"{path or '/'}: keys {sorted(a)} against {sorted(b)}"
        return next((w for k in a if (w := _first_difference(a[k], b[k], f"{path}/{k}"))), None)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return f"{path}: {len(a)} items against {len(b)}"
        return next((w for k, (x, y) in enumerate(zip(a, b)) if (w := _first_difference(x, y, f"{path}/{k}"))), None)
    if a == b:
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        if abs(a - b) <= FLOAT_RTOL * max(abs(a), abs(b)):
            return None
        return f"{path}: {a!r} against {b!r} (relative {abs(a - b) / max(abs(a), abs(b)):.1e})"
    return f"{path}: {a!r} against {b!r}"


def _dataset_report(name, entry, checker, threshold=WRONG):
    """entry (what the GPU side has) and the checker's rows of `name` as the JSON's record."""
    with checker.lock:
        rows = list(checker.results.get(name, []))
        errors = list(checker.errors.get(name, []))
        prepared = checker.prepared.get(name)
        redrawn = checker.redrawn.get(name, 0)
    images = entry.get("images", {})
    seen, pixels = set(), []
    for row in rows:
        if (row["i"], row["j"]) in seen:
            continue
        seen.add((row["i"], row["j"]))
        if images:
            row["values"] = {k: [float(v) for v in img[row["j"], row["i"]]] for k, img in images.items()}
        if row.get("checkable") and images:
            ref = np.asarray(row["reference"])
            row["errors"] = {k: float(np.abs(np.asarray(v) - ref).max()) for k, v in row["values"].items()}
        pixels.append(row)
    checked = [r for r in pixels if r.get("checkable")]
    out = {k: v for k, v in entry.items() if k != "images"}
    differs = prepared and "camera" in entry and _first_difference(
        {"camera": prepared["camera"], "transfer_function": prepared["transfer_function"]},
        {"camera": entry["camera"], "transfer_function": entry["transfer_function"]})
    if differs:
        errors.append(f"the reference's camera or transfer function is not the render's: {differs}")
    out.update(prepare_seconds=prepared and prepared["seconds"], errors=errors, checked=len(checked),
               checked_random=sum(r["why"] == "sample" for r in checked), random_redrawn=redrawn,
               checked_disputed=sum(r["why"] == "gap" for r in checked),
               unchecked_curved_pyramids=sum(not r.get("checkable") and "reference_failed" not in r for r in pixels),
               reference_failed=[{k: r.get(k) for k in ("i", "j", "why", "origin", "direction", "reference_failed")}
                                 for r in pixels if "reference_failed" in r],
               unchecked_not_reached=checker.pending_pixels(name),
               reference_missed_chord=sum(bool(r.get("reference_missed_chord")) for r in checked),
               max_reference_error=max((r["reference_error"] for r in checked), default=None))
    if images:
        vs = {}
        for k in ALL_IMAGES:
            vs[k] = _vs_reference(checked, k, threshold)
        out["vs_reference"] = vs
    out["pixels_over"] = [r for r in checked if "errors" in r and max(r["errors"].values()) > threshold]
    out["pixels"] = [{k: r.get(k) for k in PIXEL_KEYS} for r in checked]
    return out


def _vs_reference(rows, image, threshold=WRONG) -> dict:
    """One image against the reference over decided rows (each with its errors): how many over the
    threshold, how many of those where the reference's inside length is the exact chord, the
    largest error and where."""
    errs = [(r["errors"][image], r) for r in rows if r.get("errors")]
    worst = max(errs, key=lambda e: e[0], default=(None, None))
    return {"over": sum(e > threshold for e, _ in errs),
            "over_where_reference_inside_is_the_chord": sum(e > threshold and not r.get("reference_missed_chord")
                                                            for e, r in errs),
            "max_error": worst[0], "at": [worst[1]["i"], worst[1]["j"]] if worst[1] else None}


def gpu_stage(args):
    """The whole audit in one device command (module docstring): the pool starts first and
    prepares every dataset's reference while this process compiles the kernels and renders;
    the JSON is rewritten after each dataset and every 30 s, and the run stops at --deadline
    seconds with what it has (a cut-off command keeps its last JSON)."""
    import datetime
    import tempfile

    from bench.common import command_line, compile_all, git

    t_start = time.monotonic()
    deadline = t_start + args.deadline
    os.environ.setdefault("HOVR_COMPILE_WORKERS", str(args.jobs + 1))
    names = [n for n in args.datasets.split(",") if n]
    W, H = map(int, args.size.split("x"))
    cache = tempfile.mkdtemp(prefix="hovr-audit-")
    checker = _Checker(args.jobs, cache)
    for name in names:
        checker.push(PRIORITY_PREPARE, ("prepare", name, cache, (W, H)))
    # random pixels: geometric coverage needs no image, so they start with the pool
    chunks = -(-args.sample // SAMPLE_CHUNK)
    for k in range(chunks):
        for n, name in enumerate(names):
            m = min(SAMPLE_CHUNK, args.sample - k * SAMPLE_CHUNK)
            checker.push((PRIORITY_SAMPLE, k), ("sample", name, cache, [None] * m, [args.seed, n, k]))
    out = {"command": command_line(), "date": datetime.date.today().isoformat(), "commit": git("rev-parse", "HEAD"),
           "device": args.device, "size": [W, H], "threshold": WRONG, "deadline_seconds": args.deadline,
           "images": {k: _image_options(k, args.device).as_dict() for k in ALL_IMAGES}, "datasets": {}}
    entries = {}
    writing = threading.Lock()
    stop = threading.Event()

    def write(final=False):
        with writing:
            out["wall_seconds"] = round(time.monotonic() - t_start, 1)
            out["complete"] = final and not checker.busy()
            have = dict(entries)
            out["datasets"] = {name: _dataset_report(name, have.get(name, {}), checker) for name in names}
            out["summary"] = _summary(out)
            tmp = args.out + ".part"
            with open(tmp, "w") as f:
                json.dump(out, f, indent=1, default=jsonable)
            os.replace(tmp, args.out)

    def every_30_s():  # also while a long render holds the main thread: a killed command keeps its JSON
        while not stop.wait(30.0):
            write()
            with checker.lock:
                decided = sum(len(v) for v in checker.results.values())
            print(f"{round(time.monotonic() - t_start)} s: {decided} pixels decided", flush=True)

    threading.Thread(target=every_30_s, daemon=True).start()

    try:
        import warp as wp

        from hovr_blender.engine.camera import RayCamera
        from hovr_blender.engine.renderer import Renderer

        wp.config.quiet = True
        meshes = {}
        t0 = time.perf_counter()
        for name in names:
            try:
                meshes[name] = load(name)
            except FileNotFoundError as exc:
                entries[name] = {"skipped": f"missing {exc}"}
        out["load_seconds"] = round(time.perf_counter() - t0, 1)
        out["compile_seconds"] = round(compile_all([m for m, _ in meshes.values()], args.device), 1)
        out["device_name"] = wp.get_device(args.device).name
        print(f"loaded in {out['load_seconds']} s, compiled in {out['compile_seconds']} s", flush=True)
        for name, (mesh, data) in meshes.items():
            if time.monotonic() > deadline:
                entries[name] = {"skipped": "deadline"}
                continue
            cam = views(mesh)["oblique"]
            tf = transfer_function(mesh)
            camera = RayCamera.from_contract(cam, W, H)
            entry = {"elements": int(mesh.num_elements), "camera": cam, "transfer_function": tf.to_contract(),
                     "render_seconds": {}, "images": {}}
            try:
                renderer = Renderer(mesh, args.device)
                for k in ALL_IMAGES:
                    if time.monotonic() > deadline:
                        raise TimeoutError("deadline before all its images")
                    t0 = time.perf_counter()
                    res = renderer.render(camera, tf, np.zeros(3), _image_options(k, args.device))
                    entry["render_seconds"][k] = round(time.perf_counter() - t0, 3)
                    entry["images"][k] = res.rgba.astype(np.float64)
                del renderer
            except Exception as exc:  # the other datasets go on; the JSON says why this one has no images
                entries[name] = {k: v for k, v in entry.items() if k != "images"}
                entries[name]["render_error"] = f"{type(exc).__name__}: {exc}"[:2000]
                print(f"{name}: render failed: {entries[name]['render_error']}", flush=True)
                continue
            pixels, entry["vs_base"], entry["pixels_over_vs_base"] = _select(entry["images"], args.top, args.max_gap)
            for r, k in enumerate(range(0, len(pixels), GAP_CHUNK)):
                checker.push((PRIORITY_GAP, r), ("gap", name, cache, pixels[k:k + GAP_CHUNK], 0))
            entry["covered_pixels"] = int((entry["images"][BASE][..., 3] > 0.002).sum())
            entries[name] = entry
            print(f"{name}: rendered {entry['render_seconds']}; vs base: " +
                  ", ".join(f"{k} {v['pixels_over']} over (max {v['max_difference']:.2e})"
                            for k, v in entry["vs_base"].items()), flush=True)
            write()
        while checker.busy() and time.monotonic() < deadline:
            time.sleep(1.0)
    finally:
        stop.set()
        checker.stop()
        write(final=True)
        shutil.rmtree(cache, ignore_errors=True)
        print(json.dumps(out["summary"], indent=1), flush=True)


def recheck_stage(args):
    """Decides again, with this tree's reference, every pixel a gpu-stage JSON lists over the
    threshold, against the values the images had there (kept in the JSON): for a reference
    that has since been mended. The pixels' rows, the datasets' counts against the reference
    and the summary are rewritten; `rechecked` says what was done."""
    import datetime
    import tempfile

    from bench.common import command_line, git

    out = json.loads(Path(args.audit).read_text())
    cache = tempfile.mkdtemp(prefix="hovr-recheck-")
    done = {}
    try:
        for name, d in out["datasets"].items():
            over = d.get("pixels_over") or []
            if not over:
                continue
            _prepare(name, cache, out["size"])
            rows = _decide(name, cache, "gap", [(r["i"], r["j"]) for r in over])
            for old, row in zip(over, rows):
                row["why"], row["values"] = old["why"], old["values"]
                ref = np.asarray(row["reference"])
                row["errors"] = {k: float(np.abs(np.asarray(v) - ref).max()) for k, v in row["values"].items()}
            by_pixel = {(r["i"], r["j"]): {k: r.get(k) for k in PIXEL_KEYS} for r in rows}
            d["pixels"] = [{**p, **by_pixel.get((p["i"], p["j"]), {})} for p in d["pixels"]]
            d["pixels_over"] = [r for r in rows if max(r["errors"].values()) > WRONG]
            for k, v in d.get("vs_reference", {}).items():
                v.update(_vs_reference(d["pixels"], k))
            d["reference_missed_chord"] = sum(bool(p.get("reference_missed_chord")) for p in d["pixels"])
            done[name] = {"pixels": len(rows), "still_over": len(d["pixels_over"]),
                          "still_over_where_reference_inside_is_the_chord": sum(
                              not r["reference_missed_chord"] for r in d["pixels_over"])}
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    out["summary"] = _summary(out)
    out.setdefault("rechecked", []).append({"date": datetime.date.today().isoformat(), "commit": git("rev-parse", "HEAD"),
                                            "command": command_line(), "datasets": done})
    Path(args.out).write_text(json.dumps(out, indent=1, default=jsonable) + "\n")
    print(json.dumps(done, indent=1))


def _summary(out):
    """One row per dataset: pixels over the threshold against the base (whole image) and against
    the reference (decided pixels), per image; the checks' counts."""
    rows = {}
    for name, d in out["datasets"].items():
        row = {k: d.get(k) for k in ("checked", "checked_random", "checked_disputed", "unchecked_curved_pyramids",
                                     "unchecked_not_reached", "reference_missed_chord", "skipped") if d.get(k) is not None}
        for k, v in d.get("vs_base", {}).items():
            row[f"{k} vs base"] = f"{v['pixels_over']} (max {v['max_difference']:.1e})"
        for k, v in d.get("vs_reference", {}).items():
            row[f"{k} vs reference"] = (f"{v['over']} (max {v['max_error']:.1e}; "
                                        f"{v.get('over_where_reference_inside_is_the_chord', '?')} where the reference's "
                                        "inside is the exact chord)" if v["max_error"] is not None else "-")
        if d.get("reference_failed"):
            row["reference_failed"] = len(d["reference_failed"])
        if d.get("errors"):
            row["errors"] = len(d["errors"])
        rows[name] = row
    return rows


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
    g = sub.add_parser("gpu", help="the whole audit in one device command (issue 36)")
    g.add_argument("--device", default="cuda:0")
    g.add_argument("--size", default="1920x1080")
    g.add_argument("--datasets", default=",".join(SHARED_DATASETS))
    g.add_argument("--sample", type=int, default=200, help="random pixels through the domain per dataset")
    g.add_argument("--top", type=int, default=10, help="each image's largest differences from the base, decided")
    g.add_argument("--max-gap", type=int, default=400, help="at most this many pixels over 1e-3 against the base decided")
    g.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 2) - 1), help="reference processes")
    g.add_argument("--deadline", type=float, default=540.0, help="seconds: then stop and write what was decided")
    g.add_argument("--seed", type=int, default=36)
    g.add_argument("--out", required=True)
    k = sub.add_parser("recheck", help="decide a gpu JSON's pixels over the threshold again, with this reference")
    k.add_argument("audit")
    k.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    {"render": render_stage, "check": check_stage, "gpu": gpu_stage, "recheck": recheck_stage}[args.stage](args)


if __name__ == "__main__":
    main()
