"""Run by Debian's Blender 3.4 in background mode: enable HOVR as a legacy add-on, build the
sphere scene, save it (a file given on the command line suppresses the splash screen)."""
import os
import sys

import addon_utils
import bpy

# warp-lang is not packaged by Debian: take it from the project's venv (same Python 3.11 ABI),
# appended so Debian's numpy, which its Blender was built with, still comes first.
if os.environ.get("HOVR_EXTRA_SITE"):
    sys.path.append(os.environ["HOVR_EXTRA_SITE"])

out = sys.argv[sys.argv.index("--") + 1]
addon_utils.enable("hovr_blender", default_set=False, handle_error=None)
bpy.ops.wm.read_factory_settings(use_empty=False)
addon_utils.enable("hovr_blender", default_set=False, handle_error=None)
for obj in list(bpy.data.objects):
    bpy.data.objects.remove(obj)
sc = bpy.context.scene
sc.render.engine = 'HOVR'
bpy.ops.hovr.add_sphere_volume()
sphere = bpy.context.active_object
sphere.location, sphere.rotation_euler = (0.25, -0.5, 0.5), (0.0, 0.0, 0.5)
cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
sc.collection.objects.link(cam)
sc.camera = cam
cam.location = (6.5, -5.0, 4.5)
cam.rotation_euler = (1.05, 0.0, 0.92)
cam.data.lens = 35
s = sphere.hovr
s.value_min, s.value_max, s.density_units, s.density = 0.0, 2.0, 'WORLD', 2.0
sc.hovr.method = "classified"
sc.world = bpy.data.worlds.new("World")
sc.world.color = (0.05, 0.03, 0.1)
sc.view_settings.view_transform = 'Standard'
sc.view_settings.look = 'None'
sc.render.dither_intensity = 0.0
bpy.ops.wm.save_as_mainfile(filepath=out)
