"""Child process of tests/distributed/test_render_blend_confined.py: Blender (the bpy module) made to
write everything a .blend of tests/hostile/make_blend.py names, on purpose, as a render never
would: the file opened (its scripts off), frames 1-3 simulated, a frame rendered into OUT, then
every bake and export operator that could apply (fluid, point caches, ocean, Alembic). Prints one
line an operator; failures are expected where the writes are refused.

    python blend_writer.py FILE.blend OUT
"""
import os
import sys
import time

import bpy


def attempt(name, run):
    try:
        print(name, run(), flush=True)
    except Exception as exc:  # noqa: BLE001  (a refused write is what the confined run expects)
        print(name, "failed:", type(exc).__name__, str(exc).splitlines()[0] if str(exc) else "", flush=True)


def _wait_for(path, seconds=5.0):
    """The ocean bake is a job in a thread of its own: give it time to write (or to be refused)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end and not os.path.exists(path):
        time.sleep(0.1)


def main():
    blend, out = sys.argv[1], sys.argv[2]
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False, use_scripts=False)
    scene = bpy.context.scene
    for frame in (1, 2, 3):
        scene.frame_set(frame)
    scene.render.filepath = os.path.join(out, "frame.png")
    scene.render.use_file_extension = False
    attempt("render", lambda: bpy.ops.render.render(write_still=True))
    for ob in list(scene.objects):
        with bpy.context.temp_override(object=ob, active_object=ob, selected_objects=[ob]):
            for mod in ob.modifiers:
                if mod.type == "FLUID" and mod.fluid_type == "DOMAIN":
                    attempt("fluid bake", bpy.ops.fluid.bake_all)
                if mod.type == "OCEAN":
                    attempt("ocean bake", lambda: bpy.ops.object.ocean_bake(modifier=mod.name))
                    _wait_for(os.path.join(bpy.path.abspath(mod.filepath), f"disp_{mod.frame_end:04d}.exr"))
    attempt("point caches bake", lambda: bpy.ops.ptcache.bake_all(bake=True))
    for collection in bpy.data.collections:
        for exporter in getattr(collection, "exporters", ()):
            attempt("alembic export", lambda: bpy.ops.wm.alembic_export(filepath=bpy.path.abspath(exporter.filepath)))
    sys.stdout.flush()
    os._exit(0)  # Mantaflow may abort at exit over its grid cache (Blender 5.0): the work is done


if __name__ == "__main__":
    main()
