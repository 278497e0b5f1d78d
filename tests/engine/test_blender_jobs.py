"""The add-on's non-Blender work (hovr_blender/ui/jobs.py), without Blender: a Job's steps,
progress callback, result and error, and the compiled-kernel registry compiling a key once."""
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
    assert kernel_variant([sphere]) == Renderer(sphere, "cpu").kernel_variant == (False, 3, False)
    variant = kernel_variant([sphere, curved])
    assert variant[0] and Renderer(concatenate([sphere, curved]), "cpu").kernel_variant == variant
    kernels = jobs.CompiledKernels(jobs.compile_render_kernels)
    key = jobs.kernel_key("cpu", "float32", variant, False)
    assert kernels.compile_now(key) and kernels.is_ready(key)
    for kernel in render_kernels(variant, "float32"):
        assert kernel.module.execs, f"{kernel.key} not loaded"  # Warp's loaded module binaries
