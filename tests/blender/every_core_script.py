"""Child process of test_extension.py, written as a user writes a bpy script: no main guard. It
installs the built zip as an extension and renders the sphere with F12 on one CPU core, then on
All CPU Cores. Each run of this file appends a line to spec["runs"]: a device's process that ran
the user's script again would show as a second line."""
import json
import sys

import bpy
import numpy as np

from blender_helpers import build_sphere_scene, compat, render_to_exr

spec = json.loads(sys.argv[1])
with open(spec["runs"], "a", encoding="utf-8") as fh:
    fh.write("run\n")
result = bpy.ops.extensions.package_install_files(filepath=spec["zip"], repo="user_default", enable_on_install=True)
assert result == {"FINISHED"}, result
for obj in list(bpy.data.objects):  # the default startup scene's cube, light and camera
    bpy.data.objects.remove(obj)
scene = bpy.context.scene
scene.render.engine = "HOVR"
build_sphere_scene(scene, spec["contract"], spec["width"], spec["height"], [tuple(s) for s in spec["stops"]],
                   spec["value_range"], spec["density_scale"], spec["background"], spec["location"],
                   spec["angle_z"])
np.save(spec["one"], render_to_exr(scene, spec["exr"]))
scene.hovr.device = "cpu:all"
np.save(spec["every"], render_to_exr(scene, spec["exr"]))
compat().finish_script(0)
