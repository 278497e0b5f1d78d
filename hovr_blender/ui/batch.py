"""One frame of a saved .blend rendered headless to a temporary file beside its output, for
`distributed/blender_frames.py` (which links it into place, so each frame is written once).
A script, not imported by the add-on:

    python batch.py FILE.blend FRAME ROOT MODE             (bpy as a Python module: registers the add-on)
    blender -b --disable-autoexec --python-exit-code 2 --python batch.py -- FRAME ROOT MODE FILE.blend
                                                           (a Blender with the add-on enabled)

The .blend is untrusted. Before it is opened (opening it evaluates its scene: a fluid domain
writes its cache folder then), its datablocks are linked in, not evaluated, and those that make
Blender write while it renders are checked (`write_paths`): a fluid domain's cache folder, a
point cache on disk (particles, cloth, soft bodies, dynamic paint, rigid bodies: written as
frames are simulated) and the compositor's File Output nodes (inside node groups too) must lie in
ROOT, or the .blend is refused naming the path (`HOVR-ERROR <message>`, exit status 2). Bakes,
exports (Alembic, USD) and sequencer proxies are written only by their operators, which this
script never runs. On Linux, Blender's writes are also confined by the operating system to ROOT
and its private temporary folder (engine/landlock.py, set up by the task that starts Blender),
so what this list misses is refused by the kernel.

Then the .blend is opened without running its scripts (`--disable-autoexec`; `use_scripts=False`
for the module). MODE "into" writes each frame into the folder ROOT under the file name the
.blend gives it; MODE "under" keeps the .blend's output path only if it lies under ROOT (the
.blend's own folder).

Its reports go to the task alone, a JSON line each on the file descriptor HOVR_RESULT_FD (a pipe
the task made; never stdout, where an object's name can print anything): `{"status": "exists",
"out": ...}` when the frame's output (scene.render.frame_path, as `blender -b -a` names it, but
iso_q0001.png for an output path iso_q.png: frame_file) exists already; else `{"status": "rendering", "out": ..., "tmp": ...}` before it renders to
`.<name>.<pid>.tmp` beside it, and `{"status": "rendered", ...}` after.
"""
import json
import os
import sys

import bpy

EXIT_REFUSED = 2
RESULT_FD = "HOVR_RESULT_FD"


class Refused(Exception):
    """An output this run will not write."""


def _inside(path: str, root: str) -> bool:
    """Whether `path` (its existing part's links resolved) lies in the folder `root`."""
    real = os.path.realpath(path)
    top = os.path.realpath(root)
    return os.path.commonpath([real, top]) == top


def _nodes(tree, seen=None):
    """The nodes of a node tree and of the node groups inside it, each group once."""
    seen = set() if seen is None else seen
    if tree is None or tree.name_full in seen:
        return
    seen.add(tree.name_full)
    for node in tree.nodes:
        yield node
        yield from _nodes(getattr(node, "node_tree", None), seen)


def _file_output_paths(scene):
    """(name, folder) of the scene's compositor File Output nodes (those in node groups included)."""
    tree = getattr(scene, "compositing_node_group", None) or getattr(scene, "node_tree", None)
    for node in _nodes(tree):
        if node.bl_idname == "CompositorNodeOutputFile":
            for attr in ("base_path", "directory"):
                value = getattr(node, attr, None)
                if value:
                    yield f"the compositor's File Output node {node.name!r}", _absolute(value, scene)


def _absolute(path: str, datablock) -> str:
    """A datablock's path made absolute: a // path from the .blend it comes from."""
    return os.path.abspath(bpy.path.abspath(path, library=getattr(datablock, "library", None)))


def _point_caches(ob):
    """(what, point cache) of an object's simulations."""
    for psys in getattr(ob, "particle_systems", ()):
        yield f"particle system {psys.name!r}", psys.point_cache
    for mod in getattr(ob, "modifiers", ()):
        if getattr(mod, "point_cache", None) is not None:
            yield f"modifier {mod.name!r}", mod.point_cache
        for surface in getattr(getattr(mod, "canvas_settings", None), "canvas_surfaces", ()) or ():
            yield f"dynamic paint surface {surface.name!r}", surface.point_cache


def write_paths(objects, scenes, blend: str):
    """(what, path) of every place the datablocks make Blender write while it renders (module doc)."""
    disk_cache = os.path.join(os.path.dirname(os.path.abspath(blend)),
                              "blendcache_" + os.path.splitext(os.path.basename(blend))[0])
    for ob in objects:
        for mod in getattr(ob, "modifiers", ()):
            if mod.type == "FLUID" and mod.fluid_type == "DOMAIN":
                yield f"the fluid cache folder of object {ob.name!r}", _absolute(mod.domain_settings.cache_directory, ob)
        for what, cache in _point_caches(ob):
            if cache is not None and cache.use_disk_cache and not cache.use_external:
                yield f"the disk cache of object {ob.name!r}'s {what}", disk_cache
    for scene in scenes:
        world = getattr(scene, "rigidbody_world", None)
        cache = getattr(world, "point_cache", None)
        if cache is not None and cache.use_disk_cache and not cache.use_external:
            yield f"the rigid body disk cache of scene {scene.name!r}", disk_cache
        yield from _file_output_paths(scene)


def check_datablocks(blend: str, root: str):
    """Refused if a datablock of `blend` would make Blender write outside `root` (write_paths),
    looked at before the .blend is opened: its objects and scenes linked into this empty file,
    where nothing evaluates them."""
    with bpy.data.libraries.load(blend, link=True) as (src, dst):
        dst.objects = list(src.objects)
        dst.scenes = list(src.scenes)
    try:
        for what, path in write_paths([o for o in dst.objects if o is not None],
                                      [s for s in dst.scenes if s is not None], blend):
            if not _inside(path, root):
                raise Refused(f"{what} is {path}, outside {root} (Blender writes there while it renders); refused")
    finally:
        for library in list(bpy.data.libraries):
            bpy.data.libraries.remove(library)


def frame_file(scene, frame: int) -> str:
    """The file `blender -b -a` writes frame `frame` to (RenderSettings.frame_path), except that an
    output path ending in the image format's own extension, with no '#' (//iso_q.png), numbers the
    frame before the extension (iso_q0001.png) where Blender numbers it after (iso_q.png0001.png)."""
    r = scene.render
    name = os.path.basename(r.filepath)
    ext = r.file_extension
    if not (r.use_file_extension and ext and "#" not in name and name.lower().endswith(ext.lower())
            and len(name) > len(ext)):
        return r.frame_path(frame=frame)
    saved = r.filepath
    try:
        r.filepath = saved[:-len(ext)]
        return r.frame_path(frame=frame)
    finally:
        r.filepath = saved


def output_path(scene, frame: int, root: str, mode: str) -> str:
    """Where frame `frame` goes: confined to `root` (module doc); Refused otherwise."""
    out = os.path.abspath(bpy.path.abspath(frame_file(scene, frame)))
    if mode == "into":
        out = os.path.join(os.path.abspath(root), os.path.basename(out))
    elif not _inside(out, root):
        raise Refused(f"the .blend's output path {out} is outside its own folder {root}; refused "
                      f"(give render-blend -o FOLDER to write the frames there)")
    for what, path in _file_output_paths(scene):
        if not _inside(path, root):
            raise Refused(f"{what} writes to {path}, outside {root}; refused")
    return out


def _report(report: dict):
    """One line to the task alone (the pipe HOVR_RESULT_FD names)."""
    os.write(int(os.environ[RESULT_FD]), (json.dumps(report) + "\n").encode())


def render_scene_frame(frame: int, root: str, mode: str):
    scene = bpy.context.scene
    out = output_path(scene, frame, root, mode)
    if os.path.lexists(out):
        _report({"status": "exists", "out": out})
        return
    os.makedirs(os.path.dirname(out), exist_ok=True)
    if not _inside(os.path.dirname(out), root):  # a link among the folders just made
        raise Refused(f"the output folder {os.path.dirname(out)} leads outside {root}; refused")
    scene.frame_set(frame)
    tmp = os.path.join(os.path.dirname(out), f".{os.path.basename(out)}.{os.getpid()}.tmp")
    if os.path.lexists(tmp):
        os.unlink(tmp)
    _report({"status": "rendering", "tmp": tmp, "out": out})  # the task removes it, whatever happens next
    scene.render.filepath = tmp
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    _report({"status": "rendered", "tmp": tmp, "out": out})


def _one_off_renders():
    """Each frame is rendered in a Blender of its own: F12 keeps no segments for a next render that
    never comes (ui/render.FINAL.once), whichever name the add-on has here (bl_ext.<repo>.hovr_blender)."""
    for name, module in list(sys.modules.items()):
        if name.endswith("hovr_blender.ui.render") and hasattr(module, "FINAL"):
            module.FINAL.once = True


def _run(blend: str, frame: str, root: str, mode: str) -> int:
    _one_off_renders()
    try:
        check_datablocks(blend, root)
        bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False, use_scripts=False)
        render_scene_frame(int(frame), root, mode)
    except Refused as exc:
        print("HOVR-ERROR", " ".join(str(exc).split()), flush=True)
        return EXIT_REFUSED
    return 0


def main():
    if "--" in sys.argv:  # inside a Blender started without the .blend: the add-on is enabled
        frame, root, mode, blend = sys.argv[sys.argv.index("--") + 1:][:4]
        code = _run(blend, frame, root, mode)
        if code:
            sys.exit(code)  # with --python-exit-code, Blender exits with it
        return
    blend, frame, root, mode = sys.argv[1:5]
    import hovr_blender

    hovr_blender.register()
    code = _run(blend, frame, root, mode)
    hovr_blender.unregister()
    from hovr_blender.ui import compat

    compat.finish_script(code)


if __name__ == "__main__":
    main()
