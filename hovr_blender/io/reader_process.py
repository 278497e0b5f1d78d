"""The reader process (io/isolation.py starts it): the tasks a parse of an untrusted file can be,
and the loop that runs them one request at a time under the request's limits.

Started by isolation.BOOT with its configuration as JSON; it talks on its own stdin (requests)
and a private copy of its stdout (replies: reader_protocol.send), with file descriptor 1 pointed at
its stderr so that a library's stray output cannot corrupt a reply.
"""
from __future__ import annotations

import ctypes
import faulthandler
import json
import os
import signal
import sys
import threading
import time

from ..engine import limits
from . import formats, volume_source
from .reader_protocol import HEADER, encode, send


def _known(extra_formats):
    """Register the formats the parent registered at run time (a test's toy, another add-on's
    reader) from their modules' files: the reader process knows the package's own already."""
    import importlib.util

    from .format_base import Format

    for name, module_file in extra_formats:
        if any(f.name == name for f in formats.FORMATS):
            continue
        spec = importlib.util.spec_from_file_location(f"_hovr_format_{name}", module_file)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        found = [v for v in vars(module).values() if isinstance(v, Format) and v.name == name]
        if not found:
            raise ValueError(f"{module_file} declares no data format {name!r}")
        formats.register(found[0])


def _read_volume(path, solution, field, component, extra_formats=()):
    _known(extra_formats)
    return volume_source.read_volume(volume_source.VolumeSource(path, solution, field, (), component))


def _list_fields(format_name, path, extra_formats=()):
    _known(extra_formats)
    names = formats.named(format_name).list_fields(path)
    return dict(names) if isinstance(names, dict) else list(names)


def _wall_choices(format_name, path, extra_formats=()):
    _known(extra_formats)
    return formats.named(format_name).boundaries(path).choices()


def _wall_faces(format_name, path, selection, extra_formats=()):
    _known(extra_formats)
    return formats.named(format_name).boundaries(path).select(selection)


HEARTBEAT_SECONDS = 0.25  # how often the reader reports that it progressed (the parent's stall check)

TASKS = {"read_volume": _read_volume, "list_fields": _list_fields, "wall_choices": _wall_choices,
         "wall_faces": _wall_faces}


# ----------------------------------------------------------------------------- the process

def _die_with_parent(parent: int, death_signal: bool):
    """SIGKILL when the parent ends (Linux; the creating thread of the parent, so only when that
    was its main thread); else the end of the request pipe ends the loop."""
    if death_signal and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # it ended before the signal was armed
        os._exit(0)


def _read_exact(fd: int, n: int) -> bytes | None:
    out = bytearray()
    while len(out) < n:
        chunk = os.read(fd, n - len(out))
        if not chunk:
            return None
        out += chunk
    return bytes(out)


class _Task:
    """The task running now, as the reader's threads see it: its limits, the files it opened (their
    sizes make its time limit) and whether it is running; `lock` orders the messages on the pipe."""

    def __init__(self, out: int, grace: float):
        self.out, self.grace = out, grace
        self.lock = threading.Lock()
        self.running = False
        self.limits = limits.ResourceLimits()
        self.cap = None
        self.opened: dict = {}
        self.started = self.cpu = 0.0

    def send(self, message: dict, arrays=()):
        with self.lock:
            send(self.out, message, arrays)

    def begin(self, request: dict):
        self.limits = limits.ResourceLimits(**request["limits"])
        self.cap = request.get("cap")
        self.opened = {}
        self.started, self.cpu = time.monotonic(), time.process_time()
        with self.lock:
            self.running = True
            send(self.out, {"stage": "reading"})  # the parent's time limit starts now
        self.arm_alarm()

    def end(self, message: dict, arrays):
        """The reply, and no progress message after it."""
        with self.lock:
            self.running = False
            send(self.out, message, arrays)
        if hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.setitimer(signal.ITIMER_PROF, 0)

    def cpu_seconds(self) -> float:
        """The processor time the task has used (every thread of this process)."""
        return time.process_time() - self.cpu

    def arm_alarm(self):
        """The task's time limit for the files opened so far, and a grace, enforced here too should
        the parent be gone: SIGPROF when its processor time passes it (the policy's rule), SIGALRM
        when the wall time passes a flat limit; the default action of both ends the process, C
        loops included."""
        if not hasattr(signal, "setitimer"):
            return
        seconds = limits.read_seconds(sum(self.opened.values()), self.cap, self.limits) + self.grace
        if self.limits.max_read_seconds is None:
            signal.setitimer(signal.ITIMER_PROF, max(seconds - self.cpu_seconds(), 0.001))
        else:
            signal.setitimer(signal.ITIMER_REAL, max(self.started + seconds - time.monotonic(), 0.001))

    def opening(self, path, what):
        """limits.OPEN_OBSERVERS: the stage and the file (the parent counts its size), the alarm moved."""
        path = str(path)
        if path not in self.opened:
            try:
                self.opened[path] = os.stat(path).st_size
            except (OSError, ValueError):
                self.opened[path] = 0
            self.arm_alarm()
        self.send({"stage": f"reading {os.path.basename(path)}", "file": path})

    def heartbeat(self):
        """A thread: every HEARTBEAT_SECONDS in which limits.progress() was called, one progress
        message with the processor time used so far. A library looping in C (holding the
        interpreter, or not calling back) sends none."""
        seen = None
        while True:
            time.sleep(HEARTBEAT_SECONDS)
            count = limits.progress_count()
            with self.lock:
                if self.running and count != seen:
                    send(self.out, {"progress": count, "cpu": round(self.cpu_seconds(), 3)})
                seen = count


class _ImportProgress:
    """A finder of no module, first on sys.meta_path: each import a task makes (h5py's, at a first
    HDF5 file: seconds on a loaded machine) counts as progress."""

    @staticmethod
    def find_spec(name, path=None, target=None):
        limits.progress()
        return None


def _run(request: dict, task_state: _Task, config: dict):
    task = TASKS[request["task"]]
    task_state.begin(request)
    limits.cap_address_space(task_state.limits.max_memory + int(config["address_slack"]))
    try:
        with limits.using(task_state.limits):
            value = task(**request["args"])
        arrays: list = []
        result = encode(value, arrays)
        return {"result": result}, arrays
    except MemoryError:
        return {"error": {"kind": "MemoryError", "message": "out of memory"}}, []
    except Exception as exc:  # noqa: BLE001  (every failure goes back as one line)
        return {"error": {"kind": type(exc).__name__, "message": str(exc)}}, []


def main(config: dict):
    faulthandler.enable(sys.stderr)  # a crash's C stack goes to the log the parent keeps
    limits.own_address_space()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    _die_with_parent(int(config["parent"]), bool(config["death_signal"]))
    out = os.dup(1)
    os.dup2(2, 1)
    task_state = _Task(out, float(config["alarm_grace"]))
    limits.OPEN_OBSERVERS.append(task_state.opening)
    sys.meta_path.insert(0, _ImportProgress)
    threading.Thread(target=task_state.heartbeat, name="hovr-reader-heartbeat", daemon=True).start()
    header = HEADER
    while True:
        raw = _read_exact(0, header.size)
        if raw is None:
            break  # the parent closed the pipe (or ended)
        body = _read_exact(0, header.unpack(raw)[0])
        if body is None:
            break
        message, arrays = _run(json.loads(body), task_state, config)
        task_state.end(message, arrays)
    os._exit(0)
