"""F12 details beyond the Combined image: Depth and HOVR Error passes through the compositor,
render border and crop, clip start/end, progress/stats and cancellation latency."""
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import compat  # noqa: E402
from hovr_blender.ui import engine as render_engine  # noqa: E402
from hovr_blender.ui.blender_camera import ray_camera_from_blender  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.engine.view import RenderOptions  # noqa: E402
from hovr_blender.io import builtin  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import render_to_exr  # noqa: E402


def compositor_output(scene, output):
    """Route a Render Layers output to the compositor's result (what F12 then saves)."""
    tree, image = compat.new_compositor(scene, "HOVR test compositor")
    rl = tree.nodes.new("CompositorNodeRLayers")
    tree.links.new(rl.outputs[output], image)
    return rl


def depth_by_dense_sampling(camera, i, j):
    """Independent of the kernels: march pixel (i, j)'s ray in numpy (object space field,
    fine trapezoid optical depth) to where T = 0.5; return the view-axis distance."""
    o, d = camera.rays()
    o, d = o[j, i], d[j, i]
    t = np.linspace(0.0, 20.0, 400001)
    x = o + t[:, None] * d
    inv = np.linalg.inv(SPHERE.object_matrix())
    xo = x @ inv[:3, :3].T + inv[:3, 3]
    lo, hi = builtin.sphere().vertices[0].min(axis=0), builtin.sphere().vertices[0].max(axis=0)
    inside = np.all((xo >= lo) & (xo <= hi), axis=1)
    tf = TransferFunction.from_rgba_ramp([p for p, _ in SPHERE.STOPS], [c for _, c in SPHERE.STOPS], SPHERE.DENSITY_SCALE,
                                         *SPHERE.VALUE_RANGE)
    tau = np.where(inside, tf.density(builtin.sphere_field(*xo.T)), 0.0)
    od = np.concatenate([[0.0], np.cumsum(0.5 * (tau[1:] + tau[:-1]) * np.diff(t))])
    k = np.searchsorted(od, np.log(2.0))
    assert k < t.size, "the ray never reaches 50% opacity"
    return t[k] * float(d @ np.asarray(camera.extra["forward"]))


def test_passes_reach_the_compositor_only_when_enabled(scene):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    tree, _image = compat.new_compositor(scene, "c")
    rl = tree.nodes.new("CompositorNodeRLayers")
    enabled = lambda: {o.name for o in rl.outputs if o.enabled}
    assert "Image" in enabled() and "Depth" not in enabled() and "HOVR Error" not in enabled()
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.hovr.use_pass_error = True
    assert {"Depth", "HOVR Error"} <= enabled()
    vl.hovr.use_pass_error = False
    assert "HOVR Error" not in enabled()


def test_depth_pass_is_the_view_depth_at_half_opacity(scene, tmp_path):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    scene.view_layers[0].use_pass_z = True
    compositor_output(scene, "Depth")
    z = render_to_exr(scene, tmp_path / "z.exr")[..., 0]  # rows from the top
    rgba = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    hit = rgba[..., 3] >= 0.5
    assert 10 < hit.sum() < hit.size
    cam = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    np.testing.assert_allclose(z[~hit], scene.camera.data.clip_end)  # no 50% crossing: the far clip
    js, is_ = np.nonzero(hit)
    for k in np.linspace(0, js.size - 1, 6).astype(int):
        j, i = js[k], is_[k]
        assert z[j, i] == pytest.approx(depth_by_dense_sampling(cam, i, j), abs=2e-3), (i, j)


@pytest.mark.parametrize("method", ["split", "trapezoid"])
def test_error_pass_is_the_core_estimate(scene, tmp_path, method):
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE, method=method)
    scene.view_layers[0].hovr.use_pass_error = True
    compositor_output(scene, "HOVR Error")
    err = render_to_exr(scene, tmp_path / "e.exr")[..., 0]
    cam = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    tf = TransferFunction.from_rgba_ramp([p for p, _ in SPHERE.STOPS], [c for _, c in SPHERE.STOPS], SPHERE.DENSITY_SCALE,
                                         *SPHERE.VALUE_RANGE)
    # the object's own (float32) transform: the estimate sums accepted Gauss-Kronrod panels, and
    # a transform off in the 8th digit can accept a panel one subdivision sooner somewhere
    res = Renderer(builtin.sphere().transformed(np.array(obj.matrix_world)), "cpu").render(
        cam, tf, np.array(SPHERE.BACKGROUND), RenderOptions(method=method, h=0.01, tolerance=1e-6))
    np.testing.assert_array_equal(err, res.error)
    if method == "split":  # adaptive Gauss-Kronrod: positive estimates, only where the volume is
        assert err.max() > 0 and np.all(err >= 0) and np.all(err[res.rgba[..., 3] == 0] == 0)
    else:  # a fixed-step rule gives no estimate
        assert np.all(err == 0)


@pytest.mark.parametrize("crop", [False, True])
def test_render_border_renders_only_the_border(scene, tmp_path, crop):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    full = render_to_exr(scene, tmp_path / "full.exr")
    r = scene.render
    r.use_border, r.use_crop_to_border = True, crop
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.26, 0.71, 0.1, 0.55
    got = render_to_exr(scene, tmp_path / "border.exr")
    x0, x1, y0, y1 = 16, 45, 4, 26  # int(0.26*64), int(0.71*64), int(0.1*48), int(0.55*48): from the bottom
    rows = slice(SPHERE.H - y1, SPHERE.H - y0)  # the same rows counted from the top
    if crop:
        assert got.shape == (y1 - y0, x1 - x0, 4)
        np.testing.assert_allclose(got, full[rows, x0:x1], atol=1e-5)
    else:
        assert got.shape == full.shape
        np.testing.assert_allclose(got[rows, x0:x1], full[rows, x0:x1], atol=1e-5)
        outside = np.ones(full.shape[:2], bool)
        outside[rows, x0:x1] = False
        assert np.all(got[outside] == 0)  # nothing rendered outside the border
    assert full[rows, x0:x1, :3].std() > 1e-3  # the border holds part of the volume


def test_clip_start_and_end(scene, tmp_path):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    full = render_to_exr(scene, tmp_path / "a.exr")
    j, i = SPHERE.H // 2, SPHERE.W // 2
    cam = scene.camera.data
    cam.clip_start = 20.0  # beyond the volume: only the world colour is left
    assert np.abs(render_to_exr(scene, tmp_path / "b.exr")[..., :3] - SPHERE.BACKGROUND).max() < 1e-6
    cam.clip_start, cam.clip_end = 0.1, 1.0  # before the volume
    assert np.abs(render_to_exr(scene, tmp_path / "c.exr")[..., :3] - SPHERE.BACKGROUND).max() < 1e-6
    cam.clip_end = 5.2  # through the middle of the volume: less of it on the central ray
    mid = render_to_exr(scene, tmp_path / "d.exr")
    assert np.abs(mid[j, i, :3] - full[j, i, :3]).max() > 1e-3


class _Recorder:
    """Wraps the engine: records progress and stats, and says "stop" once asked to."""

    def __init__(self, engine, calls):
        self._engine, self._calls = engine, calls

    def update_progress(self, f):
        self._calls["progress"].append(f)
        self._engine.update_progress(f)

    def update_stats(self, a, b):
        self._calls["stats"].append(b)
        self._engine.update_stats(a, b)

    def report(self, kind, msg):
        self._calls.setdefault("reports", []).append((set(kind), msg))
        self._engine.report(kind, msg)

    def test_break(self):
        c = self._calls
        if c["cancel_after"] is not None and len(c["progress"]) >= c["cancel_after"] and c["break_at"] is None:
            c["break_at"] = time.perf_counter()
        return c["break_at"] is not None or self._engine.test_break()


def test_progress_stats_and_cancel_latency(scene, tmp_path, monkeypatch):
    """test_break() is polled from the renderer's progress callback after every tile; once it
    says stop, render() returns within 0.5 s and writes no result."""
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE, method="split")
    scene.hovr.tolerance = 1e-8
    scene.render.resolution_x, scene.render.resolution_y = 4 * SPHERE.W, 4 * SPHERE.H
    calls = {"progress": [], "stats": [], "break_at": None, "cancel_after": None, "end": None}
    monkeypatch.setattr(render_engine, "_engine_api", lambda engine: _Recorder(engine, calls))
    bpy.ops.render.render(write_still=False)
    p = calls["progress"]
    assert len(p) > 4 and p == sorted(p) and p[-1] == 1.0
    final = calls["stats"][-1]
    assert "1 element" in final and "samples/ray" in final and " s on cpu" in final, final
    assert any("%" in s for s in calls["stats"])  # progress shown while rendering

    calls.update(progress=[], stats=[], cancel_after=3)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    t1 = time.perf_counter()
    latency = t1 - calls["break_at"]
    print(f"cancel latency {latency * 1000:.1f} ms after {len(calls['progress'])} tiles; "
          f"cancelled render {t1 - t0:.2f} s in all")
    assert latency < 0.5 and max(calls["progress"]) < 0.5 and calls["stats"][-1] == "HOVR | cancelled"


def test_a_transfer_function_float32_cannot_resolve_is_reported(scene, tmp_path, monkeypatch):
    """The renderer's precision warning (engine/field_frame.py) reaches the user as a WARNING
    report of F12; the image is still written."""
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE, method="split")
    obj.hovr.value_min, obj.hovr.value_max = 5.0, 5.000001
    calls = {"progress": [], "stats": [], "break_at": None, "cancel_after": None, "end": None}
    monkeypatch.setattr(render_engine, "_engine_api", lambda engine: _Recorder(engine, calls))
    bpy.ops.render.render(write_still=False)
    warned = [m for kind, m in calls.get("reports", []) if kind == {'WARNING'} and "float64" in m]
    assert len(warned) == 1 and warned[0].startswith("HOVR: float32 rounds the field")
    assert calls["progress"][-1] == 1.0


def test_legend_in_render_is_composited_on_the_combined_pass(scene, tmp_path):
    """Issue 30, 40: Legend in Render (off by default) draws engine/legend.py's layout onto F12's
    Combined pass with numpy alone, so on every Blender (4.2 has no Pillow) it is the CLI's legend
    to the pixel: the bar's colours exactly, the values and field name as text; nothing else in the
    image changes."""
    from hovr_blender.engine.legend import draw_legend
    from hovr_blender.ui.legend_overlay import scene_legend

    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    scene.render.resolution_percentage = 400  # 256 x 192: room for the legend's text
    assert scene.hovr.legend_in_render is False
    plain = render_to_exr(scene, tmp_path / "plain.exr")
    scene.hovr.legend_in_render = True
    drawn = render_to_exr(scene, tmp_path / "legend.exr")
    H, W = plain.shape[:2]
    legend = scene_legend(scene, bpy.context.view_layer, W, H, scene.world.color)
    x0, y0, x1, y1 = legend.bar
    np.testing.assert_allclose(drawn[y0:y1, x0:x1, :3], np.broadcast_to(legend.bar_rgb[:, None, :], (y1 - y0, x1 - x0, 3)),
                               atol=1e-6)
    changed = np.abs(drawn - plain).max(axis=2) > 1e-6
    changed[y0:y1, x0:x1] = False
    ys, xs = np.nonzero(changed)
    assert len(xs) > 50, "no text drawn"
    left_of_bar = changed[y0:y1, :x0]
    assert left_of_bar.sum() > 20 and changed[:y0].sum() > 10  # the values beside the bar, the name above it
    assert xs.min() > W // 3 and ys.max() < y1 + legend.font_px  # the legend's corner only
    np.testing.assert_allclose(drawn, draw_legend(plain, legend), atol=1e-6)  # the CLI's drawing
