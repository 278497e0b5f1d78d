"""Work the add-on does off Blender's main thread, without bpy (tested without Blender).

- `Job`: a function run in named steps in a background thread (or in the caller's, where
  Blender has no event loop: background mode), with its progress in words and a cancel that
  stops it at its next step, or sooner: the thread is interrupted (an asynchronous exception)
  at its next Python instruction, so a long read ends without running to its end. The
  import operators run their reading as a Job.
- `KernelWarmup`: the render kernels compiled in this session, by (device, precision,
  kernel variant, surfaces), and the one background thread that compiles those a scene will
  need (reading its volumes' data first where that is what tells the variant). A final render
  waits for it rather than compiling a second time; kernels are never compiled by two threads
  at once.

Blender's API is never touched here: the threads only read data and call the core, and the
add-on reports what they do from the main thread (bpy.app.timers, a modal operator's timer).
"""
from __future__ import annotations

import ctypes
import threading
import time
from collections import deque
from typing import Callable


class Cancelled(BaseException):
    """The user cancelled the job. A BaseException, as KeyboardInterrupt is: the readers turn any
    Exception into their own error naming the file, which an interrupt must pass through."""


def _interrupt(thread: threading.Thread, exc_type=Cancelled) -> bool:
    """Raise exc_type in `thread` at its next Python instruction (C calls run to their end)."""
    set_async = ctypes.pythonapi.PyThreadState_SetAsyncExc
    set_async.argtypes = (ctypes.c_ulong, ctypes.py_object)
    set_async.restype = ctypes.c_int
    return set_async(thread.ident, exc_type) == 1


class Job:
    """`work(job)` run once, in steps: work calls job.step("reading the data") before each stage;
    step() raises Cancelled once cancel() was called. Its result, error or cancellation is kept
    for the thread that started it to collect (done, result, error, cancelled)."""

    def __init__(self, work: Callable[["Job"], object], title: str, steps: int = 0):
        self.work = work
        self.title = title
        self.steps = steps  # how many step() calls to expect (0: unknown), for "2/4" in the status
        self.stage = "starting"
        self.step_index = 0
        self.result = None
        self.error: BaseException | None = None
        self.cancelled = False
        self._started = time.perf_counter()
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._cancel_requested = False
        self._interruptible = False  # the thread is inside work(): an interrupt lands there
        self._interrupted = False
        self._thread: threading.Thread | None = None

    # --------------------------------------------------------------------------- running it

    def start(self) -> "Job":
        """Run work in a daemon thread (a quitting Blender does not wait for it)."""
        self._thread = threading.Thread(target=self._main, name=f"HOVR {self.title}", daemon=True)
        self._thread.start()
        return self

    def run(self) -> "Job":
        """Run work here, in the calling thread (Blender in background mode)."""
        self._main()
        return self

    def _main(self):
        self._started = time.perf_counter()
        try:
            try:
                with self._lock:
                    if self._cancel_requested:
                        raise Cancelled()
                    self._interruptible = self._thread is not None
                result = self.work(self)
            finally:
                with self._lock:
                    self._interruptible = False
            self._finish(result=result)
        except Cancelled:  # from step(), or the interrupt (which may land as late as here)
            self._finish(cancelled=True)
        except BaseException as exc:  # noqa: BLE001  (handed to the main thread, which reports it)
            # after a cancel, a failure is the interrupt's, turned into another error on its way out
            self._finish(cancelled=True) if self._cancel_requested else self._finish(error=exc)

    def _finish(self, result=None, error=None, cancelled=False):
        self.result, self.error, self.cancelled = result, error, cancelled
        self._done.set()

    # --------------------------------------------------------------------------- from the work

    def step(self, stage: str):
        """Enter the next stage (its words for the status); raises Cancelled once cancelled."""
        if self._cancel_requested:
            raise Cancelled()
        self.stage = stage
        self.step_index += 1

    # --------------------------------------------------------------------------- from outside

    def cancel(self):
        """Stop the work: at its next step(), and in a thread sooner (interrupted)."""
        with self._lock:
            self._cancel_requested = True
            if (self._interruptible and not self._interrupted and self._thread is not None
                    and self._thread is not threading.current_thread()):
                self._interrupted = _interrupt(self._thread)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self._started

    def status(self) -> str:
        """e.g. 'reading the data (2/4), 3.1 s'."""
        count = f" ({self.step_index}/{self.steps})" if self.steps else ""
        return f"{self.stage}{count}, {self.seconds:.1f} s"


class KernelWarmup:
    """Render kernels compiled in this session, by key (device, precision, kernel variant,
    surfaces), and one background thread that compiles those asked for. `compile_key(key)` does
    the compiling (the core's load_kernels); it runs under one lock, so a render compiling what it
    still misses (compile_now) never compiles alongside the thread."""

    COMPILING = "Compiling render kernels (first use)"
    READING = "Reading volume data for the first render"

    def __init__(self, compile_key: Callable[[tuple], None]):
        self.compile_key = compile_key
        self._ready: set = set()
        self._queue: deque = deque()  # functions returning the keys to compile
        self._cond = threading.Condition()
        self._compile_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stage: str | None = None
        self._stage_started = 0.0
        self.errors: list = []  # failures of the background work, newest last (a few)

    def is_ready(self, key) -> bool:
        with self._cond:
            return key in self._ready

    def mark_ready(self, key):
        with self._cond:
            self._ready.add(key)

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._thread is not None

    def status(self) -> str | None:
        """Words for the status bar while the thread works, e.g. 'Compiling render kernels
        (first use)… 12 s'; None when idle."""
        with self._cond:
            return None if self._thread is None else self._status_text()

    def _status_text(self) -> str:  # with self._cond held
        return f"{self._stage or self.READING}\u2026 {time.perf_counter() - self._stage_started:.0f} s"

    def request(self, keys: Callable[[], list]) -> None:
        """Compile, in the background, the keys `keys()` returns (called in the thread: it may
        read data); the thread starts if it is not running."""
        with self._cond:
            self._queue.append(keys)
            if self._thread is None:
                self._stage, self._stage_started = self.READING, time.perf_counter()
                self._thread = threading.Thread(target=self._work, name="HOVR kernel warm-up", daemon=True)
                self._thread.start()

    def wait_idle(self, poll: Callable[[str], bool] | None = None, interval: float = 0.25) -> bool:
        """Wait while the thread works, calling poll(status) every `interval` s; False as soon
        as poll returns False (the render was cancelled), True once idle."""
        while True:
            with self._cond:
                if self._thread is None:
                    return True
                self._cond.wait(interval)
                if self._thread is None:
                    return True
                status = self._status_text()
            if poll is not None and poll(status) is False:
                return False

    def compile_now(self, key) -> bool:
        """Compile `key` in the calling thread unless it is ready; True if it compiled here."""
        with self._compile_lock:
            if self.is_ready(key):
                return False
            self.compile_key(key)
            self.mark_ready(key)
            return True

    def _set_stage(self, stage: str | None):
        with self._cond:
            self._stage, self._stage_started = stage, time.perf_counter()

    def _work(self):
        while True:
            with self._cond:
                if not self._queue:
                    self._thread, self._stage = None, None
                    self._cond.notify_all()
                    return
                keys_of = self._queue.popleft()
            self._set_stage(self.READING)
            try:
                keys = [k for k in keys_of() if not self.is_ready(k)]
                for key in keys:
                    with self._compile_lock:
                        if self.is_ready(key):
                            continue
                        self._set_stage(self.COMPILING)
                        self.compile_key(key)
                        self.mark_ready(key)
            except Exception as exc:  # noqa: BLE001  (a render reports the same failure in words)
                with self._cond:
                    self.errors = (self.errors + [exc])[-4:]


def kernel_key(device: str, precision: str, variant: tuple, surfaces: bool) -> tuple:
    """What a set of compiled render kernels is for: the scene's Device and Precision, the
    kernel variant of its volumes (core.renderer.kernel_variant) and whether surfaces are cast."""
    return (str(device), str(precision), tuple(variant), bool(surfaces))


def compile_render_kernels(key: tuple) -> None:
    """Compile (or load from Warp's disk cache) a kernel_key's kernels on its device's first
    device: a split device ("cpu:all", "cuda:all") renders in processes of its own, which then
    load the kernels from the disk cache instead of compiling them."""
    from ..core.renderer import expand_devices, load_kernels

    device, precision, variant, surfaces = key
    load_kernels(variant, expand_devices(device)[0], precision, surfaces=surfaces)


# The add-on's one warm-up (kernel_warmup.py starts it, render.py waits for it)
WARMUP = KernelWarmup(compile_render_kernels)
