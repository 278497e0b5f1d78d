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


def _stage_reporter(fd: int):
    def opened(path, what):
        send(fd, {"stage": f"reading {os.path.basename(str(path))}", "file": str(path)})
    return opened


def _run(request: dict, out: int, config: dict):
    send(out, {"stage": "reading"})  # the parent's time limit starts now
    task = TASKS[request["task"]]
    lim = limits.ResourceLimits(**request["limits"])
    limits.cap_address_space(lim.max_memory + int(config["address_slack"]))
    if hasattr(signal, "setitimer"):  # SIGALRM's default action ends the process, C loops included
        signal.setitimer(signal.ITIMER_REAL, float(request["seconds"]) + float(config["alarm_grace"]))
    try:
        with limits.using(lim):
            value = task(**request["args"])
        arrays: list = []
        result = encode(value, arrays)
        return {"result": result}, arrays
    except MemoryError:
        return {"error": {"kind": "MemoryError", "message": "out of memory"}}, []
    except Exception as exc:  # noqa: BLE001  (every failure goes back as one line)
        return {"error": {"kind": type(exc).__name__, "message": str(exc)}}, []
    finally:
        if hasattr(signal, "setitimer"):
            signal.setitimer(signal.ITIMER_REAL, 0)


def main(config: dict):
    faulthandler.enable(sys.stderr)  # a crash's C stack goes to the log the parent keeps
    limits.own_address_space()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    _die_with_parent(int(config["parent"]), bool(config["death_signal"]))
    out = os.dup(1)
    os.dup2(2, 1)
    limits.OPEN_OBSERVERS.append(_stage_reporter(out))
    header = HEADER
    while True:
        raw = _read_exact(0, header.size)
        if raw is None:
            break  # the parent closed the pipe (or ended)
        body = _read_exact(0, header.unpack(raw)[0])
        if body is None:
            break
        message, arrays = _run(json.loads(body), out, config)
        send(out, message, arrays)
    os._exit(0)
