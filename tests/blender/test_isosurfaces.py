"""Isosurfaces and cut planes in Blender (contract §7, ui/surface_panels.py): F12 of a volume with
an isosurface and a clipping plane object equals `hovr render`, a render-series frame and
render-blend of the same view (the one door, engine/frame.py); moving the
plane object restarts the viewport, which converges to the moved cut; the settings survive
save and reload; the field chooser lists the derived fields of a file."""
import json
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import render, snapshot  # noqa: E402
from hovr_blender.ui.viewport import ProgressiveViewport  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import read_image, render_to_exr  # noqa: E402
from .test_viewport import camera_view  # noqa: E402

ISO = {"value": 1.5, "color": [1.0, 0.75, 0.25], "opacity": 0.75}
PLANE_LOCATION, PLANE_TILT = (0.125, 0.25, 0.5), 0.5  # the plane's normal: +Z turned about x


def _plane_object(scene, name="Cut"):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    obj.location, obj.rotation_euler = PLANE_LOCATION, (PLANE_TILT, 0.0, 0.0)
    return obj


def _scene_with_surfaces(scene):
    """SPHERE's scene with the volume at the origin (a view file has no object transform), an
    isosurface and a plane object clipping the front."""
    vol = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    vol.location, vol.rotation_euler = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    iso = vol.hovr_surfaces.isosurfaces.add()
    iso.value, iso.color, iso.opacity = ISO["value"], ISO["color"], ISO["opacity"]
    plane = _plane_object(scene)
    item = vol.hovr_surfaces.planes.add()
    item.object, item.opacity, item.clip = plane, 0.5, "front"
    return vol, plane


def _view_file(path, plane):
    """The contract's view of _scene_with_surfaces: ramp stops as value lists, the plane from its object."""
    lo, hi = SPHERE.VALUE_RANGE
    view = {"data": {"builtin": "sphere"}, "camera": SPHERE.PERSPECTIVE,
            "image": {"width": SPHERE.W, "height": SPHERE.H},
            "transfer_function": {
                "color": [[lo + p * (hi - lo), *c[:3]] for p, c in SPHERE.STOPS],
                "density": [[lo + p * (hi - lo), c[3] * SPHERE.DENSITY_SCALE] for p, c in SPHERE.STOPS]},
            "background": list(SPHERE.BACKGROUND),
            "render": {"method": "classified", "h": 0.01, "tolerance": 1e-6, "device": "cpu"},
            "isosurfaces": [ISO],
            "planes": [{"point": list(plane.matrix_world.translation),
                        "normal": list(plane.matrix_world.to_3x3().col[2]), "opacity": 0.5, "clip": "front"}]}
    path.write_text(json.dumps(view))
    return path


@pytest.mark.slow
def test_one_door_every_path_draws_the_same_view(scene, tmp_path):
    """One view with an isosurface and a clipping plane, through every way in (engine/frame.py's
    render_frame behind each): `hovr render`, a render-series frame (distributed/series.py, as a
    Dask worker runs it), F12 here, and render-blend's headless Blender of the saved .blend
    (distributed/blender_frames.py, ui/batch.py). The series frame is the CLI's image bit for bit,
    render-blend is F12's; F12 differs from the CLI only where Blender's float32 camera and plane
    move a ray across an edge."""
    import sys

    from hovr_blender import cli
    from hovr_blender.distributed import blender_frames, series

    _vol, plane = _scene_with_surfaces(scene)
    got = render_to_exr(scene, tmp_path / "f12.exr")  # first: the plane's matrix_world is evaluated now
    view = _view_file(tmp_path / "view.json", plane)
    out = tmp_path / "cli.npy"
    assert cli.main(["render", str(view), "-o", str(out)]) == 0
    want = np.load(out)
    job = series.SeriesJob(view=str(view), frames=[1], output=str(tmp_path / "series_####.npy"), device="cpu")
    assert series.write_frame(job, 1)["status"] == "written"
    np.testing.assert_array_equal(np.load(tmp_path / "series_0001.npy"), want)  # isosurfaces and planes too
    scene.render.filepath = "//blend_####.exr"  # render-blend's frame 1: blend_0001.exr beside the .blend
    blend = tmp_path / "door.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    record = blender_frames.render_blend_frame(str(blend), 1, python=sys.executable)
    assert record["status"] == "written", record
    np.testing.assert_array_equal(read_image(record["output"]), got)
    assert want.shape == got.shape == (SPHERE.H, SPHERE.W, 4)
    covered = want[..., 3] > 0.74  # the isosurface (alpha 0.75) and the plane cover part of the frame
    assert 0.05 < covered.mean() < 0.95
    # Blender keeps the camera and the plane in float32 (the view file: float64): a ray beside the
    # isosurface's or the plane's edge may fall on the other side; everywhere else the same image
    diff = np.abs(got[..., :3] - want[..., :3]).max(axis=-1)
    assert np.median(diff) < 1e-5 and (diff > 1e-3).mean() < 0.02, (np.median(diff), (diff > 1e-3).mean())


def test_f12_over_every_cpu_core_draws_the_isosurface_and_plane(scene, tmp_path):
    """Device "All CPU Cores" draws the look's isosurface and clipping plane (each process's rows
    carry them): the one-core F12 bit for bit; before, the frame was refused."""
    from hovr_blender.ui import render

    vol, _plane = _scene_with_surfaces(scene)
    one = render_to_exr(scene, tmp_path / "one.exr")
    scene.hovr.device = "cpu:all"
    try:
        every = render_to_exr(scene, tmp_path / "all.exr")
    finally:
        render.clear_cache()  # closes the processes
        scene.hovr.device = "cpu"
    np.testing.assert_array_equal(every, one)
    vol.hovr_surfaces.isosurfaces.clear()
    vol.hovr_surfaces.planes.clear()
    plain = render_to_exr(scene, tmp_path / "plain.exr")
    assert (np.abs(plain - one).max(axis=-1) > 0.05).mean() > 0.05  # the isosurface and the plane are drawn


def test_moving_the_plane_object_rerenders_the_cut(scene):
    _vol, plane = _scene_with_surfaces(scene)
    ctx = camera_view(scene, 32, 24)
    state = ProgressiveViewport()

    def converge():
        for _ in range(400):
            frame = render.viewport_step(state, ctx, bpy.context.evaluated_depsgraph_get())
            if frame.converged:
                return frame.pixels.copy()
        raise AssertionError("the viewport did not converge")

    before = converge()
    restarts = state.restarts
    plane.location.z -= 0.5
    bpy.context.view_layer.update()
    after = converge()
    assert state.restarts == restarts + 1
    assert np.abs(after - before).max() > 0.05  # the cut moved


def test_settings_survive_save_and_reload(scene, tmp_path):
    name = _scene_with_surfaces(scene)[0].name
    path = tmp_path / "surfaces.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    vol = bpy.data.objects[name]
    iso, item = vol.hovr_surfaces.isosurfaces[0], vol.hovr_surfaces.planes[0]
    assert (iso.value, tuple(iso.color), iso.opacity) == (ISO["value"], tuple(ISO["color"]), ISO["opacity"])
    assert item.object is not None and item.object.name == "Cut" and (item.opacity, item.clip) == (0.5, "front")
    surfaces = snapshot.scene_inputs(bpy.context.evaluated_depsgraph_get()).surfaces
    assert len(surfaces.isosurfaces) == 1 and len(surfaces.planes) == 1
    normal = np.array([0.0, -math.sin(PLANE_TILT), math.cos(PLANE_TILT)])
    np.testing.assert_allclose(surfaces.planes[0].normal, normal, atol=1e-6)


def test_field_chooser_lists_derived_fields(scene):
    from hovr_blender.ui.surface_panels import field_choices

    from ..helpers import data_file

    tgv = data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")
    obj = bpy.data.objects.new("TGV", None)
    scene.collection.objects.link(obj)
    obj.hovr.source = str(tgv)
    names = field_choices(obj, scene)
    assert names[:3] == ["Density", "Velocity", "Pressure"] and "Q(Velocity)" in names and "|grad|(Pressure)" in names


def test_a_plane_missing_the_volume_is_reported(scene):
    _vol, plane = _scene_with_surfaces(scene)
    plane.location = (0.0, 0.0, 50.0)
    plane.rotation_euler = (0.0, 0.0, 0.0)
    with pytest.raises(RuntimeError, match="plane 0 .* misses the volume"):
        bpy.ops.render.render(write_still=False)


def test_operators_add_and_remove(scene):
    vol = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    bpy.context.view_layer.objects.active = vol
    vol.select_set(True)
    assert bpy.ops.hovr.isosurface_add() == {'FINISHED'}
    assert vol.hovr_surfaces.isosurfaces[0].value == 0.5 * (vol.hovr.value_min + vol.hovr.value_max)
    assert bpy.ops.hovr.plane_add() == {'FINISHED'}  # nothing else selected: a new plane through the volume
    plane = vol.hovr_surfaces.planes[0].object
    assert plane is not None and plane.hide_render and plane.name in scene.objects
    assert bpy.ops.hovr.surface_remove(collection="planes", index=0) == {'FINISHED'}
    assert bpy.ops.hovr.surface_remove(collection="isosurfaces", index=0) == {'FINISHED'}
    assert len(vol.hovr_surfaces.planes) == 0 and len(vol.hovr_surfaces.isosurfaces) == 0
    assert plane.name in scene.objects  # the object stays
