"""Child process: the bpy-module form of `blender -b FILE.blend -f N`. Registers the add-on
from the repository, opens the .blend, renders frame N to the scene's output path (frame
number substituted, as -f does) and prints that path."""
import sys

import bpy

import hovr_blender


def main():
    blend, frame = sys.argv[1], int(sys.argv[2])
    hovr_blender.register()
    bpy.ops.wm.open_mainfile(filepath=blend)
    scene = bpy.context.scene
    scene.frame_set(frame)
    out = scene.render.frame_path(frame=frame)
    scene.render.filepath = out
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    print("HOVR-OUTPUT", out)
    hovr_blender.unregister()


if __name__ == "__main__":
    main()
    from hovr_blender.ui import compat

    compat.finish_script(0)
