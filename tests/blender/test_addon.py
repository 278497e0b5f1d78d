"""Registration, properties, operators and panels of the add-on inside Blender."""
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

import hovr_blender  # noqa: E402
from hovr_blender.io import builtin  # noqa: E402
from hovr_blender.ui import compat, operators, panels, snapshot  # noqa: E402
from hovr_blender.engine.looks import DEFAULT_PRESET, TF_PRESETS  # noqa: E402

from ..helpers import REPO  # noqa: E402


def _operator_registered(name):
    try:
        getattr(bpy.ops.hovr, name).get_rna_type()
        return True
    except KeyError:
        return False


def _engine_registered():
    render = bpy.context.scene.render
    try:
        render.engine = 'HOVR'  # the engine enum is dynamic: only registered engines are accepted
    except TypeError:
        return False
    render.engine = compat.eevee_engine()
    return True


def _menu_funcs():
    return getattr(bpy.types.VIEW3D_MT_add.draw, "_draw_funcs", [])


def test_register_unregister_twice_cleanly():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    stock = bpy.types.RENDER_PT_format
    assert 'HOVR' not in stock.COMPAT_ENGINES
    for _ in range(2):
        hovr_blender.register()
        try:
            _check_registered(stock)
        finally:
            hovr_blender.unregister()
        assert not hasattr(bpy.types.Scene, "hovr") and not hasattr(bpy.types.Object, "hovr")
        assert not _engine_registered()
        assert not _operator_registered("add_sphere_volume")
        assert 'HOVR' not in stock.COMPAT_ENGINES and 'BLENDER_RENDER' in stock.COMPAT_ENGINES
        assert operators.menu_add not in _menu_funcs()
        assert not hasattr(bpy.types, "HOVR_RENDER_PT_quadrature")


_EXIT_SCRIPT = """
import bpy, sys
import addon_utils
addon_utils.enable("hovr_blender", default_set=True, handle_error=None)  # as the Preferences enable it
bpy.ops.hovr.add_sphere_volume()
import hovr_blender.ui.compat as compat
compat.finish_script(0)
"""
# the LTS Blenders' bpy modules live in venvs beside this one (scripts/bootstrap.sh makes them)
_BLENDER_PYTHONS = {"5.0": sys.executable, **{v: str(Path(sys.prefix).parent / f".venv-bpy-{p}" / "bin" / "python")
                                             for v, p in (("4.2", "4.2.23"), ("4.5", "4.5.15"))}}


@pytest.mark.slow
@pytest.mark.parametrize("version", sorted(_BLENDER_PYTHONS))
def test_a_script_ends_without_a_traceback(version, tmp_path):
    """Issue 30: the add-on enabled as the Preferences do, a script's exit unregisters it once (bpy
    5.0 disables enabled add-ons at exit, and compat.unregister_before_exit does too): no traceback,
    exit status 0, on each Blender the manifest promises whose bpy module is installed here."""
    import os
    import subprocess

    python = _BLENDER_PYTHONS[version]
    if not os.path.exists(python):
        pytest.skip(f"bpy {version}'s venv is not installed ({python})")
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run([python, "-c", _EXIT_SCRIPT], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr and "unregister" not in proc.stderr, proc.stderr[-3000:]


def _check_registered(stock):
    assert hasattr(bpy.types.Scene, "hovr") and hasattr(bpy.types.Object, "hovr")
    assert _engine_registered()
    assert _operator_registered("add_sphere_volume") and _operator_registered("new_transfer_function")
    assert 'HOVR' in stock.COMPAT_ENGINES and 'HOVR' in bpy.types.DATA_PT_lens.COMPAT_ENGINES
    assert operators.menu_add in _menu_funcs()
    assert hasattr(bpy.types, "HOVR_RENDER_PT_quadrature")


def test_properties_defaults_and_enum_indices(scene):
    settings = scene.hovr
    props = type(settings).bl_rna.properties
    methods = {i.identifier: i.value for i in props["method"].enum_items}
    assert methods == {"riemann": 0, "trapezoid": 1, "classified": 2, "split": 3}
    assert {i.identifier: i.value for i in props["device"].enum_items} == {"cpu": 0, "cuda:0": 1, "cuda:all": 2,
                                                                                "cpu:all": 3}
    for name in ("h", "tolerance", "min_transmittance"):
        assert props[name].type == 'FLOAT'
    # the look is each volume's own; the scene keeps the old names only to read old files
    oprops = bpy.types.Object.bl_rna.properties["hovr"].fixed_type.properties
    assert oprops["transfer_function"].fixed_type.identifier == "Texture"
    for name in ("density", "value_min", "value_max"):
        assert oprops[name].type == 'FLOAT'
    assert {i.identifier: i.value for i in oprops["density_units"].enum_items} == {"RELATIVE": 0, "WORLD": 1}
    assert oprops["density_units"].default == "RELATIVE"
    assert {"transfer_function", "density_scale", "value_min", "value_max"} <= set(props.keys())
    # The step is relative to the volume by default; in world units its default is the core's
    assert {i.identifier: i.value for i in props["step_units"].enum_items} == {"RELATIVE": 0, "WORLD": 1}
    assert settings.step_units == "RELATIVE" and props["steps_across"].type == 'INT'
    # Defaults agree with the core's RenderOptions, so an untouched scene renders like the CLI
    # (but for the step, which the CLI takes in world units).
    from hovr_blender.engine.view import RenderOptions

    core = RenderOptions()
    assert (settings.method, settings.device) == (core.method, core.device)
    # the core's classified without h chooses each segment's step; Blender's Step is a fixed one
    assert core.h is None and settings.h > 0 and settings.tolerance == pytest.approx(core.tolerance)
    assert settings.min_transmittance == pytest.approx(core.min_transmittance)
    settings.method = "split"
    assert settings.method == "split"
    with pytest.raises(TypeError):
        settings.method = "simpson"
    obj = bpy.data.objects.new("o", None)
    assert obj.hovr.is_volume is False and obj.hovr.source == ""


def test_add_sphere_volume_operator(scene):
    assert bpy.ops.hovr.add_sphere_volume() == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.is_volume and obj.hovr.source == "builtin:sphere"
    assert obj.display_type == 'WIRE' and obj.name in scene.objects
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    def rows(a):
        return np.array(sorted(map(tuple, np.round(a, 6))))

    np.testing.assert_allclose(rows(co.reshape(-1, 3)), rows(builtin.sphere().vertices[0]), atol=1e-6)
    edges = {tuple(sorted(e.vertices)) for e in me.edges}
    assert len(edges) == 12 and len(me.polygons) == 0
    # every hex edge joins vertices that differ in exactly one coordinate
    v = co.reshape(-1, 3)
    assert all(np.count_nonzero(np.abs(v[a] - v[b]) > 1e-6) == 1 for a, b in edges)

    tex = obj.hovr.transfer_function
    assert tex is not None and tex.type == 'BLEND' and tex.use_color_ramp
    assert tex.color_ramp.interpolation == 'LINEAR' and len(tex.color_ramp.elements) == len(TF_PRESETS[DEFAULT_PRESET][2])
    # The default value range covers the field: max at the far corners, min near the origin.
    corners = builtin.sphere().vertices[0]
    assert obj.hovr.value_max == pytest.approx(builtin.sphere_field(*corners.T).max())
    assert 0.0 <= obj.hovr.value_min < 0.5

    # A second volume gets a look of its own; the first one's is left as the user set it.
    tex.color_ramp.elements[0].color = (0.5, 0.5, 0.5, 0.0)
    obj.hovr.value_min = -1.0
    bpy.ops.hovr.add_sphere_volume()
    second = bpy.context.active_object
    assert second != obj and second.hovr.transfer_function not in (None, tex) and len(bpy.data.textures) == 2
    assert obj.hovr.transfer_function == tex and obj.hovr.value_min == -1.0
    assert tuple(tex.color_ramp.elements[0].color) == (0.5, 0.5, 0.5, 0.0)
    assert sum(o.hovr.is_volume for o in scene.objects) == 2


def test_new_transfer_function_operator(scene):
    assert not bpy.ops.hovr.new_transfer_function.poll()  # no volume to give it to
    obj = bpy.data.objects.new("o", None)
    scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    obj.hovr.is_volume = True  # ticking HOVR Volume gives it the transfer function it needs
    first = obj.hovr.transfer_function
    assert first is not None and first.use_color_ramp and len(bpy.data.textures) == 1
    bpy.ops.hovr.new_transfer_function()
    assert obj.hovr.transfer_function not in (None, first) and len(bpy.data.textures) == 2
    obj.hovr.is_volume = False
    obj.hovr.is_volume = True  # ticking again keeps the one it has
    assert len(bpy.data.textures) == 2


def test_panels_follow_the_engine(scene):
    assert panels.HOVR_RENDER_PT_quadrature.COMPAT_ENGINES == {'HOVR'}
    stock = {p.__name__ for p in panels.get_panels()}
    assert {"RENDER_PT_format", "RENDER_PT_output", "DATA_PT_lens", "WORLD_PT_context_world"} <= stock
    # Panels for features HOVR does not have stay hidden.
    assert 'HOVR' not in bpy.types.DATA_PT_light.COMPAT_ENGINES
    assert 'HOVR' not in bpy.types.RENDER_PT_simplify.COMPAT_ENGINES


class _Layout:
    """Stands in for UILayout (no UI in background mode); checks every property drawn exists."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        def call(*args, **kwargs):
            if name in ("prop", "template_color_ramp"):
                data, prop = args[0], args[1]
                assert prop in data.bl_rna.properties, f"{type(data).__name__} has no property {prop!r}"
            if name == "operator":
                assert _operator_registered(args[0].split(".")[1]), args[0]
            self.log.append((name, args[1] if name in ("prop", "template_color_ramp") else args[:1]))
            return _Layout(self.log)
        return call


@pytest.mark.parametrize("with_tf", [False, True])
def test_panels_draw_existing_properties(scene, with_tf):
    from types import SimpleNamespace

    if with_tf:
        bpy.ops.hovr.add_sphere_volume()
        obj = bpy.context.active_object
    else:
        obj = bpy.data.objects.new("o", None)
    context = SimpleNamespace(scene=scene, object=obj, engine=scene.render.engine, view_layer=bpy.context.view_layer)
    drawn = []
    for cls in panels.classes:
        assert cls.poll(context)
        panel = SimpleNamespace(layout=_Layout(drawn))
        if hasattr(cls, "draw_header"):
            cls.draw_header(panel, context)
        cls.draw(panel, context)
    names = {n for _, n in drawn}
    assert {"method", "steps_across", "step_units", "tolerance", "min_transmittance", "device", "density",
            "density_units", "value_min", "value_max"} <= names
    assert "h" not in names  # the world step is drawn only in World Units
    scene.hovr.step_units = 'WORLD'
    drawn.clear()
    panels.HOVR_RENDER_PT_quadrature.draw(SimpleNamespace(layout=_Layout(drawn)), context)
    assert {"h", "step_units"} <= {n for _, n in drawn} and "steps_across" not in {n for _, n in drawn}
    assert ("color_ramp" in names) == with_tf
    context.engine = 'CYCLES'
    assert not any(cls.poll(context) for cls in panels.classes)


def test_legend_overlay_layout_of_the_active_volume(scene):
    """Issue 30: the viewport legend is the active volume's look (ui/legend_overlay.py draws
    engine/legend.py's layout with gpu and blf; the window test sees it drawn)."""
    from hovr_blender.ui import legend_overlay

    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    obj.hovr.field = "f"
    obj.hovr.units = "K"
    tf, lo, hi, title, units = snapshot.legend_volume_inputs(obj, scene)
    assert (lo, hi) == (pytest.approx(obj.hovr.value_min), pytest.approx(obj.hovr.value_max)) and title == "f"
    assert units == "K" and legend_overlay.scene_legend(scene, bpy.context.view_layer, 400, 300, (0, 0, 0)).texts[-1] \
        .text == "f [K]"
    from hovr_blender.engine.legend import legend_layout

    layout = legend_layout(tf, lo, hi, title, 400, 300)
    positions, colours = legend_overlay.legend_triangles(layout, 300)
    x0, y0, x1, y1 = layout.bar
    marks = len(legend_overlay.legend_marks(layout)[0])
    assert positions.shape == (6 * (2 * (y1 - y0) + marks), 2) and colours.shape == (len(positions), 4)
    bar = positions[: 6 * (y1 - y0)]  # the bar's rows first, then the curve's, then the marks
    assert bar[:, 1].max() == 300 - y0 and bar[:, 1].min() == 300 - y1  # region rows count up
    marked = positions[12 * (y1 - y0):, 0]  # the ticks, the curve's edge and the frame: beside and around the bar
    assert marks > len(layout.ticks) and marked.min() == min(t[0] for t in layout.ticks) and marked.max() == x1 + 1
    assert scene.hovr.show_legend and legend_overlay._handle is None  # no viewport to draw on in background mode
    # With Region Overlap the tool header lies over the view's top (the window test's Blender 3.4
    # drew the field's name under it): the legend starts below what covers the view
    from types import SimpleNamespace as R

    view = R(type="WINDOW", x=0, y=20, width=700, height=600)
    header = R(type="HEADER", x=0, y=620, width=700, height=26)  # above the view: covers nothing
    tool_header = R(type="TOOL_HEADER", x=0, y=594, width=700, height=26)
    assert legend_overlay.covered_top(view, [view, header]) == 0
    assert legend_overlay.covered_top(view, [view, header, tool_header]) == 26
