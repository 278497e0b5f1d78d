"""Reading untrusted files in a separate process: a crash, a hang or a blown limit inside a C
library (libhdf5, expat, zlib) ends that process, never Blender or the `hovr` command.

Every parse of a data file (io.sources.load_volume, the field listing behind the import dialog,
a Nektar++ mesh's composites for the walls, the format packages' read_nektar, read_pyfr and
read_mfem (read_files) and their list_fields) is a task of `reader_process.py`, run by `call` in a
reader process of this package: `python -I -c BOOT` on this interpreter (Blender's own Python, not
Blender: `interpreter`), with this process's module path, loading this package from its folder
under this process's name for it (the extension's `bl_ext.<repo>.hovr_blender`) as the render
devices' processes do (engine/bootstrap.py). Nothing is pickled: a task's
arguments and result travel as JSON, its arrays as raw bytes of whitelisted dtypes that this
process reads into arrays it allocates after checking their sizes against the memory limit.

Limits of each task, in the reader process: its address space may grow by the memory limit
(engine/limits.py, RLIMIT_AS; Linux); its processor time may be the read time limit, a base and
a rate for each MB of the files it opens (limits.read_seconds: this process counts their sizes as
the reader names them; processor time, so a loaded machine does not refuse an honest read), and it
is stopped when it reports no progress for limits.READ_STALL_SECONDS of wall time (the reader
reports, with its processor time, whenever limits.progress() was called since its last report:
libhdf5 looping on a damaged file reports nothing). HOVR_MAX_READ_SECONDS makes it a flat limit on
the wall time, without the progress check. This process kills it; a timer in it (SIGPROF, or
SIGALRM for a flat limit) ends it anyway should this process be gone. A reader process ends with this one:
a parent-death signal (Linux), the end of its request pipe (everywhere). It ignores SIGINT: Ctrl-C
reaches this process, which stops it.

One reader process is kept warm between tasks (`prestart` starts it early; the `hovr` command
does, so that its start overlaps the command's own imports): a series of frames on one mesh
reuses the mesh's parsed geometry (io/nektar/reader.py's cache), and the import dialog's listing
costs milliseconds. A failed, stopped or cancelled task's process is killed, never reused.

HOVR_ISOLATION=0 reads in this process instead (benchmarks: bench/load.py, debugging).
"""
from __future__ import annotations

import atexit
import json
import os
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, replace
from pathlib import Path

from ..engine import limits, scratch
from .reader_protocol import ARRAY_DTYPES, HEADER, ReaderFailure, array_specs, decode, send

ENV_SWITCH = "HOVR_ISOLATION"
LIST_SECONDS = 30.0  # listing fields or composites reads headers only; the dialog waits for it
START_SECONDS = 120.0  # for a reader process to start (import numpy, the readers) before its time limit runs
ADDRESS_SLACK = 256 << 20  # beyond the memory limit: the interpreter's own allocations during a task
MAX_MESSAGE = 16 << 20  # a JSON message (arrays travel beside it)
ALARM_GRACE = 5.0  # the reader ends itself this long after its deadline, should nobody stop it
MAX_FILES_COUNTED = 10_000  # files a read's time limit counts (a multi-part field folder has one a rank)
# A reader that makes no progress and uses no processor time (blocked: a file system that never
# answers) is stopped after this long; one that uses processor time after READ_STALL_SECONDS of it.
READ_BLOCKED_SECONDS = 60.0
STALL_WALL_SECONDS = 15.0  # the stall check in wall time, where the reader's processor time is not known
CHECK_SECONDS = 0.1
BLAS_THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")  # the reader's: one each

# The package is loaded as the render devices' processes load it (engine/bootstrap.py, run from
# its file: nothing of the package is importable before), under this process's name for it.
BOOT = (
    "import importlib, json, runpy, sys\n"
    "cfg = json.loads(sys.argv[1])\n"
    "sys.path[:] = cfg['path']\n"
    "runpy.run_path(cfg['bootstrap'])['import_package'](cfg['package'], cfg['folder'])\n"
    "importlib.import_module(cfg['package'] + '.io.reader_process').main(cfg)\n"
)


class ReadCancelled(Exception):
    """A read stopped by the user (Esc, a cancelled job)."""


def enabled() -> bool:
    return os.environ.get(ENV_SWITCH, "1").strip().lower() not in ("0", "off", "no", "false")


def interpreter() -> str:
    """The Python to run readers with: sys.executable, unless that is Blender itself (Blender
    before 2.91 set it to its own binary), then the Python under sys.prefix."""
    exe = sys.executable or ""
    if os.path.basename(exe).lower().startswith("python"):
        return exe
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    candidates = [getattr(sys, "_base_executable", "")]
    if os.name == "nt":
        candidates += [os.path.join(sys.prefix, "bin", "python.exe"), os.path.join(sys.prefix, "python.exe")]
    else:
        candidates += [os.path.join(sys.prefix, "bin", f"python{version}"), os.path.join(sys.prefix, "bin", "python3")]
    for candidate in candidates:
        if candidate and os.path.basename(candidate).lower().startswith("python") and os.path.isfile(candidate):
            return candidate
    raise ReaderFailure(f"no Python interpreter found to run the reader process (sys.executable is {exe!r}); "
                        f"set {ENV_SWITCH}=0 to read in this process")


# ----------------------------------------------------------------------------- the process

def process_cpu_seconds(proc) -> float | None:
    """The processor time (user and system) a child process has used, where this platform tells
    (Linux: /proc; Windows: GetProcessTimes; elsewhere psutil, where installed); None otherwise, or
    once it is gone."""
    try:
        if sys.platform.startswith("linux"):
            with open(f"/proc/{proc.pid}/stat", "rb") as fh:
                fields = fh.read().rsplit(b")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        if os.name == "nt":
            import ctypes
            from ctypes import wintypes

            times = [wintypes.FILETIME() for _ in range(4)]
            if not ctypes.windll.kernel32.GetProcessTimes(int(proc._handle), *[ctypes.byref(t) for t in times]):
                return None
            return sum((t.dwHighDateTime << 32 | t.dwLowDateTime) for t in times[2:]) / 1e7
        import psutil

        used = psutil.Process(proc.pid).cpu_times()
        return used.user + used.system
    except (OSError, ValueError, IndexError, AttributeError, ImportError):
        return None
    except Exception:  # noqa: BLE001  (psutil's NoSuchProcess, AccessDenied)
        return None


def _package_dir() -> Path:
    return Path(__file__).resolve().parents[1]


def _wait_readable(fd: int, timeout: float) -> bool:
    if os.name == "nt":  # select() takes sockets only there: poll the pipe
        import _winapi
        import msvcrt

        end = time.monotonic() + timeout
        handle = msvcrt.get_osfhandle(fd)
        while True:
            try:
                if _winapi.PeekNamedPipe(handle, 0)[0]:
                    return True
            except OSError:  # the other end is gone: reading says so
                return True
            if time.monotonic() >= end:
                return False
            time.sleep(0.005)
    import select

    return bool(select.select([fd], [], [], max(timeout, 0.0))[0])


class _Worker:
    """One reader process and its pipes."""

    def __init__(self):
        folder = _package_dir()
        config = {"path": [p for p in sys.path if isinstance(p, str)], "package": __name__.rsplit(".", 2)[0],
                  "folder": str(folder), "bootstrap": str(folder / "engine" / "bootstrap.py"),
                  "parent": os.getpid(), "alarm_grace": ALARM_GRACE,
                  "address_slack": ADDRESS_SLACK, "death_signal": threading.current_thread() is threading.main_thread()}
        self.owner = os.getpid()
        private = scratch.run_folder()  # its temporary files too: never the shared temporary folder
        self.log = tempfile.TemporaryFile(prefix="hovr-reader-", dir=private)  # its stderr, for HOVR_DEBUG
        env = scratch.child_env(private)
        env.update(dict.fromkeys(BLAS_THREADS, "1"))  # no spinning BLAS threads: its processor time is the read's
        self.proc = subprocess.Popen([interpreter(), "-I", "-c", BOOT, json.dumps(config)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.log, bufsize=0, close_fds=True, env=env)
        self.stdin = self.proc.stdin.fileno()
        self.stdout = self.proc.stdout

    def alive(self) -> bool:
        return self.owner == os.getpid() and self.proc.poll() is None

    def kill(self):
        if self.owner != os.getpid():
            return
        try:
            self.proc.kill()
        except OSError:
            pass
        self._reap()

    def close(self):
        """End an idle process: the end of its request pipe ends its loop."""
        if self.owner != os.getpid():
            return
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=2.0)
        except (OSError, subprocess.TimeoutExpired):
            self.kill()
        self._reap()

    def _reap(self):
        try:
            self.proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            pass
        for f in (self.proc.stdin, self.proc.stdout, self.log):
            try:
                f.close()
            except OSError:
                pass

    def log_tail(self) -> str:
        try:
            self.log.seek(0, os.SEEK_END)
            size = self.log.tell()
            self.log.seek(max(0, size - 4000))
            return self.log.read().decode(errors="replace")
        except (OSError, ValueError):
            return ""


_IDLE: list = []
_LOCK = threading.Lock()


def _take() -> _Worker:
    with _LOCK:
        while _IDLE:
            worker = _IDLE.pop()
            if worker.alive():
                return worker
            if worker.owner == os.getpid():
                worker.kill()
    return _Worker()


def _give_back(worker: _Worker):
    with _LOCK:
        _IDLE[:] = [w for w in _IDLE if w.alive()]  # a dead idle reader must not turn a live one away
        if not _IDLE and worker.alive():
            _IDLE.append(worker)
            return
    worker.close()


def prestart():
    """Start the warm reader process now, without waiting for it (no-op when one is idle)."""
    if not enabled():
        return
    with _LOCK:
        if any(w.alive() for w in _IDLE):
            return
    try:
        _give_back(_Worker())
    except (OSError, ReaderFailure):
        pass  # the first task reports it


@atexit.register
def shutdown():
    """End the idle reader processes (at exit; tests)."""
    with _LOCK:
        idle = list(_IDLE)
        _IDLE.clear()
    for worker in idle:
        worker.close()


# ----------------------------------------------------------------------------- one task

def _one_line(text: str, limit: int = 1000) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _error_class(kind: str):
    """The class a reader's error of that name is raised as here: a registered format's own
    error, or one of the loader's and the policy's."""
    from ..engine.mesh import MeshError
    from ..engine.mesh_base import DerivedFieldError
    from . import formats, magnitude
    from .volume_source import SourceError

    known = {"SourceError": SourceError, "DerivedError": magnitude.DerivedError, "MeshError": MeshError,
             "DerivedFieldError": DerivedFieldError,
             "ResourceLimitError": limits.ResourceLimitError, "UnsafeFileError": limits.UnsafeFileError,
             "FileNotFoundError": FileNotFoundError, "ImportError": ImportError,
             "ModuleNotFoundError": ModuleNotFoundError}
    known.update({f.error.__name__: f.error for f in formats.FORMATS})
    return known.get(kind)


class Request:
    """One task in a reader process: `poll()` until it is done (then `value()`), or `cancel()`.
    `stage` is what the reader is doing, in words ("reading flow.fld")."""

    def __init__(self, task: str, args: dict, seconds: float | None = None, what: str = "",
                 cap: float | None = None):
        self.task, self.what = task, what
        self.stage = "starting the reader"
        self.done = False
        self._result = self._error = None
        self._file = what
        self._limits = limits.current()
        if seconds is not None:  # a flat limit for this task (no progress check), as HOVR_MAX_READ_SECONDS
            self._limits = replace(self._limits, max_read_seconds=float(seconds))
        self._cap = cap
        self._opened: dict = {}  # the files the reader opened -> their sizes (stat here): the time limit's MB
        self._deadline = time.monotonic() + START_SECONDS  # then the time limit, from its "started"
        self._progressed = None  # when the reader last reported progress (its first stage starts the clock)
        self._cpu = 0.0  # the processor time the reader has used on the task, as far as known
        self._cpu_start = self._cpu_progressed = None  # its processor time (process_cpu_seconds) then
        self._pending = bytearray(HEADER.size)  # what is being read: a length, a message or an array
        self._got = 0
        self._on_filled = self._length_read
        self._arrays: list = []
        self._specs: list = []
        self._reply = None
        self._started = False
        self.on_message = None  # called as each message of the reader's arrives (bench/read_rate.py times them)
        self._worker = _take()
        try:
            send(self._worker.stdin, {"task": task, "args": args, "limits": asdict(self._limits), "cap": cap})
        except OSError:  # it died before the request: a broken start
            self._fail_dead()

    @property
    def seconds(self) -> float:
        """The time limit of this read as it stands (processor time; wall time for a flat limit):
        it grows with the files the reader opens."""
        return limits.read_seconds(self.opened_bytes, self._cap, self._limits)

    @property
    def opened_bytes(self) -> int:
        """The sizes of the files the reader has opened, in all: what the time limit's MB count."""
        return sum(self._opened.values())

    @property
    def cpu_seconds(self) -> float:
        """The processor time the reader has used on the task, as far as known here."""
        return self._cpu

    def reader_cpu_seconds(self) -> float | None:
        """The reader process's processor time now (process_cpu_seconds), None where not known."""
        return None if self._worker is None else process_cpu_seconds(self._worker.proc)

    @property
    def _flat(self) -> bool:
        return self._limits.max_read_seconds is not None

    def _time_limit(self) -> str:
        """What passed the time limit, in words."""
        if self._flat:
            return (f"reading took longer than the limit of {self.seconds:.3g} s and was stopped (raise it with "
                    "HOVR_MAX_READ_SECONDS if the file is genuine)")
        mb = self.opened_bytes / 1e6
        return (f"reading used more than its limit of {self.seconds:.3g} s of processor time "
                f"({limits.READ_BASE_SECONDS:g} s + {limits.READ_SECONDS_PER_MB:g} s a MB of the {mb:.3g} MB read) "
                "and was stopped (HOVR_MAX_READ_SECONDS sets a flat limit instead, if the file is genuine)")

    def _limit_reached(self, now: float) -> str | None:
        """Why the task must stop now, or None."""
        if not self._started:
            return (f"the reader process did not start within {START_SECONDS:g} s" if now >= self._deadline
                    else None)
        if self._flat:
            return self._time_limit() if now >= self._deadline + self.seconds else None
        cpu = self.reader_cpu_seconds()
        if cpu is not None and self._cpu_start is not None:
            self._cpu = max(self._cpu, cpu - self._cpu_start)
        if self._cpu > self.seconds:
            return self._time_limit()
        stall = limits.read_stall_seconds(self._limits)
        if cpu is not None and self._cpu_progressed is not None:  # processor time: a loaded machine slows both
            looping = cpu - self._cpu_progressed >= stall
        else:  # where the reader's processor time is not known: wall time, with room for a loaded machine
            looping = now >= self._progressed + STALL_WALL_SECONDS
        if looping:
            return (f"the reader made no progress for {stall:g} s of processor time and was stopped (a damaged "
                    "file can make a library loop without end; if the file is genuine, HOVR_MAX_READ_SECONDS "
                    "sets a flat limit)")
        if now >= self._progressed + READ_BLOCKED_SECONDS:
            return f"the reader made no progress for {READ_BLOCKED_SECONDS:g} s and was stopped"
        return None

    def _next_check(self) -> float:
        if not self._started:
            return self._deadline
        if self._flat:
            return self._deadline + self.seconds
        return time.monotonic() + CHECK_SECONDS  # the reader's processor time is looked at this often

    def _progress_reported(self):
        self._progressed = time.monotonic()
        self._cpu_progressed = self.reader_cpu_seconds()

    @property
    def pid(self) -> int | None:
        """The reader process's id while the task runs."""
        return None if self._worker is None else self._worker.proc.pid

    # ---------------------------------------------------------------- reading the reply

    def poll(self, timeout: float = 0.0) -> bool:
        """Read what the reader has sent (waiting up to `timeout`); True once the task is done."""
        end = time.monotonic() + max(timeout, 0.0)
        while not self.done:
            now = time.monotonic()
            why = self._limit_reached(now)
            if why is not None:
                self._stop(why)
                break
            wait = min(end, self._next_check()) - now
            if not _wait_readable(self._worker.stdout.fileno(), max(wait, 0.0)):
                if time.monotonic() >= end:
                    break
                continue
            try:
                n = self._worker.stdout.readinto(memoryview(self._pending)[self._got:])
            except OSError:
                n = 0
            if not n:
                self._fail_dead()
                break
            if self._started:  # a long reply is progress too
                self._progress_reported()
            self._got += n
            if self._got == len(self._pending):
                self._on_filled()
        return self.done

    def _expect(self, size: int, on_filled, buffer=None):
        self._pending = bytearray(size) if buffer is None else buffer
        self._got = 0
        self._on_filled = on_filled
        if size == 0:
            on_filled()

    def _length_read(self):
        (size,) = HEADER.unpack(bytes(self._pending))
        if size > MAX_MESSAGE:
            self._stop(f"the reader process sent a message of {size:,} bytes; refused")
            return
        self._expect(size, self._message_read)

    def _message_read(self):
        if self.on_message is not None:
            self.on_message()
        try:
            message = json.loads(bytes(self._pending))
        except ValueError:
            self._stop("the reader process sent a malformed message")
            return
        if "stage" in message or "progress" in message:
            self._progress_reported()
            if not self._started:  # the time limit runs from here (_deadline: when it started)
                self._started = True
                self._deadline, self._cpu_start = self._progressed, self._cpu_progressed
            if isinstance(message.get("cpu"), (int, float)):
                self._cpu = float(message["cpu"])
            if "stage" in message:
                self.stage = _one_line(message["stage"], 200)
                self._file = _one_line(message.get("file", self._file), 1000)
                if "file" in message:
                    self._count_file(str(message["file"]))
            self._expect(HEADER.size, self._length_read)
        elif "error" in message:
            self._reply = message
            self._finish()
        else:
            self._reply = message
            import numpy as np

            try:
                self._specs = array_specs(message.get("result"), [])
                total = 0
                for index, spec in enumerate(self._specs):
                    dtype, shape = np.dtype(spec["dtype"]), tuple(int(s) for s in spec["shape"])
                    if spec["$array"] != index or dtype.str not in ARRAY_DTYPES or any(s < 0 for s in shape):
                        raise ValueError(spec)
                    total += int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                limits.check_bytes(total, f"the arrays read from {self._file or 'the file'}")
            except limits.ResourceLimitError as exc:
                self._stop(str(exc))
                return
            except (ValueError, TypeError, KeyError, AttributeError):
                self._stop("the reader process sent a malformed result")
                return
            self._next_array()

    def _count_file(self, path: str):
        """A file the reader opened counts towards the time limit by its size, as this process sees it."""
        if path not in self._opened and len(self._opened) < MAX_FILES_COUNTED:
            try:
                st = os.stat(path)
                self._opened[path] = st.st_size if stat.S_ISREG(st.st_mode) else 0
            except (OSError, ValueError):
                self._opened[path] = 0

    def _next_array(self):
        import numpy as np

        if len(self._arrays) == len(self._specs):
            self._finish()
            return
        spec = self._specs[len(self._arrays)]
        array = np.empty(tuple(spec["shape"]), dtype=np.dtype(spec["dtype"]))
        self._arrays.append(array)
        self._expect(array.nbytes, self._next_array, memoryview(array.reshape(-1).view(np.uint8)))

    def _finish(self):
        self.done = True
        message, worker = self._reply, self._worker
        self._worker = None
        _give_back(worker)
        if "error" in message:
            error = message["error"]
            text = _one_line(error.get("message", ""))
            kind = error.get("kind", "")
            if kind == "MemoryError":
                self._error = limits.ResourceLimitError(
                    f"{self._file or 'the file'}: reading it needed more memory than the limit of "
                    f"{limits.format_size(self._limits.max_memory)} (raise it with --max-memory or HOVR_MAX_MEMORY)")
                return
            cls = _error_class(kind)
            self._error = cls(text) if cls is not None else ReaderFailure(
                f"unexpected {kind} while reading {self._file or 'the file'}: {text} (a bug: please report it)")
            return
        try:
            self._result = decode(message.get("result"), self._arrays)
        except Exception as exc:  # noqa: BLE001  (whatever the result fails, it is the file's)
            cls = _error_class(type(exc).__name__)
            self._error = cls(_one_line(exc)) if cls is not None else ReaderFailure(
                f"{self._file or 'the file'}: the reader's result is not a valid mesh ({_one_line(exc)})")

    # ---------------------------------------------------------------- endings

    def _stop(self, why: str):
        """Kill the reader and fail with `why`, naming the file."""
        worker, self._worker = self._worker, None
        if worker is not None:
            worker.kill()
        self.done = True
        self._error = ReaderFailure(f"{self._file}: {why}" if self._file else why)

    def _fail_dead(self):
        worker = self._worker
        worker.kill()
        code = worker.proc.returncode
        if code is not None and code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            if -code in (getattr(signal, "SIGALRM", None), getattr(signal, "SIGPROF", None)):
                why = self._time_limit()
            elif -code == signal.SIGKILL:
                why = "the reader process was killed (SIGKILL, perhaps out of memory) while reading it; refused"
            else:
                why = (f"the reader process crashed ({name}) while reading it: the file is damaged or not a valid "
                       "data file; nothing was loaded")
        else:
            tail = [line for line in worker.log_tail().splitlines() if line.strip()]
            why = (f"the reader process ended unexpectedly (exit status {code})"
                   + (f": {_one_line(tail[-1], 300)}" if tail else ""))
        if os.environ.get("HOVR_DEBUG"):
            sys.stderr.write(worker.log_tail())
        self._worker = None
        self.done = True
        self._error = ReaderFailure(f"{self._file}: {why}" if self._file else why)

    def cancel(self):
        """Stop the task now (its process is killed); value() raises ReadCancelled."""
        if not self.done:
            worker, self._worker = self._worker, None
            if worker is not None:
                worker.kill()
            self.done = True
            self._error = ReadCancelled(f"reading {self._file or 'the file'} was cancelled")

    def value(self):
        if not self.done:
            raise RuntimeError("the read is not done")
        if self._error is not None:
            raise self._error
        return self._result


class Finished:
    """A task already run in this process (HOVR_ISOLATION=0, or a built-in dataset): a Request's
    interface, done from the start."""

    done = True
    pid = None

    def __init__(self, run, stage: str = "reading"):
        self.stage = stage
        self._result = self._error = None
        try:
            self._result = run()
        except Exception as exc:  # noqa: BLE001  (raised by value(), as a Request's)
            self._error = exc

    def poll(self, timeout: float = 0.0) -> bool:
        return True

    def cancel(self):
        pass

    def value(self):
        if self._error is not None:
            raise self._error
        return self._result


def start(task: str, args: dict, seconds: float | None = None, what: str = "", cap: float | None = None):
    """reader_process.TASKS[task](**args) started in a reader process: a Request to poll (or a
    Finished one where isolation is off). `seconds`: a flat time limit instead of the resource
    policy's (limits.read_seconds: by the size of what is read, and no progress for a few seconds
    stops it); `cap`: at most this long. `what`: the file named by failures before the reader says
    which it opened."""
    if not enabled():
        from .reader_process import TASKS

        return Finished(lambda: TASKS[task](**args))
    return Request(task, args, seconds, what, cap)


def wait(request, on_stage=None, cancelled=None):
    """The result of a started task, waited for here; its errors are raised here as the reader's
    own classes. on_stage(text) at each stage; cancelled() -> True stops it."""
    stage = None
    try:
        while not request.poll(0.1):
            if cancelled is not None and cancelled():
                request.cancel()
            elif on_stage is not None and request.stage != stage:
                stage = request.stage
                on_stage(stage)
    except BaseException:  # KeyboardInterrupt included: the reader must not outlive the wait
        request.cancel()
        raise
    return request.value()


def call(task: str, args: dict, seconds: float | None = None, what: str = "", on_stage=None, cancelled=None,
         cap: float | None = None):
    """Run reader_process.TASKS[task](**args) in a reader process and return its result (start,
    then wait)."""
    return wait(start(task, args, seconds, what, cap), on_stage, cancelled)


# ----------------------------------------------------------------------------- the tasks, called here

def _extra_formats() -> list:
    """[(name, module file)] of the formats registered at run time from outside this package: the
    reader process registers them from their files before it reads."""
    import inspect

    from . import formats

    package = __name__.rsplit(".", 2)[0]
    out = []
    for data_format in formats.FORMATS:
        module = inspect.getmodule(data_format.read)
        if module is not None and not module.__name__.startswith(package + ".") and getattr(module, "__file__", None):
            out.append((data_format.name, module.__file__))
    return out


def read_volume_request(source):
    """io.sources.read_volume(source) started in a reader process (start)."""
    args = {"path": source.path, "solution": source.solution, "field": source.field, "component": source.component,
            "extra_formats": _extra_formats()}
    return start("read_volume", args, what=source.path)


def read_volume(source, **progress):
    """io.sources.read_volume(source) in a reader process."""
    return wait(read_volume_request(source), **progress)


def read_files(path, solution=None, field=None, component=None, **progress):
    """A format package's public reading door (io.nektar.read_nektar, io.pyfr.read_pyfr,
    io.mfem.read_mfem): read_volume of its files, named by absolute paths (the warm reader process
    keeps the working folder it was started in)."""
    from .volume_source import VolumeSource

    return read_volume(VolumeSource(os.path.abspath(path), os.path.abspath(solution) if solution else "", field or "",
                                    (), "" if component is None else str(component)), **progress)


def list_fields_request(format_name: str, path):
    """list_fields started in a reader process (start)."""
    path = os.path.abspath(path)
    return start("list_fields", {"format_name": format_name, "path": path, "extra_formats": _extra_formats()},
                 what=path, cap=LIST_SECONDS)


def list_fields(format_name: str, path, **progress):
    """The fields a file offers (its format's list_fields: names, or {name: components} for the
    formats with vector fields), read in a reader process."""
    return wait(list_fields_request(format_name, path), **progress)


def wall_choices_request(format_name: str, mesh_path):
    """wall_choices started in a reader process (start); its value as the reader sends it
    (lists: wall_choices makes them tuples)."""
    return start("wall_choices", {"format_name": format_name, "path": str(mesh_path),
                                  "extra_formats": _extra_formats()},
                 what=str(mesh_path), cap=LIST_SECONDS)


def wall_choices(format_name: str, mesh_path, **progress) -> list:
    """[(selection, label)] of a mesh's named boundaries (its format's boundaries(path).choices())."""
    return [tuple(c) for c in wait(wall_choices_request(format_name, mesh_path), **progress)]


def wall_faces_request(format_name: str, mesh_path, selection: str):
    """wall_faces started in a reader process (start)."""
    return start("wall_faces", {"format_name": format_name, "path": str(mesh_path), "selection": selection,
                                "extra_formats": _extra_formats()}, what=str(mesh_path))


def wall_faces(format_name: str, mesh_path, selection: str, **progress):
    """The faces of a selection of a mesh's named boundaries (boundaries(path).select(selection)),
    read in a reader process."""
    return wait(wall_faces_request(format_name, mesh_path, selection), **progress)
