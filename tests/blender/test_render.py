"""F12 through the HOVR engine: the written EXR equals the core renderer's image of the
same view built from the render contract, survives save/reload, and failures are reported."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import render, snapshot  # noqa: E402
from hovr_blender.ui.blender_camera import ray_camera_from_blender  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import render_to_exr, volume  # noqa: E402


@pytest.mark.parametrize("contract,method,film_transparent,percentage", [
    (SPHERE.PERSPECTIVE, "classified", False, 100),
    (SPHERE.PERSPECTIVE, "trapezoid", True, 50),
    (SPHERE.ORTHOGRAPHIC, "classified", False, 100),
])
def test_f12_matches_core_render(scene, tmp_path, contract, method, film_transparent, percentage):
    obj = SPHERE.build_scene(scene, contract, method, film_transparent, percentage)
    got = render_to_exr(scene, tmp_path / "f12.exr")
    want = SPHERE.core_render(contract, method, film_transparent)
    assert got.shape == (SPHERE.H, SPHERE.W, 4)
    assert want[..., 3].max() > 0.2 and want[..., 3].min() < 1e-6  # the volume fills part of the frame
    if film_transparent:
        np.testing.assert_allclose(got, want, atol=1e-5)  # RGB = C (premultiplied), alpha = 1 - T
    else:
        np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)  # RGB = C + T * world colour
        np.testing.assert_array_equal(got[..., 3], 1.0)
    # With the engine's own (float32-derived) camera and object transform the core gives the EXR
    # to the bit: TF, transform, background, row order and alpha all pass through unchanged.
    blender_camera = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    same = SPHERE.core_render(contract, method, film_transparent, camera=blender_camera, matrix=np.array(obj.matrix_world))
    if not film_transparent:
        same[..., 3] = 1.0
    np.testing.assert_array_equal(got, same)


def test_save_reload_renders_identically(scene, tmp_path):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    first = render_to_exr(scene, tmp_path / "a.exr")
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    render.clear_cache()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    loaded = bpy.context.scene
    assert loaded.render.engine == 'HOVR' and loaded.hovr.method == "classified"
    assert volume(loaded).hovr.transfer_function is not None
    assert [o.name for o in loaded.objects if o.hovr.is_volume] == ["HOVR Sphere"]
    second = render_to_exr(loaded, tmp_path / "b.exr")
    np.testing.assert_array_equal(first, second)


def test_f12_over_every_cpu_core_equals_one_core(scene, tmp_path, capfd):
    """Device "All CPU Cores" (cpu:all, one process a core) renders the one-core image; the
    processes are those of engine/multi_device.py, started from inside Blender. Issue 40: each
    keeps its band's segments, so an F12 after a ramp edit is shaded where they are, and says so."""
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    one = render_to_exr(scene, tmp_path / "one.exr")
    scene.hovr.device = "cpu:all"
    ramp = obj.hovr.transfer_function.color_ramp
    try:
        capfd.readouterr()
        every = render_to_exr(scene, tmp_path / "all.exr")
        assert "kept for a look-only edit" in capfd.readouterr().out
        ramp.elements[1].color = (1.0, 0.0, 0.0, 1.0)
        edited = render_to_exr(scene, tmp_path / "all_edited.exr")
        assert "shaded from the kept segments" in capfd.readouterr().out
    finally:
        render.clear_cache()  # closes the processes
    np.testing.assert_allclose(every, one, atol=1e-6)
    scene.hovr.device = "cpu"
    np.testing.assert_allclose(edited, render_to_exr(scene, tmp_path / "one_edited.exr"), atol=1e-6)


def test_the_status_line_counts_in_words():
    """Issue 40: a one-element volume's status line says '1 element'."""
    assert render.render_stats({"elements": 1}, 1, 0.5, "cpu").startswith("HOVR | 1 element | ")
    assert render.render_stats({"elements": 1760}, 1760, 0.5, "cpu").startswith("HOVR | 1,760 elements | ")


def test_renderer_is_cached_per_object_transform(scene, tmp_path):
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    render.clear_cache()
    render_to_exr(scene, tmp_path / "a.exr")
    render_to_exr(scene, tmp_path / "b.exr")
    assert len(render.RENDERERS) == 1
    obj.location.x += 1.0
    moved = render_to_exr(scene, tmp_path / "c.exr")
    assert len(render.RENDERERS) == 2
    obj.location.x -= 1.0
    back = render_to_exr(scene, tmp_path / "d.exr")
    assert len(render.RENDERERS) == 2  # the first upload was reused
    assert np.abs(moved - back).max() > 1e-3


def _fingerprint(scene):
    """The user data a render must not touch."""
    s = scene.hovr

    def look(h):
        ramp = h.transfer_function.color_ramp if h.transfer_function else None
        return (h.density, h.density_units, h.value_min, h.value_max,
                ramp and (ramp.interpolation, [(e.position, tuple(e.color)) for e in ramp.elements]))

    return (
        sorted((o.name, o.location[:], o.rotation_euler[:], o.scale[:], o.hovr.is_volume, o.hovr.source, look(o.hovr))
               for o in scene.objects),
        (s.method, s.step_units, s.steps_across, s.h, s.tolerance, s.min_transmittance, s.device),
        len(bpy.data.textures), len(bpy.data.meshes),
        len([i for i in bpy.data.images if i.type != 'RENDER_RESULT']),  # Blender adds its Render Result
    )


def _no_volume(scene):
    for o in [o for o in scene.objects if o.hovr.is_volume]:
        bpy.data.objects.remove(o)


def _ease(scene):
    volume(scene).hovr.transfer_function.color_ramp.interpolation = 'EASE'


def _empty_range(scene):
    volume(scene).hovr.value_max = volume(scene).hovr.value_min


def _no_tf(scene):
    volume(scene).hovr.transfer_function = None


def _unknown_source(scene):
    next(o for o in scene.objects if o.hovr.is_volume).hovr.source = "builtin:teapot"


def _pano(scene):
    scene.camera.data.type = 'PANO'


@pytest.mark.parametrize("breakage,message", [
    (_no_volume, "no HOVR volume"), (_ease, "Linear interpolation"), (_empty_range, "Value Max"),
    (_no_tf, "no transfer function"), (_unknown_source, "teapot"), (_pano, "panoramic"),
])
def test_errors_are_reported_and_leave_data_untouched(scene, tmp_path, breakage, message):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    breakage(scene)
    before = _fingerprint(scene)
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.render.render(write_still=False)
    assert _fingerprint(scene) == before


# Two spheres with different looks, side by side along x (not overlapping in space), seen from
# the front (side by side in the image) and from the side (one behind the other).
TWO_STOPS = [(0.0, (0.25, 0.5, 1.0, 0.0)), (0.25, (0.25, 0.5, 1.0, 1.0)), (0.5, (1.0, 1.0, 1.0, 0.0)),
             (1.0, (0.0, 0.0, 0.0, 0.0))]
FRONT = {"eye": [1.5, -9.0, 0.5], "target": [1.5, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov_y_deg": 30.0}
SIDE = {"eye": [9.0, 0.6, 0.4], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov_y_deg": 25.0}


def _two_spheres(scene):
    from .blender_helpers import add_camera, set_look

    add_camera(scene)
    scene.render.film_transparent = True
    # float64: the merged mesh rounds in float32 a little differently from each alone (~4e-5)
    scene.hovr.method, scene.hovr.tolerance, scene.hovr.precision = "classified", 1e-6, "float64"
    bpy.ops.hovr.add_sphere_volume()
    a = bpy.context.active_object
    set_look(a, SPHERE.STOPS, SPHERE.VALUE_RANGE, SPHERE.DENSITY_SCALE)
    bpy.ops.hovr.add_sphere_volume()
    b = bpy.context.active_object
    b.location = (3.0, 0.0, 0.0)
    set_look(b, TWO_STOPS, (0.0, 2.0), 1.5)
    return a, b


def _render_alone(scene, keep, others, path):
    for o in others:
        o.hide_render = True
    try:
        return render_to_exr(scene, path)
    finally:
        for o in others:
            o.hide_render = False


def test_two_volumes_with_their_own_looks_render_together(scene, tmp_path):
    """Each volume keeps its own transfer function; one pass renders both. Side by side, every
    pixel equals the render of the volume alone where the other is absent; one behind the
    other, the front volume is composited over the back one (C = C_f + T_f C_b)."""
    from .blender_helpers import set_contract_camera

    a, b = _two_spheres(scene)
    assert a.hovr.transfer_function != b.hovr.transfer_function
    for contract, name in ((FRONT, "front"), (SIDE, "side")):
        set_contract_camera(scene, contract, 64, 40)
        both = render_to_exr(scene, tmp_path / f"{name}_both.exr")
        only_a = _render_alone(scene, a, [b], tmp_path / f"{name}_a.exr")
        only_b = _render_alone(scene, b, [a], tmp_path / f"{name}_b.exr")
        assert only_a[..., 3].max() > 0.2 and only_b[..., 3].max() > 0.2
        if name == "front":
            a_only, b_only = only_b[..., 3] == 0, only_a[..., 3] == 0
            assert a_only.any() and b_only.any() and (only_a[..., 3] > 0)[a_only].any()
            np.testing.assert_allclose(both[a_only], only_a[a_only], atol=1e-5)
            np.testing.assert_allclose(both[b_only], only_b[b_only], atol=1e-5)
            # the two looks differ: b's pixels are not a's ramp
            assert np.abs(only_a.sum(axis=(0, 1)) - only_b.sum(axis=(0, 1))).max() > 1e-2
        else:  # b (x = 3) is in front of a seen from +x
            overlap = (only_a[..., 3] > 0.05) & (only_b[..., 3] > 0.05)
            assert overlap.sum() > 20
            t_front = 1.0 - only_b[..., 3:4]
            over = only_b[..., :3] + t_front * only_a[..., :3]
            np.testing.assert_allclose(both[..., :3][overlap], over[overlap], atol=2e-4)
            np.testing.assert_allclose(both[..., 3][overlap], (1 - t_front[..., 0] * (1 - only_a[..., 3]))[overlap],
                                       atol=2e-4)


def test_editing_one_volume_look_leaves_the_other(scene, tmp_path):
    from .blender_helpers import set_contract_camera

    a, b = _two_spheres(scene)
    set_contract_camera(scene, FRONT, 48, 30)
    first = render_to_exr(scene, tmp_path / "1.exr")
    b.hovr.density *= 2.0
    b.hovr.transfer_function.color_ramp.elements[1].color = (1.0, 0.0, 0.0, 1.0)
    second = render_to_exr(scene, tmp_path / "2.exr")
    only_b = _render_alone(scene, b, [a], tmp_path / "b.exr")
    a_side = only_b[..., 3] == 0
    np.testing.assert_array_equal(second[a_side], first[a_side])
    assert np.abs(second - first).max() > 1e-2


def test_relative_density_is_optical_depth_across_the_volume(scene, tmp_path):
    """Density in RELATIVE units is the contract's density times the bounding-box diagonal:
    the same picture at any scale (a sphere scaled by 1/50 with its camera)."""
    from .blender_helpers import set_look

    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    world = render_to_exr(scene, tmp_path / "world.exr")
    diag = _sphere_diagonal()  # the box's diagonal (object scale 1)
    set_look(obj, SPHERE.STOPS, SPHERE.VALUE_RANGE, SPHERE.DENSITY_SCALE * diag, units="RELATIVE")
    relative = render_to_exr(scene, tmp_path / "relative.exr")
    np.testing.assert_allclose(relative, world, atol=1e-5)
    # 1/50 the size, camera scaled with it: the relative look is unchanged
    s = 0.02
    _shrink_sphere_scene(scene, obj, s)
    scene.hovr.h *= s  # Step is in world units (it sets accuracy, not the look)
    small = render_to_exr(scene, tmp_path / "small.exr")
    np.testing.assert_allclose(small, world, atol=2e-4)


def _shrink_sphere_scene(scene, obj, s):
    """The sphere volume and its camera scaled by s about the origin (the same picture)."""
    from .blender_helpers import set_contract_camera

    obj.location = [s * x for x in SPHERE.OBJECT_LOCATION]
    obj.scale = (s, s, s)
    c = dict(SPHERE.PERSPECTIVE, eye=[s * x for x in SPHERE.PERSPECTIVE["eye"]],
             target=[s * x for x in SPHERE.PERSPECTIVE["target"]])
    set_contract_camera(scene, c, SPHERE.W, SPHERE.H)
    scene.camera.data.clip_start = 0.001


def _sphere_diagonal(scale=1.0):
    from hovr_blender.io import builtin

    v = builtin.sphere().vertices.reshape(-1, 3)
    return scale * float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))


def test_relative_step_is_the_diagonal_over_steps_across(scene, tmp_path):
    """Step Units Across Volume: the core gets h = the volume's bounding-box diagonal (world
    units, the object's scale included) / Steps Across, so the picture keeps its sampling at any
    size without touching the step (the sphere scaled by 1/50 with its camera)."""
    from hovr_blender.ui import render

    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    scene.hovr.step_units, scene.hovr.steps_across = 'RELATIVE', 50
    h = _sphere_diagonal() / 50  # 0.133: coarse enough to show in the image
    inputs = snapshot.resolve_units(snapshot.scene_inputs(bpy.context.evaluated_depsgraph_get(), original=True))
    assert inputs.options.h == pytest.approx(h, rel=1e-6)
    got = render_to_exr(scene, tmp_path / "relative.exr")
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False, h=h)
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
    assert np.abs(got[..., :3] - SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)[..., :3]).max() > 1e-3
    s = 0.02
    _shrink_sphere_scene(scene, obj, s)
    obj.hovr.density *= 1 / s  # the look in world units follows the size by hand; the step by itself
    bpy.context.view_layer.update()
    inputs = snapshot.resolve_units(snapshot.scene_inputs(bpy.context.evaluated_depsgraph_get(), original=True))
    assert inputs.options.h == pytest.approx(s * h, rel=1e-5)
    small = render_to_exr(scene, tmp_path / "small.exr")
    np.testing.assert_allclose(small, got, atol=2e-4)


def test_step_units_survive_save_and_reload(scene, tmp_path):
    """A scene saved with Step Units keeps them on reload, the default Across Volume included
    (never mistaken for a file from before Step Units, which keeps its world step)."""
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    scene.hovr.property_unset("step_units")  # as build_scene's World Units were never chosen
    scene.hovr.steps_across = 321
    assert scene.hovr.step_units == 'RELATIVE'
    path = tmp_path / "steps.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    s = bpy.context.scene.hovr
    assert (s.step_units, s.steps_across) == ('RELATIVE', 321)
    s.step_units, s.h = 'WORLD', 0.03125
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=str(path))
    s = bpy.context.scene.hovr
    assert (s.step_units, s.h, s.steps_across) == ('WORLD', 0.03125, 321)


def test_a_file_saved_before_step_units_keeps_its_world_step(scene, tmp_path):
    """tests/data/blender/legacy_world_step.blend was saved before Step Units, its step never set
    (the world default 0.01). Opened, its scene keeps that step in world units (load_post) and F12
    gives the image the old version gave; a scene of it never used with HOVR takes the new default."""
    from hovr_blender.ui import versioning

    from ..helpers import data_file

    blend = data_file("blender", "legacy_world_step.blend")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    sc = bpy.context.scene
    assert (sc.hovr.step_units, sc.hovr.h) == ('WORLD', pytest.approx(0.01))
    got = render_to_exr(sc, tmp_path / "legacy.exr")
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
    other = bpy.data.scenes.new("Unused")
    assert versioning.migrate_step_units([other]) == 0 and other.hovr.step_units == 'RELATIVE'


def test_a_file_saved_with_the_scene_look_renders_the_same(scene, tmp_path):
    """tests/data/blender/legacy_scene_look.blend was saved before looks moved onto volumes (its
    transfer function, value range and density per world unit are the scene's). Opened, its
    volume gets that look (load_post) and F12 gives the image the old version gave."""
    from hovr_blender.ui import versioning

    from ..helpers import data_file

    blend = data_file("blender", "legacy_scene_look.blend")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    sc = bpy.context.scene
    obj = volume(sc)
    assert obj.hovr.transfer_function == sc.hovr.transfer_function is not None
    assert obj.hovr.density_units == 'WORLD' and obj.hovr.density == pytest.approx(SPHERE.DENSITY_SCALE)
    assert (obj.hovr.value_min, obj.hovr.value_max) == SPHERE.VALUE_RANGE
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    got = render_to_exr(sc, tmp_path / "migrated.exr")
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
    # without the handler (the add-on enabled after the file was opened) the render reads the
    # scene's look in place: the same image
    obj.hovr.transfer_function = None
    obj.hovr.density_units, obj.hovr.density = 'RELATIVE', 4.0
    assert versioning.volume_look(obj.hovr, sc).legacy
    fallback = render_to_exr(sc, tmp_path / "fallback.exr")
    np.testing.assert_allclose(fallback, got, atol=0)


def test_f12_after_a_look_edit_is_shaded_from_the_kept_segments(scene, tmp_path, monkeypatch, capfd):
    """Issue 40: the first F12 of a view traces and keeps its segments (render.FINAL) and shades its
    picture from them, the picture of a plain render; an F12 after an edit of the look alone (ramp
    colour, density, world colour) shades from them without a trace and gives the picture of a
    fresh render of the new look; the status line says which. A moved camera traces again; an
    animation's frame and a one-off render (render-blend's) render plainly."""
    from hovr_blender.engine.frame import Frame, render_frame
    from hovr_blender.engine.renderer import Renderer

    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    render.clear_cache()
    traces, trace = [], Renderer.trace
    monkeypatch.setattr(Renderer, "trace", lambda self, *a, **k: traces.append(a[0]) or trace(self, *a, **k))
    capfd.readouterr()
    first = render_to_exr(scene, tmp_path / "1.exr")
    assert render.FINAL.cache is not None and len(traces) == 1
    assert "segments, kept for a look-only edit" in capfd.readouterr().out
    plain = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.testing.assert_allclose(first[..., :3], plain[..., :3], atol=1e-5)
    second = render_to_exr(scene, tmp_path / "2.exr")
    assert len(traces) == 1 and "shaded from the kept segments" in capfd.readouterr().out
    np.testing.assert_array_equal(second, first)
    obj.hovr.transfer_function.color_ramp.elements[1].color = (1.0, 0.0, 0.0, 1.0)
    obj.hovr.density *= 2.0
    scene.world.color = (0.25, 0.125, 0.0625)
    edited = render_to_exr(scene, tmp_path / "3.exr")
    assert len(traces) == 1 and np.abs(edited - first).max() > 1e-2
    render.clear_cache()
    assert render.FINAL.cache is None
    fresh = render_to_exr(scene, tmp_path / "4.exr")
    np.testing.assert_array_equal(edited, fresh)
    scene.camera.location.x += 0.25
    render_to_exr(scene, tmp_path / "5.exr")
    assert render.FINAL.cache is not None and len(traces) == 3
    renderer = next(r for r, _ in render.RENDERERS.values())
    depsgraph = bpy.context.evaluated_depsgraph_get()
    inputs = render.resolve_units(render.scene_inputs(depsgraph))
    camera = ray_camera_from_blender(scene.camera, depsgraph, scene.render)
    render.clear_cache()
    for once, animation in ((False, True), (True, False)):
        monkeypatch.setattr(render.FINAL, "once", once)
        res = render.render_final(renderer, inputs, camera, animation=animation)
        assert render.FINAL.cache is None and len(traces) == 3 and "segment_cache" not in res.stats
    np.testing.assert_array_equal(res.rgba, render_frame(renderer, Frame(inputs.transfer_function, inputs.background,
                                                                         inputs.options), camera).rgba)


def test_f12_whose_segments_the_memory_limit_refuses_renders_plainly(scene, tmp_path, monkeypatch):
    """A view whose cache the memory limit refuses renders plainly (the same picture) and does not
    try to keep its segments again."""
    from hovr_blender.engine import limits
    from hovr_blender.engine import segment_cache
    from hovr_blender.engine.renderer import Renderer

    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    render.clear_cache()
    first = render_to_exr(scene, tmp_path / "1.exr")
    render.clear_cache()
    monkeypatch.setattr(segment_cache, "CACHE_MIN_SEGMENTS", 1 << 26)  # its smallest arrays: ~3 GB
    traces, trace = [], Renderer.trace
    monkeypatch.setattr(Renderer, "trace", lambda self, *a, **k: traces.append(1) or trace(self, *a, **k))
    with limits.using(limits.ResourceLimits(max_memory=1 << 30)):
        second = render_to_exr(scene, tmp_path / "2.exr")
        assert render.FINAL.refused and render.FINAL.cache is None and len(traces) == 1
        third = render_to_exr(scene, tmp_path / "3.exr")
    assert len(traces) == 1
    np.testing.assert_array_equal(second, first)
    np.testing.assert_array_equal(third, first)
