"""One frame of a saved .blend rendered headless to a temporary file beside its output, for
`distributed/blender_frames.py` (which links it into place, so each frame is written once).
A script, not imported by the add-on:

    python batch.py FILE.blend FRAME                  (bpy as a Python module: registers the add-on)
    blender -b FILE.blend --python batch.py -- FRAME  (a Blender with the add-on enabled)

Prints `HOVR-EXISTS <output>` when the frame's output (scene.render.frame_path, as `blender -b
-a` names it) exists already, else renders and prints `HOVR-RENDERED <temporary> <output>`.
"""
import os
import sys

import bpy


def render_frame(frame: int):
    scene = bpy.context.scene
    out = bpy.path.abspath(scene.render.frame_path(frame=frame))
    if os.path.exists(out):
        print("HOVR-EXISTS", out, flush=True)
        return
    os.makedirs(os.path.dirname(out), exist_ok=True)
    scene.frame_set(frame)
    tmp = os.path.join(os.path.dirname(out), f".{os.path.basename(out)}.{os.getpid()}.tmp")
    scene.render.filepath = tmp
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    print("HOVR-RENDERED", tmp, out, flush=True)


def main():
    if "--" in sys.argv:  # inside a Blender: the .blend is open, the add-on enabled
        render_frame(int(sys.argv[sys.argv.index("--") + 1]))
        return
    import hovr_blender

    hovr_blender.register()
    bpy.ops.wm.open_mainfile(filepath=sys.argv[1])
    render_frame(int(sys.argv[2]))
    hovr_blender.unregister()
    from hovr_blender.ui import compat

    compat.finish_script(0)


if __name__ == "__main__":
    main()
