"""Render the bundled demo through Blender's own render pipeline (F12 path, headless).

    python -m scripts.render_demo [--output demo.png] [--size 640x480] [--device cpu]

Registers the add-on in a factory-fresh scene, adds the paper's sphere volume with the
HOVR "Add > HOVR Sphere Volume" operator, gives it the "Three Tents" transfer-function preset
(the paper's shells), points a camera at it and runs
bpy.ops.render.render(write_still=True) with the HOVR engine.
"""
from __future__ import annotations

import argparse
import os



def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--output", default="demo.png")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--method", default="classified")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))

    import bpy
    from mathutils import Vector

    import hovr_blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    try:
        scene = bpy.context.scene
        scene.render.engine = "HOVR"
        scene.render.resolution_x, scene.render.resolution_y = w, h
        scene.render.resolution_percentage = 100
        scene.render.image_settings.file_format = "PNG"
        scene.render.filepath = os.path.abspath(args.output)
        scene.hovr.method = args.method
        scene.hovr.device = args.device
        world = bpy.data.worlds.new("Demo World")
        world.color = (0.02, 0.02, 0.03)
        scene.world = world
        bpy.ops.hovr.add_sphere_volume()
        # the paper's look: thin shells of the radial field (a new volume gets a smooth ramp)
        bpy.ops.hovr.transfer_function_preset(preset="TENTS")
        cam_data = bpy.data.cameras.new("Demo Camera")
        cam_data.lens = 40.0
        cam = bpy.data.objects.new("Demo Camera", cam_data)
        scene.collection.objects.link(cam)
        cam.location = (6.5, -5.0, 6.0)
        direction = Vector((0.0, 0.0, 1.0)) - cam.location
        cam.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
        scene.camera = cam
        bpy.ops.render.render(write_still=True)
    finally:
        hovr_blender.unregister()
    print(f"demo: wrote {args.output}")


if __name__ == "__main__":
    main()
