"""Old .blend files: before per-volume looks, the transfer function, value range and density
scale (per world unit) were the scene's (Scene.hovr) and only the first volume rendered; before
Step Units, the step was always in world units (Scene.hovr.h).

`volume_look` is the one place that reads a volume's look: the object's own, or, for a
volume saved before looks moved onto objects (no transfer function of its own while the
scene still holds one), the scene's, read as it was meant (density per world unit), so
such a file renders the same with or without the load handler. `migrate` (run on
load_post and by register for the file already open) copies the scene's look onto those
volumes once, so the panels show and edit it per volume.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
from bpy.app.handlers import persistent


@dataclass
class Look:
    texture: object  # bpy.types.Texture or None
    value_min: float
    value_max: float
    density: float
    density_units: str  # "RELATIVE" | "WORLD"
    legacy: bool = False  # read from the scene (a file saved before per-volume looks)


def _needs_scene_look(hovr, scene) -> bool:
    return hovr.transfer_function is None and scene is not None and scene.hovr.transfer_function is not None


def volume_look(hovr, scene) -> Look:
    """The look of a volume (Object.hovr), with the old scene-level fallback."""
    if _needs_scene_look(hovr, scene):
        s = scene.hovr
        return Look(s.transfer_function, s.value_min, s.value_max, s.density_scale, "WORLD", legacy=True)
    return Look(hovr.transfer_function, hovr.value_min, hovr.value_max, hovr.density, hovr.density_units)


def migrate(scenes=None) -> int:
    """Copy each scene's old look onto its volumes that have none; returns how many moved.
    Every volume gets the scene's look (the old renderer showed only one volume, but all
    of them were meant to share it); the scene keeps its values, unused from then on."""
    moved = 0
    for scene in (bpy.data.scenes if scenes is None else scenes):
        for obj in scene.objects:
            hovr = obj.hovr
            if obj.library is not None or not hovr.is_volume or not _needs_scene_look(hovr, scene):
                continue
            look = volume_look(hovr, scene)
            hovr.transfer_function = look.texture
            hovr.value_min, hovr.value_max = look.value_min, look.value_max
            hovr.density_units = 'WORLD'
            hovr.density = look.density
            moved += 1
    return moved


# Scene.hovr settings a scene saved before Step Units could have set: any of them set, a HOVR
# volume in the scene or HOVR as its engine means the scene was used with HOVR
_SCENE_SETTINGS = ("method", "h", "tolerance", "min_transmittance", "device", "precision", "surfaces",
                   "transfer_function", "density_scale", "value_min", "value_max")


def _used_with_hovr(scene) -> bool:
    return (scene.render.engine == 'HOVR' or any(scene.hovr.is_property_set(p) for p in _SCENE_SETTINGS)
            or any(o.hovr.is_volume for o in scene.objects))


def migrate_step_units(scenes=None) -> int:
    """Scenes saved before Step Units keep their step in world units (Scene.hovr.h, the 0.01
    default included), so they render as they did; returns how many changed. Every file saved
    since has Step Units set in each scene (mark_step_units), so only old files are touched; a
    scene never used with HOVR takes the new default (a step relative to the volume)."""
    changed = 0
    for scene in (bpy.data.scenes if scenes is None else scenes):
        if scene.library is not None or scene.hovr.is_property_set("step_units"):
            continue
        if _used_with_hovr(scene):
            scene.hovr.step_units = 'WORLD'
            changed += 1
    return changed


@persistent
def mark_step_units(*_args):
    """On save: write each scene's Step Units into the file even where it is the default, the
    mark by which migrate_step_units tells a file saved with Step Units from an older one."""
    for scene in bpy.data.scenes:
        if scene.library is None and not scene.hovr.is_property_set("step_units"):
            scene.hovr.step_units = scene.hovr.step_units


@persistent
def migrate_on_load(*_args):
    migrate()
    migrate_step_units()


def _migrate_open_file():
    try:
        migrate()
        migrate_step_units()
    except Exception:  # never let versioning break enabling the add-on
        pass
    return None  # a one-shot timer


def register():
    if migrate_on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(migrate_on_load)
    if mark_step_units not in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.append(mark_step_units)
    # Blender runs an add-on's register() with restricted bpy.data: the file already open migrates
    # just after. Without windows no timer runs; a script that registers after opening a file
    # (bpy as a module) has full access, so migrate at once
    if not bpy.app.background:
        bpy.app.timers.register(_migrate_open_file, first_interval=0.0)
    else:
        _migrate_open_file()


def unregister():
    if migrate_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(migrate_on_load)
    if mark_step_units in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.remove(mark_step_units)
    if bpy.app.timers.is_registered(_migrate_open_file):
        bpy.app.timers.unregister(_migrate_open_file)
