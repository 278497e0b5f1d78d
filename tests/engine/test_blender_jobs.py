"""The add-on's non-Blender work (hovr_blender/ui/jobs.py), without Blender: a Job's steps,
progress callback, result and error, and the compiled-kernel registry compiling a key once."""
import numpy as np

from hovr_blender.ui import jobs


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


def test_kernels_compile_once_per_key():
    compiled = []
    kernels = jobs.CompiledKernels(compiled.append)
    key = jobs.kernel_key("cpu", "float32", (True, 3), False)
    assert kernels.compile_now(key) and not kernels.compile_now(key)
    assert kernels.is_ready(key) and compiled == [key]
    other = jobs.kernel_key("cpu", "float64", (True, 3), False)
    assert not kernels.is_ready(other) and kernels.compile_now(other) and compiled == [key, other]


def test_the_compile_loads_what_the_render_launches():
    """The real compile (the core's load_kernels): afterwards every module the render launches is
    loaded on the device, and the kernel variant of two volumes is the merged renderer's."""
    from hovr_blender.engine.mesh import concatenate
    from hovr_blender.engine.renderer import Renderer, kernel_variant, render_kernels
    from hovr_blender.io import builtin, synthetic

    sphere, curved = builtin.sphere(), synthetic.curved_cube(2, modes=3)
    assert kernel_variant([sphere]) == Renderer(sphere, "cpu").kernel_variant == (False, 3)
    variant = kernel_variant([sphere, curved])
    assert variant[0] and Renderer(concatenate([sphere, curved]), "cpu").kernel_variant == variant
    kernels = jobs.CompiledKernels(jobs.compile_render_kernels)
    key = jobs.kernel_key("cpu", "float32", variant, False)
    assert kernels.compile_now(key) and kernels.is_ready(key)
    for kernel in render_kernels(variant, "float32"):
        assert kernel.module.execs, f"{kernel.key} not loaded"  # Warp's loaded module binaries


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
    from hovr_blender.ui.jobs import summarise_warnings

    face = ("pipe.xml: curved triangle face {} (NodalTriElec, 15 points): interior point positions of this type are "
            "not reproduced; the face follows its edge curves only")
    warnings = [face.format(k) for k in (1, 102, 106, 109, 113, 120)] + ["|u|: magnitude fitted with 7 modes"]
    lines = summarise_warnings(warnings)
    assert lines == [face.format(1) + " (and 5 more faces like it: 102, 106, 109, 113, ...)",
                     "|u|: magnitude fitted with 7 modes"]
    assert summarise_warnings([f"kind {k}: x" for k in "abcdefg"], limit=3) == ["kind a: x", "kind b: x",
                                                                                 "5 more kinds of warning"]


def test_the_status_says_loading_shipped_kernels_or_compiling():
    """Issue 30: the first F12's status names what it waits for, and where the add-on ships compiled
    kernels but not these (other kernel source, order or precision) a note says they compile."""
    key = jobs.kernel_key("cpu", "float32", (False, 3), False)
    assert jobs.CompiledKernels(print, lambda k: (True, True)).stage(key) == (jobs.CompiledKernels.LOADING, "")
    assert jobs.CompiledKernels(print, lambda k: (False, True)).stage(key) == (jobs.CompiledKernels.COMPILING,
                                                                              jobs.CompiledKernels.NOT_SHIPPED)
    assert jobs.CompiledKernels(print, lambda k: (False, False)).stage(key) == (jobs.CompiledKernels.COMPILING, "")
    assert jobs.CompiledKernels(print).stage(key) == (jobs.CompiledKernels.COMPILING, "")
