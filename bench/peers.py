"""The peers side by side (issue 19): what VTK (ParaView's engine) gives on the same data, view
and transfer function as ours, with time, memory and error, measured in one run.

    python -m bench.peers --device cpu --size 192x108 --out bench/results/cpu/peers --figures docs
    python -m bench.peers --device cuda:0 --size 1920x1080 --out $OUT/peers --figures $OUT/peers
    python -m bench.peers --plot bench/results/cpu/peers/peers.json --figures docs   (figures again)

Datasets, views and transfer functions are those of the audit (hovr_blender/audit/datasets.py: every dataset
of ../shared/data that it lists, the paper-scale channel and the curved mixed cube; the
"oblique" view by default; three tents of density over the field's 2nd..98th percentiles).
Methods (--methods, comma list):

- ours-split (split, tolerance 1e-3) and ours-classified (h = bounding-box diagonal / 400):
  engine.renderer.Renderer in float32 on --device;
- vtk-lattice-MAPPER: the Lagrange cells split into linear tetrahedra on their node lattice
  (vtkDataSetTriangleFilter, what ParaView's volume representation does to nonlinear cells);
- vtk-tessL-MAPPER: vtkTessellatorFilter, every edge halved L times (L = --levels, 0..4: the
  volume counterpart of ParaView's Nonlinear Subdivision Level);
  MAPPER = raycast (vtkUnstructuredGridVolumeRayCastMapper, CPU, with the homogeneous ray
  integrator: bench/vtk_peer.py says why) or projected
  (vtkOpenGLProjectedTetrahedraMapper, OpenGL);
- vtk-resampleN-smart: vtkResampleToImage with N points along the box's longest side (--resample),
  rendered by vtkSmartVolumeMapper (vtkGPUVolumeRayCastMapper wherever OpenGL allows it; the
  JSON records the mode it used).
Transfer-function mapping and camera: bench/vtk_peer.py (checked on a constant-density cube
by bench/test_peers_calibration.py).

Measured per method, after one warm-up frame: time per frame (median of --repeats; VTK: the
Render() call, ours: the render's own render_seconds), preparation time (tessellation,
resampling, our upload) apart; host memory: the rise of the process's peak resident set
(VmHWM, reset through /proc/self/clear_refs before each method) over its resident set before
it, so preparation and frames are both in it; GPU memory (CUDA devices): the fall of the
device's free memory (cudaMemGetInfo through Warp) from before the method to after its frames,
which counts what the method still holds (VTK's textures and buffers, our arrays), not a
transient peak. Errors: the largest and the mean over pixels of the largest RGB difference
against the reference image, the mean taken over the pixels where the reference or the image
is not empty (alpha > 1/255). The reference is our renderer in float64
(engine/reference.pixel_exact_reference: split at 1e-9, no early termination); on --sample
pixels of each dataset (seeded, where the volume shows) the independent VTK reference
(hovr_blender/audit, float64, ~1 s a pixel) checks it, and the JSON records the largest
difference between the two there and every method's error on those pixels against it. Where
our float32 (split) and float64 images differ by more than 1e-3, the independent reference
decides the pixel and replaces the float64 value (up to --fix-gaps pixels, largest gaps
first); so it does at the --fix-disputed pixels where VTK's closest method (least mean error)
is more than 0.05 off, in case both our precisions share a fault there. On hexahedral meshes a
pixel is not replaced where the independent reference's stretches inside the cells fall short
of the ray's exact chord (audit/chords.py): it misses short chords where a ray clips a curved
boundary (the JSON counts those as independent_missed). On Hex_Mushroom the
float64 preset returned empty pixels where float32 and the independent reference agree to 1e-4.
VTK's pixels come from its 8-bit framebuffer: 0.5/255 = 2.0e-3 of rounding is in every VTK
error (its floor).

Every tessellation over --max-tets tetrahedra, every grid over --max-points points and every
preparation estimated (from the previous, smaller one) to take over --budget seconds is skipped
and recorded as such; after --max-minutes the methods left are skipped too. Our frames over 2 s
are not repeated.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from bench import common
from bench import vtk_peer as vp
from hovr_blender.audit import datasets  # the audit's datasets, views, transfer functions

EMPTY = 1.0 / 255  # alpha below this: an empty pixel (for the mean error)
CHORD_TOL = 1e-6  # the independent reference's inside length may miss the exact chord by this (world units)
DEFAULT_DATASETS = ["Hex_CurvedFace", "Hex_Mushroom", "ngsolve_ball", "mfem_fichera", "hump3D", "paper_scale",
                    "ngsolve_post", "pyfr_tgv", "RotPerBcs3D_Annulus", "curved_mixed_cube", "Pyr_channel_m6", "scaleHO"]


# --------------------------------------------------------------------------------- memory

def _status(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return None


class Memory:
    """Host: peak resident set rise (VmHWM after - VmRSS before, VmHWM reset first);
    GPU: fall of the device's free memory over the method (CUDA only)."""

    def __init__(self, device):
        self.device = device
        self.can_reset = True

    def __enter__(self):
        try:
            with open("/proc/self/clear_refs", "w") as fh:
                fh.write("5")
        except OSError:
            self.can_reset = False
        self.rss0 = _status("VmRSS")
        self.free0 = self._free()
        return self

    def _free(self):
        if not str(self.device).startswith("cuda"):
            return None
        import warp as wp

        return wp.get_device(self.device).free_memory

    def __exit__(self, *exc):
        hwm = _status("VmHWM")
        self.host_bytes = (hwm - self.rss0) if (hwm is not None and self.rss0 is not None and self.can_reset) else None
        free1 = self._free()
        self.gpu_bytes = (self.free0 - free1) if free1 is not None else None
        return False


# --------------------------------------------------------------------------------- errors

def errors(img, ref):
    """(max, mean over non-empty pixels) of the per-pixel largest RGB difference."""
    e = np.abs(np.asarray(img)[..., :3].astype(np.float64) - ref[..., :3]).max(axis=-1)
    seen = (ref[..., 3] > EMPTY) | (np.asarray(img)[..., 3] > EMPTY)
    return float(e.max()), float(e[seen].mean()) if seen.any() else 0.0


# --------------------------------------------------------------------------------- our side

def run_ours(mesh, camera, tf, device, methods, repeats, log):
    from hovr_blender.engine.reference import pixel_exact_reference
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    lo, hi = mesh.vertices.reshape(-1, 3).min(0), mesh.vertices.reshape(-1, 3).max(0)
    diag = float(np.linalg.norm(hi - lo))
    settings = {"ours-split": dict(method="split", tolerance=1e-3),
                "ours-classified": dict(method="classified", h=diag / 400)}
    rows, images, renderer = [], {}, None
    for name in methods:
        kw = settings[name]
        with Memory(device) as mem:
            t0 = time.perf_counter()
            if renderer is None:
                renderer, _ = common.compiled_renderer(mesh, device)  # a 4x3 frame compiles or loads the kernels
            prep = time.perf_counter() - t0
            opts = RenderOptions(device=device, **kw)
            secs = []
            for _ in range(repeats):  # a frame over 2 s is not repeated (its noise is small)
                res = renderer.render(camera, tf, np.zeros(3), opts)
                secs.append(res.stats["render_seconds"])
                if secs[-1] > 2.0:
                    break
            warm = res
        images[name] = res.rgba.astype(np.float64)
        rows.append({"method": name, "family": "ours", "setting": kw, "prepare_seconds": prep,
                     "first_frame_seconds": warm.stats["render_seconds"], "frame_seconds": float(np.median(secs)),
                     "frame_seconds_all": secs, "host_peak_bytes": mem.host_bytes, "gpu_bytes": mem.gpu_bytes,
                     "mesh_bytes": _mesh_bytes(mesh)})
        log(f"  {name:24s} {rows[-1]['frame_seconds'] * 1e3:9.1f} ms  host +{_mb(mem.host_bytes)}")
    t0 = time.perf_counter()
    ref, _ = pixel_exact_reference(mesh, camera, tf, np.zeros(3), device, renderer=renderer)
    log(f"  float64 reference in {time.perf_counter() - t0:.1f} s")
    return rows, images, ref


def _mesh_bytes(mesh):
    from bench.resample_baseline import mesh_memory_bytes

    return int(mesh_memory_bytes(mesh))


def _mb(b):
    if b is None:
        return "?"
    return f"{b / 2**20:.1f} MiB" if abs(b) >= 2**20 else f"{b / 2**10:.0f} KiB"


# --------------------------------------------------------------------------------- VTK side

def vtk_grid(name, mesh, data):
    """(vtkUnstructuredGrid of Lagrange cells with the point array 'f', None) or (None, why)."""
    from hovr_blender.audit import vtk_volume
    from hovr_blender.engine import shapes

    if data is not None and data["path"].endswith(".vtu"):
        return vtk_volume.read_vtu(data["path"], data["field"]), None
    if np.any(mesh.shape == shapes.PYR):
        return None, "pyramids: VTK has no Lagrange pyramid in the same space (hovr_blender/audit/vtk_volume.py)"
    try:
        return vtk_volume.from_mesh(mesh), None
    except (ValueError, RuntimeError) as exc:  # recorded, and the run goes on
        return None, f"conversion to VTK failed: {exc}"


def vtk_methods(args, n_cells):
    out = []
    for m in args.methods.split(","):
        if m == "vtk-lattice":
            out += [f"vtk-lattice-{k}" for k in args.mappers.split(",")]
        elif m == "vtk-tess":
            out += [f"vtk-tess{lv}-{k}" for lv in args.levels.split(",") for k in args.mappers.split(",")]
        elif m == "vtk-resample":
            out += [f"vtk-resample{n}-smart" for n in args.resample.split(",")]
    return out


def run_vtk(grid, camera_dict, W, H, tf, methods, args, deadline, log):
    """Rows and images of the VTK methods; data prepared once per preparation and reused by the
    mappers that share it."""
    rows, images = [], {}
    scene = vp.Scene(camera_dict, W, H)
    prepared = {}
    n_cells = grid.GetNumberOfCells()
    last_prep = {}  # kind -> (seconds, size): the next, larger preparation's time is estimated from it
    for name in methods:
        _, prep_name, mapper = name.split("-")
        row = {"method": name, "family": "vtk", "preparation": prep_name, "mapper": vp.MAPPERS[mapper]}
        why = None
        if time.perf_counter() > deadline:
            why = f"run deadline ({args.max_minutes} min) passed"
        elif prep_name.startswith("tess") and vp.tessellated_tets(n_cells, int(prep_name[4:])) > args.max_tets:
            why = f"about {vp.tessellated_tets(n_cells, int(prep_name[4:])):.3g} tetrahedra > --max-tets {args.max_tets:.3g}"
        elif prep_name == "lattice" and _lattice_tets(grid) > args.max_tets:
            why = f"about {_lattice_tets(grid):.3g} tetrahedra > --max-tets {args.max_tets:.3g}"
        elif prep_name.startswith("resample") and _grid_points(grid, int(prep_name[8:])) > args.max_points:
            why = f"{_grid_points(grid, int(prep_name[8:])):.3g} grid points > --max-points {args.max_points:.3g}"
        kind, size = _prep_size(prep_name, grid)
        if not why and kind in last_prep and prep_name not in prepared:
            est = last_prep[kind][0] * size / last_prep[kind][1]
            if est > args.budget:
                why = f"preparation estimated at {est:.0f} s > --budget {args.budget:g} s"
        if why:
            row["skipped"] = why
            rows.append(row)
            log(f"  {name:24s} skipped: {why}")
            continue
        with Memory(args.device) as mem:
            t0 = time.perf_counter()
            if prep_name not in prepared:
                prepared.clear()  # one prepared dataset held at a time: its memory is the method's
                if prep_name == "lattice":
                    prepared[prep_name] = vp.lattice(grid)
                elif prep_name.startswith("tess"):
                    prepared[prep_name] = vp.tessellate(grid, int(prep_name[4:]))
                else:
                    prepared[prep_name] = vp.resample(grid, int(prep_name[8:]))
                last_prep[kind] = (time.perf_counter() - t0, size)
            data = prepared[prep_name]
            prep = time.perf_counter() - t0
            fun = vp.image_functions if mapper in ("smart", "gpu", "fixedpoint") else vp.unstructured_functions
            ctf, otf, u = fun(tf)
            m = vp.make_mapper(mapper, data)
            scene.show(m, vp.volume_property(ctf, otf, u))
            img, first = scene.render()
            secs = []
            for _ in range(args.repeats):
                img, s = scene.render()
                secs.append(s)
        row.update(prepare_seconds=prep, first_frame_seconds=first, frame_seconds=float(np.median(secs)),
                   frame_seconds_all=secs, host_peak_bytes=mem.host_bytes, gpu_bytes=mem.gpu_bytes,
                   data_bytes=int(data.GetActualMemorySize()) * 1024, unit_distance=u)
        if prep_name.startswith("resample"):
            row["grid_dimensions"] = list(data.GetDimensions())
            row["smart_mode"] = {0: "default", 1: "ray cast (CPU)", 2: "GPU ray cast", 3: "OSPRay", 4: "ANARI"}.get(
                m.GetLastUsedRenderMode(), str(m.GetLastUsedRenderMode()))
        else:
            row["tetrahedra"] = int(data.GetNumberOfCells())
        if mapper == "raycast":
            integ = m.GetRayIntegrator()
            row["ray_integrator"] = integ.GetClassName() if integ is not None else "the mapper's default"
        images[name] = img
        rows.append(row)
        log(f"  {name:24s} {row['frame_seconds'] * 1e3:9.1f} ms  prep {prep:.2f} s  host +{_mb(mem.host_bytes)}"
            + (f"  {row['tetrahedra']} tets" if "tetrahedra" in row else f"  grid {row['grid_dimensions']}"))
    scene.close()
    return rows, images


def _prep_size(prep_name, grid):
    """(kind, work) of a preparation: tetrahedra made or grid points probed."""
    if prep_name.startswith("tess"):
        return "tess", vp.tessellated_tets(grid.GetNumberOfCells(), int(prep_name[4:]))
    if prep_name.startswith("resample"):
        return "resample", _grid_points(grid, int(prep_name[8:]))
    return prep_name, _lattice_tets(grid)


def _lattice_tets(grid):
    """Tetrahedra of the node-lattice split: about 6 per lattice sub-cell."""
    n = grid.GetNumberOfPoints()
    return 6 * n


def _grid_points(grid, n):
    b = np.asarray(grid.GetBounds(), float)
    L = b[1::2] - b[0::2]
    h = L.max() / (n - 1)
    return int(np.prod([int(np.ceil(x / h - 1e-9)) + 1 for x in L]))


# --------------------------------------------------------------------------------- the independent check

def independent_sample(grid, camera_dict, W, H, tf, ref, k, seed, log):
    """(pixels [(i, j)], their independent-reference RGBA (k, 4), the reference's own error
    estimate): k seeded pixels where the float64 image is not empty."""
    from hovr_blender.audit import vtk_reference as R

    rng = np.random.default_rng(seed)
    jj, ii = np.nonzero(ref[..., 3] > 0.002)
    if k <= 0 or len(ii) == 0:
        return [], np.zeros((0, 4)), None
    pick = rng.choice(len(ii), min(k, len(ii)), replace=False)
    ind = R.IndependentReference(grid, tf.color_s, tf.color_rgb, tf.density_s, tf.density_tau, tol=1e-10)
    pixels, values, est = [], [], 0.0
    t0 = time.perf_counter()
    for p in pick:
        i, j = int(ii[p]), int(jj[p])
        o, d = R.contract_ray(camera_dict, W, H, i, j)
        r = ind.pixel(o, d, np.zeros(3))
        pixels.append((i, j))
        values.append(r.rgba)
        est = max(est, r.error)
    log(f"  independent reference: {len(pixels)} pixels in {time.perf_counter() - t0:.1f} s")
    return pixels, np.array(values), est


def exact_chords(mesh):
    """chord(o, d): the exact length of the ray inside the mesh (audit/chords.py, from the
    boundary faces alone; NaN where undecided). The boundary is fitted on the first call."""
    from hovr_blender.audit import chords

    boundary = []

    def chord(o, d):
        if not boundary:
            boundary.append(chords.Boundary(mesh))
        return float(chords.chords_numpy(boundary[0], np.asarray(o)[None], np.asarray(d)[None])[0])

    return chord


def decide(grid, camera_dict, W, H, tf, ref, other, limit, log, threshold=1e-3, label="float32", seconds=60.0,
           chord=None, independent=None):
    """Where `other` (an image) and `ref` differ by more than `threshold`, the independent
    reference decides: it is computed at the `limit` largest such pixels and replaces `ref`
    there (in place), for at most `seconds`. Returns the counts: pixels over the threshold, checked, where the float64
    value was wrong (> 1e-3 off the independent one) and where `other` was. With `chord`
    (exact_chords), a pixel where the independent reference's stretches inside the cells do not
    add up to the exact chord is not replaced: it misses short chords where a ray clips a curved
    boundary (benchmarks.md, "Our two pixels over 1e-3"); those are counted as independent_missed."""
    from hovr_blender.audit import vtk_reference as R

    e = np.abs(other[..., :3].astype(np.float64) - ref[..., :3]).max(axis=-1)
    jj, ii = np.nonzero(e > threshold)
    info = {"against": label, "threshold": threshold, "pixels_over": int(len(ii)), "checked": 0,
            "float64_wrong": 0, "other_wrong": 0, "largest_float64_error": 0.0, "independent_missed": 0,
            # [i, j, |float64 - independent|, |other - independent|, independent inside / exact chord or None]
            "pixels": []}
    if len(ii) == 0:
        return info
    order = np.argsort(-e[jj, ii])[:limit]
    ind = independent if independent is not None else R.IndependentReference(
        grid, tf.color_s, tf.color_rgb, tf.density_s, tf.density_tau, tol=1e-10)
    t0 = time.perf_counter()
    for k in order:
        if time.perf_counter() - t0 > seconds:  # a time cap: the rest are counted, not checked
            info["stopped_after_seconds"] = seconds
            break
        i, j = int(ii[k]), int(jj[k])
        o, d = R.contract_ray(camera_dict, W, H, i, j)
        v = ind.pixel(o, d, np.zeros(3)).rgba
        e64 = float(np.abs(ref[j, i, :3] - v[:3]).max())
        e_other = float(np.abs(other[j, i, :3] - v[:3]).max())
        cover = None
        if chord is not None:
            exact = chord(o, d)
            inside = sum(b - a for a, b, _ in ind.stretches(o, d, 0.0, np.inf))
            cover = [inside, exact]
            if np.isfinite(exact) and abs(inside - exact) > CHORD_TOL * max(1.0, exact):
                info["independent_missed"] += 1
                info["pixels"].append([i, j, e64, e_other, cover])
                info["checked"] += 1
                continue
        info["float64_wrong"] += int(e64 > 1e-3)
        info["other_wrong"] += int(e_other > 1e-3)
        info["largest_float64_error"] = max(info["largest_float64_error"], e64)
        info["pixels"].append([i, j, e64, e_other, cover])
        ref[j, i] = v
        info["checked"] += 1
    log(f"  reference vs {label}: {len(ii)} pixels differ by > {threshold:g}; {info['checked']} checked independently "
        f"in {time.perf_counter() - t0:.1f} s: float64 wrong at {info['float64_wrong']} "
        f"(up to {info['largest_float64_error']:.2g}), {label} at {info['other_wrong']}; "
        f"the independent reference short of the exact chord at {info['independent_missed']} (kept float64)")
    return info


# --------------------------------------------------------------------------------- one dataset

def run_dataset(name, args, deadline, log):
    from hovr_blender.engine.camera import RayCamera

    W, H = (int(v) for v in args.size.split("x"))
    t0 = time.perf_counter()
    mesh, data = datasets.load(name)
    load_s = time.perf_counter() - t0
    tf = datasets.transfer_function(mesh)
    cam = dict(datasets.views(mesh)[args.view], projection="perspective")
    camera = RayCamera.from_contract(cam, W, H)
    log(f"{name}: {mesh.num_elements} elements, loaded in {load_s:.1f} s")
    entry = {"dataset": name, "data": data, "elements": int(mesh.num_elements), "view": args.view, "camera": cam,
             "transfer_function": tf.to_contract(), "load_seconds": load_s, "rows": []}
    ours = [m for m in args.methods.split(",") if m.startswith("ours-")]
    rows, images, ref = run_ours(mesh, camera, tf, args.device, ours, args.repeats, log)
    entry["rows"] += rows
    t0 = time.perf_counter()
    grid, why = vtk_grid(name, mesh, data)
    entry["vtk_grid_seconds"] = time.perf_counter() - t0
    if grid is None:
        entry["vtk_skipped"] = why
        log(f"  VTK skipped: {why}")
    else:
        entry["vtk_cells"], entry["vtk_points"] = int(grid.GetNumberOfCells()), int(grid.GetNumberOfPoints())
        vrows, vimages = run_vtk(grid, cam, W, H, tf, vtk_methods(args, grid.GetNumberOfCells()), args, deadline, log)
        entry["rows"] += vrows
        images.update(vimages)
    # where our float32 and float64 images differ by more than 1e-3 (the audit's rule), the
    # independent reference decides the pixel: it replaces the float64 value there, unless its
    # stretches miss the exact chord (hexahedral meshes)
    chord = exact_chords(mesh) if grid is not None else None
    if grid is not None and "ours-split" in images and args.fix_gaps > 0:
        entry["reference_checked"] = [decide(grid, cam, W, H, tf, ref, images["ours-split"], args.fix_gaps, log,
                                             seconds=args.check_seconds, chord=chord)]
    # and where VTK's closest method (least mean error) is far off (> 0.05), in case both our
    # precisions share a fault there
    vt = [r for r in entry["rows"] if r["family"] == "vtk" and r["method"] in images]
    if grid is not None and vt and args.fix_disputed > 0:
        best = min(vt, key=lambda r: errors(images[r["method"]], ref)[1])["method"]
        entry.setdefault("reference_checked", []).append(
            decide(grid, cam, W, H, tf, ref, images[best], args.fix_disputed, log, threshold=0.05, label=best,
                   seconds=args.check_seconds, chord=chord))
    for row in entry["rows"]:
        if row["method"] in images:
            row["max_error"], row["mean_error"] = errors(images[row["method"]], ref)
    # the independent reference on a sample of pixels: checks the float64 image, and every method there
    if grid is not None and args.sample > 0:
        pixels, vals, est = independent_sample(grid, cam, W, H, tf, ref, args.sample, args.seed, log)
        if pixels:
            idx = (np.array([p[1] for p in pixels]), np.array([p[0] for p in pixels]))
            entry["independent"] = {"pixels": pixels, "rgba": vals.tolist(), "error_estimate": est,
                                    "float64_vs_independent": float(np.abs(ref[idx][:, :3] - vals[:, :3]).max())}
            for row in entry["rows"]:
                if row["method"] in images:
                    row["sample_max_error"] = float(np.abs(images[row["method"]][idx][:, :3] - vals[:, :3]).max())
    if args.save_images:
        folder = Path(args.out) / "images"
        folder.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(folder / f"{name}.npz", reference=ref.astype(np.float32),
                            **{k.replace("-", "_"): v.astype(np.float32) for k, v in images.items()})
        entry["images"] = str((folder / f"{name}.npz").relative_to(Path(args.out)))
    entry["_images"], entry["_ref"] = images, ref
    return entry


# --------------------------------------------------------------------------------- figures and table

def _srgb(x):
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def figure_columns(entry, images):
    """The figure's methods: ours (split), VTK's ParaView default (lattice, ray cast), its finest
    tessellation, its finest grid, and VTK's best (least mean error) where it is none of those."""
    done = [r for r in entry["rows"] if r["method"] in images]

    def pick(pred, key):
        c = [r for r in done if pred(r["method"])]
        return max(c, key=key)["method"] if c else None

    cols = [m for m in (
        "ours-split" if "ours-split" in images else pick(lambda m: m.startswith("ours"), lambda r: 0),
        pick(lambda m: m.startswith("vtk-lattice"), lambda r: r["method"].endswith("raycast")),
        pick(lambda m: m.startswith("vtk-tess"), lambda r: (int(r["method"].split("-")[1][4:]), r["method"].endswith("raycast"))),
        pick(lambda m: m.startswith("vtk-resample"), lambda r: int(r["method"].split("-")[1][8:]))) if m]
    best = pick(lambda m: m.startswith("vtk-"), lambda r: -r.get("mean_error", np.inf))
    return cols + ([best] if best and best not in cols else [])


def save_figure_images(entry, images, ref, folder, max_width=480):
    """OUT/figure_images/<dataset>.npz: the figure's images and the reference, every k-th pixel
    (k so the width is at most max_width), float16: what --plot draws from (a GPU machine
    without matplotlib sends these back)."""
    cols = figure_columns(entry, images)
    k = max(1, int(np.ceil(ref.shape[1] / max_width)))
    folder = Path(folder) / "figure_images"
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / f"{entry['dataset']}.npz"
    np.savez_compressed(p, columns=np.array(cols), reference=ref[::k, ::k].astype(np.float16),
                        **{f"img{i}": images[m][::k, ::k].astype(np.float16) for i, m in enumerate(cols)})
    return p


def figure(entry, npz, folder, device_name):
    """<folder>/peers_<dataset>.png from save_figure_images' file: each column's image and,
    below it, its difference to the float64 reference (errors in the titles: full resolution)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    z = np.load(npz)
    cols = [str(c) for c in z["columns"]]
    ref = z["reference"].astype(np.float64)
    rows = {r["method"]: r for r in entry["rows"]}
    H, W = ref.shape[:2]
    fig, axs = plt.subplots(2, len(cols), figsize=(2.6 * len(cols), 2.6 * 2 * H / W + 0.6), squeeze=False)
    for k, m in enumerate(cols):
        img = z[f"img{k}"].astype(np.float64)
        axs[0, k].imshow(_srgb(img[..., :3]))
        axs[0, k].set_title(m, fontsize=7)
        e = np.abs(img[..., :3] - ref[..., :3]).max(axis=-1)
        im = axs[1, k].imshow(e, cmap="magma", vmin=0.0, vmax=max(float(e.max()), 1e-6))
        axs[1, k].set_title(f"|diff| max {rows[m]['max_error']:.1e}, mean {rows[m]['mean_error']:.1e}", fontsize=6)
        cb = fig.colorbar(im, ax=axs[1, k], fraction=0.046, pad=0.02)
        cb.ax.tick_params(labelsize=5)
        for a in axs[:, k]:
            a.set_xticks([])
            a.set_yticks([])
    fig.suptitle(f"{entry['dataset']} ({device_name}): image / difference to the float64 reference", fontsize=8)
    fig.tight_layout()
    p = Path(folder) / f"peers_{entry['dataset']}.png"
    fig.savefig(p, dpi=72)
    plt.close(fig)
    return p


def plot(json_path, folder):
    """Figures again from a peers.json and its figure_images/ (e.g. those of a GPU run)."""
    out = json.loads(Path(json_path).read_text())
    Path(folder).mkdir(parents=True, exist_ok=True)
    written = []
    for name, entry in out["datasets"].items():
        npz = Path(json_path).parent / "figure_images" / f"{name}.npz"
        if npz.exists():
            written.append(figure(entry, npz, folder, out["device_name"]))
    return written


def table(out, sizes=False):
    """Markdown rows: dataset | [size |] method | frame | prepare | data | host memory | [GPU memory |]
    max | mean error. `out` is one run's JSON, or a list of them (several sizes or groups: the
    rows of a dataset stay together, in the runs' order; `sizes` adds the image size column)."""
    runs = out if isinstance(out, list) else [out]
    gpu = any(r.get("gpu_bytes") is not None for o in runs for e in o["datasets"].values() for r in e["rows"])
    head = "| dataset | " + ("size | " if sizes else "") + "method | time per frame | preparation | data | host peak | " + \
           ("GPU held | " if gpu else "") + "max error | mean error |"
    ncol = head.count("|") - 1
    lines = [head, "|" + "---|" * ncol]
    for name, size, e in _entries(runs):
        lead = [name] + ([size] if sizes else [])
        for r in e["rows"]:
            if "skipped" in r:
                lines.append("| " + " | ".join(lead + [r["method"], f"not run: {r['skipped']}"]) + " |"
                             + " |" * (ncol - len(lead) - 2))
                continue
            cells = lead + [r["method"], _ms(r["frame_seconds"]), _s(r["prepare_seconds"]),
                            _mb(r.get("data_bytes", r.get("mesh_bytes"))), _mb(r["host_peak_bytes"])]
            if gpu:
                cells.append(_mb(r.get("gpu_bytes")))
            cells += [f"{r['max_error']:.1e}", f"{r['mean_error']:.1e}"]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _entries(runs):
    """(dataset, size, entry) over runs: each dataset's sizes together, datasets and sizes in
    the order the runs give them."""
    order = []
    for o in runs:
        for name in o["datasets"]:
            if name not in order:
                order.append(name)
    return [(name, o["size"], o["datasets"][name]) for name in order for o in runs if name in o["datasets"]]


def _grid_n(row):
    """N of a vtk-resampleN row, else None."""
    prep = row.get("preparation") or ""
    return int(prep[8:]) if prep.startswith("resample") else None


def grid_points_about(dims, n0, n):
    """Points of the N = n grid, from the dimensions `dims` measured at N = n0 (the box's
    proportions recovered from them, so about: within a point a side)."""
    return int(np.prod([np.ceil((d - 1) * (n - 1) / (n0 - 1) - 1e-9) + 1 for d in dims]))


def equal_time(entry, ours="ours-split"):
    """What VTK renders in our frame time on one dataset and size: our frame (`ours`, the
    tolerance-bounded method), the largest measured grid and VTK's least-error method whose frame
    takes no longer, and why the next grid has no row (its skip reason, or its frame was slower).
    None when `ours` or every VTK method is missing."""
    rows = {r["method"]: r for r in entry["rows"]}
    mine = rows.get(ours)
    done = [r for r in entry["rows"] if r["family"] == "vtk" and "skipped" not in r]
    if mine is None or "skipped" in mine or not done:
        return None
    t = mine["frame_seconds"]
    within = [r for r in done if r["frame_seconds"] <= t]
    grids = sorted((r for r in entry["rows"] if _grid_n(r)), key=_grid_n)
    fit = [r for r in grids if r in within]
    largest = fit[-1] if fit else None
    after = [r for r in grids if largest is None or _grid_n(r) > _grid_n(largest)]
    if not after:
        stop = "no larger grid was asked for"
    elif "skipped" in after[0]:
        stop = f"{after[0]['method']}: {after[0]['skipped']}"
    else:
        stop = f"{after[0]['method']}: its frame takes {_ms(after[0]['frame_seconds'])}"
    best = min(within, key=lambda r: r["max_error"]) if within else None
    return {"ours": mine, "largest_grid": largest, "next_grid": stop, "best_within": best}


def resampling_rates(entry, sizes=(128, 256, 512)):
    """VTK's measured resampling rate on one dataset (grid points a second, of its largest
    measured grid: vtkResampleToImage's probing dominates) and the preparation that rate gives
    the N-point grids of `sizes`, with their points. None where no grid was measured."""
    grids = [r for r in entry["rows"] if _grid_n(r) and "skipped" not in r]
    if not grids:
        return None
    r = max(grids, key=_grid_n)
    n0, dims = _grid_n(r), r["grid_dimensions"]
    rate = float(np.prod(dims)) / r["prepare_seconds"]
    est = {n: (grid_points_about(dims, n0, n), grid_points_about(dims, n0, n) / rate) for n in sizes}
    return {"from": r["method"], "n": n0, "points": int(np.prod(dims)), "seconds": r["prepare_seconds"], "rate": rate,
            "estimates": est}


def figure_check(entry):
    """(the figure's columns, VTK's best by mean error, whether the figure shows it)."""
    cols = figure_columns(entry, {r["method"] for r in entry["rows"] if "skipped" not in r})
    vt = [r for r in entry["rows"] if r["family"] == "vtk" and "skipped" not in r]
    best = min(vt, key=lambda r: r["mean_error"])["method"] if vt else None
    return cols, best, best in cols


def _link(path):
    """A path as a link from docs/ (where the report is pasted)."""
    rel = os.path.relpath(os.path.abspath(path), common.REPO / "docs")
    return f"[{Path(path).parent.name}/{Path(path).name}]({rel})"


def report(paths, ours="ours-split"):
    """The peers' report from runs' peers.json files: which run (device, date, commit, size,
    VTK's OpenGL), the table, the rows at equal time, the grids not measured with VTK's measured
    resampling rate, and whether each figure shows VTK's best. What docs/benchmarks.md's peers
    tables are: `python -m bench.peers --table A.json,B.json,...`."""
    runs = [json.loads(Path(p).read_text()) for p in paths]
    sizes = len({o["size"] for o in runs}) > 1
    out = []
    for p, o in zip(paths, runs):
        gl = o.get("vtk_opengl") or ""
        renderer = next((x.split(":", 1)[1].strip() for x in gl.split(";") if "renderer string" in x), gl)
        window = gl.split("|")[0].strip()
        out.append(f"- {o['size']}: {o['device_name']} ({o['device']}), {o['date'][:10]}, commit {(o['git_commit'] or '?')[:7]}"
                   + (" (with uncommitted changes)" if o.get("git_dirty") else "")
                   + f", Warp {o.get('warp')}, VTK {o['vtk']} ({window}, OpenGL renderer {renderer}); {_link(p)}")
    out += ["", table(runs, sizes=sizes), ""]
    out += [f"**At equal time** (VTK's methods whose frame takes no longer than ours, `{ours}`; "
            "preparation is not counted, it is paid once):", "",
            "| dataset | " + ("size | " if sizes else "") + "ours: frame, max error | largest grid within it: "
            "frame, preparation, max / mean error | the next grid | VTK's least max error within it |",
            "|---|" + ("---|" if sizes else "") + "---|---|---|---|"]
    for name, size, e in _entries(runs):
        q = equal_time(e, ours)
        if q is None:
            continue
        g, b = q["largest_grid"], q["best_within"]
        gcell = (f"{g['method']} ({'x'.join(map(str, g['grid_dimensions']))}): {_ms(g['frame_seconds'])}, "
                 f"{_s(g['prepare_seconds'])}, {g['max_error']:.1e} / {g['mean_error']:.1e}") if g else "none"
        bcell = f"{b['method']}: {b['max_error']:.1e} ({_ms(b['frame_seconds'])})" if b else "none"
        out.append("| " + " | ".join([name] + ([size] if sizes else []) + [
            f"{_ms(q['ours']['frame_seconds'])}, {q['ours']['max_error']:.1e}", gcell, q["next_grid"], bcell]) + " |")
    out += ["", "**Grids not measured**: settings " + "; ".join(
        sorted({f"N = {o['settings']['resample']}, --budget {o['settings']['budget']:g} s, --max-points "
                f"{o['settings']['max_points']:.3g}" for o in runs})) + ". VTK's resampling rate measured on its "
            "largest grid, and the preparation it gives larger grids:", "",
            "| dataset | " + ("size | " if sizes else "") + "measured | 128 | 256 | 512 |",
            "|---|" + ("---|" if sizes else "") + "---|---|---|---|"]
    for name, size, e in _entries(runs):
        q = resampling_rates(e)
        if q is None:
            continue
        est = ["measured" if n == q["n"] else f"{_count(pts)} points, {_duration(sec)}"
               for n, (pts, sec) in q["estimates"].items()]
        out.append("| " + " | ".join([name] + ([size] if sizes else []) + [
            f"{q['from']}: {_count(q['points'])} points in {_s(q['seconds'])} ({_count(q['rate'])}/s)"] + est) + " |")
    out += ["", "**Figures** (ours, VTK's ParaView default, its finest tessellation and grid; VTK's best is the "
            "least mean error):", ""]
    for name, size, e in _entries(runs):
        cols, best, shown = figure_check(e)
        if best is None:
            out.append(f"- {name} ({size}): {', '.join(cols)}; no VTK image ({e.get('vtk_skipped', 'none measured')})")
            continue
        out.append(f"- {name} ({size}): {', '.join(cols)}; VTK's best {best}: "
                   + ("shown" if shown else "**not shown**"))
    return "\n".join(out)


def _duration(s):
    return _s(s) if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.0f} h"


def _count(x):
    return f"{x / 1e6:.3g} M" if x >= 1e6 else f"{x / 1e3:.3g} k" if x >= 1e3 else f"{x:.3g}"


def _ms(s):
    return f"{s * 1e3:.1f} ms" if s < 10 else f"{s:.1f} s"


def _s(s):
    return f"{s * 1e3:.0f} ms" if s < 1 else f"{s:.1f} s"


# --------------------------------------------------------------------------------- main

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="192x108")
    ap.add_argument("--datasets", default=",".join(DEFAULT_DATASETS))
    ap.add_argument("--view", default="oblique", choices=["oblique", "along_x", "grazing"])
    ap.add_argument("--methods", default="ours-split,ours-classified,vtk-lattice,vtk-tess,vtk-resample",
                    help="ours-split, ours-classified, vtk-lattice, vtk-tess, vtk-resample")
    ap.add_argument("--mappers", default="raycast,projected", help="for the tetrahedra: raycast, projected")
    ap.add_argument("--levels", default="0,1,2,3,4", help="tessellation levels")
    ap.add_argument("--resample", default="32,64,128", help="grid points along the longest side")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-tets", type=float, default=3e6)
    ap.add_argument("--max-points", type=float, default=2.2e6)
    ap.add_argument("--max-minutes", type=float, default=40.0)
    ap.add_argument("--budget", type=float, default=60.0,
                    help="seconds a preparation (tessellation, resampling) may be estimated to take")
    ap.add_argument("--sample", type=int, default=6, help="pixels per dataset checked by the independent reference")
    ap.add_argument("--seed", type=int, default=19)
    ap.add_argument("--fix-gaps", type=int, default=100,
                    help="pixels (largest float32/float64 gaps > 1e-3 first) the independent reference decides")
    ap.add_argument("--check-seconds", type=float, default=60.0,
                    help="time cap of each of those two independent checks per dataset")
    ap.add_argument("--fix-disputed", type=int, default=30,
                    help="pixels where VTK's closest method is > 0.05 off the float64 image that it decides")
    ap.add_argument("--out", default=str(common.RESULTS / "cpu" / "peers"))
    ap.add_argument("--figures", default=None, help="folder for peers_<dataset>.png (default: --out)")
    ap.add_argument("--save-images", action="store_true", help="also keep every image (npz) under OUT/images")
    ap.add_argument("--plot", metavar="PEERS_JSON", help="only draw the figures of an earlier run (into --figures)")
    ap.add_argument("--table", metavar="JSON[,JSON...]",
                    help="only print the report of earlier runs (table, equal time, grids not measured, figures)")
    args = ap.parse_args(argv)
    if args.table:
        print(report(args.table.split(",")))
        return
    if args.plot:
        for p in plot(args.plot, args.figures or Path(args.plot).parent):
            print("wrote", p)
        return

    import warp as wp

    wp.config.quiet = True
    wp.init()
    t_start = time.perf_counter()
    deadline = t_start + 60 * args.max_minutes

    def log(*a):
        print(f"[{time.perf_counter() - t_start:7.1f} s]", *a, flush=True)

    ok, gl = vp.offscreen_status()
    if not ok:
        log(f"VTK rendering unavailable: {gl}; only our methods run")
        args.methods = ",".join(m for m in args.methods.split(",") if m.startswith("ours-"))
    import vtk

    dev = wp.get_device(args.device)
    out = {"device": args.device, "device_name": dev.name if dev.is_cuda else _cpu_name(),
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "git_dirty": common.git_dirty(args.out),
           "host": platform.node(), "python": platform.python_version(), "warp": wp.__version__,
           "vtk": vtk.vtkVersion.GetVTKVersion(), "vtk_opengl": gl, "size": args.size,
           "settings": {k: v for k, v in vars(args).items()},
           "conventions": {"error": "max / mean over non-empty pixels of max RGB |image - float64 reference|",
                           "host_peak": "VmHWM rise over VmRSS before the method (VmHWM reset by /proc/self/clear_refs)",
                           "gpu": "fall of the CUDA device's free memory over the method (held after the frames)",
                           "vtk_floor": vp.QUANT},
           "datasets": {}}
    Path(args.out).mkdir(parents=True, exist_ok=True)
    figs = Path(args.figures or args.out)
    figs.mkdir(parents=True, exist_ok=True)
    log(f"peers on {out['device_name']} ({args.device}), VTK {out['vtk']} via {gl}, commit {out['git_commit']}")
    for name in args.datasets.split(","):
        if time.perf_counter() > deadline:
            out.setdefault("skipped", {})[name] = f"run deadline ({args.max_minutes} min) passed"
            log(f"{name}: skipped, deadline passed")
            continue
        try:
            entry = run_dataset(name, args, deadline, log)
        except FileNotFoundError as exc:
            log(f"{name}: skipped, missing {exc}")
            continue
        except Exception as exc:  # noqa: BLE001  (a renderer's failure is a result: recorded, the run goes on)
            out.setdefault("failed", {})[name] = f"{type(exc).__name__}: {exc}"
            log(f"{name}: failed: {type(exc).__name__}: {exc}")
            (Path(args.out) / "peers.json").write_text(json.dumps(out, indent=1, default=common.jsonable) + "\n")
            continue
        images, ref = entry.pop("_images"), entry.pop("_ref")
        npz = save_figure_images(entry, images, ref, args.out)
        try:
            entry["figure"] = str(figure(entry, npz, figs, out["device_name"]))
        except ImportError as exc:  # no matplotlib (a bare GPU machine): draw later with --plot
            log(f"  no figure ({exc}); draw it later: python -m bench.peers --plot {args.out}/peers.json")
        out["datasets"][name] = entry
        out["wall_seconds"] = time.perf_counter() - t_start
        (Path(args.out) / "peers.json").write_text(json.dumps(out, indent=1, default=common.jsonable) + "\n")
    md = table(out)
    (Path(args.out) / "peers.md").write_text(
        f"{out['device_name']} ({args.device}), {out['date']}, commit {out['git_commit']}, {args.size}, "
        f"VTK {out['vtk']} ({gl})\n\n{md}\n")
    print(md)


def _cpu_name():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip() + f" ({os.cpu_count()} cores)"
    except OSError:
        pass
    return platform.processor() or "cpu"


if __name__ == "__main__":
    main()
