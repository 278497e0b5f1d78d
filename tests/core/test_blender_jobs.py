"""The add-on's background work without Blender (hovr_blender/blender/jobs.py): a Job's steps,
result, error and cancel (a thread stuck in a Python loop is interrupted), the kernel warm-up
compiling each key once in its thread while a render waits for it, and the core's kernel
variant of several volumes being the merged renderer's."""
import threading
import time

from hovr_blender.blender import jobs


def test_job_runs_in_steps_and_keeps_its_result():
    def work(job):
        job.step("one")
        job.step("two")
        return 42

    job = jobs.Job(work, "counting", steps=2).run()
    assert job.done and job.result == 42 and job.error is None and not job.cancelled
    assert job.step_index == 2 and job.status().startswith("two (2/2), ")


def test_job_keeps_the_error_for_the_main_thread():
    def work(job):
        job.step("reading")
        raise ValueError("bad file")

    job = jobs.Job(work, "failing").start()
    assert job.wait(10)
    assert isinstance(job.error, ValueError) and job.result is None and not job.cancelled


def test_cancel_interrupts_a_thread_in_the_middle_of_python_work():
    """A read that never reaches its next step (a Python loop here) still stops: the thread is
    interrupted at its next instruction."""
    entered = threading.Event()

    def work(job):
        job.step("reading")
        entered.set()
        n = 0
        while True:  # no step() here: only the interrupt can end it
            n += 1

    job = jobs.Job(work, "endless").start()
    assert entered.wait(10)
    t0 = time.perf_counter()
    job.cancel()
    assert job.wait(10), "the interrupt did not stop the thread"
    assert job.cancelled and job.result is None and job.error is None
    assert time.perf_counter() - t0 < 5.0


def test_cancel_at_the_next_step_and_before_the_start():
    job = jobs.Job(lambda j: j.step("a"), "never")
    job.cancel()
    assert job.run().cancelled  # in the caller's thread: no interrupt, the first step stops it
    gate = threading.Event()

    def work(j):
        j.step("waiting")
        gate.wait(10)
        j.step("after")
        return "finished"

    job = jobs.Job(work, "gated").start()
    while job.stage != "waiting":
        time.sleep(0.01)
    job.cancel()
    gate.set()
    assert job.wait(10) and job.cancelled and job.result is None


def _counting_warmup(delay=0.0):
    compiled = []

    def compile_key(key):
        time.sleep(delay)
        compiled.append(key)

    return jobs.KernelWarmup(compile_key), compiled


def test_warmup_compiles_each_key_once_in_its_thread():
    warm, compiled = _counting_warmup(delay=0.3)
    a, b = jobs.kernel_key("cpu", "float32", (True, 0), False), jobs.kernel_key("cpu", "float64", (True, 0), False)
    warm.request(lambda: [a])
    warm.request(lambda: [a, b])  # queued behind the first: a is ready by then
    assert warm.busy and warm.status().startswith(("Reading volume data", "Compiling render kernels (first use)"))
    statuses = []
    assert warm.wait_idle(lambda s: statuses.append(s) or True, interval=0.05)
    assert compiled == [a, b] and warm.is_ready(a) and warm.is_ready(b)
    assert not warm.busy and warm.status() is None
    assert any(s.startswith("Compiling render kernels (first use)\u2026") for s in statuses)
    assert warm.compile_now(a) is False and compiled == [a, b]  # ready: nothing compiled again


def test_a_render_waiting_for_the_warmup_does_not_compile_again():
    warm, compiled = _counting_warmup(delay=0.5)
    key = jobs.kernel_key("cpu", "float32", (False, 3), False)
    warm.request(lambda: [key])
    time.sleep(0.1)
    assert warm.compile_now(key) is False  # waited for the thread's compile of the same key
    assert compiled == [key]


def test_a_cancelled_wait_returns_at_once_and_failures_are_kept():
    warm, _ = _counting_warmup(delay=1.0)
    warm.request(lambda: [("cpu", "float32", (False, 0), False)])
    t0 = time.perf_counter()
    assert warm.wait_idle(lambda s: False, interval=0.05) is False
    assert time.perf_counter() - t0 < 0.5
    assert warm.wait_idle()

    def unreadable():
        raise OSError("data file not found: x.vtu")

    warm.request(unreadable)
    assert warm.wait_idle() and isinstance(warm.errors[-1], OSError)


def test_the_background_compile_loads_what_the_render_launches():
    """The real compile (the core's load_kernels) in the warm-up's thread: afterwards every
    module the render launches is loaded on the device, and the kernel variant of two volumes
    is the merged renderer's."""
    from hovr_blender.core.mesh import concatenate
    from hovr_blender.core.renderer import Renderer, kernel_variant, render_kernels
    from hovr_blender.io import builtin, synthetic

    sphere, curved = builtin.sphere(), synthetic.curved_cube(2, modes=3)
    assert kernel_variant([sphere]) == Renderer(sphere, "cpu").kernel_variant == (False, 3)
    variant = kernel_variant([sphere, curved])
    assert variant[0] and Renderer(concatenate([sphere, curved]), "cpu").kernel_variant == variant
    warm = jobs.KernelWarmup(jobs.compile_render_kernels)
    key = jobs.kernel_key("cpu", "float32", variant, False)
    warm.request(lambda: [key])
    assert warm.wait_idle() and warm.is_ready(key) and warm.errors == []
    for kernel in render_kernels(variant, "float32"):
        assert kernel.module.execs, f"{kernel.key} not loaded"  # Warp's loaded module binaries
