"""The add-on's work that is not Blender's, without bpy (tested without Blender).

- `Job`: an import's reading in named steps, with its progress in words, run in the calling
  (main) thread. Nothing runs in a background thread: Blender supports Python threads only
  when they finish before the script that started them does ("Troubleshooting Errors &
  Crashes" in Blender's Python API manual), and a read or a kernel compile left running in a
  thread crashed Blender 3.4 in the window test (a segfault inside numpy, then inside Warp's
  code generation, 1 run in 3). The reading itself is a process (io/isolation.py): a job
  whose work is a generator waits on the reader's requests it yields, either here to the end
  (`run`, a script's import) or a poll at a time (`advance`, from a modal operator's timer,
  so Blender stays responsive and Esc cancels it).
- `Listings`: what the import dialog shows of a file (its fields, its composites), read by
  reader tasks that draw() starts and never waits for.
- `CompiledKernels`: the render kernels compiled in this session, by (device, precision,
  kernel variant, surfaces), so a render says "compiling (first use)" only when something compiles.
- `ProgressLines`: when a background render's log gets a progress line (a few a frame).
"""
from __future__ import annotations

import inspect
import time
from typing import Callable

from ..io.isolation import ReadCancelled


class Job:
    """`work(job)` run once, in steps: work calls job.step("reading the data") before each
    stage, and on_step(job), if given, is called there (the import operator updates Blender's
    progress bar). Its result or error is kept (done, result, error).

    work may be a generator function: each value it yields is a started reader task (an
    io.isolation Request: poll, stage, cancel, value), and it is resumed with the task's value
    (or its error, raised at the yield) once the task is done. `run()` waits for each here;
    `start()` then `advance()` polls them without waiting; `cancel()` stops the task (its process
    is killed) and ends the job with isolation.ReadCancelled."""

    def __init__(self, work: Callable[["Job"], object], title: str, steps: int = 0,
                 on_step: Callable[["Job"], None] | None = None):
        self.work = work
        self.title = title
        self.steps = steps  # how many step() calls to expect (0: unknown), for "2/4" in the status
        self.on_step = on_step
        self.stage = "starting"
        self.step_index = 0
        self.result = None
        self.error: BaseException | None = None
        self.done = False
        self.cancelled = False
        self.waiting = None  # the reader task the work waits for
        self._steps = None  # the work's generator
        self._started = time.perf_counter()

    def run(self) -> "Job":
        """Start the job and wait here until it is done."""
        self.start()
        try:
            while not self.advance(0.1):
                pass
        except BaseException:  # KeyboardInterrupt: the reader must not outlive the wait
            self.cancel()
            raise
        return self

    def start(self) -> "Job":
        """Run the work up to the first reader task it waits for (or to its end)."""
        self._started = time.perf_counter()
        try:
            out = self.work(self)
        except Exception as exc:  # noqa: BLE001  (the operator reports it)
            return self._end(error=exc)
        if not inspect.isgenerator(out):
            return self._end(result=out)
        self._steps = out
        return self._resume(None, None)

    def advance(self, timeout: float = 0.0) -> bool:
        """Poll the reader task the work waits for (up to `timeout` seconds) and resume the work
        when it is done; True once the job is done."""
        if self.done:
            return True
        if not self.waiting.poll(timeout):
            return False
        try:
            value = self.waiting.value()
        except Exception as exc:  # noqa: BLE001  (raised in the work, at its yield)
            self._resume(None, exc)
        else:
            self._resume(value, None)
        return self.done

    def cancel(self):
        """Stop the reader task now (its process is killed) and end the job, cancelled."""
        if self.done:
            return
        self.cancelled = True
        waiting, self.waiting = self.waiting, None
        error = None
        if waiting is not None:
            waiting.cancel()
            try:
                waiting.value()
            except Exception as exc:  # noqa: BLE001  (isolation.ReadCancelled, or the read's own end)
                error = exc
        if self._steps is not None:
            self._steps.close()
        self._end(error=error or ReadCancelled(f"{self.title} was cancelled"))

    def _resume(self, value, error) -> "Job":
        try:
            self.waiting = self._steps.throw(error) if error is not None else self._steps.send(value)
        except StopIteration as stop:
            self._end(result=stop.value)
        except Exception as exc:  # noqa: BLE001  (the operator reports it)
            self._end(error=exc)
        return self

    def _end(self, result=None, error=None) -> "Job":
        self.result, self.error = result, error
        self.waiting = None
        self.done = True
        return self

    def step(self, stage: str):
        """Enter the next stage (its words for the status)."""
        self.stage = stage
        self.step_index += 1
        if self.on_step is not None:
            self.on_step(self)

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self._started

    def phase(self) -> str:
        """e.g. 'reading the data (2/4): reading flow.fld' (the reader's own stage after the
        colon, while the work waits for it)."""
        count = f" ({self.step_index}/{self.steps})" if self.steps else ""
        reader = getattr(self.waiting, "stage", "")
        return f"{self.stage}{count}{': ' + reader if reader else ''}"

    def status(self) -> str:
        """e.g. 'reading the data (2/4): reading flow.fld, 3.1 s'."""
        return f"{self.phase()}, {self.seconds:.1f} s"


class Listings:
    """What a dialog shows of a file (the fields of a solution, a mesh's composites), read by
    reader tasks (io.isolation requests) that draw() starts and never waits for, so browsing to
    a file the reader takes long over (or hangs on: libhdf5's loops) never holds Blender: get()
    answers PENDING until the task is done, and poll() (a timer's) says when one finished, for
    a redraw. One task of each kind at a time: a file browsed away from has its task cancelled.
    Answers are kept by the file's modification time; a failed listing is None."""

    PENDING = "pending"

    def __init__(self, size: int = 64):
        self.size = size
        self._done: dict = {}  # (kind, key) -> (stamp, value)
        self._pending: dict = {}  # kind -> (key, stamp, request, finish)

    def get(self, kind: str, key, stamp_path, start: Callable[[], object], finish: Callable = lambda v: v):
        """The listing of `key` (finish(the task's value)), PENDING while its task runs (start()
        starts it), or None when it failed or `stamp_path` is gone."""
        import os

        try:
            stamp = os.stat(stamp_path).st_mtime_ns
        except OSError:
            return None
        hit = self._done.get((kind, key))
        if hit is not None and hit[0] == stamp:
            return hit[1]
        pending = self._pending.get(kind)
        if pending is None or pending[:2] != (key, stamp):
            if pending is not None:
                pending[2].cancel()
            try:
                self._pending[kind] = (key, stamp, start(), finish)
            except Exception:  # noqa: BLE001  (the import itself says why)
                self._pending.pop(kind, None)
                return self._keep(kind, key, stamp, None)
        self.poll()
        hit = self._done.get((kind, key))
        return hit[1] if hit is not None and hit[0] == stamp else self.PENDING

    def poll(self) -> bool:
        """Read what the running tasks sent; True if one finished."""
        finished = False
        for kind, (key, stamp, request, finish) in list(self._pending.items()):
            if not request.poll(0.0):
                continue
            del self._pending[kind]
            try:
                value = finish(request.value())
            except Exception:  # noqa: BLE001  (the import itself says why)
                value = None
            self._keep(kind, key, stamp, value)
            finished = True
        return finished

    @property
    def waiting(self) -> bool:
        return bool(self._pending)

    def cancel(self):
        """Stop every running task (the add-on unregistering)."""
        for _, _, request, _ in self._pending.values():
            request.cancel()
        self._pending.clear()

    def _keep(self, kind, key, stamp, value):
        if len(self._done) >= self.size:
            self._done.clear()
        self._done[(kind, key)] = (stamp, value)
        return value


class CompiledKernels:
    """Render kernels compiled in this session, by key (device, precision, KernelVariant, opaque
    meshes, isosurfaces: kernel_key); `compile_key(key)` does the compiling (the core's load_kernels),
    `binaries(key)` says whether loading them compiles nothing (the add-on's compiled kernels or
    Warp's kernel cache hold every module) and whether the add-on ships any."""

    COMPILING = "Compiling render kernels (first use)"
    LOADING = "Loading compiled render kernels"
    NOT_SHIPPED = ("the render kernels of these volumes are not among the add-on's compiled kernels (built from "
                   "other kernel source, or for another GPU): compiling them once, tens of seconds on a CPU")

    def __init__(self, compile_key: Callable[[tuple], None], binaries: Callable[[tuple], tuple] | None = None):
        self.compile_key = compile_key
        self.binaries = binaries
        self._ready: set = set()

    def stage(self, key) -> tuple[str, str]:
        """(status text, note) before `key`'s kernels load: loading binaries (shipped or cached), or
        compiling, with a note to log where the add-on ships compiled kernels but not these."""
        compiles_nothing, any_shipped = self.binaries(key) if self.binaries else (False, False)
        if compiles_nothing:
            return self.LOADING, ""
        return self.COMPILING, self.NOT_SHIPPED if any_shipped else ""

    def is_ready(self, key) -> bool:
        return key in self._ready

    def mark_ready(self, key):
        self._ready.add(key)

    def compile_now(self, key) -> bool:
        """Compile `key` here unless it is ready; True if it compiled."""
        if self.is_ready(key):
            return False
        self.compile_key(key)
        self.mark_ready(key)
        return True


def kernel_key(device: str, precision: str, variant, surfaces: bool, isosurfaces: bool = False) -> tuple:
    """What a set of compiled render kernels is for: the scene's Device and Precision, the
    KernelVariant of its volumes (engine/kernel_loading.py), whether opaque meshes are cast and
    whether the look has isosurfaces or cut planes (their own integrate and shade)."""
    return (str(device), str(precision), variant, bool(surfaces), bool(isosurfaces))


def compile_render_kernels(key: tuple) -> None:
    """Compile (or load from Warp's disk cache) a kernel_key's kernels on its device's first
    device: a split device ("cpu:all", "cuda:all") renders in processes of its own, which then
    load the kernels from the disk cache instead of compiling them."""
    from ..engine.devices import expand_devices
    from ..engine.kernel_loading import load_kernels

    device, precision, variant, surfaces, isosurfaces = key
    load_kernels(variant, expand_devices(device)[0], precision, surfaces=surfaces, isosurfaces=isosurfaces)


def render_kernel_binaries(key: tuple) -> tuple[bool, bool]:
    """(loading a kernel_key's kernels compiles nothing: the add-on's compiled kernels or Warp's
    kernel cache hold every module, the add-on ships compiled kernels)."""
    from ..engine import shipped_kernels
    from ..engine.devices import expand_devices
    from ..engine.kernel_loading import session_kernels

    device, precision, variant, surfaces, isosurfaces = key
    pending = shipped_kernels.to_compile(session_kernels(variant, precision, surfaces, isosurfaces),
                                         expand_devices(device)[0])
    return not pending, shipped_kernels.store_dir().is_dir()


# What this Blender session has compiled (render.py asks before a render's first use)
KERNELS = CompiledKernels(compile_render_kernels, render_kernel_binaries)


class ProgressLines:
    """A few progress lines a frame for a log (Blender in background mode, like Cycles'): a line
    when the render has moved on by `step` (10 %) since the last, or, on a slow render, when
    `every_s` seconds have passed and it moved at all; the first and the last always."""

    def __init__(self, step: float = 0.1, every_s: float = 30.0, clock=time.monotonic):
        self.step, self.every_s, self.clock = step, every_s, clock
        self.fraction, self.time = None, clock()

    def due(self, fraction: float) -> bool:
        now = self.clock()
        if self.fraction is None or fraction >= 1.0 or fraction >= self.fraction + self.step or (
                fraction > self.fraction and now - self.time >= self.every_s):
            self.fraction, self.time = fraction, now
            return True
        return False
