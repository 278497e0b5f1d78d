"""Hostile files inside Blender (issue 13): a refused import or render reaches the user as a
report, quickly; nothing the user had changes, and the session and its .blend survive.
The files come from the hostile suite's generators (tests/hostile/cases.py)."""
import os
import time

import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from ..hostile import cases  # noqa: E402
from .blender_helpers import datablock_counts  # noqa: E402

SECONDS = 5.0


def _fifo(folder, name):
    os.mkfifo(folder / name)
    return folder / name


def _mesh_is_fifo(folder):
    return "hovr_nektar", {"filepath": str(_fifo(folder, "m.xml"))}, ["FIFO"]


def _mesh_is_dev_zero(folder):
    os.symlink("/dev/zero", folder / "m.xml")
    return "hovr_nektar", {"filepath": str(folder / "m.xml")}, ["device"]


def _solution_is_fifo(folder):
    (folder / "m.xml").write_text(cases.nektar_mesh())
    _fifo(folder, "m.fld")
    return "hovr_nektar", {"filepath": str(folder / "m.xml")}, ["FIFO"]


def _hdf5_external_storage(folder):
    (folder / "m.xml").write_text(cases.nektar_mesh())
    cases._external_data("/etc/passwd")(folder / "m.fld")
    return "hovr_nektar", {"filepath": str(folder / "m.xml"), "field": "p"}, ["m.fld", "external"]


def _domain_amplification(folder):
    (folder / "m.xml").write_text(cases.nektar_mesh(domain=",".join(["C[0-1048575]"] * 2000)))
    return "hovr_nektar", {"filepath": str(folder / "m.xml")}, ["m.xml"]


def _vtu_bomb(folder):
    cases.many_blocks_of_zeros(folder)
    return "hovr_vtu", {"filepath": str(folder / "m.vtu"), "field": "f"}, ["m.vtu"]


def _vtu_is_fifo(folder):
    return "hovr_vtu", {"filepath": str(_fifo(folder, "m.vtu"))}, ["FIFO"]


def _hdf5_mutant(mutant, words):
    """One of the hostile suite's HDF5 mutants (libhdf5 crashes or loops on it): the reader
    process's failure is the report; Blender is not touched."""
    def build(folder):
        (folder / "m.xml").write_text(cases.nektar_mesh())
        mutant(folder / "m.fld")
        return "hovr_nektar", {"filepath": str(folder / "m.xml"), "field": "p"}, ["m.fld", *words]
    return build


IMPORTS = {"HDF5 vlen type bits (SIGSEGV)": _hdf5_mutant(cases.VLEN_TYPE_BITS, ["crashed"]),
           "HDF5 heap object of size 0 (loops)": _hdf5_mutant(cases.HEAP_OBJECT_SIZE, ["longer than the limit"]),
           "mesh is a FIFO": _mesh_is_fifo, "mesh is /dev/zero": _mesh_is_dev_zero,
           "solution is a FIFO": _solution_is_fifo, "HDF5 external storage": _hdf5_external_storage,
           "DOMAIN amplification": _domain_amplification, "VTU 800 blocks of zeros": _vtu_bomb,
           "VTU is a FIFO": _vtu_is_fifo}


@pytest.mark.parametrize("kind", list(IMPORTS))
def test_hostile_import_is_refused_quickly_and_changes_nothing(scene, tmp_path, kind, monkeypatch):
    monkeypatch.setenv("HOVR_MAX_READ_SECONDS", "1")  # libhdf5's loops: stopped after a second
    bpy.ops.hovr.add_sphere_volume()
    s = bpy.context.active_object.hovr  # the user's volume: an import must not touch its look
    s.value_min, s.value_max = -3.0, 7.0
    blend = tmp_path / "before.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    before = datablock_counts()
    active = bpy.context.view_layer.objects.active
    volume_name = active.name
    op, kwargs, expected = IMPORTS[kind](tmp_path)
    t0 = time.perf_counter()
    with pytest.raises(RuntimeError) as info:
        getattr(bpy.ops.import_scene, op)(**kwargs)
    assert time.perf_counter() - t0 < SECONDS
    message = str(info.value)
    assert "HOVR: cannot import" in message and "Traceback" not in message
    for part in expected:
        assert part in message, message
    assert datablock_counts() == before
    assert (s.value_min, s.value_max) == (-3.0, 7.0)
    assert bpy.context.view_layer.objects.active == active
    # the session goes on: the file saves and opens again with the user's volume in it
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "after.blend"))
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "after.blend"))
    assert [o.name for o in bpy.data.objects if o.hovr.is_volume] == [volume_name]


def test_render_of_a_hostile_source_is_a_report(scene, tmp_path):
    """A volume whose file was swapped for a FIFO: F12 reports, does not hang, changes nothing."""
    from .blender_helpers import add_camera, set_contract_camera

    bpy.ops.hovr.add_sphere_volume()
    add_camera(scene)
    set_contract_camera(scene, {"eye": [0, -12, 1], "target": [0, 0, 1], "up": [0, 0, 1], "fov_y_deg": 40}, 16, 12)
    scene.render.resolution_x, scene.render.resolution_y = 16, 12
    vol = next(o for o in scene.objects if o.hovr.is_volume)
    vol.hovr.source = str(_fifo(tmp_path, "m.xml"))
    t0 = time.perf_counter()
    with pytest.raises(RuntimeError, match="FIFO"):
        bpy.ops.render.render(write_still=False)
    assert time.perf_counter() - t0 < SECONDS
    assert vol.hovr.source.endswith("m.xml")
