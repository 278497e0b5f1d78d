"""File > Import > HOVR Nektar++ (.xml) / HOVR VTU (.vtu) / ...: a finite-element volume as an
object. One operator and one menu entry per registered format (io/formats.py), made from the
registry when the add-on registers: import_scene.hovr_<format name> (hovr_nektar, hovr_vtu), its
settings those the format has (Solution, Field, Component, Walls From).

The file is read first; only a successful read creates anything (the outline mesh, the
object and its own look: a transfer function, the field's range, a density relative to its
size; with Walls as Mesh, the domain's boundary faces, or a Nektar++ file's chosen composites or
boundary regions, as a triangle mesh, engine/walls.py), so a malformed file or a selection the
file cannot satisfy leaves the .blend as it was and the error names the file (and the element,
record or composite where the reader can tell). Add Walls (hovr.add_walls) makes the same mesh
for a volume already imported. Importing never changes another volume. By default the scene
camera (made if there is none) then frames the new volume.

From the file browser the import is modal (ModalImport): the reader process reads while a
window-manager timer polls it, the status bar shows the stage, and Esc or right-click cancels
(the reader is killed; nothing was made). A script's import (bpy.ops...(filepath=...),
EXEC_DEFAULT) and a redo read to the end before returning, as before. No thread either way (a
thread left running after the operator returns is not supported by Blender: jobs.py says why).

The object stores the data's path relative to the saved .blend ('//'); a save handler keeps
that true when the .blend is first saved or saved elsewhere (Blender's own relative-path
remapping does not see add-on properties).
"""
import os
from dataclasses import dataclass, field as dc_field

import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..engine import walls as core_walls
from ..engine.words import plural, summarise_warnings
from ..io import formats, isolation
from ..io.sources import VolumeSource, cached_volume, cached_volume_steps, choose_steps, parse_component
from . import compat, operators
from .jobs import Job, Listings
from .render import failure_text
from .snapshot import volume_extent, volume_points, volume_source
from ..engine.looks import field_samples


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
    if isinstance(exc, ImportError):
        what = failure_text(exc)
    else:
        what = str(exc) if isinstance(exc, (ValueError, OSError)) else f"unexpected {type(exc).__name__}: {exc}"
    op.report({'ERROR'}, f"HOVR: cannot import {os.path.basename(path)}: {what}")
    return {'CANCELLED'}


@dataclass
class ImportRequest:
    """An import's settings as plain values, taken from the operator on the main thread (the
    reading thread must not touch Blender's data, operator properties included)."""

    kind: str  # the format's name (io/formats.py): "nektar", "vtu", ...
    path: str  # absolute
    solution: str = ""  # formats with solution files (Nektar++): absolute, or "" to pick the likeliest
    field: str = ""
    component: str = ""  # formats with vector fields (VTU)
    fit_range: bool = True
    walls: bool = False
    walls_tolerance: float = core_walls.DEFAULT_RELATIVE_TOLERANCE
    frame: int = 1
    walls_from: str = ""  # formats with named boundaries (Nektar++): the walls' faces ("" = every boundary face)

    @property
    def steps(self) -> int:
        return 3 + int(self.fit_range) + int(self.walls)


@dataclass
class ImportRead:
    """What read_import found and read, for conclude_import to turn into objects."""

    request: ImportRequest
    source: VolumeSource
    mesh: object  # engine.mesh.VolumeMesh
    solution: str
    field: str
    component: str
    notes: list = dc_field(default_factory=list)
    warnings: list = dc_field(default_factory=list)
    values: object = None  # sampled field values and their volumes (Fit Value Range: looks.field_samples)
    walls: object = None  # engine.walls.Walls (Walls as Mesh)


def read_import(request: ImportRequest, step=lambda stage: None):
    """Everything an import reads and computes, with no bpy: the solution and field, the data
    (kept in io.sources' cache for the first render), its extent and corner points (the panel's
    step, Frame Camera), the sampled field (Fit Value Range) and the walls. step(stage) is called
    before each stage (a jobs.Job's step: the progress bar). A generator (a jobs.Job's work): it
    yields each reader task it waits for, and returns an ImportRead."""
    step("finding the solution and field")
    data_format = formats.named(request.kind)
    if data_format.components:
        parse_component(request.component)  # a bad entry is reported before the file is read
    choice = yield from choose_steps(data_format, request.path, request.solution, request.field, request.component)
    step("reading the data")
    source = VolumeSource.resolve(request.path, choice.solution, choice.field, request.frame,
                                  component=choice.component)
    mesh = yield from cached_volume_steps(source)
    step("measuring the volume")
    volume_extent(source)
    volume_points(source)
    values = walls = None
    if request.fit_range:
        step("sampling the field")
        values = field_samples(mesh, weights=True)
    if request.walls:
        step("tessellating the walls")
        faces_read = wall_faces_request(request.path, request.walls_from)
        faces = None if faces_read is None else (yield faces_read)
        walls = tessellate_walls(mesh, faces, request.walls_tolerance)
    return ImportRead(request, source, mesh, choice.solution, choice.field, choice.component, list(choice.notes),
                      list(choice.warnings), values, walls)


def import_job(request: ImportRequest, on_step=None) -> Job:
    """The import's reading as a Job (run() it, or start() and advance() it), on_step(job)
    called at each stage."""
    return Job(lambda job: read_import(request, job.step), f"importing {os.path.basename(request.path)}",
               steps=request.steps, on_step=on_step)


def finish_import(op, context, request: ImportRequest, job: Job, frame_camera: bool = True) -> set:
    """The end of an import: the error for a failed read (nothing was made), else the objects
    (conclude_import)."""
    if job.error is not None:  # a reader bug too must end as a message, not a traceback
        return _fail(op, request.path, job.error)
    return conclude_import(op, context, job.result, frame_camera)


def conclude_import(op, context, read: ImportRead, frame_camera: bool = True) -> set:
    """The volume object (and walls) of a finished read, its look fitted, the camera framed, the
    report."""
    path, mesh = read.request.path, read.mesh
    notes, warnings = list(read.notes), list(read.warnings)
    stem = os.path.splitext(os.path.basename(path))[0]
    try:
        obj = operators.create_volume_object(context, stem, mesh, stored_path(path), stored_path(read.solution),
                                             read.field, read.component)
    except Exception as exc:
        return _fail(op, path, exc)
    if read.walls is not None:
        walls = read.walls
        try:
            create_walls_object(context, obj, walls)
            note, warning = walls_report(walls, read.request.walls_from)
            notes.append(note)
            if warning:
                warnings.append(warning)
        except Exception as exc:  # the volume itself was imported
            warnings.append(f"walls not made: {failure_text(exc)}")
        context.view_layer.objects.active = obj
    if read.values is not None and read.values[0].size:
        warning = operators.give_first_look(obj, context.scene, read.values)  # the first picture's look
        if warning:  # a constant field keeps the smooth ramp: there is no structure to place a look by
            warnings.append(warning)
    if getattr(mesh, "has_field", True) is False:
        warnings.append("no solution file: geometry only, a zero field (set Solution in Object > HOVR Volume)")
    warnings += summarise_warnings(getattr(mesh, "warnings", []))  # one line per kind, each reported apart
    notes += getattr(mesh, "notes", [])  # a derived field's fit, where it is as good as exact
    if frame_camera:
        try:
            operators.frame_volumes(context, [o for o in context.scene.objects
                                              if o.hovr.is_volume and o.visible_get()] or [obj])
        except Exception as exc:  # framing is a convenience: the import itself succeeded
            notes.append(f"camera not framed: {failure_text(exc)}")
    label = f" field {mesh.field_name}" if mesh.field_name else ""
    op.report({'INFO'}, f"HOVR: {obj.name}: {plural(mesh.num_elements, 'element')},{label}"
              + "".join(f"; {n}" for n in notes))
    for w in warnings:
        op.report({'WARNING'}, f"HOVR: {obj.name}: {w}")
    return {'FINISHED'}


class _ImportVolume(ImportHelper):
    bl_options = {'REGISTER', 'UNDO', 'PRESET'}

    fit_range: BoolProperty(name="Fit Value Range", default=True,
                            description="Set the new volume's Value Min/Max to its field's range, and its look "
                                        "from the field's values (shells at their 10, 50 and 90 % quantiles)")
    frame: BoolProperty(name="Frame Camera", default=True,
                        description="Point the scene camera (a new one if there is none) at the HOVR volumes and "
                                    "set its clip start/end from their size")
    walls: BoolProperty(name="Walls as Mesh", default=False,
                        description="Also make the domain's boundary faces a triangle mesh (\"<volume> Walls\", a child "
                                    "of the volume), curved faces tessellated within the tolerance, for a Cycles "
                                    "material. With HOVR's Surfaces on, the walls are opaque and hide the volume inside")
    walls_tolerance: FloatProperty(name="Wall Tolerance", default=core_walls.DEFAULT_RELATIVE_TOLERANCE,
                                   min=1e-6, max=0.1, precision=6, step=0.01,
                                   description="Largest distance of the walls' triangles from the true curved "
                                               "faces, as a fraction of the volume's bounding-box diagonal")

    format_name = ""  # the format (io/formats.py) of the operator import_operator made

    def request(self, context, path: str) -> ImportRequest:
        """The settings as plain values (a setting the format lacks is empty)."""
        return ImportRequest(self.format_name, path, _absolute(getattr(self, "solution", ""), os.path.dirname(path)),
                             self.field, getattr(self, "component", ""), self.fit_range, self.walls,
                             self.walls_tolerance, context.scene.frame_current, getattr(self, "walls_from", ""))

    def invoke(self, context, event):
        isolation.prestart()  # the reader process starts while the user picks a file
        self.from_file_browser = True  # the browser's execute() then imports modally (Esc cancels)
        return super().invoke(context, event)

    def execute(self, context):
        path = os.path.abspath(bpy.path.abspath(self.filepath))
        request = self.request(context, path)
        if getattr(self, "from_file_browser", False) and context.window is not None:
            self.from_file_browser = False  # a redo of this operator (the same instance) runs here, to the end
            self.modal_import = ModalImport(self, context, request, self.frame)
            return self.modal_import.begin(context)
        wm = context.window_manager  # a script's import (EXEC_DEFAULT), or a redo: to the end here
        job = import_job(request, on_step=lambda j: wm.progress_update(j.step_index))
        wm.progress_begin(0, request.steps)
        try:
            job.run()
        finally:
            wm.progress_end()
        return finish_import(self, context, request, job, self.frame)

    def modal(self, context, event):
        return self.modal_import.on_event(context, event)

    def cancel(self, context):
        """Blender ends the modal import (a file loaded, the window closed): the reader stops."""
        self.modal_import.stop(context)


class ModalImport:
    """An import from the file browser, read while Blender stays responsive: a window-manager
    timer polls the reader process (jobs.Job.advance), the status bar and the progress cursor
    show the stage, Esc or right-click cancels it (the reader is killed, nothing was made, one
    line in the report). Only the finished read creates objects (finish_import). No thread:
    the reading is a process, the rest runs in this, the main, thread between events."""

    CANCEL_EVENTS = ('ESC', 'RIGHTMOUSE')
    INTERVAL = 0.1  # seconds between polls

    def __init__(self, op, context, request: ImportRequest, frame_camera: bool = True):
        self.op, self.request, self.frame_camera = op, request, frame_camera
        self.timer = None
        self.job = import_job(request, on_step=self._progress)
        self.context = None  # the context of the event being handled (a step's progress goes there)
        self.phases: list = []  # each phase shown (jobs.Job.phase), in order

    def begin(self, context) -> set:
        """Start the read and the timer, as the operator's execute() (or invoke()) returns."""
        wm = context.window_manager
        wm.progress_begin(0, self.request.steps)
        self.context = context
        try:
            self.job.start()
        finally:
            self.context = None
        if self.job.done:  # nothing to wait for (a cached mesh), or a failure before the read
            return self._end(context)
        self.timer = wm.event_timer_add(self.INTERVAL, window=context.window)
        wm.modal_handler_add(self.op)
        self._show(context)
        return {'RUNNING_MODAL'}

    def on_event(self, context, event) -> set:
        """The operator's modal(): a timer tick polls the reader; Esc or right-click cancels;
        other events pass through (the viewport stays usable)."""
        if event.type in self.CANCEL_EVENTS and event.value == 'PRESS':
            self.job.cancel()
            self._cleanup(context)
            self.op.report({'WARNING'}, f"HOVR: import of {os.path.basename(self.request.path)} cancelled "
                                        f"({self.job.stage}); nothing was made")
            return {'CANCELLED'}
        if event.type == 'TIMER':
            self.context = context
            try:
                self.job.advance(0.0)
            finally:
                self.context = None
            if self.job.done:
                return self._end(context)
            self._show(context)
        return {'PASS_THROUGH'}

    def stop(self, context):
        """Cancelled by Blender (a file loaded, the window closed)."""
        self.job.cancel()
        self._cleanup(context)

    def _progress(self, job):
        if self.context is not None:
            self.context.window_manager.progress_update(job.step_index)
            self._show(self.context)

    def _show(self, context):
        if not self.phases or self.phases[-1] != self.job.phase():
            self.phases.append(self.job.phase())
        text = f"HOVR: {self.job.title}: {self.job.status()} (Esc to cancel)"
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(text)

    def _end(self, context) -> set:
        self._cleanup(context)
        return finish_import(self.op, context, self.request, self.job, self.frame_camera)

    def _cleanup(self, context):
        wm = context.window_manager
        if self.timer is not None:
            wm.event_timer_remove(self.timer)
            self.timer = None
        wm.progress_end()
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(None)


def _with_boundaries(path: str):
    """The format of `path` if it names boundary faces (Nektar++'s composites and regions), else None."""
    data_format = formats.format_of(path, sniff=False)
    return data_format if data_format is not None and data_format.boundaries is not None else None


def wall_faces_request(path: str, selection: str):
    """The reader task (started) that finds a selection's faces (C[...], B[...] or names: a
    Nektar++ file's composites or boundary regions), or None for an empty selection (every
    boundary face)."""
    if not selection.strip():
        return None
    data_format = _with_boundaries(path)
    if data_format is None:
        which = " or ".join(f"{f.label} mesh's ({', '.join(f.extensions)})" for f in formats.FORMATS if f.boundaries)
        raise ValueError(f"walls from {selection.strip()!r}: composites and boundary regions are a {which}, "
                         f"not {os.path.basename(path) or path}'s; leave the selection empty for all boundary "
                         "faces")
    return isolation.wall_faces_request(data_format.name, path, selection)


def make_walls(mesh, path: str, selection: str, relative_tolerance: float):
    """core_walls.Walls of the volume `mesh` read from `path`: its boundary faces, or with a
    selection (C[...], B[...] or names) those of a Nektar++ file's composites or boundary regions."""
    faces_read = wall_faces_request(path, selection)
    return tessellate_walls(mesh, None if faces_read is None else isolation.wait(faces_read), relative_tolerance)


def tessellate_walls(mesh, faces, relative_tolerance: float):
    """core_walls.Walls of `faces` (None: every boundary face) within the relative tolerance."""
    return core_walls.tessellate(mesh, core_walls.default_tolerance(mesh, relative_tolerance), faces=faces)


def walls_report(walls, selection: str):
    """(note, warning or None) for the report of a walls mesh."""
    what = f" of {selection.strip()}" if selection.strip() else ""
    note = (f"walls{what}: {plural(len(walls.element), 'face')}, {plural(len(walls.triangles), 'triangle')} within "
            f"{walls.tolerance:.3g}")
    warning = None
    if walls.cap_hit:
        warning = (f"walls: {walls.capped} curved faces reached {walls.max_k} x {walls.max_k} "
                   f"triangles still farther than {walls.tolerance:.3g} from the true surface")
    return note, warning


def create_walls_object(context, volume, walls, name=None):
    """The tessellated boundary (core_walls.Walls) as the mesh object `name` (default "<volume>
    Walls"), a child of the volume with an identity local transform (the volume's own transform),
    smooth shaded, in the volume's collections. Vertices of neighbouring faces are not welded
    (engine/walls.py)."""
    name = name or f"{volume.name} Walls"
    me = obj = None
    try:
        me = bpy.data.meshes.new(name)
        me.from_pydata(walls.vertices.tolist(), [], walls.triangles.tolist())
        me.update()
        compat.shade_smooth(me)
        obj = bpy.data.objects.new(name, me)
        obj.parent = volume
        for collection in volume.users_collection or [context.scene.collection]:
            collection.objects.link(obj)
    except Exception:
        operators.discard(obj, me)
        raise
    return obj


# The file browser redraws the operator's panel often: field-file scans per folder are
# remembered (by modification time) so drawing stays cheap; a file's fields and composites are
# read by the reader process without waiting for it (LISTINGS), a timer redrawing when they come.
_SCAN_CACHE: dict = {}
LISTINGS = Listings()
LISTING_POLL_SECONDS = 0.1


def _poll_listings():
    """bpy.app.timers: redraw the windows when a listing came in; again while any is read."""
    if LISTINGS.poll():
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                area.tag_redraw()
    return LISTING_POLL_SECONDS if LISTINGS.waiting else None


def _listed(kind: str, path: str, start, finish=lambda value: value):
    """LISTINGS.get, with the timer that redraws the dialog once the reader has answered."""
    value = LISTINGS.get(kind, path, path, start, finish)
    if value is Listings.PENDING and not bpy.app.timers.is_registered(_poll_listings):
        bpy.app.timers.register(_poll_listings, first_interval=LISTING_POLL_SECONDS)
    return value


def _cached(key, stamp_path, compute):
    try:
        stamp = os.stat(stamp_path).st_mtime_ns
    except OSError:
        return None
    hit = _SCAN_CACHE.get(key)
    if hit is not None and hit[0] == stamp:
        return hit[1]
    try:
        value = compute()
    except Exception:
        value = None
    if len(_SCAN_CACHE) > 64:
        _SCAN_CACHE.clear()
    _SCAN_CACHE[key] = (stamp, value)
    return value


WALLS_FROM_DESCRIPTION = ("Which faces become the walls: empty for all the domain's boundary faces; or the "
                          "file's composites C[1,3-4], boundary regions B[0] (from its CONDITIONS), or names "
                          "(a composite's or region's NAME, or a condition type such as WallViscous), "
                          "separated by commas")


def draw_wall_choices(layout, path, data_format):
    """The composites and boundary regions a Nektar++ mesh offers for Walls From."""
    choices = _listed("walls", path, lambda: isolation.wall_choices_request(data_format.name, path),
                      lambda value: [tuple(c) for c in value])
    box = layout.box()
    if choices is Listings.PENDING:
        box.label(text="Reading the file's composites...", icon='TIME')
        return
    if choices is None:
        box.label(text="Cannot list the file's composites (importing says why)", icon='ERROR')
        return
    if not choices:
        box.label(text="No face composites: all boundary faces", icon='INFO')
        return
    box.label(text="Walls From (empty: all boundary faces):")
    for _, label in choices[:12]:
        box.label(text=label[:60])
    if len(choices) > 12:
        box.label(text=f"... {len(choices) - 12} more")


class HOVR_OT_add_walls(bpy.types.Operator):
    """Add a triangle mesh of the active HOVR volume's walls: its boundary faces, or a Nektar++
    mesh's chosen composites or boundary regions, curved faces tessellated within the tolerance"""

    bl_idname = "hovr.add_walls"
    bl_label = "Add Walls"
    bl_options = {'REGISTER', 'UNDO'}

    walls_from: StringProperty(name="Walls From", default="", description=WALLS_FROM_DESCRIPTION)
    walls_tolerance: FloatProperty(name="Wall Tolerance", default=core_walls.DEFAULT_RELATIVE_TOLERANCE,
                                   min=1e-6, max=0.1, precision=6, step=0.01,
                                   description="Largest distance of the walls' triangles from the true curved "
                                               "faces, as a fraction of the volume's bounding-box diagonal")

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.hovr.is_volume and bool(obj.hovr.source.strip())

    def invoke(self, context, _event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "walls_from")
        layout.prop(self, "walls_tolerance")
        data_format = _with_boundaries(context.object.hovr.source)
        if data_format is not None:
            try:
                draw_wall_choices(layout, volume_source(context.object, context.scene).path, data_format)
            except ValueError:
                pass

    def execute(self, context):
        volume = context.object
        try:
            source = volume_source(volume, context.scene)
            mesh = cached_volume(source)
            walls = make_walls(mesh, source.path, self.walls_from, self.walls_tolerance)
        except Exception as exc:
            self.report({'ERROR'}, f"HOVR: no walls for {volume.name}: {failure_text(exc)}")
            return {'CANCELLED'}
        selection = self.walls_from.strip()
        obj = create_walls_object(context, volume, walls,
                                  f"{volume.name} Walls {selection}" if selection else None)
        note, warning = walls_report(walls, selection)
        self.report({'INFO'}, f"HOVR: {obj.name}: {note}")
        if warning:
            self.report({'WARNING'}, f"HOVR: {obj.name}: {warning}")
        return {'FINISHED'}


COMPONENT_DESCRIPTION = ("For vector arrays: empty or \"magnitude\" renders the magnitude, an index (0, 1, 2, ...) "
                         "that component")


def draw_solution_choice(layout, path, data_format):
    """Which solution file an import with an empty Solution will take, why, and its fields."""
    folder = os.path.dirname(path) or "."
    found = _cached(("scan", path), folder, lambda: data_format.pick_solution(path))
    box = layout.box()
    if not found:
        return
    picked, why, others = found
    if picked is None:
        box.label(text="No solution picked:", icon='ERROR')
        box.label(text="geometry only (zero field)")
        for p in others[:6]:
            box.label(text=p.name, icon='FILE')
        return
    box.label(text=f"Solution: {picked.name}", icon='CHECKMARK')
    box.label(text=why[:60])
    fields = _listed("fields", str(picked), lambda: isolation.list_fields_request(data_format.name, picked), list)
    if fields is Listings.PENDING:
        box.label(text="Fields: reading...", icon='TIME')
    elif fields:
        box.label(text="Fields: " + ", ".join(fields[:8]))
    for p in [p for p in others if p != picked][:5]:
        box.label(text=f"also: {p.name}", icon='FILE')


def draw_import_options(op, data_format):
    """The import options of a format's operator: its own settings, then the common ones."""
    layout = op.layout
    layout.use_property_split = True
    if data_format.takes_solution:
        layout.prop(op, "solution")
    layout.prop(op, "field")
    if data_format.components:
        layout.prop(op, "component")
    layout.prop(op, "fit_range")
    layout.prop(op, "frame")
    layout.prop(op, "walls")
    col = layout.column()
    col.enabled = op.walls
    col.prop(op, "walls_tolerance")
    path = bpy.path.abspath(op.filepath)
    if data_format.boundaries is not None:
        col.prop(op, "walls_from")
        if op.walls and data_format.reads(path):
            draw_wall_choices(col, path, data_format)
    if data_format.pick_solution is not None and not op.solution.strip() and data_format.reads(path):
        draw_solution_choice(layout, path, data_format)


def import_operator(data_format):
    """File > Import's operator for a registered format: import_scene.hovr_<name>, with the
    settings the format has."""
    settings = {"filter_glob": StringProperty(default=";".join("*" + e for e in data_format.extensions),
                                              options={'HIDDEN'})}
    if data_format.takes_solution:
        settings["solution"] = StringProperty(name="Solution", default="", description=data_format.solution_help)
    settings["field"] = StringProperty(name="Field", default="", description=data_format.field_help)
    if data_format.components:
        settings["component"] = StringProperty(name="Component", default="", description=COMPONENT_DESCRIPTION)
    if data_format.boundaries is not None:
        settings["walls_from"] = StringProperty(name="Walls From", default="", description=WALLS_FROM_DESCRIPTION)
    return type(f"HOVR_OT_import_{data_format.name}", (_ImportVolume, bpy.types.Operator), {
        "__doc__": data_format.description or f"Import a {data_format.label} file as a HOVR volume",
        "__annotations__": settings,
        "bl_idname": f"import_scene.hovr_{data_format.name}",
        "bl_label": f"Import {data_format.label} Volume",
        "filename_ext": data_format.extensions[0],
        "format_name": data_format.name,
        "menu_text": data_format.menu_text(),
        "draw": lambda self, _context: draw_import_options(self, data_format),
    })


OPERATORS: dict = {}  # format name -> its import operator, made from the registry by register()


def menu_import(self, _context):
    for cls in OPERATORS.values():
        self.layout.operator(cls.bl_idname, text=cls.menu_text)


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


def register():
    OPERATORS.clear()
    OPERATORS.update((f.name, import_operator(f)) for f in formats.FORMATS)
    for cls in (*OPERATORS.values(), HOVR_OT_add_walls):
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
    for cls in (HOVR_OT_add_walls, *reversed(OPERATORS.values())):
        bpy.utils.unregister_class(cls)
    OPERATORS.clear()
    if bpy.app.timers.is_registered(_poll_listings):
        bpy.app.timers.unregister(_poll_listings)
    LISTINGS.cancel()
