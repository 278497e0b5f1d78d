"""`hovr`: render a view file exactly per the render contract, without Blender.

    hovr render FILE|VIEW.json [-o out.npy] [--png out.png [--png-background view|transparent|R,G,B]
                [--legend [--units UNITS]]] [--field NAME] [--size WxH] [--stats stats.json]
                [--method NAME] [--h STEP] [--tolerance TOL] [--device cpu|cpu:all|cuda:0|cuda:0,cuda:1|cuda:all]
    hovr view FILE|VIEW.json [--field NAME] [--size WxH] > view.json
                                                           (the view a data file gets: Blender's first look)
    hovr reference VIEW.json -o ref.npy [--png ref.png]    (float64 certifying reference)
    hovr render-series VIEW.json -o out/frame_####.npy --frames 1-100 [--png] [--orbit DEG]
                [--camera-path cams.json] [--scheduler ADDRESS | --workers N] [--device auto|cpu|cuda:0]
                                                           (frames over a Dask cluster)

Every failure ends with one `hovr: error: ...` line and exit code 2 (--debug adds the traceback);
Ctrl-C and SIGTERM end with one line too (exit codes 130 and 143).
Outputs are written to temporary files in their folders and renamed into place only when
all of them succeeded: a failed run leaves no partial result.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import sys
import threading
import tempfile
import time
import traceback

from .engine import scratch
from .engine.methods import METHODS
from .engine.words import plural

EXIT_ERROR = 2
DEFAULT_SIZE = (960, 540)  # a data file's image without --size: half Blender's default 1920 x 1080


class OutputError(ValueError):
    """An output path the command will not write to."""


class Terminated(BaseException):
    """SIGTERM: ended like Ctrl-C (children closed, temporaries removed), with one line."""


def _cluster_options(q):
    """The Dask cluster options of render-series and render-blend (docs/distributed.md)."""
    q.add_argument("--scheduler", help="address of a running Dask scheduler (tls://host:8786) or a scheduler "
                   "file (.json); default: a local cluster only this run can reach (TLS, keys made for the run)")
    q.add_argument("--workers", type=int, help="local cluster: worker processes (default: one per CUDA device, "
                   "else one per CPU core; at most one a core, or HOVR_MAX_PROCESSES)")
    q.add_argument("--dashboard", nargs="?", const="127.0.0.1:8787", metavar="ADDRESS",
                   help="local cluster: open Dask's dashboard (plain HTTP, readable by anyone on this machine) "
                   "at ADDRESS (default 127.0.0.1:8787); without it no HTTP port is opened")
    q.add_argument("--tls-ca-file", help="--scheduler: the cluster's CA certificate (with --tls-cert and --tls-key; "
                   "default: Dask's configuration, distributed.comm.tls)")
    q.add_argument("--tls-cert", help="--scheduler: your client certificate")
    q.add_argument("--tls-key", help="--scheduler: your client certificate's private key")


def _parser() -> argparse.ArgumentParser:
    from .io import formats

    p = argparse.ArgumentParser(prog="hovr", description=__doc__.split("\n\n")[0],
                                epilog=f"The view's data.path: builtin:NAME or a file of {formats.described()}.")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")
    sub = p.add_subparsers(dest="command", required=True)

    def view_source(q):
        q.add_argument("view", help="a data file (its view as Blender's import gives it: docs/cli.md) or a view "
                       "JSON (docs/spec/render-contract.md), whose image, camera, transfer_function and background "
                       "may be left out")
        q.add_argument("--field", help="the data's field instead of the view's data.field (a data file's default: "
                       "its first): a name, |a,b,c| or a derived field such as Q(Velocity), "
                       "vorticity(rhou,rhov,rhow/rho), |grad|(p) (docs/spec/render-contract.md §8)")
        q.add_argument("--size", type=_size, metavar="WxH", help="image size in pixels instead of the view's "
                       f"(default for a data file: {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")

    def common(q):
        view_source(q)
        q.add_argument("-o", "--output", help="float32 (H, W, 4) RGBA .npy (its folder must exist); -o, --png or both")
        q.add_argument("--png", help="an sRGB 8-bit .png")
        q.add_argument("--png-background", default="view", type=_png_background, metavar="view|transparent|R,G,B",
                       help="the PNG's background: view (default: flattened on the view's background colour, "
                       "no alpha), transparent (the volume alone, straight alpha) or a linear colour R,G,B")
        q.add_argument("--legend", action="store_true", help="draw the colour legend on the PNG: the transfer "
                       "function's colours over its value range with its density as a curve, the field's name and "
                       "units (engine/legend.py)")
        q.add_argument("--units", help="the field's units for the legend's title (e.g. kg/m^3)")
        q.add_argument("--stats", help="write render statistics as .json")
        q.add_argument("--max-memory", help="memory limit of the load and the render, e.g. 8G (default 4G, "
                       "or HOVR_MAX_MEMORY)")
        q.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)

    r = sub.add_parser("render", help="render a data file or a view file with the Warp kernels")
    common(r)
    r.add_argument("--method", choices=METHODS, help="quadrature (default: the view's, else classified)")
    r.add_argument("--h", type=float, help="fixed step in world units: Riemann and trapezoid need one; classified "
                   "without it chooses each piecewise-smooth segment's step from its error bound")
    r.add_argument("--tolerance", type=float, help="absolute error per adaptive Gauss-Kronrod panel")
    r.add_argument("--min-transmittance", type=float, help="early ray termination threshold")
    r.add_argument("--inner", choices=("spectral", "trapezoid"), help="inner integral on smooth segments")
    r.add_argument("--device", help="Warp device: cpu, cuda:0, a list (cuda:0,cuda:1: the frame's rows split "
                   "over them), cuda:all (every CUDA device here) or cpu:all (one process a CPU core)")
    r.add_argument("--precision", choices=("float32", "float64"), help="kernel arithmetic (default float32)")
    r.add_argument("--max-samples-per-ray", type=int, help="fixed-step methods: refuse a step h that takes more "
                   "samples across the data (default 100000, or HOVR_MAX_SAMPLES_PER_RAY)")
    f = sub.add_parser("reference", help="render the float64 reference (affine hexahedra)")
    common(f)
    v = sub.add_parser("view", help="print the view of a data file (or complete a view file's) as JSON: the "
                       "camera, transfer function and range Blender's import gives it, to edit and render")
    view_source(v)
    v.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    s = sub.add_parser("render-series", help="render numbered frames (a field series, a camera path, or both) "
                       "over a Dask cluster (docs/distributed.md)")
    s.add_argument("view", help="view JSON; a run of '#' in data.path or data.solution is the frame number")
    s.add_argument("-o", "--output", required=True, help="output pattern with a run of '#', ending in .npy "
                   "(out/frame_####.npy); its folder must exist")
    s.add_argument("--frames", required=True, help="frame numbers: 1-100, 1-100:2, 3,5,8-10")
    s.add_argument("--png", action="store_true", help="also write frame_####.png")
    s.add_argument("--stats", action="store_true", help="also write frame_####.json (render and load times)")
    s.add_argument("--camera-path", help="JSON: {\"first_frame\": N, \"cameras\": [camera, ...]} (contract cameras)")
    s.add_argument("--orbit", type=float, help="turn the view's camera about its up axis by this many degrees "
                   "over the frames")
    _cluster_options(s)
    s.add_argument("--device", default="auto", help="each worker's device: auto (a local worker k: cuda:k; "
                   "else cuda:0, or cpu without CUDA), cpu or cuda:N")
    s.add_argument("--method", choices=METHODS, help="quadrature (default: the view's)")
    s.add_argument("--h", type=float, help="fixed step in world units (as render's --h)")
    s.add_argument("--tolerance", type=float, help="absolute error per adaptive Gauss-Kronrod panel")
    s.add_argument("--precision", choices=("float32", "float64"), help="kernel arithmetic")
    s.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    b = sub.add_parser("render-blend", help="render a saved .blend's frames with headless Blenders over a Dask "
                       "cluster, into the files `blender -b FILE -a` writes")
    b.add_argument("blend", help="the .blend (its output path and frame range as saved; its scripts never run)")
    b.add_argument("--frames", required=True, help="frame numbers: 1-250, 1-250:2, 3,5,8-10")
    b.add_argument("-o", "--output", help="folder to write the frames into (their names as the .blend gives them); "
                   "default: the .blend's output path, which must lie under the .blend's own folder")
    b.add_argument("--frame-timeout", type=float, default=3600.0, help="seconds a frame's Blender may run before "
                   "it is stopped (default 3600)")
    b.add_argument("--blender", help="Blender binary with the add-on enabled (default: this Python, with bpy)")
    _cluster_options(b)
    b.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return p


def _png_background(text: str):
    """--png-background: "view", "transparent" or "r,g,b" (linear, each 0..1)."""
    from .engine.image_io import PNG_BACKGROUNDS

    if text in PNG_BACKGROUNDS:
        return text
    try:
        rgb = tuple(float(x) for x in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise argparse.ArgumentTypeError(f"{text!r}: give view, transparent or a linear colour R,G,B (each 0..1)")
    return rgb


def _output_path(path: str, suffix: str, what: str) -> str:
    """The absolute path to write `what` to: it ends with `suffix`, its folder exists, and if it
    exists already it is a regular file (never a folder, FIFO or device), not a link (replacing a
    link would quietly write elsewhere than the user may think; limits.open_output refuses them too)."""
    if not path.lower().endswith(suffix):
        raise OutputError(f"{what} {path!r} must end with {suffix}")
    path = os.path.abspath(path)
    folder = os.path.dirname(path)
    if not os.path.isdir(folder):
        raise OutputError(f"{what} {path}: folder {folder} does not exist")
    if os.path.islink(path):
        raise OutputError(f"{what} {path} is a symbolic link; refused (outputs never follow links)")
    if os.path.lexists(path) and not os.path.isfile(path):
        raise OutputError(f"{what} {path} exists and is not a regular file")
    return path


def _write_all(outputs):
    """Write each (path, writer) to a temporary file beside its target; rename all into place
    only when every one was written (a failure removes the temporaries)."""
    done = []
    try:
        for path, writer in outputs:
            fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix="." + os.path.basename(path) + ".",
                                       suffix=".tmp")
            done.append((tmp, path))
            with os.fdopen(fd, "wb") as fh:
                writer(fh)
        for tmp, path in done:
            os.replace(tmp, path)
    except BaseException:
        for tmp, _ in done:
            if os.path.exists(tmp):
                os.unlink(tmp)
        raise


def _size(text: str) -> tuple[int, int]:
    """--size WxH: whole numbers of pixels."""
    from .engine.view import MAX_IMAGE_SIDE

    w, _, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not all(1 <= s <= MAX_IMAGE_SIDE for s in size):
        raise argparse.ArgumentTypeError(f"{text!r}: give the image size as WxH, each 1..{MAX_IMAGE_SIDE} pixels")
    return size


def _is_view_file(path: str) -> bool:
    return path.lower().endswith(".json")


def _reads_a_file(view_path) -> bool:
    """Whether a view names a data file (not builtin:): a cheap first look, errors left to the run."""
    if not _is_view_file(view_path):
        return not view_path.startswith("builtin:")
    from .engine import strict_json
    from .engine.view import MAX_VIEW_BYTES, ViewError
    from .engine.limits import read_regular

    try:
        data = strict_json.loads(read_regular(view_path, "view file", max_bytes=MAX_VIEW_BYTES), view_path, ViewError)
        return "path" in data.get("data", {})
    except Exception:  # noqa: BLE001  (the run itself reports what is wrong)
        return False


def _data_of_file(path: str, field: str | None) -> tuple[dict, list]:
    """(the view's data object, notes) of a data file as Blender's import reads it (io.sources.choose_data:
    the solution given or the likeliest beside it, the field given or the file's first)."""
    if path.startswith("builtin:"):
        return {"builtin": path.partition(":")[2]}, []
    from .io.sources import choose_data

    path = os.path.abspath(path)
    _, choice = choose_data(path, field=field or "", settings=("--field", "give a view file's data.solution"))
    data = {"path": path, **{k: v for k, v in (("solution", choice.solution), ("field", choice.field),
                                                ("component", choice.component)) if v}}
    return data, [*choice.notes, *(f"warning: {w}" for w in choice.warnings)]


def _view_object(args) -> tuple[dict, str, list]:
    """(view object, base folder, notes): a view file's keys, or a data file's {"data": ...}, with
    --field and --size over them; completed by _first_view once the data is read."""
    from .engine import limits, strict_json
    from .engine.view import MAX_VIEW_BYTES, ViewError, data_spec

    if _is_view_file(args.view):
        raw = limits.read_regular(args.view, "view file", max_bytes=MAX_VIEW_BYTES)
        view = strict_json.as_object(strict_json.loads(raw, args.view, ViewError), "a view", ViewError)
        if "data" not in view:
            raise ViewError("view needs 'data'")
        base_dir, notes = os.path.dirname(os.path.abspath(args.view)), []
        if args.field:
            view["data"] = {**data_spec(view["data"]), "field": args.field}
    else:
        data, notes = _data_of_file(args.view, args.field)
        view, base_dir = {"data": data}, os.getcwd()
    if args.size:
        view["image"] = {"width": args.size[0], "height": args.size[1]}
    return view, base_dir, notes


def _first_view(view: dict, mesh):
    """(view, F12's camera or None, warnings): a view without a camera or a transfer function completed
    from the data's first view (engine/first_view.default_view: Blender's import), each key it gives
    kept, and where the camera is the first view's, the rays Blender's F12 has (factory_camera); a
    view with both is left as it is (its background black and its render settings the defaults where
    it gives none, as ever)."""
    if "camera" in view and "transfer_function" in view:
        return view, None, []
    from .engine import first_view
    from .engine.strict_json import as_integer, as_object
    from .engine.view import MAX_IMAGE_SIDE, ViewError

    image = as_object(view.get("image", {}), "image", ViewError)
    width = as_integer(image.get("width", DEFAULT_SIZE[0]), "image size: width", ViewError, 1, MAX_IMAGE_SIDE)
    height = as_integer(image.get("height", DEFAULT_SIZE[1]), "image size: height", ViewError, 1, MAX_IMAGE_SIDE)
    first = first_view.default_view(mesh, view["data"], width, height)
    out = {**first.view, **view}
    out["render"] = {**first.view["render"], **as_object(view.get("render", {}), "render", ViewError)}
    return out, (first.camera if "camera" not in view else None), first.warnings


def _load_view(args):
    """(View, its object, mesh) of the command line's data file or view file (_view_object,
    _first_view); what the data's choice, its reader and its first look have to say goes to stderr,
    as Blender's import reports it."""
    from .engine.view import View, data_spec
    from .engine.words import summarise_warnings
    from .io.sources import VolumeSource, load_volume

    d, base_dir, notes = _view_object(args)
    mesh = load_volume(VolumeSource.from_view_data(data_spec(d["data"]), base_dir))
    d, camera, warnings = _first_view(d, mesh)
    view = View.from_dict(d, base_dir)
    if camera is not None:
        view.camera = camera
    for note in notes + getattr(mesh, "notes", []):
        print(f"hovr: {note}", file=sys.stderr)
    for warning in summarise_warnings(getattr(mesh, "warnings", [])) + warnings:
        print(f"hovr: warning: {warning}", file=sys.stderr)
    return view, d, mesh


def _run_view(args) -> str:
    """hovr view: the completed view on stdout, as JSON (the notes on stderr)."""
    if _reads_a_file(args.view):
        from .io import isolation

        isolation.prestart()
    return view_json(_load_view(args)[1])


def view_json(view: dict) -> str:
    """A view as JSON to read and edit: a key a line, a transfer function's breakpoint a line."""
    import json

    def rows(key, value):
        if key != "transfer_function":
            return json.dumps(value)
        parts = [f'  "{k}": [\n' + ",\n".join(f"   {json.dumps(r)}" for r in v) + "]" for k, v in value.items()]
        return "{\n" + ",\n".join(parts) + "}"

    return "{\n" + ",\n".join(f' "{k}": {rows(k, v)}' for k, v in view.items()) + "\n}"


def _run(args) -> str:
    from .io import isolation

    if _reads_a_file(args.view):
        isolation.prestart()  # the reader process starts while this one imports the readers and the engine
    from .engine import limits
    from .engine.image_io import png_pixels, write_json, write_npy, write_png
    from .engine.mesh import data_diagonal

    if not args.output and not args.png:
        raise OutputError("give -o out.npy, --png out.png or both")
    out = _output_path(args.output, ".npy", "-o") if args.output else None
    png = _output_path(args.png, ".png", "--png") if args.png else None
    if args.legend and not png:
        raise OutputError("--legend draws on the PNG: give --png too")
    if args.units and not args.legend:
        raise OutputError("--units names the legend's units: give --legend too")
    st_path = _output_path(args.stats, ".json", "--stats") if args.stats else None
    lim = limits.current()
    if args.max_memory:  # the other limits (inflation, read time) stay as the environment sets them
        lim = dataclasses.replace(lim, max_memory=limits.parse_size(args.max_memory))
    if getattr(args, "max_samples_per_ray", None) is not None:
        lim = dataclasses.replace(lim, max_samples_per_ray=args.max_samples_per_ray)
    with limits.using(lim):
        t0 = time.perf_counter()
        view, _, mesh = _load_view(args)  # the data is read before Warp loads: most hostile files are
        load_s = time.perf_counter() - t0  # refused by their reader
        if args.command == "render":
            view.options = view.options.with_(
                method=args.method, h=args.h, tolerance=args.tolerance,
                min_transmittance=args.min_transmittance, inner=args.inner, device=args.device,
                precision=args.precision,
            )
            # what the policy refuses without the data or Warp is refused first (Warp takes seconds to load)
            w, h = view.camera.width, view.camera.height
            limits.check_bytes(view.options.image_bytes(w, h), f"a {w}x{h} image in {view.options.precision} "
                                                               "(its pixels alone)")
            view.options.check_steps(data_diagonal(mesh))
            from .engine.frame import Frame, render_frame
            from .engine.multi_device import make_renderer

            frame = Frame.from_view(view)
            with make_renderer(mesh, view.options.device, frame=frame) as renderer:  # a device list splits the rows
                result = render_frame(renderer, frame, view.camera)
            rgba, stats = result.rgba, result.stats
            for warning in stats.get("warnings", []):
                print(f"hovr: warning: {warning}", file=sys.stderr)
        else:
            from .engine.reference import reference_render

            t0 = time.perf_counter()
            rgba, info = reference_render(mesh, view.camera, view.transfer_function, view.background)
            stats = {"device": "cpu (numpy float64)", "render_seconds": time.perf_counter() - t0,
                     "method": "reference", "parameters": {}, **info}
    stats["load_seconds"] = load_s
    outputs = [(out, lambda fh: write_npy(fh, rgba))] if out else []
    if png:
        shown = png_pixels(rgba, view.background, args.png_background)
        if args.legend:
            from .engine.legend import draw_legend, legend_layout, tf_value_range

            over = view.background if isinstance(args.png_background, str) else args.png_background
            title = mesh.field_name or view.data.get("field") or "value"
            shown = draw_legend(shown, legend_layout(view.transfer_function, *tf_value_range(view.transfer_function),
                                                     title, view.camera.width, view.camera.height, over,
                                                     units=args.units))
        outputs.append((png, lambda fh: write_png(fh, shown, alpha=args.png_background == "transparent")))
    if st_path:
        outputs.append((st_path, lambda fh: write_json(fh, stats)))
    _write_all(outputs)
    return (f"hovr: {view.camera.width}x{view.camera.height} {stats['method']} in {stats['render_seconds']:.3f} s "
            f"on {stats['device']} -> {', '.join(p for p in (out, png) if p)}")


class _dask_client:  # noqa: N801  (a context manager read as a function)
    """The Dask client of --scheduler (an address or a scheduler file, with the user's security),
    else of a local cluster only this run can reach (distributed/series.py)."""

    def __init__(self, args, device="auto"):
        from .distributed import series

        self.cluster = None
        if args.scheduler:
            if args.dashboard:
                raise ValueError("--dashboard opens a local cluster's dashboard; a --scheduler's is its own")
            self.client = series.remote_client(args.scheduler, args.tls_ca_file, args.tls_cert, args.tls_key)
        else:
            if args.tls_ca_file or args.tls_cert or args.tls_key:
                raise ValueError("--tls-ca-file, --tls-cert and --tls-key are for --scheduler (a local cluster "
                                 "makes its own keys)")
            self.cluster = series.local_cluster(args.workers, device, dashboard=args.dashboard, quiet=not args.debug)
            try:
                self.client = series.cluster_client(self.cluster)
            except BaseException:
                self.cluster.close()
                raise

    def __enter__(self):
        return self.client

    def __exit__(self, *exc):
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()


_BAR_OPEN = []  # a progress bar is drawn and its line not ended yet (a message starts below it)


def _end_progress_line():
    if _BAR_OPEN:
        print(file=sys.stderr)
        _BAR_OPEN.clear()


def _progress_bar(t0):
    """progress(done, total, record): one line on stderr, redrawn, with a bar over the frames."""
    def progress(done, total, rec):
        rate = done / (time.perf_counter() - t0)
        bar = "#" * (30 * done // total) + "." * (30 - 30 * done // total)
        print(f"\rhovr: [{bar}] {done}/{total} frames, {rate:.2f} frames/s (frame {rec['frame']}: {rec['status']})",
              end="" if done < total else "\n", file=sys.stderr, flush=True)
        _BAR_OPEN[:] = [True] if done < total else []

    return progress


def _run_blend(args) -> str:
    """render-blend: a .blend's frames over a Dask cluster (distributed/blender_frames.py)."""
    from .distributed import blender_frames, series

    from .engine import limits

    blend = os.path.abspath(args.blend)
    limits.check_regular(blend, ".blend file")
    frames = series.parse_frames(args.frames)
    if not args.frame_timeout > 0:
        raise ValueError(f"--frame-timeout {args.frame_timeout:g} must be a positive number of seconds")
    blender_frames.output_root(blend, args.output)  # -o checked before a cluster starts
    t0 = time.perf_counter()
    with _dask_client(args, "cpu" if args.workers else "auto") as client:
        records = blender_frames.render_animation(blend, frames, client, blender=args.blender,
                                                  progress=_progress_bar(t0), timeout=args.frame_timeout,
                                                  output=args.output)
    written = sum(1 for r in records if r["status"] == "written")
    return (f"hovr: {plural(written, 'frame')} written, {len(records) - written} were already there, in "
            f"{time.perf_counter() - t0:.1f} s")


def _run_series(args) -> str:
    """render-series: the frames not yet written, over a Dask cluster (distributed/series.py)."""
    from .engine.view import View
    from .distributed import series

    if "#" not in args.output:
        raise OutputError(f"-o {args.output!r} needs a run of '#' for the frame number (out/frame_####.npy)")
    _output_path(args.output, ".npy", "-o")
    frames = series.parse_frames(args.frames)
    view_path = os.path.abspath(args.view)
    view = View.load(view_path)
    if args.camera_path and args.orbit is not None:
        raise ValueError("give --camera-path or --orbit, not both")
    cameras = {}
    if args.camera_path:
        cameras = series.read_camera_path(args.camera_path, frames, view.camera.width, view.camera.height)
    elif args.orbit is not None:
        from .engine import limits, strict_json

        camera = strict_json.loads(limits.read_regular(view_path, "view file"), view_path)["camera"]
        cameras = series.orbit_cameras(camera, frames, args.orbit)
    options = {k: v for k, v in (("method", args.method), ("h", args.h), ("tolerance", args.tolerance),
                                 ("precision", args.precision)) if v is not None}
    view.options.with_(**options)  # checked here, before any worker starts
    device = "auto" if args.device == "cuda:all" else args.device
    job = series.SeriesJob(view=view_path, frames=frames, output=os.path.abspath(args.output), png=args.png,
                           stats=args.stats, cameras=cameras, options=options, device=device)
    todo = series.pending_frames(job)
    if not todo:
        return f"hovr: all {len(frames)} frames are written already ({job.npy(frames[0])} ...)"
    series.check_outputs(job, todo)  # a planted link refused before any worker starts
    t0 = time.perf_counter()
    with _dask_client(args, args.device) as client:
        records = series.render_series(job, client, progress=_progress_bar(t0))
    seconds = time.perf_counter() - t0
    written = [r for r in records if r["status"] == "written"]
    load = sum(r["load_seconds"] for r in written) / max(len(written), 1)
    return (f"hovr: {plural(len(written), 'frame')} written ({len(frames) - len(todo)} were already there) in "
            f"{seconds:.1f} s, {len(written) / seconds:.2f} frames/s, load {load:.3f} s a frame -> "
            f"{os.path.dirname(job.npy(frames[0]))}")


def _terminate(signum, frame):
    raise Terminated()


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    on_sigterm = threading.current_thread() is threading.main_thread()  # signal handlers live there only
    previous = signal.signal(signal.SIGTERM, _terminate) if on_sigterm else None
    try:
        with scratch.adopted():  # every temporary file of the run, its children's included, in a private folder
            message = {"render-series": _run_series, "render-blend": _run_blend,
                       "view": _run_view}.get(args.command, _run)(args)
    except KeyboardInterrupt:
        _end_progress_line()
        print("hovr: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        _end_progress_line()
        print("hovr: terminated (SIGTERM)", file=sys.stderr)
        return 143
    except MemoryError:
        _end_progress_line()
        if args.debug:
            traceback.print_exc()
        print("hovr: error: out of memory (lower the image size, or set --max-memory below what this "
              "machine has so that the run is refused before it starts)", file=sys.stderr)
        return EXIT_ERROR
    except (ValueError, RuntimeError, OSError) as exc:  # the readers' and renderer's clear errors
        _end_progress_line()
        if args.debug:
            traceback.print_exc()
        print(f"hovr: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except Exception as exc:  # a bug: still one line, the traceback only when asked for
        _end_progress_line()
        if args.debug:
            traceback.print_exc()
        print(f"hovr: error: unexpected {type(exc).__name__}: {exc} (a bug: please report it; "
              "--debug shows the traceback)", file=sys.stderr)
        return EXIT_ERROR
    finally:
        if on_sigterm:
            signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
    print(message)
    return 0


if __name__ == "__main__":
    sys.exit(main())
