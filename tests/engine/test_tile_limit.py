"""Launch tiles follow the resource policy's memory limit (engine/limits.py): a render whose
one-tile buffers would exceed the limit is split into more tiles instead of being refused, and
the tiles do not change a pixel."""
import numpy as np

from hovr_blender.engine import limits
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import curved_cube

from ..helpers import COLORS, framing, tents


def test_tile_follows_memory_limit_and_keeps_pixels():
    mesh = curved_cube(2)
    cam = framing(mesh, 96, 64)
    v = mesh.field_samples(3)
    tf = tents(float(v.min()), float(v.max()), COLORS, 3.0)
    r = Renderer(mesh, "cpu")
    prec = r._upload("float32").precision
    whole = r.render(cam, tf, np.zeros(3), RenderOptions())
    small = limits.ResourceLimits(max_memory=int(6000 * r.tile_bytes_per_ray(prec)))  # tiles of ~3000 rays
    with limits.using(small):
        tile = r._tile_limit(prec)
        assert tile * r.tile_bytes_per_ray(prec) <= 0.5 * small.max_memory
        assert tile < cam.width * cam.height  # the 96x64 image takes several tiles
        tiled = r.render(cam, tf, np.zeros(3), RenderOptions())
    np.testing.assert_array_equal(tiled.rgba, whole.rgba)


def test_gpu_tiles_follow_device_memory_not_the_host_limit(monkeypatch):
    """On a GPU a launch tile's buffers are device memory: a 1920x1080 frame (~8 GB of them in
    float32) is one launch on a card with 40 GB free under the 4 GiB host limit, which still
    counts the image's own buffers and copies (a card stood in by its two properties)."""
    import warp as wp

    r = Renderer(curved_cube(1), "cpu")
    prec = r._upload("float32").precision
    ray_bytes = r.tile_bytes_per_ray(prec)

    class Card:
        is_cuda = True
        free_memory = 40 * 2**30

    monkeypatch.setattr(wp, "get_device", lambda *args: Card())
    with limits.using(limits.ResourceLimits(max_memory=4 * 2**30)):
        tile = r._tile_limit(prec)
        assert tile >= 1920 * 1080 > 4 * 2**30 / ray_bytes
        counted = r.check_limits(1920, 1080, RenderOptions(), tile)
    assert 0 < counted < 4 * 2**30 < tile * ray_bytes


def test_a_cpu_render_over_threads_is_the_one_thread_image():
    """A CPU render runs its tiles on cpu_threads threads (Warp's CPU launches run without Python's
    lock), each with launch buffers of its own: the image and the counts are the one thread's bit
    for bit; progress is reported as tiles finish, a False stops the tiles not started, and an
    error in one tile is the render's error."""
    import pytest

    from hovr_blender.engine.render_result import RenderError

    mesh = curved_cube(1)
    cam = framing(mesh, 128, 96)  # 12,288 rays: three threads of at least MIN_THREAD_RAYS
    v = mesh.field_samples(3)
    tf = tents(float(v.min()), float(v.max()), COLORS, 3.0)
    r = Renderer(mesh, "cpu")
    r.cpu_threads = 1
    one = r.render(cam, tf, np.zeros(3), RenderOptions())
    r.cpu_threads = 3
    assert r._threads_for(128 * 96) == 3
    threaded = r.render(cam, tf, np.zeros(3), RenderOptions())
    np.testing.assert_array_equal(threaded.rgba, one.rgba)
    np.testing.assert_array_equal(threaded.depth, one.depth)
    assert threaded.stats["field_evaluations"] == one.stats["field_evaluations"]
    seen = []
    tiled = r.render(cam, tf, np.zeros(3), RenderOptions(), progress=seen.append, tile_pixels=2048)
    assert len(seen) == 6 and seen == sorted(seen) and seen[-1] == 1.0 and not tiled.cancelled
    np.testing.assert_array_equal(tiled.rgba, one.rgba)
    stopped = r.render(cam, tf, np.zeros(3), RenderOptions(), progress=lambda f: False, tile_pixels=2048)
    empty = lambda res: int((res.rgba.reshape(-1, 4) == 0).all(axis=1).sum())
    assert stopped.cancelled and empty(stopped) > empty(one)  # the tiles not started are left empty
    calls = []
    trace = Renderer._trace_tile

    def fails_on_the_second_tile(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RenderError("the second tile failed")
        return trace(self, *args, **kwargs)

    Renderer._trace_tile = fails_on_the_second_tile
    try:
        with pytest.raises(RenderError, match="the second tile failed"):
            r.render(cam, tf, np.zeros(3), RenderOptions(), tile_pixels=2048, progress=lambda f: None)
    finally:
        Renderer._trace_tile = trace


def test_cpu_threads_follow_the_variable(monkeypatch):
    """HOVR_CPU_THREADS sets a CPU render's threads (1: one core); unset, every core this process
    may use; anything but a whole number of at least 1 is a one-line error naming it."""
    import pytest

    monkeypatch.delenv(limits.CPU_THREADS_VARIABLE, raising=False)
    assert limits.cpu_threads() == limits.cpu_cores()
    monkeypatch.setenv(limits.CPU_THREADS_VARIABLE, "1")
    assert limits.cpu_threads() == 1 and Renderer(curved_cube(1), "cpu").cpu_threads == 1
    monkeypatch.setenv(limits.CPU_THREADS_VARIABLE, "0")
    assert limits.cpu_threads() == 1
    monkeypatch.setenv(limits.CPU_THREADS_VARIABLE, "many")
    with pytest.raises(limits.ResourceLimitError, match=r"^HOVR_CPU_THREADS='many': a whole number of threads, 1 or more$"):
        limits.cpu_threads()
