"""Writes one hostile .blend for tests/hostile/run_cases.py; run as a child process with the bpy
module (`python make_blend.py KIND OUT.blend [MARKER]`), so the runner never imports bpy.

Every .blend is an empty 4x4 scene rendered by Workbench (nothing to compile), saved with:
- "plain": nothing more (renders);
- "register": a text block registered to run on load (writes MARKER if it runs);
- "driver": a driver that computes factorial(10**8) from frame 2 on (Blender's restricted mode
  lets it through; frame 1, where the file is saved, stays instant);
- "outside": the output path //../elsewhere/frame_#### (above the .blend's folder);
- "absolute": the output path MARKER (an absolute path elsewhere).
"""
import sys

import bpy


def main():
    kind, out = sys.argv[1], sys.argv[2]
    marker = sys.argv[3] if len(sys.argv) > 3 else ""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 4
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = "//out/frame_####"
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    if kind == "register":
        text = bpy.data.texts.new("autorun.py")
        text.write(f"open({marker!r}, 'w').write('ran')\n")
        text.use_module = True
    elif kind == "driver":
        empty = bpy.data.objects.new("Driven", None)
        scene.collection.objects.link(empty)
        curve = empty.driver_add("location", 0)
        curve.driver.type = "SCRIPTED"
        curve.driver.expression = "factorial(10**8 * (frame > 1))"
    elif kind == "outside":
        scene.render.filepath = "//../elsewhere/frame_####"
    elif kind == "absolute":
        scene.render.filepath = marker
    bpy.ops.wm.save_as_mainfile(filepath=out)


if __name__ == "__main__":
    main()
