"""A saved .blend's animation over a local Dask cluster (issue 18): 2 workers, each frame rendered
by a headless Blender (the bpy module here) into the file `blender -b -a` writes, each exactly once;
a rerun renders nothing."""
import json
import os
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
distributed = pytest.importorskip("distributed")
pytestmark = [pytest.mark.blender, pytest.mark.slow]

from hovr_blender.distributed import blender_frames, series  # noqa: E402

from .blender_helpers import build_sphere_scene  # noqa: E402

CONTRACT = {"eye": [8.0, 6.0, 4.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}
STOPS = [(0.0, (0.0, 0.0, 0.0, 0.0)), (0.5, (1.0, 0.5, 0.25, 0.6)), (1.0, (0.25, 0.25, 1.0, 0.3))]


def test_blend_animation_over_two_workers(scene, tmp_path):
    from distributed import Client, LocalCluster

    obj = build_sphere_scene(scene, CONTRACT, 32, 24, STOPS, (0.0, 20.0), 1.0, (0.05, 0.05, 0.1),
                             (0.0, 0.0, 0.0), 0.0)
    for frame, angle in ((1, 0.0), (3, 1.2)):
        obj.rotation_euler = (0.0, 0.0, angle)
        obj.keyframe_insert("rotation_euler", frame=frame)
    scene.frame_start, scene.frame_end = 1, 3
    scene.render.filepath = "//out/frame_####"
    scene.render.image_settings.file_format = 'PNG'
    blend = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    expected = {f: Path(bpy.path.abspath(scene.render.frame_path(frame=f))) for f in (1, 2, 3)}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        seen = []
        records = blender_frames.render_animation(str(blend), [1, 2, 3], client,
                                                  progress=lambda done, total, rec: seen.append(done))
        assert seen == [1, 2, 3]
        assert [r["status"] for r in records] == ["written"] * 3
        assert {r["frame"]: Path(r["output"]) for r in records} == expected
        again = blender_frames.render_animation(str(blend), [1, 2, 3], client)
        assert [r["status"] for r in again] == ["exists"] * 3
    with open(expected[1].parent / series.LOG_NAME) as fh:
        assert sorted(json.loads(line)["frame"] for line in fh) == [1, 2, 3]
    assert not [p for p in os.listdir(expected[1].parent) if p.endswith(".tmp")]
    imgs = []
    for f in (1, 3):
        img = bpy.data.images.load(str(expected[f]))
        px = np.empty(32 * 24 * 4, np.float32)
        img.pixels.foreach_get(px)
        imgs.append(px)
    assert np.abs(imgs[0] - imgs[1]).max() > 0.01  # the keyframed rotation shows


def test_an_output_path_ending_in_its_extension_numbers_the_frame_before_it(scene, tmp_path):
    """Issue 40: a .blend whose output path is //iso_q.png gives render-blend's frame 7 the name
    iso_q0007.png, not Blender's iso_q.png0007.png."""
    build_sphere_scene(scene, CONTRACT, 8, 6, STOPS, (0.0, 20.0), 1.0, (0.05, 0.05, 0.1), (0.0, 0.0, 0.0), 0.0)
    scene.render.filepath = "//iso_q.png"
    scene.render.image_settings.file_format = 'PNG'
    blend = tmp_path / "iso.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    record = blender_frames.render_blend_frame(str(blend), 7)
    assert record["status"] == "written" and Path(record["output"]) == tmp_path / "iso_q0007.png"
    assert sorted(p.name for p in tmp_path.glob("iso_q*")) == ["iso_q0007.png"]
