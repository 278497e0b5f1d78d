"""File > Import > HOVR Nektar++ (.xml) / HOVR VTU (.vtu): a finite-element volume as an object.

The file is read first; only a successful read creates anything (the outline mesh, the
object, a transfer function if the scene has none), so a malformed file leaves the .blend as
it was and the error names the file (and the element or record where the reader can tell).
The object stores the data's path relative to the saved .blend ('//'); a save handler keeps
that true when the .blend is first saved or saved elsewhere (Blender's own relative-path
remapping does not see add-on properties).
"""
import os

import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..io import nektar, vtu
from ..io.sources import VolumeSource, cached_volume, parse_component
from . import operators
from .scene import field_samples


def _relative_wanted() -> bool:
    prefs = getattr(bpy.context, "preferences", None)
    return prefs is None or prefs.filepaths.use_relative_paths


def stored_path(path: str) -> str:
    """How Object.hovr keeps a data path: '//'-relative to the saved .blend (Blender's relative
    paths preference, on by default), else absolute."""
    if not path or not bpy.data.filepath or not _relative_wanted():
        return path
    try:
        return bpy.path.relpath(path)
    except ValueError:  # another drive (Windows): no relative form
        return path


def _absolute(path: str, base_dir: str) -> str:
    """A path typed in the operator: '//' is the .blend's folder, other relative paths the data's."""
    path = path.strip()
    if not path:
        return ""
    if path.startswith("//"):
        path = bpy.path.abspath(path)
    elif not os.path.isabs(path):
        path = os.path.join(base_dir, path)
    return os.path.abspath(path)


def _fail(op, path, exc) -> set:
    what = str(exc) if isinstance(exc, (ValueError, OSError)) else f"unexpected {type(exc).__name__}: {exc}"
    op.report({'ERROR'}, f"HOVR: cannot import {os.path.basename(path)}: {what}")
    return {'CANCELLED'}


class _ImportVolume(ImportHelper):
    bl_options = {'REGISTER', 'UNDO', 'PRESET'}

    fit_range: BoolProperty(name="Fit Value Range", default=True,
                            description="Set the scene's Value Min/Max to the imported field's range")

    def resolve(self, path):
        """(solution, field, component, notes) to store; raises ValueError for bad settings."""
        raise NotImplementedError

    def execute(self, context):
        path = os.path.abspath(bpy.path.abspath(self.filepath))
        try:
            solution, field, component, notes = self.resolve(path)
            source = VolumeSource.resolve(path, solution, field, context.scene.frame_current, component=component)
            mesh = cached_volume(source)  # the first render finds it here
            values = field_samples(mesh) if self.fit_range else None
        except Exception as exc:  # a reader bug must not leave a traceback instead of a message
            return _fail(self, path, exc)
        stem = os.path.splitext(os.path.basename(path))[0]
        try:
            obj = operators.create_volume_object(context, stem, mesh, stored_path(path), stored_path(solution),
                                                 field, component)
        except Exception as exc:
            return _fail(self, path, exc)
        settings = context.scene.hovr
        if settings.transfer_function is None:
            settings.transfer_function = operators.new_transfer_function_texture()
        if values is not None and values.size:
            operators.SAMPLES.put(source.key, values)
            lo, hi = float(values.min()), float(values.max())
            if hi <= lo:  # a constant field (no solution: zero): a range around it
                lo, hi = lo - 0.5 * max(abs(lo), 1.0), hi + 0.5 * max(abs(hi), 1.0)
            settings.value_min, settings.value_max = lo, hi
        for w in getattr(mesh, "warnings", [])[:5]:
            notes.append(w)
        label = f" field {mesh.field_name}" if mesh.field_name else ""
        self.report({'INFO'}, f"HOVR: {obj.name}: {mesh.num_elements} elements,{label}"
                              + "".join(f"; {n}" for n in notes))
        return {'FINISHED'}


class HOVR_OT_import_nektar(_ImportVolume, bpy.types.Operator):
    """Import a Nektar++ mesh (.xml) and optionally its solution (.fld/.chk/.rst) as a HOVR volume"""

    bl_idname = "import_scene.hovr_nektar"
    bl_label = "Import Nektar++ Volume"

    filename_ext = ".xml"
    filter_glob: StringProperty(default="*.xml", options={'HIDDEN'})
    solution: StringProperty(name="Solution", default="",
                             description="Field file (.fld/.chk/.rst or a .fld/ folder), relative to the mesh's "
                                         "folder; empty: the mesh's name with .fld/.chk/.rst beside it, if any")
    field: StringProperty(name="Field", default="",
                          description='Field to render; "|u,v,w|" is the magnitude of u, v, w. '
                                      "Empty: the file's first field")

    def resolve(self, path):
        folder = os.path.dirname(path)
        solution = _absolute(self.solution, folder) or str(nektar.find_solution(path) or "")
        field, notes = self.field.strip(), []
        if solution and not field:
            names = nektar.list_fields(solution)
            if not names:
                raise nektar.NektarError(f"{solution}: holds no fields")
            field = names[0]
            if len(names) > 1:
                notes.append(f"showing {field!r} of {', '.join(names)} (set Field to choose)")
        if not solution:
            if field:
                raise nektar.NektarError(f"{path}: field {field!r} requested but no solution file is given or "
                                         "found beside the mesh")
            notes.append("no solution file: geometry only, a zero field")
        return solution, field, "", notes

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "solution")
        layout.prop(self, "field")
        layout.prop(self, "fit_range")


class HOVR_OT_import_vtu(_ImportVolume, bpy.types.Operator):
    """Import a VTK unstructured grid (.vtu, Lagrange or Bezier cells) as a HOVR volume"""

    bl_idname = "import_scene.hovr_vtu"
    bl_label = "Import VTU Volume"

    filename_ext = ".vtu"
    filter_glob: StringProperty(default="*.vtu", options={'HIDDEN'})
    field: StringProperty(name="Field", default="",
                          description="Point-data array to render; empty: the file's first one")
    component: StringProperty(name="Component", default="",
                              description="For vector arrays: empty or \"magnitude\" renders the magnitude, "
                                          "an index (0, 1, 2, ...) that component")

    def resolve(self, path):
        parse_component(self.component)  # a bad entry is reported before the file is read
        field = self.field.strip()
        if not field:
            names = list(vtu.list_fields(path))
            if not names:
                raise vtu.VtuError(f"{path}: no point-data array to render")
            field = names[0]
        return "", field, self.component.strip(), []

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "field")
        layout.prop(self, "component")
        layout.prop(self, "fit_range")


def menu_import(self, _context):
    self.layout.operator(HOVR_OT_import_nektar.bl_idname, text="HOVR Nektar++ (.xml)")
    self.layout.operator(HOVR_OT_import_vtu.bl_idname, text="HOVR VTU (.vtu)")


# ------------------------------------------------------------------------- relative paths on save

_BEFORE_SAVE: list = []  # (object, property, value) changed by the last save_pre


def _saved_path(args) -> str:
    return next((a for a in args if isinstance(a, str)), "")


@persistent
def remap_paths_before_save(*args):
    """Object.hovr paths relative to the folder the .blend is being saved to: '//' paths are
    re-based (Save As elsewhere), absolute ones made relative when the preference asks for it."""
    _BEFORE_SAVE.clear()
    target = _saved_path(args)
    if not target:
        return
    new_dir = os.path.dirname(os.path.abspath(target))
    for obj in bpy.data.objects:
        if obj.library is not None or not obj.hovr.is_volume:
            continue
        for prop in ("source", "solution"):
            value = getattr(obj.hovr, prop)
            if not value or value.startswith("builtin:"):
                continue
            relative = value.startswith("//")
            if relative and not bpy.data.filepath:  # typed into a new file: already meant for this save
                continue
            if not relative and not _relative_wanted():
                continue
            absolute = bpy.path.abspath(value)
            try:
                new = bpy.path.relpath(os.path.abspath(absolute), start=new_dir)
            except ValueError:
                new = os.path.abspath(absolute)
            if new != value:
                _BEFORE_SAVE.append((obj, prop, value))
                setattr(obj.hovr, prop, new)


@persistent
def restore_paths_after_copy(*args):
    """Save Copy leaves the session on the old file: give the objects their old paths back."""
    target = _saved_path(args)
    try:
        copy = bool(target) and os.path.abspath(target) != os.path.abspath(bpy.data.filepath or "")
        if copy:
            for obj, prop, value in _BEFORE_SAVE:
                setattr(obj.hovr, prop, value)
    finally:
        _BEFORE_SAVE.clear()


classes = (HOVR_OT_import_nektar, HOVR_OT_import_vtu)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(menu_import)
    if remap_paths_before_save not in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.append(remap_paths_before_save)
    if restore_paths_after_copy not in bpy.app.handlers.save_post:
        bpy.app.handlers.save_post.append(restore_paths_after_copy)


def unregister():
    for handlers, fn in ((bpy.app.handlers.save_post, restore_paths_after_copy),
                         (bpy.app.handlers.save_pre, remap_paths_before_save)):
        if fn in handlers:
            handlers.remove(fn)
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
