"""A series of frames over a Dask cluster: a numbered field series (`flow_####.fld`), a camera
path, or both. Dask schedules; this module says what one frame is (write_frame, run on a
worker: the view's Frame through engine/frame.render_frame, as `hovr render` renders it, then
its files) and submits the frames that are not written yet (render_series, on the client).

A worker keeps its Renderer between frames (process-global, one task at a time per worker:
threads_per_worker=1): the kernels stay compiled and, while the geometry stays the same, only
the field goes to the device (Renderer.replace_field); a frame whose data did not change (a
camera path over one snapshot) reads nothing (io.cached_volume).

Writing exactly once: each output is written to a temporary file beside it and hard-linked to
its name (os.link fails if the name exists, so no frame is ever overwritten, even by a task
Dask ran twice after losing its worker), the .npy last: a frame is done when its .npy exists.
A line per frame written goes to the series log (`.hovr-series.log` in the .npy's folder,
appended with O_APPEND), so a run can be audited for frames written twice. No output is written
through a link: the log is opened with O_NOFOLLOW, and a frame whose .npy, .png or .json is a link
(or anything but a regular file) is refused, naming it.

A local cluster is its owner's only (local_cluster): the scheduler, nannies and workers speak TLS
with certificates made for this run (distributed.security.Security.temporary), so connecting
needs the run's key; Dask's HTTP servers are never started unless a dashboard is asked for; its
scratch is a private folder of the run; its workers end with the process that started them. A frame that fails is not retried (a refusal is
deterministic): the run ends with that frame's one-line error. A lost worker's frames are
rerun by the scheduler (distributed.scheduler.allowed-failures times).
"""
from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import re
import socket
import stat
import tempfile
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..engine import limits, scratch, strict_json
from ..engine.camera import RayCamera
from ..engine.frame import Frame, render_frame
from ..engine.image_io import png_pixels, write_json, write_npy, write_png
from ..engine.view import View
from ..io.sources import VolumeSource, cached_volume, frame_path

LOG_NAME = ".hovr-series.log"
MAX_FRAMES = 1_000_000  # frames one run may name (a list of them is built; 10^8 took 5.8 GB)
MAX_CAMERA_PATH_BYTES = 16 << 20  # a camera is ~200 bytes: ~80,000 cameras
_FRAME_PART = re.compile(r"(\d{1,12})(?:-(\d{1,12}))?(?::(\d{1,12}))?")


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


def parse_frames(text: str, option: str = "--frames") -> list[int]:
    """"1-100", "1-100:2" (a step), "3,5,8-10" -> frame numbers (whole numbers >= 0) in order, each
    once; at most MAX_FRAMES, counted before any list is built."""
    usage = "frames are whole numbers >= 0: 1-100, 1-100:2, 3,5,8-10"
    ranges, count = [], 0
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        m = _FRAME_PART.fullmatch(part)
        if m is None:
            raise ValueError(f"{option} {text!r}: {part!r} is not a frame range ({usage})"[:300])
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        step = int(m.group(3)) if m.group(3) is not None else 1
        if hi < lo or step < 1:
            raise ValueError(f"{option} {text!r}: {part!r} is empty (the first frame comes first; a step is >= 1)"[:300])
        count += (hi - lo) // step + 1
        if count > MAX_FRAMES:
            raise ValueError(f"{option} {text!r} names more than {MAX_FRAMES} frames (the most one run renders; "
                             f"split the series)"[:300])
        ranges.append(range(lo, hi + 1, step))
    if not ranges:
        raise ValueError(f"{option} {text!r}: no frames ({usage})"[:300])
    return list(dict.fromkeys(f for r in ranges for f in r))


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


def read_camera_path(path: str, frames, width: int = 1, height: int = 1) -> dict:
    """A camera path file: {"first_frame": N, "cameras": [camera, ...]} (contract §1 camera
    objects, frame N first) or a plain list (first frame 1). Read under the file policy (a
    regular file of at most MAX_CAMERA_PATH_BYTES, no key twice), and each frame's camera checked
    here (RayCamera.from_contract at width x height), before any worker starts."""
    raw = limits.read_regular(path, "camera path", max_bytes=MAX_CAMERA_PATH_BYTES)
    what = f"camera path {path}"
    data = strict_json.loads(raw, what)
    if isinstance(data, list):
        first, cams = 1, data
    else:
        data = strict_json.as_object(data, f"{what}: the file")
        if "cameras" not in data:
            raise ValueError(f"{what} needs \"cameras\": [camera, ...] (or is a list of cameras)")
        first = strict_json.as_integer(data.get("first_frame", 1), f"{what}: first_frame", ValueError, 0)
        cams = data["cameras"]
        if not isinstance(cams, list):
            raise ValueError(f"{what}: cameras must be a list of camera objects, not {type(cams).__name__}")
    out = {}
    for f in frames:
        if not 0 <= f - first < len(cams):
            raise ValueError(f"{what} has no camera for frame {f} (frames {first}..{first + len(cams) - 1})")
        try:
            RayCamera.from_contract(cams[f - first], width, height)
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"{what}, frame {f}: {exc}"[:300]) from None
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
    from ..engine.devices import cuda_devices

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
    _WORKER["renderer"].cpu_threads = 1  # a worker's threads render frames of their own
    return _WORKER["renderer"], "uploaded"


def link_file(tmp: str, path: str) -> bool:
    """Hard-link the finished file `tmp` to `path`: False (nothing written) if `path` exists
    (os.link never replaces a file, so two tasks of one frame cannot both write it)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        return False
    return True


def check_output(path: str) -> bool:
    """Whether an output `path` exists already (a regular file); a link or anything else there is
    refused, naming it (a planted link would otherwise count as the frame written)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    if stat.S_ISLNK(st.st_mode):
        raise limits.UnsafeFileError(f"output {path} is a symbolic link; refused (outputs never follow links)")
    if not stat.S_ISREG(st.st_mode):
        raise limits.UnsafeFileError(f"output {path} exists and is not a regular file; refused")
    return True


def _link_into_place(path: str, writer) -> bool:
    """Write via a temporary file beside `path` and link it there (link_file); False if a regular
    file is there already (check_output refuses anything else)."""
    folder = os.path.dirname(path)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix="." + os.path.basename(path) + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        if link_file(tmp, path):
            return True
        check_output(path)  # planted meanwhile: refused if it is not a regular file
        return False
    finally:
        os.unlink(tmp)


def append_log(folder: str, record: dict):
    """Append one line to the series log: one write of an O_APPEND descriptor (workers share the
    file), never through a link."""
    with limits.open_output(os.path.join(folder, LOG_NAME), "series log", append=True) as fh:
        fh.write((json.dumps(record) + "\n").encode())


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


def write_frame(job, frame: int, before_render=None) -> dict:
    """Render one frame of `job` (a SeriesJob or its dict) here and write its files (module doc);
    `before_render()`, if given, is called first (instrumentation, e.g. the tests' slow
    frames). Returns what happened: written or skipped, seconds to load and render, the worker."""
    job = job if isinstance(job, SeriesJob) else SeriesJob(**job)
    out = job.npy(frame)
    record = {"frame": int(frame), "host": socket.gethostname(), "pid": os.getpid()}
    base = out[: -len(".npy")]
    for extra, wanted in ((".json", job.stats), (".png", job.png)):
        if wanted:
            check_output(base + extra)
    if check_output(out):
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
    result = render_frame(renderer, Frame.from_view(view, options=options), camera)  # isosurfaces and planes too
    stats = {**result.stats, "frame": int(frame), "load_seconds": load_s, "upload_seconds": upload_s,
             "upload": upload, "source": source.path + (" " + source.solution if source.solution else "")}
    if job.stats:
        _link_into_place(base + ".json", lambda fh: write_json(fh, stats))
    if job.png:
        _link_into_place(base + ".png", lambda fh: write_png(fh, png_pixels(result.rgba, view.background), alpha=False))
    written = _link_into_place(out, lambda fh: write_npy(fh, result.rgba))  # last: the frame is done
    record.update(status="written" if written else "exists", device=renderer.device, load_seconds=load_s,
                  upload_seconds=upload_s, upload=upload, render_seconds=result.stats["render_seconds"])
    if written:
        append_log(os.path.dirname(out), {**record, "time": time.time()})
    return record


# ------------------------------------------------------------------------------- on the client

def pending_frames(job: SeriesJob) -> list[int]:
    """The job's frames whose .npy is not written yet (a link there is refused: check_output)."""
    return [f for f in job.frames if not check_output(job.npy(f))]


def check_outputs(job: SeriesJob, frames) -> None:
    """The files `frames` would write (.npy, .png, .json as asked) and their folders' series logs
    checked on the client before any worker starts (check_output; each frame checks again)."""
    folders = set()
    for f in frames:
        out = job.npy(f)
        base = out[: -len(".npy")]
        for path, wanted in ((out, True), (base + ".json", job.stats), (base + ".png", job.png)):
            if wanted:
                check_output(path)
        folders.add(os.path.dirname(out))
    for folder in folders:
        check_output(os.path.join(folder, LOG_NAME))


def render_series(job: SeriesJob, client, progress=None, before_render=None, retries: int = 0) -> list[dict]:
    """Submit the frames not yet written to the Dask `client` (one task a frame; the scheduler
    reruns a frame whose worker was lost; a frame that fails is not retried unless `retries`)
    and wait for them; progress(done, total, record) after each. Returns the records of the
    frames submitted, in frame order."""
    folder = os.path.dirname(job.npy(job.frames[0]))
    if not os.path.isdir(folder):
        raise ValueError(f"output folder {folder} does not exist")
    payload = job.to_dict()
    return submit_frames(client, pending_frames(job), "hovr-frame",
                         lambda f, key: client.submit(write_frame, payload, f, before_render, key=key, pure=False,
                                                      retries=retries), progress)


class FrameError(RuntimeError):
    """A frame that failed: the run ends with its one line."""


def submit_frames(client, frames, prefix: str, submit, progress=None) -> list[dict]:
    """One task a frame, submit(frame, key) each (keys unique to this run), then the records
    as they finish (progress(done, total, record) after each), returned in frame order. The
    first frame that fails cancels the others and raises its error, with the frame named."""
    from distributed import as_completed

    token = f"{os.getpid()}-{time.time_ns()}"
    futures = [submit(f, f"{prefix}-{f}-{token}") for f in frames]
    frame_of = {fut.key: f for f, fut in zip(frames, futures)}
    records = {}
    try:
        for fut in as_completed(futures):
            if fut.status == "error":
                exc = fut.exception()
                raise _frame_error(frame_of[fut.key], exc) from None
            rec = fut.result()
            records[rec["frame"]] = rec
            if progress is not None:
                progress(len(records), len(futures), rec)
    except BaseException:
        client.cancel(futures)
        raise
    return [records[f] for f in frames]


def _frame_error(frame: int, exc: BaseException) -> BaseException:
    """The exception a failed frame's task raised, as the run's one-line error: the reader's and
    renderer's own errors keep their type (and message); a worker that kept dying, or anything
    else, becomes a FrameError naming the frame."""
    name = type(exc).__name__
    first_line = (str(exc).strip().splitlines() or [""])[0][:400]
    if name == "KilledWorker":
        return FrameError(f"frame {frame}: every worker that rendered it died (out of memory, or killed); "
                          f"the frame was not written")
    named = first_line if first_line.startswith(f"frame {frame}") else f"frame {frame}: {first_line}"
    if isinstance(exc, (ValueError, RuntimeError, OSError)):
        try:
            return type(exc)(named)
        except TypeError:  # an exception type that needs other arguments
            pass
    return FrameError(f"frame {frame}: {name}: {first_line}")


def local_cluster(workers: int | None = None, device: str = "auto", dashboard: str | None = None,
                  quiet: bool = True):
    """A dask.distributed LocalCluster for a series that only its owner can reach (module doc):
    one worker process per CUDA device (worker k renders on cuda:k), or without one (or for
    device "cpu") one per CPU core, within the process limit (limits.check_processes); each
    worker runs one task at a time. `dashboard`: an address for Dask's (unauthenticated) HTTP
    dashboard; None: no HTTP server at all, not even for a moment (local_workers.PrivateCluster). Dask's scratch (the scheduler's `temporary-directory`, the workers'
    `local_directory` with its lock files, and the workers' TMPDIR) is a private folder of this
    run (engine/scratch.py), never the shared temporary folder. `quiet`: Dask's own log lines (a
    failed task's traceback, worker shutdowns) are not printed; the run reports the error itself.
    Connect with cluster_client(cluster)."""
    import dask
    from distributed.security import Security

    from .local_workers import PrivateCluster

    if workers is None:
        workers = 1
        from ..engine.devices import cuda_devices

        if device in ("auto", "cuda:all"):
            workers = len(cuda_devices())
        if workers == 0 or device == "cpu":
            workers = limits.cpu_cores()  # the cores this process may use, as cpu:all counts them
    workers = int(workers)
    if workers < 1:
        raise ValueError(f"--workers {workers}: a cluster needs at least one worker")
    limits.check_processes(workers, f"a local Dask cluster of {workers} workers")
    try:
        security = Security.temporary()  # a CA and certificates for this run only, in memory
    except ImportError as exc:
        raise RuntimeError(f"a local cluster needs the cryptography package for its TLS keys ({exc})") from None
    folder = scratch.private_folder("dask-")
    # the scheduler's own scratch, and the workers'; this process's environment as it was: Dask's
    # nannies set their workers' pre-spawn variables (OMP_NUM_THREADS=1 ...) here for good, so the
    # processes this one starts later (All CPU Cores' devices) would run BLAS unlike this one
    with dask.config.set({"temporary-directory": folder}), _environment_kept():
        cluster = PrivateCluster(n_workers=workers, threads_per_worker=1, processes=True, protocol="tls",
                                 host="127.0.0.1", security=security, dashboard_address=dashboard,
                                 worker_dashboard_address=None, local_directory=folder,
                                 env={"TMPDIR": folder, "TEMP": folder, "TMP": folder},
                                 silence_logs=logging.CRITICAL if quiet else logging.WARN, http=bool(dashboard))
    cluster.hovr_dashboard = dashboard
    return cluster


@contextlib.contextmanager
def _environment_kept():
    """This process's environment variables as they were before the block, after it."""
    saved = dict(os.environ)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


def cluster_client(cluster):
    """A Client of a local_cluster, with its run's certificates; the workers confined
    (LocalWorkerConfinement)."""
    from distributed import Client

    from .local_workers import LocalWorkerConfinement

    client = Client(cluster, security=cluster.security)
    try:
        client.register_plugin(LocalWorkerConfinement())
    except BaseException:
        client.close()
        raise
    return client


def remote_client(scheduler: str, tls_ca_file=None, tls_cert=None, tls_key=None):
    """A Client of a running scheduler (an address, or a scheduler file .json) with the user's
    security: the TLS files given, else Dask's own configuration (distributed.comm.tls.* in
    ~/.config/dask/, or DASK_DISTRIBUTED__COMM__TLS__* variables; docs/distributed.md)."""
    from distributed import Client
    from distributed.security import Security

    given = [tls_ca_file, tls_cert, tls_key]
    if any(given) and not all(given):
        raise ValueError("--tls-ca-file, --tls-cert and --tls-key go together (the cluster's CA, and your "
                         "certificate and key)")
    for path in filter(None, given):
        limits.check_regular(path, "TLS file")
    security = (Security(tls_ca_file=tls_ca_file, tls_client_cert=tls_cert, tls_client_key=tls_key,
                         require_encryption=True) if all(given) else Security())
    kwargs = {"security": security, "timeout": "30s"}
    if scheduler.endswith(".json"):
        limits.check_regular(scheduler, "scheduler file")
        return Client(scheduler_file=scheduler, **kwargs)
    return Client(scheduler, **kwargs)
