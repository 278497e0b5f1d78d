"""One frame of a saved .blend rendered headless to a temporary file beside its output, for
`distributed/blender_frames.py` (which links it into place, so each frame is written once).
A script, not imported by the add-on:

    python batch.py FILE.blend FRAME ROOT MODE             (bpy as a Python module: registers the add-on)
    blender -b --disable-autoexec FILE.blend --python-exit-code 2 --python batch.py -- FRAME ROOT MODE
                                                           (a Blender with the add-on enabled)

The .blend is opened without running its scripts (`--disable-autoexec`; `use_scripts=False` for
the module). Its outputs are confined to ROOT: MODE "into" writes each frame into the folder ROOT
under the file name the .blend gives it; MODE "under" keeps the .blend's output path only if it
lies under ROOT (the .blend's own folder). A compositor File Output node writing elsewhere, or an
output path outside ROOT, is refused naming the path (`HOVR-ERROR <message>`, exit status 2).

Prints `HOVR-EXISTS {"out": ...}` when the frame's output (scene.render.frame_path, as
`blender -b -a` names it, but iso_q0001.png for an output path iso_q.png: frame_file) exists
already, else renders and prints
`HOVR-RENDERED {"tmp": ..., "out": ...}`.
"""
import json
import os
import sys

import bpy

EXIT_REFUSED = 2


class Refused(Exception):
    """An output this run will not write."""


def _inside(path: str, root: str) -> bool:
    """Whether `path` (its existing part's links resolved) lies in the folder `root`."""
    real = os.path.realpath(path)
    top = os.path.realpath(root)
    return os.path.commonpath([real, top]) == top


def _file_output_paths(scene):
    """The folders the scene's compositor File Output nodes write to."""
    tree = getattr(scene, "compositing_node_group", None) or getattr(scene, "node_tree", None)
    if tree is None:
        return
    for node in tree.nodes:
        if node.bl_idname == "CompositorNodeOutputFile":
            for attr in ("base_path", "directory"):
                value = getattr(node, attr, None)
                if value:
                    yield node.name, bpy.path.abspath(value)


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
    for name, path in _file_output_paths(scene):
        if not _inside(path, root):
            raise Refused(f"the compositor's File Output node {name!r} writes to {path}, outside {root}; refused")
    return out


def render_scene_frame(frame: int, root: str, mode: str):
    scene = bpy.context.scene
    out = output_path(scene, frame, root, mode)
    if os.path.lexists(out):
        print("HOVR-EXISTS", json.dumps({"out": out}), flush=True)
        return
    os.makedirs(os.path.dirname(out), exist_ok=True)
    if not _inside(os.path.dirname(out), root):  # a link among the folders just made
        raise Refused(f"the output folder {os.path.dirname(out)} leads outside {root}; refused")
    scene.frame_set(frame)
    tmp = os.path.join(os.path.dirname(out), f".{os.path.basename(out)}.{os.getpid()}.tmp")
    if os.path.lexists(tmp):
        os.unlink(tmp)
    scene.render.filepath = tmp
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    print("HOVR-RENDERED", json.dumps({"tmp": tmp, "out": out}), flush=True)


def _one_off_renders():
    """Each frame is rendered in a Blender of its own: F12 keeps no segments for a next render that
    never comes (ui/render.FINAL.once), whichever name the add-on has here (bl_ext.<repo>.hovr_blender)."""
    for name, module in list(sys.modules.items()):
        if name.endswith("hovr_blender.ui.render") and hasattr(module, "FINAL"):
            module.FINAL.once = True


def _run(frame: str, root: str, mode: str) -> int:
    _one_off_renders()
    try:
        render_scene_frame(int(frame), root, mode)
    except Refused as exc:
        print("HOVR-ERROR", exc, flush=True)
        return EXIT_REFUSED
    return 0


def main():
    if "--" in sys.argv:  # inside a Blender: the .blend is open (scripts not run), the add-on enabled
        frame, root, mode = sys.argv[sys.argv.index("--") + 1:][:3]
        code = _run(frame, root, mode)
        if code:
            sys.exit(code)  # with --python-exit-code, Blender exits with it
        return
    blend, frame, root, mode = sys.argv[1:5]
    import hovr_blender

    hovr_blender.register()
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False, use_scripts=False)
    code = _run(frame, root, mode)
    hovr_blender.unregister()
    from hovr_blender.ui import compat

    compat.finish_script(code)


if __name__ == "__main__":
    main()
