"""The frames of a saved .blend over a Dask cluster: each task starts Blender headless for one
frame (ui/batch.py: `blender -b --disable-autoexec --python batch.py -- N ROOT MODE FILE`, or the
same script under a Python with the bpy module), which renders to a temporary file beside the
frame's output, named as `blender -b FILE -a` names it; the task links it into place
(series.link_file: never over a frame already written, never through a link) and logs it. Frames
already written are skipped (the script checks before it renders), so a rerun renders nothing; a
task whose worker is lost is run again by Dask.

The .blend is not trusted:
- its scripts never run (auto-run disabled whatever the user's preference);
- a frame that runs past the per-frame time limit is stopped (an endless driver expression
  passes Blender's restricted mode), and Blender ends with the task that started it
  (engine/processes.die_with_parent);
- the frames land in the folder the user named (`-o`) or, without it, under the .blend's own
  folder only (ui/batch.py refuses anything else, naming the path, as it refuses datablocks that
  would write elsewhere while rendering: caches, File Output nodes);
- on Linux its Blender may write only there (ROOT), in a private temporary folder of the frame
  (engine/scratch.py: its TMPDIR, removed after the frame) and in Warp's kernel cache
  (engine/landlock.py: the kernel refuses any other write, whatever datablock asks for it);
- its reports come back through a pipe only this task reads (never Blender's output, which an
  object's name can fill with anything), and their paths are checked before the frame is linked
  into place: the output in ROOT, the temporary the one batch.py names beside it (announced
  before it renders, so a Blender that fails after rendering leaves no temporary behind), a
  regular file.
"""
from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import time

from ..engine import landlock, scratch
from ..engine.processes import die_with_parent
from .series import FrameError, append_log, check_output, link_file, submit_frames

BATCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "ui", "batch.py")
PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_FRAME_TIMEOUT = 3600.0  # seconds a frame's Blender may run (--frame-timeout)
RESULT_FD = "HOVR_RESULT_FD"  # ui/batch.py's result pipe (its RESULT_FD)
MAX_RESULT_BYTES = 1 << 16


def output_root(blend: str, output: str | None) -> tuple[str, str]:
    """(ROOT, MODE) for ui/batch.py: ("FOLDER", "into") for -o FOLDER (which must exist), else the
    .blend's own folder and "under"."""
    if output:
        folder = os.path.abspath(output)
        if not os.path.isdir(folder):
            raise ValueError(f"-o {output}: no such folder (render-blend writes the frames into an existing folder)")
        return folder, "into"
    return os.path.dirname(os.path.abspath(blend)), "under"


def batch_command(blend: str, frame: int, root: str, mode: str, blender: str | None = None,
                  python: str | None = None) -> list[str]:
    """The command that renders `frame` of `blend` into `root` (ui/batch.py): with a Blender binary
    (its scripts disabled; the script opens the .blend itself, after checking it), or a Python
    with bpy."""
    if blender:
        return [blender, "-b", "--disable-autoexec", "--python-exit-code", "2", "--python", BATCH, "--",
                str(int(frame)), root, mode, blend]
    return [python or sys.executable, BATCH, blend, str(int(frame)), root, mode]


def _blender_error(output: str) -> str:
    """The one line that says why Blender failed: batch.py's own refusal, else Blender's last
    error line, else its last line."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    for ln in reversed(lines):
        if ln.startswith("HOVR-ERROR "):
            return ln[len("HOVR-ERROR "):][:600]
    for ln in reversed(lines):
        if "Error" in ln or "error:" in ln:
            return ln[:300]
    return lines[-1][:300] if lines else "no output"


def _inside(path: str, root: str) -> bool:
    real, top = os.path.realpath(path), os.path.realpath(root)
    return os.path.commonpath([real, top]) == top


def warp_cache_folder() -> str:
    """Warp's kernel cache (where a render with the add-on compiles its kernels): $WARP_CACHE_PATH,
    else Warp's default on Linux, $XDG_CACHE_HOME/warp or ~/.cache/warp. Made if missing."""
    folder = os.environ.get("WARP_CACHE_PATH") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "warp")
    os.makedirs(folder, exist_ok=True)
    return folder


def _confined(ruleset):
    """The Blender child's preexec_fn: it ends with the task's thread, and writes only where the
    Landlock ruleset lets it (none: Landlock is not available here)."""
    def preexec():
        die_with_parent()
        if ruleset is not None:
            landlock.restrict_self(ruleset)
    return preexec


def _reports(fd: int) -> list:
    """batch.py's reports on the pipe `fd` (what it wrote before it exited): JSON objects, a line
    each, up to the first that is not one."""
    os.set_blocking(fd, False)
    try:
        raw = os.read(fd, MAX_RESULT_BYTES)
    except BlockingIOError:
        raw = b""
    reports = []
    for line in raw.decode(errors="replace").splitlines():
        try:
            report = json.loads(line)
        except ValueError:
            break
        if not isinstance(report, dict) or not isinstance(report.get("out"), str):
            break
        reports.append(report)
    return reports


def _temporary(report: dict, root: str, pid: int) -> str | None:
    """The temporary file batch.py (process `pid`) renders a report's output to: `.<name>.<pid>.tmp`
    beside the output, which must lie in `root`; None otherwise."""
    out = report["out"]
    if not os.path.isabs(out) or not _inside(os.path.dirname(out), root):
        return None
    return os.path.join(os.path.dirname(out), f".{os.path.basename(out)}.{pid}.tmp")


def _checked(report, frame: int, blend: str, root: str, tmp: str | None) -> dict:
    """batch.py's last report, its paths checked: the output in `root`; for a rendered frame, the
    temporary it names is the one beside the output (`tmp`) and a regular file."""
    what = f"frame {frame} of {blend}"
    if report is None or report.get("status") not in ("exists", "rendered"):
        raise FrameError(f"{what}: Blender gave no result")
    out = report["out"]
    if not _inside(os.path.dirname(out), root):
        raise FrameError(f"{what}: its output {out} is outside {root}; refused")
    if report["status"] == "rendered":
        if report.get("tmp") != tmp:
            raise FrameError(f"{what}: Blender's result names {report.get('tmp')!r}, not {tmp}; refused")
        try:
            st = os.lstat(tmp)
        except OSError:
            raise FrameError(f"{what}: Blender rendered no file {tmp}") from None
        if not stat.S_ISREG(st.st_mode):
            raise FrameError(f"{what}: {tmp} is not a regular file; refused")
    return report


def render_blend_frame(blend: str, frame: int, blender: str | None = None, python: str | None = None,
                       timeout: float | None = DEFAULT_FRAME_TIMEOUT, output: str | None = None) -> dict:
    """Render one frame of `blend` here (a Dask task); returns what happened."""
    record = {"frame": int(frame), "host": socket.gethostname(), "pid": os.getpid()}
    root, mode = output_root(blend, output)
    private = scratch.private_folder("blender-")  # Blender's temporary folder: its session, its crash log
    env = scratch.child_env(private)
    if not blender:  # bpy as a module: the add-on package from this checkout
        env["PYTHONPATH"] = os.pathsep.join([PACKAGE_PARENT] + [p for p in [env.get("PYTHONPATH")] if p])
    readable, writable = os.pipe()
    env[RESULT_FD] = str(writable)
    tmp = None  # the temporary batch.py announced: removed whatever happens
    try:
        ruleset = landlock.write_ruleset([root, private, warp_cache_folder()])
        t0 = time.perf_counter()
        try:
            proc = subprocess.Popen(batch_command(blend, frame, root, mode, blender, python), env=env,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    stdin=subprocess.DEVNULL, pass_fds=(writable,), preexec_fn=_confined(ruleset))
        finally:
            os.close(writable)
            if ruleset is not None:
                os.close(ruleset)
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise FrameError(f"frame {frame} of {blend}: Blender ran past the per-frame limit of {timeout:g} s and "
                             f"was stopped (a driver that never ends?); raise it with --frame-timeout") from None
        except BaseException:
            proc.kill()
            proc.communicate()
            raise
        finally:
            reports = _reports(readable)
            tmp = next((_temporary(r, root, proc.pid) for r in reports if "tmp" in r), None)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            raise FrameError(f"frame {frame} of {blend}: Blender exited with {proc.returncode}: "
                             f"{_blender_error(stdout + chr(10) + stderr)}")
        info = _checked(reports[-1] if reports else None, frame, blend, root, tmp)
        out = info["out"]
        if info["status"] == "exists":
            check_output(out)
            return {**record, "status": "exists", "output": out}
        written = link_file(tmp, out)
        if not written:
            check_output(out)
    finally:
        os.close(readable)
        scratch.remove(private)
        if tmp is not None and os.path.lexists(tmp):
            os.unlink(tmp)  # a link there: the link only
    record.update(status="written" if written else "exists", output=out, seconds=seconds)
    if written:
        append_log(os.path.dirname(out), {**record, "time": time.time()})
    return record


def render_animation(blend: str, frames, client, blender: str | None = None, python: str | None = None,
                     progress=None, retries: int = 0, timeout: float | None = DEFAULT_FRAME_TIMEOUT,
                     output: str | None = None) -> list[dict]:
    """Submit one task a frame to the Dask `client`; progress(done, total, record) after each. A
    frame that fails ends the run with its one-line error (not retried unless `retries`)."""
    blend = os.path.abspath(blend)
    output_root(blend, output)  # the folder checked before any task
    return submit_frames(client, list(frames), "hovr-blend",
                         lambda f, key: client.submit(render_blend_frame, blend, f, blender, python, timeout, output,
                                                      key=key, pure=False, retries=retries), progress)
