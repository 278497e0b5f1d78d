"""The bench suite (issue 6): small on the CPU (regressions), full on a CUDA GPU (the figures).

    python -m bench.suite --device cpu --size small --out bench/results/cpu
    python -m bench.suite --device cuda:0 --size full --out OUT/cuda
    python -m bench.suite --plot OUT/cuda/suite.json          (plots again from a JSON)

Needs numpy, warp-lang and matplotlib only (no bpy, no file readers, no network). Writes
DIR/suite.json after every section (a run cut short keeps what it measured) and the plots
DIR/suite_time_vs_error.png, suite_resample.png, suite_scaling.png, suite_paper_scale.png.

1. methods: time against max error of riemann / trapezoid / classified (a sweep of h) and
   split (a sweep of tolerance) on three datasets: the paper's sphere (reference: the float64
   integrator, engine/reference.py), a curved mixed-shape cube (hexahedra, prisms, tetrahedra
   and pyramids, io/synthetic.curved_cube) and the paper-scale
   curved channel (io/paper_scale.paper_scale_mesh: full = 3,328 hexahedra + 7,680 prisms at
   order 6). Curved datasets have no closed-form reference: theirs is the Renderer in float64
   (engine/reference.pixel_exact_reference, RenderOptions.pixel_exact(): split, tolerance 1e-9, curved
   tails 1e-12, no early termination; on the sphere the suite records how far that is from the integrator). Full: at 1900x950 and 1920x1080.
2. resample: what users do today (bench/resample_baseline.py): the field resampled onto a
   regular grid of spacing h_g and ray-marched trilinearly (step h_g / 2): error against the
   reference, grid build and render time, grid memory, for several h_g; on the sphere and
   the paper-scale dataset (the paper's Figs. 9-11).
3. scaling: render time against image size (paper-scale dataset), samples per ray (from 1),
   order 1..14 (a brick of affine hexahedra), element count (affine bricks, full: 1,000 to
   1,000,000), and the fraction of element segments skipped as empty.

Every render is bounded: in a sweep that gets more expensive step by step, a configuration
whose time estimated from the previous one exceeds the budget (--budget, seconds; small 20,
full 30) is skipped and recorded as such; so are grids and meshes estimated to be too large,
and every render left once the suite has run --max-minutes (small 15, full 150).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time

import numpy as np

from hovr_blender.audit.scenes import BACKGROUND, COLORS, curved_mixed_scene, framing, mesh_bounds, tents
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.methods import METHODS, samples_segments, takes_step
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.io.synthetic import brick

from bench.common import RESULTS, command_line, compiled_renderer, git, git_dirty, jsonable, rgb_error, row_of, timed


CONFIG = {
    "small": {
        "method_sizes": [(64, 48)],
        "paper": {"n_hex": 48, "n_prism": 96},
        "cube_cells": 2,
        "h_divisions": [25, 50, 100, 200, 400],
        "tolerances": [1e-2, 1e-3, 1e-4, 1e-5, 1e-6],
        "repeats": 1,
        "budget": 20.0,
        "max_minutes": 15.0,
        "resample_sphere": [0.4, 0.2, 0.1, 0.05],
        "resample_paper": [2, 4, 8, 16],  # h_g = cell size / this
        "max_pairs": 3e6,
        "image_sizes": [(32, 16), (64, 32), (128, 64)],
        "order_cells": 3, "order_size": (32, 24), "orders": list(range(1, 15)),
        "count_cells": [10, 20, 40], "count_size": (32, 24), "count_modes": 4,
    },
    "full": {
        "method_sizes": [(1900, 950), (1920, 1080)],
        "paper": {"n_hex": 3400, "n_prism": 7600},
        "cube_cells": 4,
        "h_divisions": [25, 50, 100, 200, 400, 800, 1600, 3200],
        "tolerances": [1e-2, 1e-3, 1e-4, 1e-5, 1e-6],
        "repeats": 3,
        "budget": 30.0,
        "max_minutes": 150.0,
        "resample_sphere": [0.4, 0.2, 0.1, 0.05, 0.025, 0.0125],
        "resample_paper": [1, 2, 4, 8, 16],
        "max_pairs": 1.2e8,
        "image_sizes": [(480, 270), (960, 540), (1920, 1080), (3840, 2160)],
        "order_cells": 10, "order_size": (1920, 1080), "orders": list(range(1, 15)),
        "count_cells": [10, 20, 40, 60, 80, 100], "count_size": (1920, 1080), "count_modes": 4,
    },
}


# --------------------------------------------------------------------------------- datasets


def wave(x, y, z):
    return np.sin(2 * np.pi * x) * np.sin(2 * np.pi * y) * np.cos(np.pi * z) + 0.3 * z


SPHERE_TF = {
    "color": [[1.0, 1.0, 0.9, 0.2], [4.0, 0.2, 1.0, 0.3], [9.0, 0.1, 0.4, 1.0], [16.0, 1.0, 0.2, 0.6]],
    "density": [[1.5, 0.0], [2.0, 2.0], [2.5, 0.0], [4.5, 0.0], [5.0, 1.5], [5.5, 0.0],
                [8.5, 0.0], [9.0, 1.0], [9.5, 0.0], [15.0, 0.0], [16.0, 0.4], [17.0, 0.0]],
}


def dataset(name, cfg):
    """(mesh, transfer function, camera factory(w, h), description)."""
    from hovr_blender.io.builtin import sphere

    if name == "sphere":
        cam = {"projection": "perspective", "eye": [7.0, 5.5, 8.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 0.0, 1.0],
               "fov_y_deg": 40.0}
        return (sphere(), TransferFunction.from_contract(SPHERE_TF), lambda w, h: RayCamera.from_contract(cam, w, h),
                "the paper's sphere: one hexahedron, f = x^2 + y^2 + z^2")
    if name == "curved_mixed":
        return (*curved_mixed_scene(cfg["cube_cells"]),
                f"mixed_cube({cfg['cube_cells']}) of all four shapes, order 4, bent by a quadratic map (3 geometry modes)")
    if name == "paper_scale":
        from hovr_blender.io.paper_scale import paper_scale_mesh

        mesh = paper_scale_mesh(**cfg["paper"])
        info = {k: v for k, v in mesh.paper_scale.items() if k not in ("map", "source")}
        return (mesh, tents(0.25, 1.55, COLORS, 3.0), lambda w, h: framing(mesh, w, h, direction=(0.3, -1.0, 1.2)),
                f"paper-scale channel with a block: {info}")
    raise ValueError(name)


class Suite:
    def __init__(self, args):
        import warp as wp

        wp.config.quiet = True
        wp.init()
        self.wp = wp
        self.args = args
        self.cfg = dict(CONFIG[args.size])
        if args.budget is not None:
            self.cfg["budget"] = args.budget
        if args.method_sizes:
            self.cfg["method_sizes"] = [tuple(int(v) for v in wh.split("x")) for wh in args.method_sizes.split(",")]
        self.t_start = time.perf_counter()
        if args.max_minutes is None:
            args.max_minutes = self.cfg["max_minutes"]
        self.cfg["max_minutes"] = args.max_minutes  # the JSON's config says what this run used
        self.deadline = self.t_start + 60.0 * args.max_minutes
        dev = wp.get_device(args.device)
        self.out = {
            "device": str(dev), "device_name": getattr(dev, "name", str(dev)), "size": args.size,
            "date": datetime.datetime.now().isoformat(timespec="seconds"),
            "command": command_line(),
            "git_commit": git("rev-parse", "HEAD"), "git_dirty": git_dirty(args.out),
            "host": platform.node(), "python": platform.python_version(), "warp": wp.__version__,
            "numpy": np.__version__, "config": {k: v for k, v in self.cfg.items()},
            "note": ("CPU numbers are for regressions only (one CPU thread per render on a shared 2-core machine); "
                     "the figures come from the full run on a GPU.") if dev.is_cpu else
                    "Render seconds exclude kernel compilation and data loading (best of 'repeats').",
            "sections": {},
        }
        os.makedirs(args.out, exist_ok=True)

    def skip(self, est):
        """Why a render estimated to take `est` seconds is not run, or None."""
        if time.perf_counter() > self.deadline:
            return f"suite deadline ({self.args.max_minutes} min) passed"
        if est > self.cfg["budget"]:
            return f"estimated {est:.1f} s > budget {self.cfg['budget']} s"
        return None

    def log(self, *a):
        print(f"[{time.perf_counter() - self.t_start:7.1f} s]", *a, flush=True)

    def dump(self):
        self.out["wall_seconds"] = time.perf_counter() - self.t_start
        path = os.path.join(self.args.out, "suite.json")
        with open(path, "w") as fh:
            json.dump(self.out, fh, indent=1, default=jsonable)
        return path

    def renderer(self, mesh):
        return compiled_renderer(mesh, self.args.device)

    def opts(self, **kw):
        from hovr_blender.engine.view import RenderOptions

        return RenderOptions(device=self.args.device, **kw)

    # ------------------------------------------------------------------------------ section 1

    def methods(self):
        from hovr_blender.engine.reference import pixel_exact_reference, reference_render
        from hovr_blender.engine.image_io import write_png

        sec = self.out["sections"].setdefault("methods", {})
        cfg = self.cfg
        for name in ("sphere", "curved_mixed", "paper_scale"):
            t0 = time.perf_counter()
            mesh, tf, camera, desc = dataset(name, cfg)
            build = time.perf_counter() - t0
            r, first = self.renderer(mesh)
            lo, hi = mesh_bounds(mesh)
            diag = float(np.linalg.norm(hi - lo))
            self.log(f"{name}: {mesh.num_elements} elements, built in {build:.1f} s, upload {r.upload_seconds:.2f} s, "
                     f"first render (compile/load) {first:.1f} s")
            for W, H in cfg["method_sizes"]:
                cam = camera(W, H)
                case = {"dataset": name, "description": desc, "elements": mesh.num_elements, "size": [W, H],
                        "build_seconds": build, "upload_seconds": r.upload_seconds, "first_render_seconds": first,
                        "transfer_function": tf.to_contract(), "runs": []}
                t1 = time.perf_counter()
                ref, ref_stats = pixel_exact_reference(mesh, cam, tf, BACKGROUND, self.args.device, renderer=r)
                case["renderer_float64_seconds"] = ref_stats["render_seconds"]
                if name == "sphere":
                    exact, info = reference_render(mesh, cam, tf, BACKGROUND)
                    case["reference"] = "float64 integrator (engine/reference.py)"
                    case["reference_error_estimate"] = info.get("error_estimate")
                    case["renderer_float64_vs_integrator"] = rgb_error(ref, exact)
                    ref = exact
                else:
                    case["reference"] = "pixel_exact_reference: Renderer in float64, split, tolerance 1e-9, min_transmittance 0"
                case["reference_seconds"] = time.perf_counter() - t1
                self.log(f"  {W}x{H}: reference in {case['reference_seconds']:.1f} s")
                if name == "paper_scale" and (W, H) == tuple(cfg["method_sizes"][-1]):
                    write_png(os.path.join(self.args.out, "suite_paper_scale.png"), ref.astype(np.float32), alpha=False)
                for method in METHODS:
                    if not takes_step(method):  # split: a sweep of its tolerance
                        sweep = [dict(tolerance=t) for t in cfg["tolerances"]]
                    else:
                        sweep = [dict(h=diag / d) for d in cfg["h_divisions"]]
                    times = []
                    for i, kw in enumerate(sweep):
                        grow = 2.0 if not takes_step(method) or i == 0 else (sweep[i - 1]["h"] / kw["h"])
                        # time ~ a + b / h: from two renders extrapolate the growing part only (curved
                        # data spend most of the time locating elements, whatever h); from one, all of it
                        est = times[-1] + grow * max(times[-1] - times[-2], 0.0) if len(times) > 1 else \
                            (times[-1] * grow if times else 0.0)
                        why = self.skip(est)
                        if why:
                            case["runs"].append({"method": method, **kw, "skipped": why})
                            self.log(f"    {method} {kw}: skipped ({why})")
                            continue
                        res = timed(r, cam, tf, self.opts(method=method, min_transmittance=0.0, **kw), cfg["repeats"])
                        row = row_of(res, method=method, **kw, max_error=rgb_error(res.rgba, ref))
                        times.append(row["seconds"])
                        case["runs"].append(row)
                        self.log(f"    {method:10s} {kw}: error {row['max_error']:.2e}, {row['seconds'] * 1e3:.1f} ms, "
                                 f"{row['samples_per_ray']:.1f} samples/ray, empty {row['empty_fraction']:.2f}")
                sec[f"{name}@{W}x{H}"] = case
                self.dump()
            del r

    # ------------------------------------------------------------------------------ section 2

    def resample(self):
        from bench import resample_baseline as rb
        from hovr_blender.engine.reference import pixel_exact_reference, reference_render

        sec = self.out["sections"].setdefault("resample", {})
        cfg = self.cfg
        W, H = cfg["method_sizes"][-1]
        for name in ("sphere", "paper_scale"):
            mesh, tf, camera, desc = dataset(name, cfg)
            cam = camera(W, H)
            r, _ = self.renderer(mesh)
            split = timed(r, cam, tf, self.opts(method="split", tolerance=1e-5), cfg["repeats"])
            if name == "sphere":
                ref = reference_render(mesh, cam, tf, BACKGROUND)[0]
                hs = cfg["resample_sphere"]
            else:
                ref, _ = pixel_exact_reference(mesh, cam, tf, BACKGROUND, self.args.device, renderer=r)
                hs = [mesh.paper_scale["cell_size"] / d for d in cfg["resample_paper"]]
            case = {"dataset": name, "description": desc, "size": [W, H], "elements": mesh.num_elements,
                    "mesh_bytes": rb.mesh_memory_bytes(mesh),
                    "split_1e-5": {"seconds": split.stats["render_seconds"], "max_error": rgb_error(split.rgba, ref)},
                    "step": "h_g / 2", "rows": []}
            self.log(f"resample baseline on {name} at {W}x{H} (split 1e-5: error {case['split_1e-5']['max_error']:.2e}, "
                     f"{case['split_1e-5']['seconds'] * 1e3:.1f} ms; mesh {case['mesh_bytes'] / 2**20:.2f} MiB)")
            rb.march(rb.resample(mesh, max(hs) * 2), cam, tf, BACKGROUND, device=self.args.device)  # compile
            case["rows"] = rb.compare(mesh, cam, tf, BACKGROUND, hs, ref, device=self.args.device,
                                      max_pairs=cfg["max_pairs"], log=self.log)
            sec[name] = case
            self.dump()
            del r

    # ------------------------------------------------------------------------------ section 3

    def scaling(self):
        sec = self.out["sections"].setdefault("scaling", {})
        cfg = self.cfg

        # image size, on the paper-scale dataset
        mesh, tf, camera, _ = dataset("paper_scale", cfg)
        r, _ = self.renderer(mesh)
        lo, hi = mesh_bounds(mesh)
        h = float(np.linalg.norm(hi - lo)) / 400
        rows, last = [], {}
        for W, H in cfg["image_sizes"]:
            for method, kw in (("split", {"tolerance": 1e-5}), ("classified", {"h": h})):
                t_prev, px_prev = last.get(method, (0.0, 1))
                why = self.skip(t_prev * W * H / px_prev)  # time grows with the pixel count
                if why:
                    rows.append({"method": method, "size": [W, H], "pixels": W * H, **kw, "skipped": why})
                    continue
                res = timed(r, camera(W, H), tf, self.opts(method=method, **kw), cfg["repeats"])
                last[method] = (res.stats["render_seconds"], W * H)
                rows.append(row_of(res, method=method, size=[W, H], pixels=W * H, **kw))
                self.log(f"image size {W}x{H} {method}: {rows[-1]['seconds'] * 1e3:.1f} ms")
        sec["image_size"] = {"dataset": "paper_scale", "elements": mesh.num_elements, "rows": rows}
        del r
        self.dump()

        # order 1..14 on an affine brick
        n = cfg["order_cells"]
        W, H = cfg["order_size"]
        rows = []
        last = {}
        for order in cfg["orders"]:
            mesh = brick((0, 0, 0), (1, 1, 1), (n, n, n), order + 1, wave)
            r, _ = self.renderer(mesh)
            cam = framing(mesh, W, H)
            tf = tents(-0.9, 1.2, COLORS, 8.0)
            for method, kw in (("split", {"tolerance": 1e-5}), ("classified", {"h": np.sqrt(3) / 400})):
                why = self.skip(last.get(method, 0.0) * 2.0)
                if why:
                    rows.append({"method": method, "order": order, **kw, "skipped": why})
                    continue
                res = timed(r, cam, tf, self.opts(method=method, **kw), cfg["repeats"])
                last[method] = res.stats["render_seconds"]
                rows.append(row_of(res, method=method, order=order, modes=order + 1, **kw))
                self.log(f"order {order} {method}: {rows[-1]['seconds'] * 1e3:.1f} ms, "
                         f"{rows[-1]['samples_per_ray']:.1f} samples/ray")
            del r
        sec["order"] = {"elements": n ** 3, "size": [W, H], "rows": rows}
        self.dump()

        # element count, affine bricks over the unit cube (the same field at every count)
        W, H = cfg["count_size"]
        modes = cfg["count_modes"]
        rows, last = [], {}
        for c in cfg["count_cells"]:
            N = c ** 3
            need = N * (modes ** 3 * (8 + 4) + 8 * 3 * 8 * 2 + 200)  # host float64 + device float32, roughly
            if not self._fits(need):
                rows.append({"elements": N, "skipped": f"needs about {need / 2**30:.1f} GiB"})
                continue
            t0 = time.perf_counter()
            mesh = brick((0, 0, 0), (1, 1, 1), (c, c, c), modes, wave)
            build = time.perf_counter() - t0
            r, _ = self.renderer(mesh)
            cam = framing(mesh, W, H)
            tf = tents(-0.9, 1.2, COLORS, 8.0)
            for method, kw in (("split", {"tolerance": 1e-5}), ("classified", {"h": np.sqrt(3) / 400})):
                why = self.skip(last.get(method, (0.0, 1))[0] * (N / last.get(method, (0.0, 1))[1]) ** (2.0 / 3.0))
                if why:
                    rows.append({"method": method, "elements": N, **kw, "skipped": why})
                    continue
                res = timed(r, cam, tf, self.opts(method=method, **kw), cfg["repeats"])
                last[method] = (res.stats["render_seconds"], N)
                rows.append(row_of(res, method=method, elements=N, build_seconds=build, upload_seconds=r.upload_seconds, **kw))
                self.log(f"{N} elements {method}: {rows[-1]['seconds'] * 1e3:.1f} ms, segments {rows[-1]['segments']}, "
                         f"empty {rows[-1]['empty_fraction']:.2f}")
            del r, mesh
        sec["element_count"] = {"modes": modes, "size": [W, H], "rows": rows}
        self.dump()

    def _fits(self, nbytes):
        dev = self.wp.get_device(self.args.device)
        free = getattr(dev, "free_memory", None) if dev.is_cuda else None
        host = _host_memory()
        return (free is None or nbytes < 0.6 * free) and (host is None or nbytes < 0.5 * host)


def _host_memory():
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


# ------------------------------------------------------------------------------------- plots

STYLE = {"riemann": ("tab:red", "o"), "trapezoid": ("tab:blue", "s"), "classified": ("tab:green", "^"),
         "split": ("tab:purple", "D")}


def plot(path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(path) as fh:
        d = json.load(fh)
    folder = os.path.dirname(os.path.abspath(path))
    title = f"{d['device_name']} ({d['device']}), size {d['size']}, {d['date'][:10]}"
    written = []
    secs = d["sections"]

    if "methods" in secs and secs["methods"]:
        cases = secs["methods"]
        fig, axs = plt.subplots(1, len(cases), figsize=(5 * len(cases), 4.3), squeeze=False)
        for ax, (key, case) in zip(axs[0], cases.items()):
            for m in METHODS:
                rows = [r for r in case["runs"] if r["method"] == m and "skipped" not in r]
                if rows:
                    col, mk = STYLE[m]
                    ax.loglog([r["seconds"] for r in rows], [max(r["max_error"], 1e-9) for r in rows], marker=mk,
                              color=col, label=m)
            ax.axhline(1e-3, color="0.6", ls=":", lw=1)
            ax.set_title(f"{key} ({case['elements']} el.)", fontsize=9)
            ax.set_xlabel("render time (s)")
            ax.set_ylabel("max RGB error vs reference")
            ax.legend(fontsize=8)
        fig.suptitle(f"Time against error per method: {title}", fontsize=10)
        fig.tight_layout()
        written.append(_save(fig, folder, "suite_time_vs_error.png"))

    if "resample" in secs and secs["resample"]:
        fig, axs = plt.subplots(1, 3, figsize=(15, 4.3))
        for i, (name, case) in enumerate(secs["resample"].items()):
            rows = [r for r in case["rows"] if "skipped" not in r]
            if not rows:
                continue
            col = f"C{i}"
            hs = [r["h_g"] for r in rows]
            axs[0].loglog(hs, [r["max_error"] for r in rows], "o-", color=col, label=f"{name}: grid + trilinear, max")
            if "p99_error" in rows[0]:
                axs[0].loglog(hs, [r["p99_error"] for r in rows], "v:", color=col, label=f"{name}: 99th percentile")
            axs[0].axhline(case["split_1e-5"]["max_error"], color=col, ls="--", lw=1, label=f"{name}: split 1e-5 (exact geometry)")
            axs[1].loglog(hs, [r["render_seconds"] for r in rows], "o-", color=col, label=f"{name}: march")
            axs[1].loglog(hs, [r["build_seconds"] for r in rows], "x:", color=col, label=f"{name}: grid build (host)")
            axs[1].axhline(case["split_1e-5"]["seconds"], color=col, ls="--", lw=1, label=f"{name}: split 1e-5")
            axs[2].loglog(hs, [r["grid_bytes"] / 2**20 for r in rows], "o-", color=col, label=f"{name}: grid")
            axs[2].axhline(case["mesh_bytes"] / 2**20, color=col, ls="--", lw=1, label=f"{name}: high-order mesh")
        for ax, yl in zip(axs, ("max RGB error", "seconds", "memory (MiB)")):
            ax.set_xlabel("grid spacing h_g")
            ax.set_ylabel(yl)
            ax.invert_xaxis()
            ax.legend(fontsize=7)
        fig.suptitle(f"Resample onto a grid and ray-march trilinearly (step h_g/2): {title}", fontsize=10)
        fig.tight_layout()
        written.append(_save(fig, folder, "suite_resample.png"))

    if "scaling" in secs and secs["scaling"]:
        sc = secs["scaling"]
        fig, axs = plt.subplots(2, 3, figsize=(16, 8.6))
        axs = axs.ravel()
        for m in ("split", "classified"):
            col, mk = STYLE[m]

            def ok(part):
                return [r for r in sc.get(part, {}).get("rows", []) if r.get("method") == m and "skipped" not in r]

            rows = ok("image_size")
            axs[0].loglog([r["pixels"] for r in rows], [r["seconds"] for r in rows], marker=mk, color=col, label=m)
            rows = ok("order")
            axs[2].semilogy([r["order"] for r in rows], [r["seconds"] for r in rows], marker=mk, color=col, label=m)
            rows = ok("element_count")
            axs[3].loglog([r["elements"] for r in rows], [r["seconds"] for r in rows], marker=mk, color=col, label=m)
            axs[4].semilogx([r["elements"] for r in rows], [r["empty_fraction"] for r in rows], marker=mk, color=col,
                            label=f"{m}: affine bricks")
            axs[5].loglog([r["elements"] for r in rows], [r["segments"] / r["seconds"] for r in rows], marker=mk,
                          color=col, label=m)
        for i, (key, case) in enumerate(secs.get("methods", {}).items()):
            for m in METHODS:
                rows = [r for r in case["runs"] if r["method"] == m and "skipped" not in r]
                if not rows:
                    continue
                col, mk = STYLE[m]
                if key.startswith("paper_scale"):
                    axs[1].loglog([r["samples_per_ray"] for r in rows], [r["seconds"] for r in rows], marker=mk,
                                  color=col, ls="", label=f"{m} ({key})")
                if samples_segments(m):
                    axs[4].semilogx([case["elements"]], [rows[-1]["empty_fraction"]], marker=mk, color=f"C{i + 3}",
                                    ls="", label=f"{m}: {key}")
        for ax, (xl, yl, t) in zip(axs, [("pixels", "seconds", "image size (paper-scale data)"),
                                         ("samples per ray", "seconds", "samples per ray (paper-scale methods sweep)"),
                                         ("order", "seconds", f"order (affine brick, {sc.get('order', {}).get('elements', '?')} el.)"),
                                         ("elements", "seconds", "element count (affine bricks)"),
                                         ("elements", "segments_empty / segments", "segments skipped as empty"),
                                         ("elements", "element segments per second", "traversal throughput (bricks)")]):
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_title(t, fontsize=9)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
        fig.suptitle(f"Scaling: {title}", fontsize=10)
        fig.tight_layout()
        written.append(_save(fig, folder, "suite_scaling.png"))
    return written


def _save(fig, folder, name):
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, NullFormatter

    for ax in fig.axes:  # minor-tick labels of short log axes overlap: label 1, 2, 5 x 10^k instead
        for axis in (ax.xaxis, ax.yaxis):
            if axis.get_scale() == "log":
                lo, hi = sorted(axis.get_view_interval())
                if lo > 0 and hi / lo < 3:  # a narrow range (curved data: time set by location) reads best linear
                    (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("linear")
                    continue
                if lo > 0 and hi / lo < 30:
                    axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                axis.set_minor_formatter(NullFormatter())
    p = os.path.join(folder, name)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p


def main(argv=None):
    ap = argparse.ArgumentParser(description="hovr bench suite (issue 6)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", choices=sorted(CONFIG), default="small")
    ap.add_argument("--out", default=str(RESULTS / "cpu"))
    ap.add_argument("--only", default="methods,resample,scaling", help="comma list of sections")
    ap.add_argument("--budget", type=float, default=None, help="seconds one render may be estimated to take")
    ap.add_argument("--max-minutes", type=float, default=None,
                    help="after this, the renders left are skipped (recorded); default 15 small, 150 full")
    ap.add_argument("--method-sizes", default=None, help="e.g. 1920x1080 (default: small 64x48; full 1900x950,1920x1080)")
    ap.add_argument("--plot", metavar="SUITE_JSON", help="only draw the plots of an existing suite.json")
    args = ap.parse_args(argv)
    if args.plot:
        for p in plot(args.plot):
            print("wrote", p)
        return
    s = Suite(args)
    s.log(f"suite {args.size} on {s.out['device_name']} ({s.out['device']}), commit {s.out['git_commit']}")
    for section in args.only.split(","):
        t0 = time.perf_counter()
        getattr(s, section.strip())()
        s.out.setdefault("section_seconds", {})[section.strip()] = time.perf_counter() - t0
        s.dump()
    path = s.dump()
    for p in plot(path):
        s.log("wrote", p)
    s.log("wrote", path)


if __name__ == "__main__":
    main()
