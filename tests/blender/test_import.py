"""File > Import > HOVR Nektar++ / VTU inside Blender: the object it makes, failures that change
nothing, relative paths across save / move / reopen, and the render cache."""
import base64
import os
import re
import shutil
import zlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.engine.looks import field_samples  # noqa: E402
from hovr_blender.ui import render  # noqa: E402
from hovr_blender.engine.outline import outline_edges  # noqa: E402
from hovr_blender.io import sources  # noqa: E402
from hovr_blender.io import nektar  # noqa: E402
from hovr_blender.ui import import_operators, panels  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import (TET, add_camera, copy_tet, datablock_counts, f12_and_engine, render_to_exr,  # noqa: E402
                             set_contract_camera)

W, H = 24, 16
CONTRACT = {"eye": [2.6, -1.9, 2.2], "target": [0.5, 0.5, 0.5], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}


def vector_vtu(path: Path) -> Path:
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    vel = np.c_[pts[:, 0] - 0.3, pts[:, 1] + 1.0, pts[:, 2]]
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", np.arange(8)[None])],
                                        point_data={"vel": vel, "s": pts[:, 2]}), binary=False)
    return path


def mesh_edges(obj):
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    ed = np.empty(len(me.edges) * 2, np.int32)
    me.edges.foreach_get("vertices", ed)
    return co.reshape(-1, 3), ed.reshape(-1, 2)


def test_menu_operators_and_save_handlers_come_and_go(addon):
    draw_funcs = getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])
    assert import_operators.menu_import in draw_funcs
    assert bpy.ops.import_scene.hovr_nektar.get_rna_type() and bpy.ops.import_scene.hovr_vtu.get_rna_type()
    assert import_operators.remap_paths_before_save in bpy.app.handlers.save_pre
    addon.unregister()
    try:
        assert import_operators.menu_import not in getattr(bpy.types.TOPBAR_MT_file_import.draw, "_draw_funcs", [])
        assert import_operators.remap_paths_before_save not in bpy.app.handlers.save_pre
        assert import_operators.restore_paths_after_copy not in bpy.app.handlers.save_post
        with pytest.raises(KeyError):
            bpy.ops.import_scene.hovr_nektar.get_rna_type()
    finally:
        addon.register()


def test_import_nektar_magnitude(scene, tmp_path):
    xml = copy_tet(tmp_path)
    before = datablock_counts()
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="|u,v,w|", frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    after = datablock_counts()
    assert after["objects"] == before["objects"] + 1 and after["meshes"] == before["meshes"] + 1
    assert obj.name == TET and obj.select_get() and obj.name in scene.objects
    h = obj.hovr
    assert h.is_volume and h.field == "|u,v,w|" and h.component == ""
    # an unsaved .blend has no folder to be relative to: absolute for now (made relative on save)
    assert h.source == str(xml) and h.solution == str(xml.with_suffix(".fld"))  # found beside the mesh
    # the outline: boundary edges of the element hulls, as blender_scene computes them
    source = sources.VolumeSource.resolve(h.source, h.solution, h.field, scene.frame_current)
    mesh = sources._MESHES.get(source.key)  # loaded once by the import, kept for the render
    assert mesh.field_name == "|u,v,w|" and mesh.num_elements == 48
    verts, edges = outline_edges(mesh)
    co, ed = mesh_edges(obj)
    np.testing.assert_allclose(co, verts, atol=1e-6)
    assert {tuple(sorted(e)) for e in ed.tolist()} == {tuple(e) for e in edges.tolist()}
    assert len(obj.data.polygons) == 0 and obj.display_type == 'WIRE'
    # its own transfer function over the field's range
    s = obj.hovr
    assert s.transfer_function is not None
    lo, hi = field_samples(mesh).min(), field_samples(mesh).max()
    assert s.value_min == pytest.approx(lo, abs=1e-6) and s.value_max == pytest.approx(hi, rel=1e-6)
    assert hi == pytest.approx(0.25, rel=1e-6)  # the channel's peak speed


def test_import_picks_the_first_field_and_reports_the_others(scene, tmp_path):
    xml = copy_tet(tmp_path)
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml)) == {'FINISHED'}
    assert bpy.context.active_object.hovr.field == "u"
    # a solution typed relative to the mesh's folder, a chosen field
    sub = tmp_path / "other"
    sub.mkdir()
    shutil.move(str(xml.with_suffix(".fld")), sub / "flow.fld")
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), solution="other/flow.fld", field="p") == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.solution == str(sub / "flow.fld") and obj.hovr.field == "p"
    assert obj.name != TET  # a second object of the same name gets Blender's suffix


def test_import_vtu_scalar_and_vector_components(scene, tmp_path):
    mfem = data_file("vtu", "mfem_fichera_cells_p4.vtu")  # MFEM's cells at the corner, where u peaks
    assert bpy.ops.import_scene.hovr_vtu(filepath=str(mfem)) == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.source == str(mfem) and obj.hovr.field == "u" and len(obj.data.edges) > 0
    assert obj.hovr.value_max == pytest.approx(0.1515, abs=2e-3)  # info.json: u_max 0.15155

    path = vector_vtu(tmp_path / "vec.vtu")
    assert bpy.ops.import_scene.hovr_vtu(filepath=str(path), field="vel", component="1") == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.component == "1"
    src = sources.VolumeSource.resolve(obj.hovr.source, "", obj.hovr.field, 1, component=obj.hovr.component)
    assert sources.cached_volume(src).field_name == "vel[1]"
    assert obj.hovr.value_min == pytest.approx(1.0) and obj.hovr.value_max == pytest.approx(2.0)
    assert bpy.ops.import_scene.hovr_vtu(filepath=str(path), field="vel") == {'FINISHED'}
    obj = bpy.context.active_object
    src = sources.VolumeSource.resolve(obj.hovr.source, "", obj.hovr.field, 1, component=obj.hovr.component)
    mag = sources.cached_volume(src)
    assert mag.field_name == "|vel|" and hasattr(mag, "derived_error")
    # the object panel shows Component for VTU sources (and no Solution)
    drawn = []

    class Layout:
        def __getattr__(self, name):
            def call(*args, **kwargs):
                if name == "prop":
                    assert args[1] in args[0].bl_rna.properties
                    drawn.append(args[1])
                return Layout()
            return call

    ctx = SimpleNamespace(object=obj, engine='HOVR', scene=scene)
    panels.HOVR_OBJECT_PT_volume.draw(SimpleNamespace(layout=Layout()), ctx)
    assert "component" in drawn and "solution" not in drawn


def corrupt_tet(folder: Path, kind: str):
    """A copy of the tet channel broken one way; returns (operator, kwargs, what the message names)."""
    xml = copy_tet(folder)
    fld = xml.with_suffix(".fld")
    if kind == "truncated mesh":
        xml.write_text(xml.read_text()[:5000])
        return "hovr_nektar", {"filepath": str(xml), "field": "u"}, [xml.name, "not well-formed"]
    if kind == "NaN coefficient":
        text = fld.read_text()
        body = re.search(r">([^<]+)</ELEMENTS>", text).group(1)
        values = np.frombuffer(zlib.decompress(base64.b64decode(body + "=" * (-len(body) % 4))), "<f8").copy()
        values[5 * 10 + 2] = np.nan  # field u (first), element 5 (10 coefficients per 3-mode tet)
        raw = zlib.compress(values.astype("<f8").tobytes())
        raw += b"\0" * (-len(raw) % 3)
        fld.write_text(text.replace(body, base64.b64encode(raw).decode()))
        return "hovr_nektar", {"filepath": str(xml), "field": "|u,v,w|"}, [fld.name, "element 5", "NaN"]
    if kind == "unknown field":
        return "hovr_nektar", {"filepath": str(xml), "field": "|u,q|"}, [fld.name, "no field 'q'"]
    if kind == "missing solution":
        return "hovr_nektar", {"filepath": str(xml), "solution": "nowhere.fld"}, ["nowhere.fld"]
    if kind == "truncated vtu":
        path = vector_vtu(folder / "vec.vtu")
        path.write_bytes(path.read_bytes()[:700])
        return "hovr_vtu", {"filepath": str(path)}, [path.name]
    if kind == "bad component":
        path = vector_vtu(folder / "vec.vtu")
        return "hovr_vtu", {"filepath": str(path), "field": "vel", "component": "x"}, ["vec.vtu", "component 'x'"]
    if kind == "component out of range":
        path = vector_vtu(folder / "vec.vtu")
        return "hovr_vtu", {"filepath": str(path), "field": "vel", "component": "3"}, ["vec.vtu", "0..2"]
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["truncated mesh", "NaN coefficient", "unknown field", "missing solution",
                                  "truncated vtu", "bad component", "component out of range"])
def test_failed_import_names_the_file_and_changes_nothing(scene, tmp_path, kind):
    op, kwargs, expected = corrupt_tet(tmp_path, kind)
    bpy.ops.hovr.add_sphere_volume()  # the user's volume: a failed import must not touch its look
    s = bpy.context.active_object.hovr
    s.value_min, s.value_max = -3.0, 7.0
    tex = s.transfer_function
    before = datablock_counts()
    active = bpy.context.view_layer.objects.active
    with pytest.raises(RuntimeError) as info:
        getattr(bpy.ops.import_scene, op)(**kwargs)
    message = str(info.value)
    assert "HOVR: cannot import" in message
    for part in expected:
        assert part in message, message
    assert datablock_counts() == before
    assert s.transfer_function == tex and (s.value_min, s.value_max) == (-3.0, 7.0)
    assert scene.camera is None  # nothing was framed either
    assert bpy.context.view_layer.objects.active == active


def _resolved(obj, frame=1):
    h = obj.hovr
    return sources.VolumeSource.resolve(h.source, h.solution, h.field, frame, component=h.component,
                                       abspath=lambda p: bpy.path.abspath(p, library=obj.library))


def test_relative_paths_survive_save_move_and_reopen(scene, tmp_path):
    project = tmp_path / "project"
    xml = copy_tet(project / "data")
    bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="p")  # into an unsaved file: absolute
    name = bpy.context.active_object.name
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "scene.blend"))
    obj = bpy.data.objects[name]
    assert (obj.hovr.source, obj.hovr.solution) == ("//data/Tet_channel_m3.xml", "//data/Tet_channel_m3.fld")
    # saved once more into a subfolder as a copy: the session keeps its own paths
    (project / "copies").mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(project / "copies" / "copy.blend"), copy=True)
    assert obj.hovr.source == "//data/Tet_channel_m3.xml"
    coeffs = sources.load_volume(_resolved(obj)).coeffs

    bpy.ops.wm.read_factory_settings(use_empty=True)  # registered classes and handlers stay
    moved = tmp_path / "moved"
    shutil.move(str(project), str(moved))
    for blend in (moved / "scene.blend", moved / "copies" / "copy.blend"):
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        obj = bpy.data.objects[name]
        src = _resolved(obj)
        assert src.path == str(moved / "data" / "Tet_channel_m3.xml"), (blend, obj.hovr.source)
        assert src.solution == str(moved / "data" / "Tet_channel_m3.fld")
        np.testing.assert_array_equal(sources.load_volume(src).coeffs, coeffs)
    assert bpy.data.objects[name].hovr.source == "//../data/Tet_channel_m3.xml"


def test_import_into_a_saved_file_stores_relative_paths(scene, tmp_path):
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "a.blend"))
    xml = copy_tet(tmp_path / "d")
    bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="w")
    obj = bpy.context.active_object
    assert obj.hovr.source == "//d/Tet_channel_m3.xml" and obj.hovr.solution == "//d/Tet_channel_m3.fld"
    assert _resolved(obj).path == str(xml)


def _render(scene):
    bpy.ops.render.render(write_still=False)


def test_imported_volume_renders_like_the_core(scene, tmp_path):
    """F12 of the moved, rotated import equals the core renderer's image of the derived mesh."""
    from hovr_blender.io.nektar.format import read_nektar_field

    xml = copy_tet(tmp_path)
    bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="|u,v,w|")
    obj = bpy.context.active_object
    obj.location, obj.rotation_euler = (0.25, -0.5, 0.0), (0.0, 0.0, 0.5)
    bpy.context.view_layer.update()  # matrix_world follows
    mesh = read_nektar_field(xml, xml.with_suffix(".fld"), "|u,v,w|")
    img, core = f12_and_engine(scene, obj, mesh, CONTRACT, W, H, 8.0, tmp_path)
    np.testing.assert_allclose(img, core, atol=1e-5)


def test_render_cache_reuses_the_mesh_and_rereads_changed_files(scene, tmp_path, monkeypatch):
    xml = copy_tet(tmp_path)
    render.clear_cache()
    reads = []
    real_start = sources.volume_request  # every read, waited for or polled (the modal import), starts here
    monkeypatch.setattr(sources, "volume_request", lambda *a: reads.append(a) or real_start(*a))
    bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="|u,v,w|")
    assert len(reads) == 1
    obj = bpy.context.active_object
    add_camera(scene)
    set_contract_camera(scene, CONTRACT, W, H)
    obj.hovr.density = 5.0
    imported = dict(sources._MESHES.items())
    assert len(imported) == 1
    (key, mesh), = imported.items()

    _render(scene)  # the import's read serves the render
    assert sources._MESHES.items() == [(key, mesh)]
    renderers = {id(r) for r, _ in render.RENDERERS.values()}
    _render(scene)  # nothing changed: same renderer, no read
    assert {id(r) for r, _ in render.RENDERERS.values()} == renderers
    obj.location = (0.5, 0.0, 0.0)
    obj.rotation_euler = (0.0, 0.0, 0.3)
    _render(scene)  # moved: another upload of the same loaded mesh
    assert sources._MESHES.items() == [(key, mesh)]
    assert len({id(r) for r, _ in render.RENDERERS.values()} - renderers) == 1
    assert len(reads) == 1  # three renders, one read (the import's)

    fld = xml.with_suffix(".fld")
    st = os.stat(fld)
    os.utime(fld, ns=(st.st_atime_ns, st.st_mtime_ns + 3_000_000_000))  # same bytes, new time stamp
    _render(scene)
    assert len(sources._MESHES) == 2 and sources._MESHES.get(key) is mesh
    (new_key, new_mesh), = [(k, m) for k, m in sources._MESHES.items() if k != key]
    assert new_mesh is not mesh and new_key[:3] == key[:3]
    np.testing.assert_array_equal(new_mesh.coeffs, mesh.coeffs)
    assert len(reads) == 2
    render.clear_cache()
