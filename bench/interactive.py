"""Interactive speed on real curved data (issue 21): every shared dataset at 1920x1080 and the
paper-scale channel and hump3D at 512x512, split and classified at default settings, one run,
with each frame's kernel profile, memory per ray and per element, and its error against a
float64 render converged far below 1e-3 (the independent reference's audit is scripts/audit.py).

    python -m bench.interactive --device cuda:0 --out $OUT/interactive.json
    python -m bench.interactive --device cuda:0 --cold --out $OUT/cold.json      first image, empty caches
    python -m bench.interactive --device cpu --cold --cold-dataset sphere --size 480x270 --out $OUT/cold_cpu.json
    python -m bench.interactive --device cuda:0 --million --out $OUT/million.json  1 M curved elements
    python -m bench.interactive --device cuda:0 --all --out $OUT/all.json     datasets, edits and 1 M elements
    python -m bench.interactive --device cpu --size 192x108 --datasets hump3D    (a small CPU check)
    python -m bench.interactive --probe --device cuda:0 --sizes 1920x1080,512x512 --out $OUT/frame.json
    python -m bench.interactive --probe --device cpu --paper 48,96 --sizes 64x48 --repeats 3   (a small CPU check)

Datasets, views and transfer functions are the audit's (hovr_blender/audit/datasets.py: the oblique view, three
tents over the field's 2..98 % range). Times are the best of --repeats renders after a warm-up
render, each waited for (Renderer.render synchronises); the profile is one more render with every
kernel launch waited for and timed (its total is a little above the plain time).

--cold: for each kernel-compile setting (--cold-rows: parallel modules, one after another), a fresh Python
process with an empty Warp kernel cache (a new temporary WARP cache folder) and the CUDA driver's
compute cache off (CUDA_CACHE_DISABLE=1) loads hump3D, builds the renderer and renders one
1920x1080 frame; reported: the process's wall time to the image, and the render call's (what F12
costs once the data is imported: kernel compile + first frame). A third row, "shipped kernels",
first builds the dataset's kernels as the extension's build step ships them for this device
(scripts/build_extension.py: the CPU's objects, or the CUBIN of the GPU's arch family, into a
temporary store or --kernel-store, where what is there already is kept; its time is reported apart
as build_seconds, not the user's wait), then runs the child with an empty kernel cache and that
store (HOVR_KERNEL_BINARIES): the first image as the installed extension gives it (target 5 s);
`compiled` lists any module that still compiled. --cold-dataset sphere is the built-in sphere.

Each frame records its work counts (engine/work_counts.work_counts: per ray, Newton iterations by
phase, BVH candidates, segments, samples, and each one's divergence over 32-ray blocks; the
counts tests/perf guards on the CPU), and per dataset and method a transfer-function edit: the
view traced once (Renderer.trace) and --tf-edits edits shaded from its segments (bench/tf_edit.py's
edits, which keep the field's frame), the best of --repeats each.

--all: the datasets (with their edits) and --million in one run, one JSON.

--probe: one frame looked at closely, the quick probe for performance work (run_probe): the
paper-scale channel, curved and straight, at --sizes and --settings (SETTINGS), with the counters
per ray, the error against the pixel-exact reference and its worst pixel, and with --profile the
time per kernel. bench/suite.py is the full benchmark.

--million: copies of the curved paper-scale channel (order 6, 11,008 elements each) side by side
in a grid, one volume of about 1 M curved elements (elements of different copies never touch;
every ray crosses several copies), rendered at 1920x1080.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import common
from hovr_blender.audit import datasets  # the audit's datasets, views, transfer functions
from hovr_blender.engine.kernels.precision import Precision

# --probe's method settings by name (h_div: h = the data's diagonal / h_div); bench/multigpu.py's too
SETTINGS = {
    "split-1e-5": dict(method="split", tolerance=1e-5),
    "split-1e-3": dict(method="split", tolerance=1e-3),
    "classified-d400": dict(method="classified", h_div=400),
    "classified-d800": dict(method="classified", h_div=800),
    "classified-d1600": dict(method="classified", h_div=1600),
    "classified-d2400": dict(method="classified", h_div=2400),
    "trapezoid-d400": dict(method="trapezoid", h_div=400),
    "trapezoid-d3200": dict(method="trapezoid", h_div=3200),
}
DATASETS = ["paper_scale", "hump3D", "scaleHO", "ngsolve_ball", "ngsolve_post", "mfem_fichera", "pyfr_tgv"]
SMALL = ["paper_scale", "hump3D"]  # the 512x512 targets
METHODS = ("split", "classified")
TARGET_1080 = {"paper_scale": 0.060}  # seconds; every other dataset 0.100
TARGET_512_FPS = 60.0
COLD_ROWS = ("parallel", "serial", "shipped")  # --cold's rows: modules compiled side by side, one at a time, shipped


def _camera(mesh, W, H):
    from hovr_blender.engine.camera import RayCamera

    return RayCamera.from_contract(datasets.views(mesh)["oblique"], W, H)


def device_bytes_per_element(renderer, precision="float32") -> float:
    """The mesh's arrays on the device (MeshArgs, BVH boxes, neighbours) over its elements."""
    return renderer.device_bytes(precision) / renderer.mesh.num_elements


def options(renderer, method, classified_div):
    """Default settings (classified: its own step per segment), or with `classified_div` a fixed
    step of the data's diagonal / classified_div."""
    from hovr_blender.engine.view import RenderOptions

    extra = {"h": renderer.data_diagonal / classified_div} if method == "classified" and classified_div else {}
    return RenderOptions(method=method, device=renderer.device, **extra)


def frame(renderer, mesh, tf, W, H, method, repeats, reference=None, classified_div=None):
    from hovr_blender.engine.work_counts import work_counts

    cam = _camera(mesh, W, H)
    opts = options(renderer, method, classified_div)
    renderer.render(cam, tf, np.zeros(3), opts)  # warm-up (kernels loaded, buffers sized)
    best = None
    for _ in range(repeats):
        res = renderer.render(cam, tf, np.zeros(3), opts)
        if best is None or res.stats["render_seconds"] < best.stats["render_seconds"]:
            best = res
    prof = renderer.render(cam, tf, np.zeros(3), opts, profile=True, ray_counts=True)
    s = best.stats
    row = {"size": [W, H], "method": method, "seconds": s["render_seconds"], "rounds": s["rounds"],
           "samples_per_ray": s["samples_per_ray"], "segments_per_ray": s["segments"] / (W * H),
           "curved_locates_per_ray": s["curved_locates"] / (W * H), "walks": s["walks"],
           "kernel_seconds": prof.stats["kernel_seconds"], "options": opts.as_dict(),
           "work_counts": work_counts(Precision.named(opts.precision).kernels, prof.ray_counts),
           "lane_occupancy": prof.stats["lane_occupancy"], "regroup": renderer.regroup}
    if reference is not None:
        row["max_error_vs_float64"] = float(np.abs(best.rgba.astype(np.float64) - reference).max())
    return row


def tf_edit(renderer, mesh, tf, W, H, method, edits, repeats, classified_div=None) -> dict:
    """The view traced once, then `edits` transfer functions (tf_edit.edits: the field's frame kept)
    shaded from its segments: the best of `repeats` shades each (after a warm-up shade)."""
    from bench import tf_edit as edit_bench
    from hovr_blender.engine.limits import ResourceLimitError

    cam = _camera(mesh, W, H)
    opts = options(renderer, method, classified_div)
    try:
        cache = renderer.trace(cam, tf, opts)
    except ResourceLimitError as exc:  # the cache over the memory limit (HOVR_MAX_MEMORY raises it)
        return {"size": [W, H], "method": method, "refused": str(exc)}
    seconds = []
    for edited in edit_bench.edits(tf, edits):
        secs, _, _ = edit_bench.best(lambda: renderer.shade(cache, edited, np.zeros(3), opts), repeats, "render_seconds")
        seconds.append(secs)
    return {"size": [W, H], "method": method, "trace_seconds": cache.stats["trace_seconds"],
            "shade_seconds_min_median_max": [min(seconds), float(np.median(seconds)), max(seconds)],
            "target_seconds": 0.010, "cache": cache.describe()}


def reference_image(renderer, mesh, tf, W, H):
    """float64 split at tolerance 1e-9 without early termination: converged far below 1e-3."""
    from hovr_blender.engine.view import RenderOptions

    res = renderer.render(_camera(mesh, W, H), tf, np.zeros(3),
                          RenderOptions(method="split", precision="float64", tolerance=1e-9, min_transmittance=0.0,
                                        device=renderer.device))
    return res.rgba.astype(np.float64)


def run_datasets(args, out):
    from hovr_blender.engine.kernel_loading import load_kernels
    from hovr_blender.engine.renderer import Renderer

    W, H = map(int, args.size.split("x"))
    for name in args.datasets.split(","):
        try:
            t0 = time.perf_counter()
            mesh, _ = datasets.load(name)
            load = time.perf_counter() - t0
        except FileNotFoundError as exc:
            print(f"{name}: skipped, missing {exc}", flush=True)
            continue
        tf = datasets.transfer_function(mesh)
        t0 = time.perf_counter()
        r = Renderer(mesh, args.device, regroup=not args.no_regroup)
        load_kernels(r.kernel_variant, r.device, "float32")
        setup = time.perf_counter() - t0
        entry = {"elements": mesh.num_elements, "curved": int((~mesh.affine).sum()) if mesh.affine is not None else 0,
                 "load_seconds": load, "renderer_seconds": setup,
                 "device_bytes_per_element": device_bytes_per_element(r),
                 "tile_bytes_per_ray": r.tile_bytes_per_ray(Precision.named("float32")), "frames": []}
        ref = reference_image(r, mesh, tf, W, H) if not args.no_reference else None
        for method in METHODS:
            row = frame(r, mesh, tf, W, H, method, args.repeats, ref, args.classified_div)
            row["target_seconds"] = TARGET_1080.get(name, 0.100) if (W, H) == (1920, 1080) else None
            entry["frames"].append(row)
            print(f"{name} {W}x{H} {method}: {1e3 * row['seconds']:.1f} ms, {row['rounds']} rounds, "
                  f"{row['segments_per_ray']:.2f} seg/ray, err {row.get('max_error_vs_float64', float('nan')):.1e}", flush=True)
            if args.tf_edits > 0:
                edit = tf_edit(r, mesh, tf, W, H, method, args.tf_edits, args.repeats, args.classified_div)
                entry.setdefault("tf_edits", []).append(edit)
                print(f"{name} {W}x{H} {method}: transfer-function edit from cached segments: "
                      + (edit["refused"] if "refused" in edit else
                         f"{1e3 * edit['shade_seconds_min_median_max'][1]:.1f} ms (median)"), flush=True)
        if name in SMALL and not args.no_small:
            for method in METHODS:
                row = frame(r, mesh, tf, 512, 512, method, max(args.repeats, 10), None, args.classified_div)
                row["fps"] = 1.0 / row["seconds"]
                row["target_fps"] = TARGET_512_FPS
                entry["frames"].append(row)
                print(f"{name} 512x512 {method}: {1e3 * row['seconds']:.1f} ms = {row['fps']:.0f} fps", flush=True)
        out["datasets"][name] = entry
        _write(args.out, out)


def million_mesh(target: int):
    from hovr_blender.engine.mesh import concatenate
    from hovr_blender.io.paper_scale import paper_scale_mesh

    base = paper_scale_mesh()
    copies = int(np.ceil(target / base.num_elements))
    nx = int(np.ceil(np.sqrt(copies)))
    V = base.vertices.reshape(-1, 3)
    ext = V.max(0) - V.min(0)
    parts = []
    for k in range(copies):
        M = np.eye(4)
        M[:2, 3] = 1.05 * ext[0] * (k % nx), 1.05 * ext[1] * (k // nx)
        parts.append(base.transformed(M))
    mesh = concatenate(parts)
    mesh.volume = np.zeros(mesh.num_elements, np.int32)  # one volume: one field frame, one transfer function
    return mesh, copies


def run_million(args, out):
    from hovr_blender.engine.kernel_loading import load_kernels
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.transfer_function import TransferFunction

    W, H = map(int, args.size.split("x"))
    t0 = time.perf_counter()
    mesh, copies = million_mesh(args.million_elements)
    build = time.perf_counter() - t0
    print(f"million: {mesh.num_elements} elements ({copies} copies), built in {build:.1f} s", flush=True)
    t0 = time.perf_counter()
    r = Renderer(mesh, args.device, regroup=not args.no_regroup)
    load_kernels(r.kernel_variant, r.device, "float32")
    setup = time.perf_counter() - t0
    V = mesh.vertices.reshape(-1, 3)
    lo, hi = V.min(0), V.max(0)
    c, rad = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    d = np.array([1.0, -0.8, 0.7]) / np.linalg.norm([1.0, -0.8, 0.7])
    from hovr_blender.engine.camera import RayCamera

    cam = RayCamera.from_contract({"eye": (c + 2.6 * rad * d).tolist(), "target": c.tolist(), "up": [0, 0, 1],
                                   "fov_y_deg": 30.0}, W, H)
    tf = TransferFunction.from_contract({"color": [[0.25, 0.1, 0.2, 1.0], [0.9, 0.2, 1.0, 0.3], [1.55, 1.0, 0.3, 0.1]],
                                         "density": [[0.25, 0.0], [0.6, 0.0], [0.9, 3.0 / rad * 4], [1.2, 0.0]]})
    entry = {"elements": mesh.num_elements, "copies": copies, "build_seconds": build, "renderer_seconds": setup,
             "device_bytes_per_element": device_bytes_per_element(r),
             "tile_bytes_per_ray": r.tile_bytes_per_ray(Precision.named("float32")), "frames": []}
    for method in METHODS:
        opts = options(r, method, args.classified_div)
        r.render(cam, tf, np.zeros(3), opts)
        secs = []
        for _ in range(args.repeats):
            res = r.render(cam, tf, np.zeros(3), opts)
            secs.append(res.stats["render_seconds"])
        s = res.stats
        entry["frames"].append({"method": method, "seconds": min(secs), "rounds": s["rounds"],
                                "segments_per_ray": s["segments"] / (W * H), "alpha_mean": float(res.rgba[..., 3].mean()),
                                "target_seconds": 0.3})
        print(f"million {method}: {1e3 * min(secs):.0f} ms, {s['segments'] / (W * H):.1f} seg/ray", flush=True)
    out["million"] = entry
    _write(args.out, out)


def cold_child(args):
    """One first image in this (fresh) process: prints a JSON line."""
    t_start = float(os.environ["HOVR_COLD_T0"])
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.engine.kernel_loading import load_kernels

    mesh = _cold_mesh(args.cold_child)
    tf = datasets.transfer_function(mesh)
    r = Renderer(mesh, args.device, regroup=not args.no_regroup)
    W, H = map(int, args.size.split("x"))
    t0 = time.perf_counter()
    report = load_kernels(r.kernel_variant, r.device)  # what F12 does first (ui/jobs.compile_render_kernels)
    res = r.render(_camera(mesh, W, H), tf, np.zeros(3), RenderOptions(method="classified", device=args.device))
    t1 = time.perf_counter()
    print(json.dumps({"render_call_seconds": t1 - t0, "frame_seconds": res.stats["render_seconds"],
                      "process_seconds": time.time() - t_start, "alpha_max": float(res.rgba[..., 3].max()),
                      "shipped": len(report.shipped), "cached": report.cached, "compiled": report.compiled}), flush=True)


def _files(folder) -> set:
    return {str(f) for f in Path(folder).rglob("*") if f.is_file()}


def _cold_mesh(name):
    if name == "sphere":
        from hovr_blender.io.builtin import sphere

        return sphere()
    return datasets.load(name)[0]


def run_cold(args, out):
    import warp as wp

    from hovr_blender.engine import shipped_kernels
    from hovr_blender.engine.devices import resolve_device
    from hovr_blender.engine.kernel_loading import kernel_variant
    from scripts import build_extension  # the extension's kernel build step

    rows = []
    settings = [("parallel modules", "0", None), ("one module at a time", "1", None), ("shipped kernels", "0", "store")]
    settings = [s for s, name in zip(settings, COLD_ROWS) if name in args.cold_rows.split(",")]
    device = wp.get_device(resolve_device(args.device))
    # the binaries the extension's zip holds for this device: the CPU's objects, or the CUBIN of the
    # device's major arch that shipped_kernels takes (PTX where none is)
    cubin = [a for a in shipped_kernels.CUBIN_ARCHS if device.is_cuda and a // 10 == device.arch // 10 and a <= device.arch]
    build = dict(cpu=device.is_cpu, cubin_archs=cubin[-1:], ptx_archs=() if cubin or device.is_cpu else None)
    with tempfile.TemporaryDirectory() as scratch:
        store = args.kernel_store or scratch
        for label, workers, shipped in settings:
            extra = {}
            if shipped:
                before = _files(store)
                t0 = time.perf_counter()
                build_extension.compile_kernels(build_extension.host_platform(),
                                                variants=[kernel_variant([_cold_mesh(args.cold_dataset)]).key],
                                                precisions=("float32",), isosurfaces=(False,),
                                                store=Path(store), **build)
                extra = {"HOVR_KERNEL_BINARIES": store}
                build_seconds = time.perf_counter() - t0
                built = len(_files(store) - before)  # 0: the store held every binary already (--kernel-store)
            with tempfile.TemporaryDirectory() as cache:
                env = dict(os.environ, WARP_CACHE_PATH=cache, CUDA_CACHE_DISABLE="1", HOVR_COMPILE_WORKERS=workers,
                           HOVR_COLD_T0=repr(time.time()))
                env.pop("HOVR_KERNEL_BINARIES", None)
                env.update(extra)
                p = subprocess.run([sys.executable, "-m", __spec__.name, "--cold-child", args.cold_dataset, "--device",
                                    args.device, "--size", args.size], cwd=common.REPO, env=env, capture_output=True,
                                   text=True, timeout=900)
            lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
            if p.returncode != 0 or not lines:
                raise RuntimeError(f"cold child failed: {p.stderr[-2000:]}")
            row = {"setting": label, "HOVR_COMPILE_WORKERS": workers, **json.loads(lines[-1])}
            if shipped:
                row["build_seconds"] = build_seconds
                row["store"] = {"cubin_archs": build["cubin_archs"], "ptx_archs": build["ptx_archs"], "cpu": build["cpu"],
                                "files_built": built}
            rows.append(row)
            print(f"cold ({label}): render call {row['render_call_seconds']:.1f} s, process {row['process_seconds']:.1f} s,"
                  f" {row['shipped']} modules shipped, {len(row['compiled'])} compiled"
                  + (f" (store: {built} files built, {build_seconds:.1f} s)" if shipped else ""), flush=True)
    out["cold"] = {"dataset": args.cold_dataset, "size": args.size, "method": "classified", "rows": rows,
                   "target_seconds": 5.0}
    _write(args.out, out)


def run_probe(args):
    """--probe: one frame looked at closely (what bench/frame.py was): the paper-scale channel
    (--variants curved, straight; --paper hexahedra,prisms) at --sizes and --settings (SETTINGS),
    with the kernel's counters per ray and the error against engine/reference.pixel_exact_reference
    (float64, split at tolerance 1e-9, no early termination; --no-reference skips it). Each case:
    the build time, the first render (kernel compile or cache load), then per setting the best of
    --repeats renders: seconds, element segments, curved locations, field and restriction
    evaluations per ray, the empty/smooth/piecewise counts, the max RGB error and the worst pixel;
    with --profile one more render per setting, each kernel waited for and timed."""
    import warp as wp

    from hovr_blender.audit import scenes  # framing and transfer functions: the suite's own
    from hovr_blender.engine.reference import pixel_exact_reference  # every benchmark's reference
    from hovr_blender.engine.view import RenderOptions

    wp.config.quiet = True
    wp.init()
    n_hex, n_prism = (int(v) for v in args.paper.split(","))
    out = {"device": args.device, "device_name": wp.get_device(args.device).name,
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "cases": []}
    from hovr_blender.io.paper_scale import paper_scale_mesh

    for variant in args.variants.split(","):
        t0 = time.perf_counter()
        mesh = paper_scale_mesh(n_hex, n_prism, curved=(variant == "curved"))
        build = time.perf_counter() - t0
        tf = scenes.tents(0.25, 1.55, scenes.COLORS, 3.0)
        r, first = common.compiled_renderer(mesh, args.device)
        lo, hi = scenes.mesh_bounds(mesh)
        diag = float(np.linalg.norm(hi - lo))
        print(f"{variant}: {mesh.num_elements} elements ({int(mesh.affine.sum())} affine), build {build:.1f} s, "
              f"upload {r.upload_seconds:.2f} s, first render {first:.1f} s", flush=True)
        for size in args.sizes.split(","):
            W, H = (int(v) for v in size.split("x"))
            cam = scenes.framing(mesh, W, H, direction=(0.3, -1.0, 1.2))
            case = {"variant": variant, "elements": mesh.num_elements, "affine": int(mesh.affine.sum()),
                    "size": [W, H], "build_seconds": build, "first_render_seconds": first, "runs": []}
            ref = None
            if not args.no_reference:
                ref, ref_stats = pixel_exact_reference(mesh, cam, tf, scenes.BACKGROUND, args.device, renderer=r)
                case["reference_seconds"] = ref_stats["render_seconds"]
            for name in args.settings.split(","):
                kw = dict(SETTINGS[name])
                if "h_div" in kw:
                    kw["h"] = diag / kw.pop("h_div")
                res = common.timed(r, cam, tf, RenderOptions(device=args.device, **kw), args.repeats)
                row = common.row_of(res, setting=name, **kw)
                px = W * H
                row.update(segments_per_ray=row["segments"] / px, locates_per_ray=row["curved_locates"] / px,
                           field_evals_per_ray=row["field_evaluations"] / px,
                           restriction_evals_per_ray=row["restriction_evaluations"] / px)
                row["rounds"] = res.stats.get("rounds")
                if args.profile:
                    prof = r.render(cam, tf, scenes.BACKGROUND, RenderOptions(device=args.device, **kw), profile=True)
                    row["kernel_seconds"] = prof.stats["kernel_seconds"]
                if ref is not None:
                    row["max_error"] = common.rgb_error(res.rgba, ref)
                    err = np.abs(res.rgba[..., :3].astype(np.float64) - ref[..., :3]).max(axis=-1)
                    worst = np.unravel_index(int(err.argmax()), err.shape)
                    row["worst_pixel"] = {"row": int(worst[0]), "col": int(worst[1]),
                                          "got": res.rgba[worst].tolist(), "reference": ref[worst].tolist()}
                    row["pixels_over"] = {f"{v:g}": int((err > v).sum()) for v in (1e-5, 1e-4, 1e-3, 1 / 255)}
                case["runs"].append(row)
                print(f"  {W}x{H} {name:16s} {row['seconds'] * 1e3:9.1f} ms  err {row.get('max_error', float('nan')):.1e}  "
                      f"seg/ray {row['segments_per_ray']:.2f} loc/ray {row['locates_per_ray']:.2f} "
                      f"field/ray {row['field_evals_per_ray']:.1f} restr/ray {row['restriction_evals_per_ray']:.1f} "
                      f"empty {row['empty_fraction']:.2f}" + (f" kernels {row['kernel_seconds']}" if args.profile else ""),
                      flush=True)
            out["cases"].append(case)
            if args.out:
                with open(args.out, "w") as fh:
                    json.dump(out, fh, indent=1, default=common.jsonable)
        del r



def _write(path, out):
    if path:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, "w") as f:
            json.dump(out, f, indent=1, default=common.jsonable)
            f.write("\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--datasets", default=",".join(DATASETS))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--classified-div", type=float, default=0.0,
                    help="classified's fixed step h = the data's box diagonal / this (0: the core's default, its own step per segment)")
    ap.add_argument("--no-reference", action="store_true")
    ap.add_argument("--no-small", action="store_true", help="skip the 512x512 frames")
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--cold-dataset", default="hump3D")
    ap.add_argument("--cold-child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--cold-rows", default=",".join(COLD_ROWS), help="--cold: the rows to run (default %(default)s)")
    ap.add_argument("--kernel-store", default=None,
                    help="--cold: the shipped kernels' store to use and keep (binaries missing there are built into it "
                         "first; default: a temporary one)")
    ap.add_argument("--million", action="store_true")
    ap.add_argument("--million-elements", type=int, default=1_000_000)
    ap.add_argument("--tf-edits", type=int, default=4, help="transfer-function edits shaded from cached segments "
                    "per dataset and method (0: none)")
    ap.add_argument("--all", action="store_true", help="the datasets, then --million, in one run and one JSON")
    ap.add_argument("--no-regroup", action="store_true", help="the rays in the order each round leaves them "
                    "(Renderer(regroup=False)), to time the regrouping against it")
    ap.add_argument("--probe", action="store_true", help="one frame looked at closely (run_probe): the paper-scale "
                    "channel at --sizes and --settings")
    ap.add_argument("--sizes", default="1920x1080", help="--probe: image sizes")
    ap.add_argument("--paper", default="3400,7600", help="--probe: requested hexahedra,prisms")
    ap.add_argument("--variants", default="curved,straight", help="--probe: curved, straight or both")
    ap.add_argument("--settings", default="split-1e-5,split-1e-3,classified-d400,trapezoid-d400",
                    help="--probe: SETTINGS names")
    ap.add_argument("--profile", action="store_true", help="--probe: one more render per setting, each kernel waited "
                    "for and timed")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if args.cold_child:
        return cold_child(args)
    if args.probe:
        return run_probe(args)
    import warp as wp

    from hovr_blender.engine.devices import resolve_device

    resolve_device(args.device)
    out = {"device": args.device, "device_name": wp.get_device(args.device).name,
           "date": datetime.datetime.now().isoformat(timespec="seconds"),
           "command": common.command_line(),
           "git_commit": common.git("rev-parse", "HEAD"), "datasets": {}}
    if args.cold:
        run_cold(args, out)
    elif args.million:
        run_million(args, out)
    else:
        run_datasets(args, out)
        if args.all:
            run_million(args, out)


if __name__ == "__main__":
    main()
