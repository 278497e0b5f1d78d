"""Writes one hostile .blend for tests/hostile/run_cases.py; run as a child process with the bpy
module (`python make_blend.py KIND OUT.blend [MARKER]`), so the runner never imports bpy.

Every .blend is an empty 4x4 scene rendered by Workbench (nothing to compile), saved with:
- "plain": nothing more (renders);
- "register": a text block registered to run on load (writes MARKER if it runs);
- "driver": a driver that computes factorial(10**8) from frame 2 on (Blender's restricted mode
  lets it through; frame 1, where the file is saved, stays instant);
- "outside": the output path //../elsewhere/frame_#### (above the .blend's folder);
- "absolute": the output path MARKER (an absolute path elsewhere);
- "fluid": a fluid domain (and a flow) whose cache folder is MARKER (Blender writes it as soon as
  the scene is evaluated: on opening the file, and as frames are simulated);
- "pointcache": a particle system with its point cache on disk (Blender writes it next to the
  .blend, in blendcache_<name>, as frames are simulated);
- "ocean": an ocean modifier whose bake folder is MARKER (written by its bake operator);
- "alembic": a collection with an Alembic exporter to MARKER/thing.abc (written by the export
  operators).
"""
import os
import sys

import bpy


def _cube(scene, name, size=1.0):
    import bmesh  # after bpy

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=size)
    bm.to_mesh(mesh)
    bm.free()
    ob = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(ob)
    return ob


def main():
    kind, out = sys.argv[1], sys.argv[2]
    marker = sys.argv[3] if len(sys.argv) > 3 else ""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no s.blend1 beside it
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
    elif kind == "fluid":
        domain = _cube(scene, "Domain", 2.0).modifiers.new("Fluid", "FLUID")
        domain.fluid_type = "DOMAIN"
        domain.domain_settings.resolution_max = 6
        domain.domain_settings.cache_directory = marker
        _cube(scene, "Flow", 0.5).modifiers.new("Fluid", "FLUID").fluid_type = "FLOW"
    elif kind == "pointcache":
        _cube(scene, "Emitter").modifiers.new("Particles", "PARTICLE_SYSTEM")
    elif kind == "ocean":
        ocean = _cube(scene, "Ocean").modifiers.new("Ocean", "OCEAN")
        ocean.filepath, ocean.resolution, ocean.use_foam = marker, 1, True
        ocean.frame_start, ocean.frame_end = 1, 2
    elif kind == "alembic":
        collection = bpy.data.collections.new("Exported")
        scene.collection.children.link(collection)
        thing = _cube(scene, "Thing")
        scene.collection.objects.unlink(thing)
        collection.objects.link(thing)
        collection.exporters.new("IO_FH_alembic").filepath = os.path.join(marker, "thing.abc")
    bpy.ops.wm.save_as_mainfile(filepath=out)
    if kind == "pointcache":  # a disk cache needs a saved file
        cache = bpy.data.objects["Emitter"].particle_systems[0].point_cache
        cache.use_disk_cache = True
        bpy.ops.wm.save_as_mainfile(filepath=out)
    if kind == "fluid":  # Mantaflow aborts at exit over its grid cache (Blender 5.0): the file is saved
        sys.stdout.flush()
        os._exit(0)


if __name__ == "__main__":
    main()
