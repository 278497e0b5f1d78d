"""Running one hostile case the way a user would meet it: the `hovr` command in a fresh process,
with a memory cap, a wall-clock limit and its peak memory measured.

A case passes when the process ends with the expected exit code, a clear one-line error
(`hovr: error: ...` containing the expected words, no traceback), in under MAX_SECONDS and
under MAX_PEAK_MB of peak resident memory (the issue's 5 s and 500 MB). The memory cap
(RLIMIT_AS) is only a safety net for the machine running the tests; the judgement is on the
measured peak.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MAX_SECONDS = 5.0
MAX_PEAK_MB = 500.0
ADDRESS_SPACE_CAP = 6 << 30  # Warp maps large libraries: the cap sits well above any real peak
HANG_SECONDS = 60.0  # killed after this (a hang)


@dataclass
class Outcome:
    returncode: int
    stdout: str
    stderr: str
    seconds: float
    peak_mb: float
    timed_out: bool = False


@dataclass
class Case:
    """One hostile input: `build(folder)` writes the files and returns the `hovr` arguments."""

    name: str
    klass: str
    build: object  # callable(Path) -> list[str]
    expect_rc: int = 2
    expect: tuple = ()  # words the error line must contain
    env: dict = field(default_factory=dict)
    after: object = None  # callable(Path folder, Outcome) -> list of problems (what the run left behind)
    max_seconds: float = MAX_SECONDS  # more only where the refusal needs a Dask cluster or Blender started first
    max_peak_mb: float = MAX_PEAK_MB  # more only where Blender itself renders a legitimate frame


# The measured command: `hovr` itself, reporting its own peak resident memory (VmHWM) at exit, or
# its reader process's if that was larger.
# The parent's getrusage would count the pytest process the child was forked from (its pages
# are the child's until exec), so the child reads its own high-water mark after exec.
_WRAPPER = """
import atexit, os, resource, sys
def _report_peak():
    try:
        with open('/proc/self/status') as fh:
            kb = int(next(line.split()[1] for line in fh if line.startswith('VmHWM:')))
        # the reader process (io/isolation.py), reaped by then: its own peak counts too
        kb = max(kb, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
        with open(os.environ['HOVR_PEAK_FILE'], 'w') as out:
            out.write(str(kb))
    except (OSError, StopIteration):
        pass
atexit.register(_report_peak)
from hovr_blender.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _limit_child():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_CAP, ADDRESS_SPACE_CAP))
    os.setsid()  # its own process group: a hang is killed with everything it started


def run_hovr(args, cwd, env_extra=None, timeout=HANG_SECONDS) -> Outcome:
    """`hovr ARGS` (hovr_blender.cli) in `cwd`; exit code, output, wall time, peak RSS."""
    peak_file = tempfile.NamedTemporaryFile(prefix="hovr-peak-", delete=False)
    peak_file.close()
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1",
               HOVR_PEAK_FILE=peak_file.name, **(env_extra or {}))
    env.pop("HOVR_DEBUG", None)
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        p = subprocess.Popen([sys.executable, "-c", _WRAPPER, *args], cwd=cwd, env=env,
                             stdin=subprocess.DEVNULL, stdout=out, stderr=err, preexec_fn=_limit_child)
        killed = threading.Event()

        def kill():
            killed.set()
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass

        timer = threading.Timer(timeout, kill)
        timer.start()
        try:
            _, status, usage = os.wait4(p.pid, 0)
        finally:
            timer.cancel()
        seconds = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)  # reaped here: keep Popen from waiting again
        out.seek(0)
        err.seek(0)
        try:
            peak_mb = int(Path(peak_file.name).read_text()) / 1024.0
        except (OSError, ValueError):  # killed before it could report: what the kernel counted
            peak_mb = usage.ru_maxrss / 1024.0
        finally:
            os.unlink(peak_file.name)
        return Outcome(p.returncode, out.read().decode(errors="replace"), err.read().decode(errors="replace"),
                       seconds, peak_mb, killed.is_set())


def judge(case: Case, o: Outcome) -> list[str]:
    """What is wrong with the outcome (empty: the case passes)."""
    problems = []
    if o.timed_out:
        return [f"hung: killed after {o.seconds:.0f} s"]
    if o.returncode != case.expect_rc:
        problems.append(f"exit code {o.returncode}, expected {case.expect_rc}")
    if "Traceback" in o.stderr:
        problems.append("printed a traceback")
    if case.expect_rc == 2:
        lines = [ln for ln in o.stderr.splitlines() if ln.strip()]
        if len(lines) != 1 or not lines[0].startswith("hovr: error: "):
            problems.append(f"expected one 'hovr: error:' line, got {o.stderr[-400:]!r}")
        for word in case.expect:
            if word not in o.stderr:
                problems.append(f"message lacks {word!r}: {o.stderr[-400:]!r}")
    if o.seconds > case.max_seconds:
        problems.append(f"took {o.seconds:.1f} s (limit {case.max_seconds} s)")
    if o.peak_mb > case.max_peak_mb:
        problems.append(f"peak memory {o.peak_mb:.0f} MB (limit {case.max_peak_mb} MB)")
    return problems


def run_case(case: Case, folder: Path) -> tuple[Outcome, list[str]]:
    args = case.build(folder)
    o = run_hovr(args, folder, case.env)
    problems = judge(case, o)
    if case.after is not None:
        problems += case.after(folder, o)
    return o, problems


def write_view(folder: Path, view: dict, name: str = "view.json") -> Path:
    p = folder / name
    p.write_text(json.dumps(view))
    return p
