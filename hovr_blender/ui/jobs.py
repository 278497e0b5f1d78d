"""The add-on's work that is not Blender's, without bpy (tested without Blender).

- `Job`: an import's reading in named steps, with its progress in words, run in the calling
  (main) thread. Nothing runs in a background thread: Blender supports Python threads only
  when they finish before the script that started them does ("Troubleshooting Errors &
  Crashes" in Blender's Python API manual), and a read or a kernel compile left running in a
  thread crashed Blender 3.4 in the window test (a segfault inside numpy, then inside Warp's
  code generation, 1 run in 3).
- `CompiledKernels`: the render kernels compiled in this session, by (device, precision,
  kernel variant, surfaces), so a render says "compiling (first use)" only when it does.
"""
from __future__ import annotations

import time
from typing import Callable


class Job:
    """`work(job)` run once, in steps: work calls job.step("reading the data") before each
    stage, and on_step(job), if given, is called there (the import operator updates Blender's
    progress bar). Its result or error is kept (done, result, error)."""

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
        self._started = time.perf_counter()

    def run(self) -> "Job":
        self._started = time.perf_counter()
        try:
            self.result = self.work(self)
        except Exception as exc:  # noqa: BLE001  (the operator reports it)
            self.error = exc
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

    def status(self) -> str:
        """e.g. 'reading the data (2/4), 3.1 s'."""
        count = f" ({self.step_index}/{self.steps})" if self.steps else ""
        return f"{self.stage}{count}, {self.seconds:.1f} s"


class CompiledKernels:
    """Render kernels compiled in this session, by key (device, precision, kernel variant,
    surfaces); `compile_key(key)` does the compiling (the core's load_kernels)."""

    COMPILING = "Compiling render kernels (first use)"

    def __init__(self, compile_key: Callable[[tuple], None]):
        self.compile_key = compile_key
        self._ready: set = set()

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


def kernel_key(device: str, precision: str, variant: tuple, surfaces: bool) -> tuple:
    """What a set of compiled render kernels is for: the scene's Device and Precision, the
    kernel variant of its volumes (engine.renderer.kernel_variant) and whether surfaces are cast."""
    return (str(device), str(precision), tuple(variant), bool(surfaces))


def compile_render_kernels(key: tuple) -> None:
    """Compile (or load from Warp's disk cache) a kernel_key's kernels on its device's first
    device: a split device ("cpu:all", "cuda:all") renders in processes of its own, which then
    load the kernels from the disk cache instead of compiling them."""
    from ..engine.renderer import expand_devices, load_kernels

    device, precision, variant, surfaces = key
    load_kernels(variant, expand_devices(device)[0], precision, surfaces=surfaces)


# What this Blender session has compiled (render.py asks before a render's first use)
KERNELS = CompiledKernels(compile_render_kernels)
