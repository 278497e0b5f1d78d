"""The frames of a saved .blend over a Dask cluster: each task starts Blender headless for one
frame (ui/batch.py: `blender -b FILE --python batch.py -- N`, or the same script under a
Python with the bpy module), which renders to a temporary file beside the frame's output, named
as `blender -b FILE -a` names it; the task links it into place (series.link_file: never over a
frame already written) and logs it. Frames already written are skipped (the script checks before
it renders), so a rerun renders nothing; a task whose worker is lost is run again by Dask.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

from .series import append_log, link_file, submit_frames

BATCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "ui", "batch.py")
PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def batch_command(blend: str, frame: int, blender: str | None = None, python: str | None = None) -> list[str]:
    """The command that renders `frame` of `blend`: with a Blender binary, or a Python with bpy."""
    if blender:
        return [blender, "-b", blend, "--python", BATCH, "--", str(int(frame))]
    return [python or sys.executable, BATCH, blend, str(int(frame))]


def render_blend_frame(blend: str, frame: int, blender: str | None = None, python: str | None = None,
                       timeout: float | None = None) -> dict:
    """Render one frame of `blend` here (a Dask task); returns what happened."""
    record = {"frame": int(frame), "host": socket.gethostname(), "pid": os.getpid()}
    env = dict(os.environ)
    if not blender:  # bpy as a module: the add-on package from this checkout
        env["PYTHONPATH"] = os.pathsep.join([PACKAGE_PARENT] + [p for p in [env.get("PYTHONPATH")] if p])
    t0 = time.perf_counter()
    proc = subprocess.run(batch_command(blend, frame, blender, python), env=env, capture_output=True, text=True,
                          timeout=timeout)
    seconds = time.perf_counter() - t0
    lines = [ln.split(" ", 2) for ln in proc.stdout.splitlines() if ln.startswith("HOVR-")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"frame {frame} of {blend}: Blender exited with {proc.returncode}: "
                           f"{(proc.stdout + proc.stderr)[-2000:]}")
    if lines[-1][0] == "HOVR-EXISTS":
        return {**record, "status": "exists", "output": lines[-1][1]}
    _, tmp, out = lines[-1]
    try:
        written = link_file(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    record.update(status="written" if written else "exists", output=out, seconds=seconds)
    if written:
        append_log(os.path.dirname(out), {**record, "time": time.time()})
    return record


def render_animation(blend: str, frames, client, blender: str | None = None, python: str | None = None,
                     progress=None, retries: int = 3) -> list[dict]:
    """Submit one task a frame to the Dask `client`; progress(done, total, record) after each."""
    blend = os.path.abspath(blend)
    return submit_frames(client, list(frames), "hovr-blend",
                         lambda f, key: client.submit(render_blend_frame, blend, f, blender, python, key=key,
                                                      pure=False, retries=retries), progress)
