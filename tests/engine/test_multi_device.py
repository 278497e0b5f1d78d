"""One frame over several devices (issue 18), on CPU devices: rows split over processes give the
one-device image bit for bit; the sort-last split of the elements into slabs composites to the
one-device image within 1e-6 (engine/sort_last.py says why it is exact up to quadrature)."""
import dataclasses
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from hovr_blender.engine.mesh import subset
from hovr_blender.engine.multi_device import (MultiDeviceRenderer, balanced_rows, device_spread, prepass_camera,
                                              upsampled_rows)
from hovr_blender.engine.devices import expand_devices
from hovr_blender.engine.limits import cpu_cores
from hovr_blender.engine.render_result import RenderError
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.sort_last import SortLastRenderer, serves, slab_partition
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io import synthetic

from ..helpers import BACKGROUND, curved_mixed_scene, framing, mesh_bounds, tents

W, H = 32, 24


def test_balanced_rows_follow_cost_and_speed():
    cost = np.array([1.0] * 10 + [9.0] * 10)
    bands = balanced_rows(cost, [1.0, 1.0])
    assert bands[0][0] == 0 and bands[-1][1] == 20 and bands[0][1] == bands[1][0]
    assert 10 < bands[0][1] < 20  # the cheap rows all go to the first device
    assert balanced_rows(np.ones(3), [1, 1, 1, 1]) == [(0, 1), (1, 2), (2, 3)]  # a row each, at most
    fast_first = balanced_rows(np.ones(30), [3.0, 1.0])
    assert fast_first[0] == (0, 22) or fast_first[0] == (0, 23)


def test_upsampled_rows_take_the_prepass_row_of_their_centre():
    assert upsampled_rows([1.0, 2.0, 3.0], 6).tolist() == [1, 1, 2, 2, 3, 3]
    assert upsampled_rows([1.0, 2.0], 5).tolist() == [1, 1, 2, 2, 2]  # row 2's centre, 2.5 of 5, is in the second
    assert upsampled_rows([7.0], 4).tolist() == [7] * 4


@pytest.mark.parametrize("size", [(64, 48), (70, 45), (5, 3)])
def test_prepass_camera_sees_the_frame_view_at_a_smaller_size(size):
    """The pre-pass's rays are the frame's rays at the same fractions of the image, also where the
    rounded size changes the aspect ratio."""
    mesh, _, camera = curved_mixed_scene(1)
    cam = camera(*size)
    low = prepass_camera(cam, 8)
    w, h = int(low.width), int(low.height)
    assert (w, h) == (-(-size[0] // 8), -(-size[1] // 8))
    _, d = low.rays()
    fx, fy = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
    u, v = (2 * fx - 1) * cam.width / cam.height, 1 - 2 * fy  # the frame's uv at those fractions
    ref = cam.d0 + u[..., None] * cam.du + v[..., None] * cam.dv
    assert np.allclose(d, ref / np.linalg.norm(ref, axis=-1, keepdims=True), atol=1e-12)


def test_device_spread_is_the_slowest_over_the_fastest():
    s = device_spread([1.0, 1.1, 1.05])
    assert s["device_spread"] == pytest.approx(0.1) and s["device_balance"] == pytest.approx(1.05 / 1.1)
    assert device_spread([2.0])["device_spread"] == 0.0


def _band_balance(row_cost, bands):
    c = np.array([row_cost[a:b].sum() for a, b in bands])
    return c.mean() / c.max()


def test_rows_of_a_frame_over_two_cpu_processes_equal_one_device():
    """The first frame is split by a pre-pass, the next by its row costs, another first frame in
    equal rows: each image is the one device's bit for bit. The view puts the mesh in the image's
    upper part, where equal rows would leave one device most of the work: the pre-pass's bands
    carry about equal costs, and the stats say how the frame was split and the devices' spread."""
    mesh, tf, camera = curved_mixed_scene(2)
    centred = camera(W, H)
    cam = dataclasses.replace(centred, d0=centred.d0 - 0.45 * centred.dv)  # the mesh moves up the image
    opts = RenderOptions()
    # the one-device image from a process started like the split's: the host-side set-up (numpy's
    # BLAS) can round differently with another thread count, and a LocalCluster started earlier in
    # this process (tests/distributed) leaves OPENBLAS_NUM_THREADS=1 for the processes started after it
    with MultiDeviceRenderer(mesh, ["cpu"]) as one:
        whole = one.render(cam, tf, BACKGROUND, opts)
        assert whole.stats["split_by"] == "equal rows" and whole.stats["prepass_seconds"] == 0.0
    equal = _band_balance(whole.row_cost, balanced_rows(np.ones(H), [1, 1]))
    assert equal < 0.75  # the scene is one where the split matters
    with MultiDeviceRenderer(mesh, "cpu,cpu") as md:
        splits = []
        for _ in range(2):  # the second frame is split by the first one's row costs
            split = md.render(cam, tf, BACKGROUND, opts)
            assert np.array_equal(split.rgba, whole.rgba)
            assert [d["rows"] for d in split.stats["devices"]][0][0] == 0
            splits.append(split.stats)
        assert split.stats["field_evaluations"] == whole.stats["field_evaluations"]
        md.reset_split()
        md.prepass_scale = 0
        plain = md.render(cam, tf, BACKGROUND, opts)
        assert np.array_equal(plain.rgba, whole.rgba)
    first, second = splits
    assert first["split_by"] == "pre-pass" and 0.0 < first["prepass_seconds"] < first["render_seconds"]
    assert second["split_by"] == "previous frame" and second["prepass_seconds"] == 0.0
    assert plain.stats["split_by"] == "equal rows"
    assert [d["rows"] for d in plain.stats["devices"]] == [[0, H // 2], [H // 2, H]]
    assert _band_balance(whole.row_cost, [d["rows"] for d in first["devices"]]) > 0.85
    for stats in (*splits, plain.stats):
        assert stats["device_spread"] == device_spread([d["render_seconds"] for d in stats["devices"]])["device_spread"]


def test_device_set_up_loads_the_frame_kernels_once_before_any_frame():
    """Each device's process uploads the mesh and loads the kernels of the renderer's precision
    when it starts (MultiDeviceRenderer.setup says what each cost), not in the first frame."""
    from hovr_blender.engine.kernel_loading import render_kernels

    mesh, _, _ = curved_mixed_scene(1)
    with MultiDeviceRenderer(mesh, "cpu,cpu") as md:
        needed = {k.module.name for k in render_kernels(md.kernel_variant, "float32")}
        for p, report in zip(md._procs, md.setup["devices"]):
            assert needed <= set(p.setup["kernel_modules"])
            assert report["kernel_seconds"] > 0.0 and report["upload_seconds"] > 0.0
        assert md.setup["precision"] == "float32" and md.setup["seconds"] > 0.0


def test_cpu_all_is_one_cpu_device_a_core():
    assert expand_devices("cpu:all") == ["cpu"] * cpu_cores()
    assert expand_devices("cpu, cpu") == ["cpu", "cpu"]
    with pytest.raises(RenderError):
        expand_devices("")


def test_subset_keeps_each_element():
    mesh = synthetic.mixed_cube(2, 3, synthetic.cube_field)
    part = subset(mesh, [3, 0, 7])
    assert part.num_elements == 3
    for k, e in enumerate([3, 0, 7]):
        assert np.array_equal(part.element_coeffs(k), mesh.element_coeffs(e))
        assert np.array_equal(part.vertices[k], mesh.vertices[e])


def test_slab_partition_covers_every_element():
    mesh = synthetic.curved_cube(3, 4)
    planes, parts = slab_partition(mesh, [1.0, 0.3, 0.2] / np.linalg.norm([1.0, 0.3, 0.2]), 2)
    assert len(planes) == 1 and len(parts) == 2
    assert set(np.concatenate(parts)) == set(range(mesh.num_elements))
    assert all(len(p) < mesh.num_elements for p in parts)


@pytest.mark.parametrize("scene,processes", [("curved", True), ("mixed", False)])
def test_sort_last_over_two_cpu_devices_equals_one_device(scene, processes):
    if scene == "curved":
        mesh = synthetic.curved_cube(3, 4)
    else:
        mesh = synthetic.mixed_cube(3, 4, synthetic.cube_field)
    lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
    tf = tents(lo, hi, [(0.9, 0.3, 0.1), (0.2, 0.8, 0.3), (0.1, 0.3, 0.9)], 6.0)
    cam = framing(mesh, W, H, direction=(1.0, -0.7, 0.5))
    opts = RenderOptions.pixel_exact()
    if processes:  # the one-device image from a process started like the parts' (see the test above)
        with MultiDeviceRenderer(mesh, ["cpu"]) as one:
            whole = one.render(cam, tf, BACKGROUND, opts)
    else:
        whole = Renderer(mesh, "cpu").render(cam, tf, BACKGROUND, opts)
    with SortLastRenderer(mesh, ["cpu", "cpu"], processes=processes) as sl:
        part = sl.render(cam, tf, BACKGROUND, opts)
        assert len(sl.part_elements) == 2 and max(sl.part_elements) < mesh.num_elements
        assert serves(sl.axis, cam)
    assert whole.rgba[..., 3].max() > 0.5  # the scene is not empty
    assert np.abs(part.rgba.astype(np.float64) - whole.rgba).max() <= 1e-6


def test_sort_last_repartitions_for_a_camera_behind():
    mesh, tf, camera = curved_mixed_scene(2)
    cam = camera(16, 12)
    lo, hi = mesh_bounds(mesh)
    back = framing(mesh, 16, 12, direction=(-1.0, 0.8, -0.7))
    sl = SortLastRenderer(mesh, ["cpu", "cpu"], processes=False)
    sl.render(cam, tf, BACKGROUND, RenderOptions())
    axis = sl.axis.copy()
    assert not serves(axis, back)
    sl.render(back, tf, BACKGROUND, RenderOptions())
    assert np.dot(axis, sl.axis) < 0


def _segments():
    return set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()


@pytest.mark.skipif(not os.path.isdir("/dev/shm"), reason="POSIX shared memory in /dev/shm")
def test_split_frame_shared_memory_is_unlinked_once_every_process_has_it():
    """The shared image's name goes as soon as both device processes have it open: the block
    serves every later frame of its size and nothing stays in /dev/shm, whatever happens next."""
    mesh, tf, camera = curved_mixed_scene(2)
    md = MultiDeviceRenderer(mesh, "cpu,cpu")
    try:
        first = md.render(camera(16, 12), tf, BACKGROUND, RenderOptions())
        shared = md._shared
        assert shared.name.lstrip("/") not in _segments()
        again = md.render(camera(16, 12), tf, BACKGROUND, RenderOptions())
        assert md._shared is shared and np.array_equal(first.rgba, again.rgba)
        second = md.render(camera(W, H), tf, BACKGROUND, RenderOptions())  # another size: another block
        assert md._shared is not shared and md._shared.name.lstrip("/") not in _segments()
        assert first.rgba.shape == (12, 16, 4) and second.rgba.shape == (H, W, 4)
        # the results are the caller's own arrays, not views of the shared image
        third = md.render(camera(W, H), tf, BACKGROUND, RenderOptions(method="classified", h=0.05))
        assert not np.shares_memory(second.rgba, third.rgba) and not np.array_equal(second.rgba, third.rgba)
        # a device's process dies: the frame fails, the renderer still closes its memory
        md._procs[1]._proc.kill()
        md._procs[1]._proc.join()
        with pytest.raises(RenderError, match="ended unexpectedly"):
            md.render(camera(W, H), tf, BACKGROUND, RenderOptions())
    finally:
        md.close()


@pytest.mark.skipif(not os.path.isdir("/dev/shm"), reason="POSIX shared memory in /dev/shm")
def test_split_frame_processes_and_memory_go_with_a_killed_parent():
    """SIGKILL of the parent: its device processes end (each watches its parent) and no block is
    left in /dev/shm; SIGKILL of the whole process group leaves none either (issue 29)."""
    script = (
        "import os, sys, time\n"
        "sys.path.insert(0, %r)\n"
        "from tests.helpers import BACKGROUND, curved_mixed_scene\n"
        "from hovr_blender.engine.multi_device import MultiDeviceRenderer\n"
        "from hovr_blender.engine.view import RenderOptions\n"
        "if __name__ == '__main__':\n"
        "    mesh, tf, camera = curved_mixed_scene(2)\n"
        "    md = MultiDeviceRenderer(mesh, 'cpu,cpu')\n"
        "    md.render(camera(16, 12), tf, BACKGROUND, RenderOptions())\n"
        "    print(md._shared.name, *[p._proc.pid for p in md._procs], flush=True)\n"
        "    time.sleep(600)\n") % os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    import signal

    for group in (False, True):
        proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)
        try:
            name, *pids = proc.stdout.readline().split()
            assert name and len(pids) == 2, proc.stderr.read() if proc.poll() is not None else ""
            assert name.lstrip("/") not in _segments()
            if group:
                os.killpg(proc.pid, signal.SIGKILL)
            else:
                os.kill(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
            deadline = time.monotonic() + 10
            while any(_alive(int(p)) for p in pids) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert not any(_alive(int(p)) for p in pids)
            assert name.lstrip("/") not in _segments()
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)


def _alive(pid: int) -> bool:
    """Whether `pid` runs (not a zombie)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


_SCRIPT_WITHOUT_MAIN_GUARD = r"""
import json, sys
sys.path.insert(0, {repo!r})
with open({runs!r}, "a") as fh:
    fh.write("run\n")  # a device's process that re-ran this script would add a line
from hovr_blender.engine.bootstrap import import_package
ext = "fake_bl_ext.user_repo.hovr_blender"  # the package under an installed extension's kind of name
import_package(ext, {repo!r} + "/hovr_blender")
import importlib
md = importlib.import_module(ext + ".engine.multi_device")
synthetic = importlib.import_module(ext + ".io.synthetic")
view = importlib.import_module(ext + ".engine.view")
camera = importlib.import_module(ext + ".engine.camera")
tf = importlib.import_module(ext + ".engine.transfer_function")
mesh = synthetic.brick((0, 0, 0), (1, 1, 1), (2, 2, 2), 3, lambda x, y, z: x + y * z)
cam = camera.RayCamera.from_contract({{"eye": [2.6, -2.1, 1.8], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1],
                                      "fov_y_deg": 30.0}}, 16, 12)
ramp = tf.TransferFunction.from_rgba_ramp([0.0, 1.0], [(0, 0, 1, 0), (1, 0.5, 0, 1)], 4.0, 0.0, 2.0)
images = {{}}
for devices in (["cpu"], ["cpu", "cpu"]):
    with md.MultiDeviceRenderer(mesh, devices) as r:
        images[len(devices)] = r.render(cam, ramp, (0, 0, 0), view.RenderOptions()).rgba
print(json.dumps({{"equal": bool((images[1] == images[2]).all()), "alpha": float(images[1][..., 3].max()),
                  "mesh_class": type(mesh).__module__}}))
"""


def test_device_processes_neither_rerun_the_script_nor_need_the_package_on_sys_path(tmp_path):
    """Issue 30: the parent's script has no main guard (a device's process that re-ran it would
    start processes of its own and count a second run) and its package is imported under a name
    no folder on sys.path gives (as Blender's bl_ext.<repo>.hovr_blender): the split frame still
    equals the one-device frame, and the script ran once."""
    from ..helpers import REPO

    script = tmp_path / "user_script.py"
    runs = tmp_path / "runs.txt"
    script.write_text(_SCRIPT_WITHOUT_MAIN_GUARD.format(repo=str(REPO), runs=str(runs)))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    import json

    out = json.loads(proc.stdout.splitlines()[-1])
    assert out["mesh_class"].startswith("fake_bl_ext.user_repo.hovr_blender.")
    assert out["equal"] and out["alpha"] > 0.05
    assert runs.read_text().splitlines() == ["run"]


def test_a_device_process_that_cannot_import_the_package_says_so():
    """A failure before the device's loop (here, the package's folder missing) is answered on the
    pipe at once, in words, instead of leaving the parent waiting."""
    import multiprocessing

    from hovr_blender.engine.bootstrap import start_device

    parent, child = multiprocessing.Pipe()
    start_device(child, "nowhere_ext.repo.hovr_blender", "/nonexistent/hovr_blender", b"")
    kind, message = parent.recv()
    assert kind == "error" and message.startswith("cannot import nowhere_ext.repo.hovr_blender in a device process")
    assert "nowhere_ext.repo.hovr_blender" not in sys.modules


def test_a_device_process_that_dies_at_start_is_reported_within_seconds(monkeypatch):
    """A process that ends before it answers (here its payload cannot be unpickled) fails the
    start-up with an error, not a wait."""
    from hovr_blender.engine import multi_device

    mesh, _, _ = curved_mixed_scene(1)
    monkeypatch.setattr(multi_device.pickle, "dumps", lambda *a, **k: b"not a pickle")
    t0 = time.monotonic()
    with pytest.raises(RenderError, match="cpu: UnpicklingError"):
        multi_device.start_processes([mesh], ["cpu"])
    assert time.monotonic() - t0 < 60


def test_a_frame_a_renderer_cannot_draw_is_refused_in_one_line():
    """The door (engine/frame.py) asks each renderer's capabilities: the sort-last renderer (which
    draws the volume alone) refuses isosurfaces, planes and opaque meshes before it renders; a
    device list draws them all; a segment cache is only saved work, so a renderer that keeps none
    renders the frame plainly."""
    from hovr_blender.engine.frame import Capability, Frame, SegmentSlot, UnsupportedFrame, render_frame
    from hovr_blender.engine.isosurfaces import Isosurface, Surfaces
    from hovr_blender.engine.opaque import OpaqueMesh, OpaqueScene

    mesh, tf, camera = curved_mixed_scene(2)
    cam = camera(16, 12)
    lo, hi = np.percentile(mesh.field_samples(3), [10, 90])
    iso = Frame(tf, BACKGROUND, RenderOptions(), surfaces=Surfaces((Isosurface(0.5 * (lo + hi), (1, 1, 0)),)))
    assert {Capability.OPAQUE, Capability.SURFACES} <= MultiDeviceRenderer.capabilities
    assert Renderer.capabilities == frozenset(Capability)
    plane = OpaqueScene([OpaqueMesh([[-1, -1, 0.5], [2, -1, 0.5], [2, 2, 0.5]], [[0, 1, 2]])])
    sl = SortLastRenderer(mesh, ["cpu", "cpu"], processes=False)
    for frame in (iso, iso.with_(surfaces=None, opaque=plane)):
        with pytest.raises(UnsupportedFrame, match="sort-last"):
            render_frame(sl, frame, cam)
    with pytest.raises(UnsupportedFrame, match="a band of rows"):
        render_frame(sl, iso.with_(surfaces=None), cam, rows=(0, 4))
    slot = SegmentSlot()
    plain = render_frame(sl, iso.with_(surfaces=None, cache=slot), cam)
    assert slot.cache is None
    np.testing.assert_array_equal(plain.rgba, sl.render(cam, tf, BACKGROUND, RenderOptions()).rgba)


def test_isosurfaces_and_planes_over_two_cpu_processes_equal_one_device():
    """All CPU Cores draws a frame's isosurfaces and cut planes: each device's rows carry them, so
    the image is the one device's bit for bit, rendered plainly and traced then shaded from kept
    segments (a look-only edit moves the isosurface's colour); an isosurface no ray meets is said
    once, of the whole image, as on one device."""
    from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame
    from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, Surfaces

    mesh, tf, camera = curved_mixed_scene(2)
    cam = camera(W, H)
    lo, hi = np.percentile(mesh.field_samples(3), [10, 90])
    centre = 0.5 * (np.asarray(mesh_bounds(mesh)[0]) + np.asarray(mesh_bounds(mesh)[1]))
    surfaces = Surfaces((Isosurface(0.5 * (lo + hi), (1.0, 0.8, 0.2), opacity=0.7),),
                        (CutPlane.through(centre, (0.3, 1.0, 0.2), opacity=0.5, clip=1),))
    recoloured = Surfaces((dataclasses.replace(surfaces.isosurfaces[0], color=(0.2, 0.4, 1.0)),), surfaces.planes)
    frames = [Frame(tf, BACKGROUND, RenderOptions(), surfaces=s) for s in (surfaces, recoloured)]
    outside = Frame(tf, BACKGROUND, RenderOptions(),
                    surfaces=Surfaces((Isosurface(float(mesh.field_samples(3).max()) + 1.0, (1, 0, 0)),)))
    said = Renderer(mesh, "cpu").surface_misses(cam, outside.surfaces)
    assert len(said) == 1
    images = {}
    for devices in (["cpu"], "cpu,cpu"):  # the one device started like the split's (the test above says why)
        with MultiDeviceRenderer(mesh, devices) as md:
            slot = SegmentSlot()
            got = [render_frame(md, f, cam) for f in frames]
            got += [render_frame(md, f.with_(cache=slot), cam) for f in frames]
            images[len(md.devices)] = got
            assert [r.stats["segment_cache"]["use"] for r in got[2:]] == ["traced", "shaded"]
            assert md.surface_misses(cam, outside.surfaces) == said
    for one, split in zip(images[1], images[2]):
        assert np.array_equal(one.rgba, split.rgba)
    plain = render_frame(Renderer(mesh, "cpu"), Frame(tf, BACKGROUND, RenderOptions()), cam)
    assert not np.array_equal(images[2][0].rgba, plain.rgba)  # the surfaces are in the image
    assert not np.array_equal(images[2][0].rgba, images[2][1].rgba)  # and the edit changed them


def test_a_first_frame_with_an_opaque_mesh_is_split_by_a_prepass_that_stops_at_it():
    """The pre-pass of a frame with opaque meshes samples their hits (surface_t) at its pixels;
    the split image equals the one device's bit for bit."""
    from hovr_blender.engine.frame import Frame, render_frame
    from hovr_blender.engine.opaque import OpaqueMesh, OpaqueScene

    mesh, tf, camera = curved_mixed_scene(2)
    cam = camera(W, H)
    plane = OpaqueScene([OpaqueMesh([[-1, -1, 0.5], [2, -1, 0.5], [2, 2, 0.5]], [[0, 1, 2]])])
    frame = Frame(tf, BACKGROUND, RenderOptions(), opaque=plane)
    with MultiDeviceRenderer(mesh, ["cpu"]) as one:
        whole = render_frame(one, frame, cam)
    with MultiDeviceRenderer(mesh, "cpu,cpu") as md:
        split = render_frame(md, frame, cam)
    assert split.stats["split_by"] == "pre-pass"
    assert np.array_equal(split.rgba, whole.rgba)
    t = plane.cast(cam).t
    assert np.isfinite(t).mean() > 0.2 and not np.isfinite(t).all()  # the plane stops some rays, not all


def test_a_look_only_edit_over_two_cpu_processes_shades_the_kept_segments():
    """Issue 40: All CPU Cores keeps each band's segments in its process; the next frame with only
    the look changed is shaded where they are (no field evaluated), equal to the one device's shade
    of the same segments; its stats say what was done; a dropped cache is dropped by the devices."""
    from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame
    from hovr_blender.engine.segment_cache import SegmentCache

    mesh, tf, camera = curved_mixed_scene(2)
    cam = camera(W, H)
    recoloured = type(tf)(tf.color_s, tf.color_rgb[::-1].copy(), tf.density_s, 1.5 * tf.density_tau)
    one_slot, slot = SegmentSlot(), SegmentSlot()
    with MultiDeviceRenderer(mesh, ["cpu"]) as one:  # started like the split's (as the test above says)
        first_one = render_frame(one, Frame(tf, BACKGROUND, RenderOptions(), cache=one_slot), cam)
        again_one = render_frame(one, Frame(recoloured, BACKGROUND, RenderOptions(), cache=one_slot), cam)
    with MultiDeviceRenderer(mesh, "cpu,cpu") as md:
        first = render_frame(md, Frame(tf, BACKGROUND, RenderOptions(), cache=slot), cam)
        assert first.stats["segment_cache"]["use"] == "traced" and first.stats["field_evaluations"] > 0
        assert first.stats["segment_cache"]["devices"] == 2 and not isinstance(slot.cache, SegmentCache)
        again = render_frame(md, Frame(recoloured, BACKGROUND, RenderOptions(), cache=slot), cam)
        assert again.stats["segment_cache"]["use"] == "shaded" and again.stats["field_evaluations"] == 0
        for split, whole in ((first, first_one), (again, again_one)):
            assert np.array_equal(split.rgba, whole.rgba)
        assert again.stats["segments"] == again_one.stats["segments"] > 0
        old = slot.cache.id
        slot.cache = None  # the caller lets go of it: the devices drop it with their next request
        md.render(cam, tf, BACKGROUND, RenderOptions())
        assert md._dropped == [] and old not in [c.id for c in [slot.cache] if c is not None]


def test_a_first_traced_frame_is_split_by_the_prepass_and_its_costs_split_the_next_trace():
    """A first F12 over the devices keeps segments (trace): its bands come from the pre-pass, as a
    render's would, and the image equals the one device's; the next trace of that height splits
    by the pre-pass's costs without another pre-pass (a trace measures none)."""
    from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame

    mesh, tf, camera = curved_mixed_scene(2)
    centred = camera(W, H)
    cam = dataclasses.replace(centred, d0=centred.d0 - 0.45 * centred.dv)  # as in the render test above
    with MultiDeviceRenderer(mesh, ["cpu"]) as one:
        whole = render_frame(one, Frame(tf, BACKGROUND, RenderOptions(), cache=SegmentSlot()), cam)
    with MultiDeviceRenderer(mesh, "cpu,cpu") as md:
        first = render_frame(md, Frame(tf, BACKGROUND, RenderOptions(), cache=SegmentSlot()), cam)
        again = render_frame(md, Frame(tf, BACKGROUND, RenderOptions(), cache=SegmentSlot()), cam)
    assert np.array_equal(first.rgba, whole.rgba) and np.array_equal(again.rgba, whole.rgba)
    traced, retraced = first.stats["segment_cache"], again.stats["segment_cache"]
    assert traced["use"] == retraced["use"] == "traced"
    assert traced["split_by"] == "pre-pass" and traced["prepass_seconds"] > 0.0
    assert retraced["split_by"] == "previous frame" and retraced["prepass_seconds"] == 0.0
    assert traced["device_spread"] >= 0.0
