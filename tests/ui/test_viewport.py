"""The progressive viewport scheduler (engine/viewport.py) without Blender: its frames,
resolutions, time per call, restarts, and that it ends at the F12 image of the same view."""
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.frame import Frame
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.ui.viewport import (
    MAX_PREVIEW_SCALE, ProgressiveViewport, ViewportRequest, preview_camera, preview_options,
)
from hovr_blender.io import builtin

CONTRACT = {"eye": [4.0, 3.0, 3.5], "target": [0.0, 0.0, 0.5], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}
TF = TransferFunction.from_rgba_ramp([0.0, 0.125, 0.25, 0.5, 1.0],
                                     [(1, 0.8, 0.2, 0.5), (1, 0.5, 0.2, 1), (0.2, 1, 0.4, 0.3), (1, 0.2, 0.5, 0), (0, 0, 0, 0)],
                                     2.0, 0.0, 2.0)
BG = np.array([0.0625, 0.03125, 0.125])


def request(w=96, h=64, tf=TF, method="split", film_transparent=False):
    cam = RayCamera.from_contract(CONTRACT, w, h)
    return ViewportRequest(cam, Frame(tf, BG, RenderOptions(method=method, h=0.01, tolerance=1e-6)), film_transparent,
                           ("sphere",))


@pytest.fixture(scope="module")
def renderer():
    return Renderer(builtin.sphere(), "cpu")


@pytest.mark.parametrize("scale", [1, 3, 5])
def test_preview_pixels_are_the_centres_of_full_resolution_blocks(scale):
    cam = RayCamera.from_contract(CONTRACT, 31, 20)  # not multiples of the scale: padded blocks
    small = preview_camera(cam, scale)
    assert (small.width, small.height) == (-(-31 // scale), -(-20 // scale))
    o, d = cam.rays()
    so, sd = small.rays()
    c = scale // 2  # odd scales: the block centre is a full-resolution pixel
    for j in range(small.height):
        for i in range(small.width):
            y, x = j * scale + c, i * scale + c
            if y < 20 and x < 31:
                np.testing.assert_allclose(sd[j, i], d[y, x], atol=1e-12)
                np.testing.assert_allclose(so[j, i], o[y, x], atol=1e-12)


def test_preview_options_are_looser_but_valid():
    o = RenderOptions(method="split", h=0.01, tolerance=1e-6)
    p = preview_options(o)
    assert p.tolerance == pytest.approx(1e-4) and p.h == 0.02 and p.method == "split"
    assert preview_options(RenderOptions(tolerance=1e-2)).tolerance == 1e-2  # never tighter
    assert preview_options(RenderOptions()).h is None  # classified's own steps stay its own


def test_progressive_frames_end_at_the_full_render(renderer):
    req = request()
    vp = ProgressiveViewport(first_frame_seconds=0.1)
    assert vp.sync(renderer, req) is True and vp.stage == "preview"
    assert vp.status_text().startswith("HOVR | preview")
    steps, t_steps, said = 0, [], set()
    while not vp.converged:
        t0 = time.perf_counter()
        vp.step(0.05)
        t_steps.append(time.perf_counter() - t0)
        said.add(vp.status_text())
        steps += 1
        if steps == 1:
            assert vp.display is not None  # something to show after the first call
            assert vp.log[0].kind == "preview" and vp.log[0].scale > 1 and vp.stage in ("refining", "converged")
        assert steps < 500
    assert vp.display.shape == (64, 96, 4) and vp.display.dtype == np.float32
    assert vp.status_text() == "HOVR | done"
    assert all(t == "HOVR | done" or t.startswith("HOVR | refining ") and t.endswith("%") for t in said)
    want = renderer.render(req.camera, TF, BG, req.options).rgba[::-1]  # bottom row first
    np.testing.assert_allclose(vp.display[..., :3], want[..., :3], atol=1e-5)
    np.testing.assert_array_equal(vp.display[..., 3], 1.0)  # opaque film, as F12
    # (the preview's lower resolution is asserted above; how much of the final image the first
    # call already holds depends on the machine's speed, so its pixels are not compared)
    bands = [r for r in vp.log if r.kind == "band"]
    rows = sorted(r.rows for r in bands)
    assert rows[0][0] == 0 and all(a[0] + a[1] == b[0] for a, b in zip(rows, rows[1:]))  # bands tile the region
    assert rows[-1][0] + rows[-1][1] == 64
    print(f"viewport 96x64 split: preview {vp.log[0].seconds * 1000:.1f} ms at 1/{vp.log[0].scale}, "
          f"{len(bands)} bands, {steps} calls, slowest call {max(t_steps) * 1000:.1f} ms")
    # wall-time budgets are checked deterministically with a fake clock below (not here:
    # a loaded CI machine would make a timed assertion flaky)
    assert vp.step(0.05) is False  # converged: no more work, no redraw needed


def test_restarts_on_change_and_learns_the_preview_scale(renderer):
    vp = ProgressiveViewport(first_frame_seconds=0.05)
    req = request()
    vp.sync(renderer, req)
    vp.step(0.02)
    v = vp.version
    assert vp.sync(renderer, request()) is False and vp.version == v  # same view: keep going
    tf2 = TransferFunction(TF.color_s, TF.color_rgb, TF.density_s, TF.density_tau * 2)
    for changed in (request(tf=tf2), request(w=97), request(method="trapezoid"), request(film_transparent=True)):
        assert vp.sync(renderer, changed) is True
        assert vp.display is None and not vp.converged and vp.stage == "preview"
        vp.step(0.02)
        assert vp.display is not None and vp.display.shape[:2] == (64, changed.camera.width)
    # a first frame per restart: a preview, or for the look-only change (tf2) with every band
    # already cached, the region shaded from the caches
    firsts = [r for r in vp.log if r.kind in ("preview", "reshade")]
    assert len(firsts) == 5 and vp.restarts == 5
    # the preview's resolution comes from the measured cost (timed with a fake clock below)
    assert all(r.scale >= 1 for r in firsts)


class FakeRenderer:
    """Costs `cost` fake seconds per pixel, checks progress per tile like Renderer.render."""

    capabilities = frozenset()  # a plain image (engine/frame.py)
    kind = "as a fake"

    def __init__(self, clock, cost):
        self.clock, self.cost, self.calls = clock, cost, []

    def render(self, camera, tf, bg, options, progress=None, tile_pixels=None):
        n = camera.width * camera.height
        self.calls.append((camera.width, camera.height, options.tolerance))
        done, cancelled = 0, False
        while done < n:
            k = min(tile_pixels, n - done)
            self.clock.t += k * self.cost
            done += k
            if progress(done / n) is False and done < n:
                cancelled = True
                break
        img = np.full((camera.height, camera.width, 4), 0.5, np.float32)
        return SimpleNamespace(rgba=img, cancelled=cancelled, stats={})


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_overruns_shrink_the_work_instead_of_blocking():
    clock = Clock()
    fake = FakeRenderer(clock, cost=1e-3)  # 1 ms per pixel: a 200x100 region takes 20 s in full
    vp = ProgressiveViewport(first_frame_seconds=0.1, clock=clock)
    vp.sync(fake, request(200, 100))
    t0 = clock.t
    vp.step(0.05)
    # first guess too fine: cancelled at the 0.2 s deadline, then the scale doubles next call
    assert vp.log[0].kind == "preview-overrun" and clock.t - t0 <= 0.2 + 256e-3
    while vp.display is None:
        vp.step(0.05)
    ok = [r for r in vp.log if r.kind == "preview"][0]
    assert ok.scale > vp.log[0].scale and ok.seconds <= 0.2 + 256e-3
    # refinement: every call stays near the budget (one tile of slack)
    for _ in range(50):
        t0 = clock.t
        vp.step(0.05)
        assert clock.t - t0 <= 0.05 + 0.256 + 1e-9
    assert 0 < vp.progress() < 1 and not vp.converged
    assert max(w * h for w, h, _ in fake.calls[len([r for r in vp.log if r.kind.startswith("preview")]):]) <= 2 * 200


def test_preview_at_maximum_scale_always_finishes():
    clock = Clock()
    fake = FakeRenderer(clock, cost=1e-2)  # absurdly expensive: even 1/16 takes 80 s, still a frame
    vp = ProgressiveViewport(first_frame_seconds=0.1, clock=clock)
    vp.sync(fake, request(2048, 1024))
    for calls in range(1, 10):
        vp.step(0.05)
        if vp.display is not None:
            break
    scales = [r.scale for r in vp.log]
    assert vp.display is not None and vp.log[-1].kind == "preview" and vp.log[-1].scale == MAX_PREVIEW_SCALE
    assert scales == sorted(scales) and calls <= 5 and vp.display.shape == (1024, 2048, 4)


def converge(vp, budget=0.05):
    for _ in range(500):
        if vp.converged:
            return
        vp.step(budget)
    raise AssertionError("the viewport did not converge")


def test_a_look_change_is_shaded_from_the_bands_caches(renderer):
    """After the view converged, an edit of the look alone (colours, density, background,
    tolerance) is shaded from the bands' cached segments: the whole region at full resolution as
    the first frame, no trace and no preview, equal to F12 of the new look. A change of the view
    drops the caches."""
    vp = ProgressiveViewport(first_frame_seconds=10.0)  # room for the region at once on any machine
    vp.sync(renderer, request())
    converge(vp)
    caches = dict(vp._caches)
    assert caches and sum(rows for rows, _ in caches.values()) == 64  # every band kept its segments
    looks = [TransferFunction(TF.color_s, TF.color_rgb[::-1], TF.density_s, TF.density_tau * 3.0),
             TransferFunction(TF.color_s, TF.color_rgb, TF.density_s, TF.density_tau * 0.25)]
    for tf in looks:
        base = request(tf=tf)
        req = replace(base, frame=base.frame.with_(background=np.array([0.5, 0.25, 0.0]),
                                                   options=RenderOptions(method="split", tolerance=1e-5)))
        assert vp.sync(renderer, req) is True
        n = len(vp.log)
        assert vp.step(0.05) is True and vp.converged
        assert [r.kind for r in vp.log[n:]] == ["reshade"]
        assert all(vp._caches[y][1] is c for y, (_, c) in caches.items())  # shaded, not traced again
        want = renderer.render(req.camera, tf, req.frame.background, req.options).rgba[::-1]
        np.testing.assert_allclose(vp.display[..., :3], want[..., :3], atol=1e-5)
    vp.sync(renderer, request(w=97))
    assert vp._caches == {}
    n = len(vp.log)
    vp.step(0.05)
    assert vp.log[n].kind.startswith("preview")


def test_a_look_change_mid_refinement_shades_the_cached_bands(renderer):
    """Before convergence only some bands have caches: the look change starts with a preview, the
    cached bands are shaded again (same rows), the rest traced; the end is F12 of the new look."""
    vp = ProgressiveViewport(first_frame_seconds=0.05)
    vp.sync(renderer, request())
    while not vp._caches or vp.converged:
        if vp.converged:
            vp.sync(renderer, request(method="classified"))  # a fresh start with fewer bands done
        vp.step(0.01)
    first = dict(vp._caches)
    tf = TransferFunction(TF.color_s, TF.color_rgb, TF.density_s, TF.density_tau * 2.0)
    req = request(tf=tf, method=vp._request.options.method)
    vp.sync(renderer, req)
    n = len(vp.log)
    converge(vp)
    assert vp.log[n].kind == "preview"
    assert all(vp._caches[y][1] is c for y, (_, c) in first.items())
    want = renderer.render(req.camera, tf, BG, req.options).rgba[::-1]
    np.testing.assert_allclose(vp.display[..., :3], want[..., :3], atol=1e-5)


def test_caches_the_memory_limit_refuses_are_not_kept(renderer, monkeypatch):
    """Every band's render fits the limit, no band's cache does (its smallest arrays are made
    larger than the limit): the first band's trace is refused, the view's later bands do not try
    again; they render plainly, keep nothing, and the image is the same."""
    from hovr_blender.engine import limits
    from hovr_blender.engine import segment_cache

    vp = ProgressiveViewport(first_frame_seconds=0.05)
    image = renderer.check_limits(96, 64, RenderOptions(method="split"), 96 * 64)
    monkeypatch.setattr(segment_cache, "CACHE_MIN_SEGMENTS", image // 8)
    traces, trace = [], Renderer.trace
    monkeypatch.setattr(Renderer, "trace", lambda self, *a, **k: traces.append(1) or trace(self, *a, **k))
    with limits.using(limits.ResourceLimits(max_memory=image)):
        vp.sync(renderer, request())
        converge(vp)
    assert vp._caches == {} and vp._cache_refused and len(traces) == 1
    assert len([r for r in vp.log if r.kind == "band"]) > 1
    want = renderer.render(vp._request.camera, TF, BG, vp._request.options).rgba[::-1]
    np.testing.assert_allclose(vp.display[..., :3], want[..., :3], atol=1e-5)


def test_viewport_with_opaque_meshes_ends_at_the_f12_picture(renderer):
    """The progressive viewport (previews, then bands of rows: sub-cameras, each cast against the
    surfaces itself) ends at the door's whole image, as F12 shows it."""
    from hovr_blender.engine.opaque import OpaqueScene

    from ..engine import test_opaque as op

    camera = RayCamera.from_contract(op.CAMERAS["perspective"], op.W, op.H)
    opts = RenderOptions(method="split", tolerance=1e-6, device="cpu")
    scene = OpaqueScene([op.plane_mesh()])
    req = ViewportRequest(camera, Frame(op.TF, op.BACKGROUND, opts, opaque=scene), False, ("sphere", "plane"))
    vp = ProgressiveViewport(first_frame_seconds=0.05)
    vp.sync(renderer, req)
    for _ in range(500):
        if vp.converged:
            break
        vp.step(0.05)
    assert vp.converged
    want = op.opaque_render(renderer, scene, camera, opts).rgba[::-1]
    np.testing.assert_allclose(vp.display[..., :3], want[..., :3], atol=1e-5)
    np.testing.assert_array_equal(vp.display[..., 3], 1.0)  # an opaque film, as F12
