"""The frames of a saved .blend over a Dask cluster: each task starts Blender headless for one
frame (ui/batch.py: `blender -b --disable-autoexec FILE --python batch.py -- N ROOT MODE`, or the
same script under a Python with the bpy module), which renders to a temporary file beside the
frame's output, named as `blender -b FILE -a` names it; the task links it into place
(series.link_file: never over a frame already written, never through a link) and logs it. Frames
already written are skipped (the script checks before it renders), so a rerun renders nothing; a
task whose worker is lost is run again by Dask.

The .blend is not trusted: its scripts never run (auto-run disabled whatever the user's
preference), a frame that runs past the per-frame time limit is stopped (an endless driver
expression passes Blender's restricted mode), Blender ends with the task that started it
(engine/processes.die_with_parent), and the frames land in the folder the user named (`-o`) or,
without it, under the .blend's own folder only (ui/batch.py refuses anything else, naming the
path, and the task checks again before it links).
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time

from ..engine.processes import die_with_parent
from .series import FrameError, append_log, check_output, link_file, submit_frames

BATCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "ui", "batch.py")
PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_FRAME_TIMEOUT = 3600.0  # seconds a frame's Blender may run (--frame-timeout)


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
    (its scripts disabled), or a Python with bpy."""
    if blender:
        return [blender, "-b", "--disable-autoexec", blend, "--python-exit-code", "2", "--python", BATCH, "--",
                str(int(frame)), root, mode]
    return [python or sys.executable, BATCH, blend, str(int(frame)), root, mode]


def _blender_error(output: str) -> str:
    """The one line that says why Blender failed: batch.py's own refusal, else Blender's last
    error line, else its last line."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    for ln in reversed(lines):
        if ln.startswith("HOVR-ERROR "):
            return ln[len("HOVR-ERROR "):]
    for ln in reversed(lines):
        if "Error" in ln or "error:" in ln:
            return ln[:300]
    return lines[-1][:300] if lines else "no output"


def _inside(path: str, root: str) -> bool:
    real, top = os.path.realpath(path), os.path.realpath(root)
    return os.path.commonpath([real, top]) == top


def render_blend_frame(blend: str, frame: int, blender: str | None = None, python: str | None = None,
                       timeout: float | None = DEFAULT_FRAME_TIMEOUT, output: str | None = None) -> dict:
    """Render one frame of `blend` here (a Dask task); returns what happened."""
    record = {"frame": int(frame), "host": socket.gethostname(), "pid": os.getpid()}
    root, mode = output_root(blend, output)
    env = dict(os.environ)
    if not blender:  # bpy as a module: the add-on package from this checkout
        env["PYTHONPATH"] = os.pathsep.join([PACKAGE_PARENT] + [p for p in [env.get("PYTHONPATH")] if p])
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(batch_command(blend, frame, root, mode, blender, python), env=env, capture_output=True,
                              text=True, timeout=timeout, stdin=subprocess.DEVNULL, preexec_fn=die_with_parent)
    except subprocess.TimeoutExpired:  # run() has killed it
        raise FrameError(f"frame {frame} of {blend}: Blender ran past the per-frame limit of {timeout:g} s and was "
                         f"stopped (a driver that never ends?); raise it with --frame-timeout") from None
    seconds = time.perf_counter() - t0
    found = [ln.split(" ", 1) for ln in proc.stdout.splitlines() if ln.startswith(("HOVR-EXISTS ", "HOVR-RENDERED "))]
    if proc.returncode != 0 or not found:
        raise FrameError(f"frame {frame} of {blend}: Blender exited with {proc.returncode}: "
                         f"{_blender_error(proc.stdout + chr(10) + proc.stderr)}")
    kind, info = found[-1][0], json.loads(found[-1][1])
    out = info["out"]
    if not _inside(os.path.dirname(out), root):
        raise FrameError(f"frame {frame} of {blend}: its output {out} is outside {root}; refused")
    if kind == "HOVR-EXISTS":
        check_output(out)
        return {**record, "status": "exists", "output": out}
    tmp = info["tmp"]
    try:
        written = link_file(tmp, out)
        if not written:
            check_output(out)
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)
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
