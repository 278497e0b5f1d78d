"""Animation over a numbered series of field files (one per frame, '#' in the path), re-read
only when the frame's file changes; and the `blender -b file.blend -f N` path in a fresh
process through the bpy module."""
import base64
import os
import re
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import render  # noqa: E402
from hovr_blender.ui.blender_camera import ray_camera_from_blender  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.engine.view import RenderOptions  # noqa: E402
from hovr_blender.io.nektar import read_nektar  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import add_camera, render_to_exr, set_contract_camera, set_ramp  # noqa: E402

HERE = Path(__file__).resolve().parent
STEM = "Hex_01_01_01_03Modes_x2_Offset3"  # one hex [-1,1]^2 x [-4,-2], p = x^2 + y^2 + z^2
W, H = 32, 24
STOPS = [(0.0, (0.0, 0.0, 0.0, 0.0)), (0.25, (1.0, 0.5, 0.25, 0.5)), (0.5, (0.25, 1.0, 0.5, 1.0)),
         (1.0, (0.25, 0.25, 1.0, 0.25))]
CONTRACT = {"eye": [5.0, 4.0, 0.5], "target": [0.0, 0.0, -3.0], "up": [0.0, 0.0, 1.0], "fov_y_deg": 35.0}


def write_series(folder: Path, scales):
    """m.xml plus m_0001.fld, m_0002.fld, ...: the ElVis field times scales[k] in frame k+1."""
    shutil.copy(data_file("nektar", f"{STEM}.xml"), folder / "m.xml")
    fld = data_file("nektar", f"{STEM}.fld").read_text()
    body = re.search(r">([^<]+)</ELEMENTS>", fld).group(1)
    values = np.frombuffer(zlib.decompress(base64.b64decode(body + "=" * (-len(body) % 4))), "<f8")
    for k, s in enumerate(scales, start=1):
        raw = zlib.compress(np.asarray(values * s, dtype="<f8").tobytes())
        raw += b"\0" * (-len(raw) % 3)  # Nektar++'s encoding: NUL-padded to 3 bytes, no '='
        text = fld.replace(body, base64.b64encode(raw).decode())
        (folder / f"m_{k:04d}.fld").write_text(text)


def build(scene, folder: Path):
    add_camera(scene)
    set_contract_camera(scene, CONTRACT, W, H)
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.0625, 0.0625, 0.125)
    scene.hovr.method, scene.hovr.step_units = "classified", 'WORLD'  # the core images' h = 0.01
    obj = bpy.data.objects.new("Flow", None)
    scene.collection.objects.link(obj)
    obj.hovr.is_volume = True  # ticking it gives the volume a transfer function
    obj.hovr.source, obj.hovr.solution, obj.hovr.field = "//m.xml", "//m_####.fld", "p"
    set_ramp(obj.hovr.transfer_function, STOPS)
    h = obj.hovr
    h.value_min, h.value_max, h.density_units, h.density = 4.0, 24.0, 'WORLD', 1.0
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "series.blend"))  # '//' is this folder
    return obj


def core_image(scene, folder, frame):
    mesh = read_nektar(folder / "m.xml", folder / f"m_{frame:04d}.fld", field="p")
    cam = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    tf = TransferFunction.from_rgba_ramp([p for p, _ in STOPS], [c for _, c in STOPS], 1.0, 4.0, 24.0)
    rgba = Renderer(mesh, "cpu").render(cam, tf, np.array([0.0625, 0.0625, 0.125]),
                                        RenderOptions(method="classified", h=0.01, tolerance=1e-5)).rgba
    rgba[..., 3] = 1.0
    return rgba


def test_frames_read_their_own_file_once(scene, tmp_path):
    write_series(tmp_path, [1.0, 1.25, 1.0])
    build(scene, tmp_path)
    render.clear_cache()
    images, renderers = {}, {}
    for frame in (1, 2, 2, 3):
        scene.frame_set(frame)
        images.setdefault(frame, []).append(render_to_exr(scene, tmp_path / f"f{frame}.exr"))
        renderers.setdefault(frame, set()).update(id(r) for r, _ in render.RENDERERS.values())
    np.testing.assert_array_equal(images[2][0], images[2][1])
    assert np.abs(images[1][0] - images[2][0]).max() > 1e-2  # a different file, a different field
    np.testing.assert_array_equal(images[1][0], images[3][0])  # frames 1 and 3 hold the same field
    for frame in (1, 2):
        np.testing.assert_allclose(images[frame][0], core_image(scene, tmp_path, frame), atol=1e-5)
    # frame 2 rendered twice with one upload (the second render reused the cached renderer)
    assert len(renderers[2]) == 2 and len(render.RENDERERS) <= render.RENDERERS.size


def test_missing_frame_file_is_reported(scene, tmp_path):
    write_series(tmp_path, [1.0])
    build(scene, tmp_path)
    scene.frame_set(5)
    with pytest.raises(RuntimeError, match="m_0005.fld"):
        bpy.ops.render.render(write_still=False)


def test_background_render_of_a_saved_blend(scene, tmp_path):
    """`blender -b series.blend -f 2` through the bpy module, in a fresh process: the frame's
    output file equals the in-process render of frame 2."""
    write_series(tmp_path, [1.0, 1.25])
    build(scene, tmp_path)
    r = scene.render
    r.filepath = str(tmp_path / "out" / "frame_####.exr")
    r.image_settings.file_format = 'OPEN_EXR'
    r.image_settings.color_depth = '32'
    scene.view_settings.view_transform = 'Standard'
    bpy.ops.wm.save_mainfile()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parents[1]), str(HERE)]))
    proc = subprocess.run([sys.executable, str(HERE / "render_blend_frame.py"), str(tmp_path / "series.blend"), "2"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = tmp_path / "out" / "frame_0002.exr"
    assert f"HOVR-OUTPUT {out}" in proc.stdout and out.is_file()
    img = bpy.data.images.load(str(out))
    px = np.empty(W * H * 4, np.float32)
    img.pixels.foreach_get(px)
    got = px.reshape(H, W, 4)[::-1]
    scene.frame_set(2)
    np.testing.assert_allclose(got, core_image(scene, tmp_path, 2), atol=1e-5)
