"""Ctrl-C and SIGTERM in the middle of a split frame (`--device cpu,cpu`, as cpu:all on two cores):
one line, its exit code, and the device processes gone with the run (issue 29: Ctrl-C printed
about 70 lines, SIGTERM nothing, and killing the parent left its workers rendering)."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from tests.helpers import ctrl_c_as_at_a_terminal

psutil = pytest.importorskip("psutil")

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
pytestmark = pytest.mark.slow

VIEW = {"data": {"builtin": "sphere"},
        "camera": {"projection": "perspective", "eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40},
        "image": {"width": 1600, "height": 1600},
        "transfer_function": {"color": [[0.0, 1, 1, 1], [0.5, 1, 0, 0], [1.0, 0, 0, 1]],
                              "density": [[0.0, 0.5], [0.5, 3.0], [1.0, 0.5]]},
        "render": {"method": "split", "tolerance": 1e-9, "precision": "float64", "device": "cpu,cpu"}}


def _started(tmp_path):
    view = tmp_path / "view.json"
    view.write_text(json.dumps(VIEW))
    proc = subprocess.Popen([sys.executable, "-m", "hovr_blender.cli", "render", str(view), "-o",
                             str(tmp_path / "out.npy")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=REPO, HOVR_MAX_PROCESSES="2"), start_new_session=True,
                            preexec_fn=ctrl_c_as_at_a_terminal)
    deadline = time.monotonic() + 240
    children = []
    while time.monotonic() < deadline and proc.poll() is None:  # both device processes busy rendering
        children = [c for c in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(c.cmdline())]
        if len(children) == 2 and all(c.cpu_times().user > 3.0 for c in children):
            break
        time.sleep(0.2)
    assert proc.poll() is None and len(children) == 2, "the render ended before it could be interrupted"
    return proc, children


@pytest.mark.parametrize("sig, to_group, code, line", [
    (signal.SIGINT, True, 130, "hovr: interrupted"),  # Ctrl-C: the terminal signals the whole group
    (signal.SIGTERM, False, 143, "hovr: terminated (SIGTERM)"),
])
def test_interrupt_ends_with_one_line_and_no_processes(tmp_path, sig, to_group, code, line):
    proc, children = _started(tmp_path)
    try:
        (os.killpg if to_group else os.kill)(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == code
        assert [ln for ln in err.splitlines() if ln.strip()] == [line], err[-2000:]
        deadline = time.monotonic() + 10
        while any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE for c in children) \
                and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(c.is_running() and c.status() != psutil.STATUS_ZOMBIE for c in children)
        assert not [p for p in os.listdir(tmp_path) if p.endswith(".tmp") or p == "out.npy"]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
