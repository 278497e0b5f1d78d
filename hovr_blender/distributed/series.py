"""A series of frames over a Dask cluster: a numbered field series (`flow_####.fld`), a camera
path, or both. Dask schedules; this module says what one frame is (render_frame, run on a
worker) and submits the frames that are not written yet (render_series, on the client).

A worker keeps its Renderer between frames (process-global, one task at a time per worker:
threads_per_worker=1): the kernels stay compiled and, while the geometry stays the same, only
the field goes to the device (Renderer.replace_field); a frame whose data did not change (a
camera path over one snapshot) reads nothing (io.cached_volume).

Writing exactly once: each output is written to a temporary file beside it and hard-linked to
its name (os.link fails if the name exists, so no frame is ever overwritten, even by a task
Dask ran twice after losing its worker), the .npy last: a frame is done when its .npy exists.
A line per frame written goes to the series log (`.hovr-series.log` in the .npy's folder,
appended with O_APPEND), so a run can be audited for frames written twice.
"""
from __future__ import annotations

import json
import math
import os
import socket
import tempfile
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..engine.camera import RayCamera
from ..engine.image_io import png_pixels, write_json, write_npy, write_png
from ..engine.view import View
from ..io.sources import VolumeSource, cached_volume, frame_path

LOG_NAME = ".hovr-series.log"


@dataclass
class SeriesJob:
    """What a series renders: the view file (a `#` run in data.path or data.solution is the frame
    number), frames, output pattern (`out/frame_####.npy`), an optional camera per frame, and
    render-option overrides. Small and picklable: it travels with every task."""

    view: str
    frames: list
    output: str
    png: bool = False
    stats: bool = False
    cameras: dict = field(default_factory=dict)  # frame -> contract camera object (a camera path)
    options: dict = field(default_factory=dict)  # RenderOptions overrides (device excluded)
    device: str = "auto"  # a worker's Warp device: "auto" (worker_device) or a name

    def npy(self, frame: int) -> str:
        return os.path.abspath(frame_path(self.output, frame))

    def to_dict(self) -> dict:
        return asdict(self)


def parse_frames(text: str) -> list[int]:
    """"1-100", "1-100:2" (a step), "3,5,8-10" -> frame numbers in order, each once."""
    frames = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        rng, _, step = part.partition(":")
        a, sep, b = rng.partition("-")
        lo, hi = int(a), int(b) if sep else int(a)
        frames.extend(range(lo, hi + 1, int(step) if step else 1))
    if not frames:
        raise ValueError(f"no frames in {text!r}")
    return list(dict.fromkeys(frames))


def orbit_cameras(camera: dict, frames, degrees: float = 360.0) -> dict:
    """A camera path: the view's camera turned about its `up` axis through its target, `degrees`
    over the frames (frame k of n at k/n of the turn)."""
    eye, target = np.asarray(camera["eye"], float), np.asarray(camera["target"], float)
    axis = np.asarray(camera["up"], float)
    axis = axis / np.linalg.norm(axis)
    out = {}
    frames = list(frames)
    for k, f in enumerate(frames):
        a = math.radians(degrees) * k / max(len(frames), 1)
        r = eye - target
        # Rodrigues' rotation of the eye about the up axis through the target
        rot = r * math.cos(a) + np.cross(axis, r) * math.sin(a) + axis * np.dot(axis, r) * (1 - math.cos(a))
        out[int(f)] = {**camera, "eye": (target + rot).tolist()}
    return out


def read_camera_path(path: str, frames) -> dict:
    """A camera path file: {"first_frame": N, "cameras": [camera, ...]} (contract §1 camera
    objects, frame N first) or a plain list (first frame 1)."""
    with open(path) as fh:
        data = json.load(fh)
    first, cams = (1, data) if isinstance(data, list) else (int(data.get("first_frame", 1)), data["cameras"])
    out = {}
    for f in frames:
        if not 0 <= f - first < len(cams):
            raise ValueError(f"camera path {path} has no camera for frame {f} (frames {first}..{first + len(cams) - 1})")
        out[int(f)] = cams[f - first]
    return out


# ------------------------------------------------------------------------------- on the worker

_WORKER: dict = {}  # this process's renderer, device and view (kept across frames)


def worker_device(requested: str = "auto") -> str:
    """The device this process renders on: `requested`, or for "auto" the CUDA device of this
    Dask worker (worker name k of an integer-named local cluster -> cuda:k mod count; else
    cuda:0), or cpu where there is none."""
    if requested != "auto":
        return requested
    from ..engine.renderer import cuda_devices

    cuda = cuda_devices()
    if not cuda:
        return "cpu"
    try:
        from distributed import get_worker

        name = get_worker().name
        index = int(name) if isinstance(name, int) or str(name).isdigit() else 0
    except (ImportError, ValueError):
        index = 0
    return cuda[index % len(cuda)]


def _renderer_for(mesh, device):
    """This process's Renderer, given `mesh`: kept if it is the same mesh or the same geometry (the
    field replaced), else a new one."""
    from ..engine.renderer import Renderer

    cur = _WORKER.get("renderer")
    if cur is not None and cur.device == device:
        if cur.mesh is mesh:
            return cur, "kept"
        if cur.same_geometry(mesh):
            cur.replace_field(mesh)
            return cur, "field"
    _WORKER["renderer"] = Renderer(mesh, device)
    return _WORKER["renderer"], "uploaded"


def link_file(tmp: str, path: str) -> bool:
    """Hard-link the finished file `tmp` to `path`: False (nothing written) if `path` exists
    (os.link never replaces a file, so two tasks of one frame cannot both write it)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        return False
    return True


def _link_into_place(path: str, writer) -> bool:
    """Write via a temporary file beside `path` and link it there (link_file)."""
    folder = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix="." + os.path.basename(path) + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        return link_file(tmp, path)
    finally:
        os.unlink(tmp)


def _log(folder: str, record: dict):
    line = (json.dumps(record) + "\n").encode()
    fd = os.open(os.path.join(folder, LOG_NAME), os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
    finally:
        os.close(fd)


def frame_view(job: SeriesJob, frame: int):
    """(view, source, camera) of one frame: the view file with the frame's data and camera."""
    view = _WORKER.get(("view", job.view))
    if view is None:
        view = _WORKER[("view", job.view)] = View.load(job.view)
    data = view.data
    if "builtin" in data:
        source = VolumeSource("builtin:" + data["builtin"])
    else:
        comp = data.get("component")
        source = VolumeSource.resolve(data["path"], data.get("solution") or "", data.get("field") or "",
                                      frame=frame, base_dir=view.base_dir, component="" if comp is None else comp)
    camera = view.camera
    if frame in job.cameras or str(frame) in job.cameras:
        spec = job.cameras.get(frame, job.cameras.get(str(frame)))
        camera = RayCamera.from_contract(spec, camera.width, camera.height)
    return view, source, camera


def render_frame(job, frame: int, before_render=None) -> dict:
    """Render one frame of `job` (a SeriesJob or its dict) here and write its files (module doc);
    `before_render()`, if given, is called first (instrumentation, e.g. the tests' slow
    frames). Returns what happened: written or skipped, seconds to load and render, the worker."""
    job = job if isinstance(job, SeriesJob) else SeriesJob(**job)
    out = job.npy(frame)
    record = {"frame": int(frame), "host": socket.gethostname(), "pid": os.getpid()}
    if os.path.exists(out):
        return {**record, "status": "exists"}
    if before_render is not None:
        before_render()
    device = worker_device(job.device)
    t0 = time.perf_counter()
    view, source, camera = frame_view(job, frame)
    mesh = cached_volume(source)
    load_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    renderer, upload = _renderer_for(mesh, device)
    upload_s = time.perf_counter() - t1
    options = view.options.with_(**{**job.options, "device": renderer.device})
    result = renderer.render(camera, view.transfer_function, view.background, options)
    stats = {**result.stats, "frame": int(frame), "load_seconds": load_s, "upload_seconds": upload_s,
             "upload": upload, "source": source.path + (" " + source.solution if source.solution else "")}
    base = out[: -len(".npy")]
    if job.stats:
        _link_into_place(base + ".json", lambda fh: write_json(fh, stats))
    if job.png:
        _link_into_place(base + ".png", lambda fh: write_png(fh, png_pixels(result.rgba, view.background), alpha=False))
    written = _link_into_place(out, lambda fh: write_npy(fh, result.rgba))  # last: the frame is done
    record.update(status="written" if written else "exists", device=renderer.device, load_seconds=load_s,
                  upload_seconds=upload_s, upload=upload, render_seconds=result.stats["render_seconds"])
    if written:
        _log(os.path.dirname(out), {**record, "time": time.time()})
    return record


# ------------------------------------------------------------------------------- on the client

def pending_frames(job: SeriesJob) -> list[int]:
    """The job's frames whose .npy is not written yet."""
    return [f for f in job.frames if not os.path.exists(job.npy(f))]


def render_series(job: SeriesJob, client, progress=None, before_render=None, retries: int = 3) -> list[dict]:
    """Submit the frames not yet written to the Dask `client` (one task a frame; Dask retries a
    frame whose worker was lost) and wait for them; progress(done, total, record) after each.
    Returns the records of the frames submitted, in frame order."""
    folder = os.path.dirname(job.npy(job.frames[0]))
    if not os.path.isdir(folder):
        raise ValueError(f"output folder {folder} does not exist")
    payload = job.to_dict()
    return submit_frames(client, pending_frames(job), "hovr-frame",
                         lambda f, key: client.submit(render_frame, payload, f, before_render, key=key, pure=False,
                                                      retries=retries), progress)


def submit_frames(client, frames, prefix: str, submit, progress=None) -> list[dict]:
    """One task a frame, submit(frame, key) each (keys unique to this run), then the records
    as they finish (progress(done, total, record) after each), returned in frame order."""
    from distributed import as_completed

    token = f"{os.getpid()}-{time.time_ns()}"
    futures = [submit(f, f"{prefix}-{f}-{token}") for f in frames]
    records = {}
    for fut in as_completed(futures):
        rec = fut.result()
        records[rec["frame"]] = rec
        if progress is not None:
            progress(len(records), len(futures), rec)
    return [records[f] for f in frames]


def local_cluster(workers: int | None = None, device: str = "auto"):
    """A dask.distributed LocalCluster for a series: one worker process per CUDA device (worker k
    renders on cuda:k), or without one (or for device "cpu") one per CPU core; each worker runs
    one task at a time."""
    from distributed import LocalCluster

    if workers is None:
        workers = 1
        from ..engine.renderer import cpu_cores, cuda_devices

        if device in ("auto", "cuda:all"):
            workers = len(cuda_devices())
        if workers == 0 or device == "cpu":
            workers = cpu_cores()  # the cores this process may use, as cpu:all counts them
    return LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True, dashboard_address=None)
