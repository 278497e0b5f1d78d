"""The add-on's non-Blender work (hovr_blender/ui/jobs.py), without Blender: a Job's steps,
progress callback, result and error; a Job whose work waits for reader tasks, polled (the modal
import) or waited for, and cancelled; and the compiled-kernel registry compiling a key once."""
import os

import numpy as np
import pytest

from hovr_blender.engine.kernel_loading import KernelVariant
from hovr_blender.io import isolation
from hovr_blender.ui import jobs

from ..engine.test_shipped_kernels import SPHERE_VARIANT, store  # noqa: F401  (the store fixture)


def test_job_runs_in_steps_and_keeps_its_result():
    seen = []

    def work(job):
        job.step("one")
        job.step("two")
        return 42

    job = jobs.Job(work, "counting", steps=2, on_step=lambda j: seen.append(j.stage)).run()
    assert job.done and job.result == 42 and job.error is None
    assert seen == ["one", "two"] and job.step_index == 2 and job.status().startswith("two (2/2), ")


def test_job_keeps_the_error_for_the_operator():
    def work(job):
        job.step("reading")
        raise ValueError("bad file")

    job = jobs.Job(work, "failing").run()
    assert job.done and isinstance(job.error, ValueError) and job.result is None


class _Task:
    """A reader task (isolation.Request's interface) done after `polls` polls."""

    def __init__(self, value, polls=3, error=None):
        self.value_, self.polls, self.error = value, polls, error
        self.stage, self.cancelled = "starting the reader", False

    def poll(self, timeout=0.0):
        self.polls -= 1
        self.stage = "reading m.fld"
        return self.polls <= 0

    def cancel(self):
        self.cancelled = True

    def value(self):
        if self.cancelled:
            raise isolation.ReadCancelled("reading m.fld was cancelled")
        if self.error is not None:
            raise self.error
        return self.value_


def _reading(tasks, ended):
    def work(job):
        job.step("listing")
        names = yield tasks[0]
        job.step("reading")
        try:
            data = yield tasks[1]
        finally:
            ended.append(True)
        return names, data
    return work


def test_a_job_waiting_for_reader_tasks_is_polled_without_waiting():
    tasks, ended = [_Task(["p"]), _Task(np.arange(3), polls=2)], []
    job = jobs.Job(_reading(tasks, ended), "importing m.xml", steps=2).start()
    assert not job.done and job.waiting is tasks[0] and job.phase() == "listing (1/2): starting the reader"
    polls = 1
    while not job.advance(0.0):
        polls += 1
        assert job.phase().startswith(("listing (1/2): reading m.fld", "reading (2/2)"))
    assert polls == 5 and job.result[0] == ["p"] and list(job.result[1]) == [0, 1, 2] and ended == [True]
    assert job.waiting is None and job.phase() == "reading (2/2)"
    waited = jobs.Job(_reading([_Task(["p"]), _Task(1)], []), "importing m.xml").run()  # a script's: here, to the end
    assert waited.done and waited.result == (["p"], 1)


def test_a_reader_error_is_raised_in_the_work_at_its_yield():
    caught = []

    def work(job):
        try:
            yield _Task(None, error=ValueError("m.fld: damaged"))
        except ValueError as exc:
            caught.append(str(exc))
            raise
    job = jobs.Job(work, "importing").run()
    assert caught == ["m.fld: damaged"] and isinstance(job.error, ValueError) and job.done


def test_cancel_stops_the_reader_task_and_ends_the_work():
    tasks, ended = [_Task(["p"]), _Task(1, polls=10 ** 9)], []
    job = jobs.Job(_reading(tasks, ended), "importing m.xml").start()
    while job.waiting is not tasks[1]:
        job.advance()
    job.advance()
    job.cancel()
    assert tasks[1].cancelled and ended == [True] and job.done and job.cancelled
    assert isinstance(job.error, isolation.ReadCancelled) and job.result is None
    job.cancel()  # once done, nothing more
    assert job.advance() is True


def test_an_interrupted_wait_cancels_the_reader_task():
    class Interrupting(_Task):
        def poll(self, timeout=0.0):
            raise KeyboardInterrupt

    task = Interrupting(None)
    with pytest.raises(KeyboardInterrupt):
        jobs.Job(lambda job: (yield task), "importing").run()
    assert task.cancelled


def test_listings_never_wait_and_one_of_a_kind_runs_at_a_time(tmp_path):
    """The import dialog's listings (jobs.Listings): PENDING while the reader reads, the value once
    it has answered, a file browsed away from has its task cancelled, a changed file is listed
    again, a failure is None."""
    a, b = tmp_path / "a.fld", tmp_path / "b.fld"
    a.write_text("a")
    b.write_text("b")
    listings, started = jobs.Listings(), []

    def start(value, polls=2, error=None):
        def go():
            started.append(_Task(value, polls, error))
            return started[-1]
        return go

    assert listings.get("fields", str(a), a, start(["p"], polls=3)) is jobs.Listings.PENDING  # polled once
    assert listings.waiting and not listings.poll()
    assert listings.poll() and not listings.waiting
    assert listings.get("fields", str(a), a, start(["never"])) == ["p"] and len(started) == 1  # kept
    assert listings.get("fields", str(b), b, start(["q"], polls=10 ** 9)) is jobs.Listings.PENDING
    assert listings.get("walls", str(a), a, start([["C[1]", "C[1] wall"]]), lambda v: [tuple(c) for c in v]) \
        is jobs.Listings.PENDING  # another kind runs beside it
    assert listings.get("fields", str(a), a, start(["never"])) == ["p"]  # done ones need no task
    assert listings.poll() and listings.get("walls", str(a), a, start(None)) == [("C[1]", "C[1] wall")]
    os.utime(a, ns=(0, 10 ** 9))  # changed on disk: listed again, the other file's task cancelled
    assert listings.get("fields", str(a), a, start(None, polls=1, error=ValueError("damaged"))) is None
    assert started[1].cancelled and not listings.waiting
    assert listings.get("fields", str(tmp_path / "gone"), tmp_path / "gone", start(["x"])) is None

    def broken():
        raise OSError("no reader")
    assert listings.get("fields", str(b), b, broken) is None and not listings.waiting
    listings.get("fields", str(tmp_path), tmp_path, start(["x"], polls=10 ** 9))
    listings.cancel()
    assert started[-1].cancelled and not listings.waiting


def test_kernels_compile_once_per_key():
    compiled = []
    kernels = jobs.CompiledKernels(compiled.append)
    key = jobs.kernel_key("cpu", "float32", KernelVariant(True, 3), False)
    assert kernels.compile_now(key) and not kernels.compile_now(key)
    assert kernels.is_ready(key) and compiled == [key]
    other = jobs.kernel_key("cpu", "float64", KernelVariant(True, 3), False)
    assert not kernels.is_ready(other) and kernels.compile_now(other) and compiled == [key, other]


def test_the_compile_loads_what_the_render_launches():
    """The real compile (the core's load_kernels): afterwards every module the render launches is
    loaded on the device, and the kernel variant of two volumes is the merged renderer's."""
    from hovr_blender.engine.mesh import concatenate
    from hovr_blender.engine.kernel_loading import KernelVariant, kernel_variant, render_kernels
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.io import builtin, synthetic

    sphere, curved = builtin.sphere(), synthetic.curved_cube(2, modes=3)
    assert kernel_variant([sphere]) == Renderer(sphere, "cpu").kernel_variant == KernelVariant(False, 3, False)
    assert kernel_variant([sphere]).key == "affine:3"
    variant = kernel_variant([sphere, curved])
    assert variant.curved and Renderer(concatenate([sphere, curved]), "cpu").kernel_variant == variant
    kernels = jobs.CompiledKernels(jobs.compile_render_kernels)
    key = jobs.kernel_key("cpu", "float32", variant, False)
    assert kernels.compile_now(key) and kernels.is_ready(key)
    for kernel in render_kernels(variant, "float32"):
        assert kernel.module.execs, f"{kernel.key} not loaded"  # Warp's loaded module binaries


def test_a_look_with_isosurfaces_compiles_their_kernels_in_the_compile_stage():
    """Isosurfaces and cut planes have their own integrate and shade: their key is another key,
    and its compile loads those, so F12's first frame does not compile them inside the render."""
    from hovr_blender.engine.kernel_loading import KernelVariant, render_kernels

    variant = KernelVariant(False, 3, False)
    plain, iso = jobs.kernel_key("cpu", "float32", variant, False), jobs.kernel_key("cpu", "float32", variant, False, True)
    assert plain != iso
    kernels = jobs.CompiledKernels(jobs.compile_render_kernels)
    assert kernels.compile_now(iso) and not kernels.is_ready(plain)
    for kernel in render_kernels(variant, "float32", isosurfaces=True):
        assert kernel.module.execs, f"{kernel.key} not loaded"


def test_progress_lines_are_a_few_a_frame():
    """Issue 30: Blender 4.2 printed ~900 progress lines for one frame; a background render's log
    gets a line each 10 %, or each 30 s of a slow render, the first and the last."""
    from hovr_blender.ui.jobs import ProgressLines

    now = [0.0]
    lines = ProgressLines(clock=lambda: now[0])
    tiles = np.linspace(0.001, 1.0, 900)
    printed = [f for f in tiles if lines.due(f)]
    assert 10 <= len(printed) <= 12 and printed[0] == tiles[0] and printed[-1] == 1.0
    slow = ProgressLines(clock=lambda: now[0])
    shown = []
    for k, f in enumerate(np.linspace(0.001, 0.05, 50)):  # 5 % in 500 s: a line each 30 s
        now[0] = 10.0 * k
        shown += [f] if slow.due(f) else []
    assert 15 <= len(shown) <= 18


def test_per_face_warnings_are_summarised():
    """Issue 30: Womersley's 136 per-face notes (scaleHO's 4,676) become one line per kind, whole."""
    from hovr_blender.engine.words import summarise_warnings

    face = ("pipe.xml: curved triangle face {} (NodalTriElec, 15 points): interior point positions of this type are "
            "not reproduced; the face follows its edge curves only")
    warnings = [face.format(k) for k in (1, 102, 106, 109, 113, 120)] + ["|u|: magnitude fitted with 7 modes"]
    lines = summarise_warnings(warnings)
    assert lines == [face.format(1) + " (and 5 more faces like it: 102, 106, 109, 113, ...)",
                     "|u|: magnitude fitted with 7 modes"]
    assert summarise_warnings([f"kind {k}: x" for k in "abcdefg"], limit=3) == ["kind a: x", "kind b: x",
                                                                                 "5 more kinds of warning"]


def test_the_status_says_loading_or_compiling():
    """Issue 30: the first F12's status names what it waits for; issue 37: it says compiling, and
    where the add-on ships compiled kernels a note says these are not among them, only when
    something compiles (neither the add-on's kernels nor Warp's kernel cache hold them)."""
    key = jobs.kernel_key("cpu", "float32", (False, 3), False)
    assert jobs.CompiledKernels(print, lambda k: (True, True)).stage(key) == (jobs.CompiledKernels.LOADING, "")
    assert jobs.CompiledKernels(print, lambda k: (True, False)).stage(key) == (jobs.CompiledKernels.LOADING, "")
    assert jobs.CompiledKernels(print, lambda k: (False, True)).stage(key) == (jobs.CompiledKernels.COMPILING,
                                                                              jobs.CompiledKernels.NOT_SHIPPED)
    assert jobs.CompiledKernels(print, lambda k: (False, False)).stage(key) == (jobs.CompiledKernels.COMPILING, "")
    assert jobs.CompiledKernels(print).stage(key) == (jobs.CompiledKernels.COMPILING, "")


def test_blenders_first_f12_knows_whether_the_store_holds_its_kernels(store, tmp_path, monkeypatch):
    from hovr_blender.engine import shipped_kernels
    from hovr_blender.ui import jobs

    key = jobs.kernel_key("cpu", "float32", SPHERE_VARIANT, False)
    monkeypatch.setenv(shipped_kernels.STORE_ENV, str(store))
    assert jobs.render_kernel_binaries(key) == (True, True)
    monkeypatch.setenv(shipped_kernels.STORE_ENV, str(tmp_path))  # no store for this Warp
    assert jobs.render_kernel_binaries(key)[1] is False
