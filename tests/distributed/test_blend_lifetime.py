"""render-blend's Blender ends with `hovr` (issue 29: the Blender child outlived a SIGTERM): a frame
stuck in an endless driver expression, then SIGTERM (one line, exit 143), SIGKILL of `hovr`, or
Ctrl-C to the whole process group (one line, exit 130), and
the Blender is gone within seconds (the worker watches its parent, Blender has the parent-death
signal of the task that started it)."""
import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import ctrl_c_as_at_a_terminal

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")
if importlib.util.find_spec("bpy") is None:
    pytest.skip("render-blend here needs the bpy module", allow_module_level=True)

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.slow, pytest.mark.blender]


def _blenders(pid):
    try:
        return [p for p in psutil.Process(pid).children(recursive=True) if "batch.py" in " ".join(p.cmdline())]
    except psutil.NoSuchProcess:
        return []


def _running(p):
    try:
        return p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


@pytest.mark.parametrize("sig, group, code, line", [
    (signal.SIGTERM, False, 143, "hovr: terminated (SIGTERM)"),
    (signal.SIGKILL, False, None, None),
    (signal.SIGINT, True, 130, "hovr: interrupted"),  # Ctrl-C: the terminal signals the whole group
])
def test_blender_ends_with_hovr(tmp_path, sig, group, code, line):
    (tmp_path / "scene").mkdir()
    blend = tmp_path / "scene" / "s.blend"
    subprocess.run([sys.executable, str(REPO / "tests" / "hostile" / "make_blend.py"), "driver", str(blend)],
                   check=True, capture_output=True, timeout=120)
    proc = subprocess.Popen([sys.executable, "-m", "hovr_blender.cli", "render-blend", str(blend), "--frames", "2",
                             "--workers", "1", "--frame-timeout", "600"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)),
                            start_new_session=True,
                            preexec_fn=ctrl_c_as_at_a_terminal)
    try:
        deadline = time.monotonic() + 180
        blenders = []
        while not blenders and time.monotonic() < deadline and proc.poll() is None:
            blenders = _blenders(proc.pid)
            time.sleep(0.2)
        assert blenders, "no Blender started"
        time.sleep(2.0)  # inside the endless driver
        assert all(_running(b) for b in blenders)
        (os.killpg if group else os.kill)(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
        deadline = time.monotonic() + 15
        while any(_running(b) for b in blenders) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_running(b) for b in blenders)
        if line is not None:
            assert proc.returncode == code
            assert [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("hovr: [")] == [line], \
                err[-2000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for b in _blenders(proc.pid):
            b.kill()
