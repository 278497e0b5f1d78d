"""The render kernels a scene needs, compiled in the background (jobs.WARMUP) before its first
render: after an import, when the add-on is enabled or a file opened with HOVR volumes in a
scene rendered by HOVR, and when the Rendered viewport meets kernels not compiled yet (it draws
a message meanwhile rather than holding the UI for the compile). While the thread works, the
status bar says "HOVR: Compiling render kernels (first use)… N s", as a modal operator's text
(Python cannot redraw the status bar otherwise: it is not one of the screen's areas), unless an
import is showing its own there; a timer on the main thread writes it and redraws the 3D views,
the thread itself never touches Blender. F12 waits for it (render.py). Blender in background
mode renders at once and compiles in place: nothing starts here there."""
import bpy
from bpy.app.handlers import persistent

from .jobs import WARMUP, kernel_key

REDRAW_SECONDS = 0.5


def scene_volumes(scene) -> list:
    """The HOVR volumes an F12 of the scene renders."""
    return [o for o in scene.objects if o.hovr.is_volume and not o.hide_render]


def scene_kernel_keys(scene):
    """A function for the warm-up thread: it reads the scene's volumes (cached for the render, so
    F12 finds them) and returns the kernel_key their render needs. The sources are resolved here,
    on the main thread; the data is read in the thread."""
    from ..core.renderer import kernel_variant
    from ..io.sources import cached_volume
    from .operators import volume_source

    sources = [volume_source(o, scene) for o in scene_volumes(scene)]
    settings = scene.hovr
    device, precision, surfaces = settings.device, settings.precision, settings.surfaces != "NONE"

    def keys():
        meshes = [cached_volume(s) for s in sources]
        return [kernel_key(device, precision, kernel_variant(meshes), surfaces)] if meshes else []

    return keys


def warm_up_scene(scene):
    """Compile, in the background, the kernels the scene's first render needs."""
    if bpy.app.background or not scene_volumes(scene):
        return
    try:
        keys = scene_kernel_keys(scene)
    except ValueError:  # a volume whose path cannot be resolved: its render reports it
        return
    request(keys)


def request(keys):
    """jobs.WARMUP.request(keys), with the status bar kept up to date while it works."""
    WARMUP.request(keys)
    if not bpy.app.background and not bpy.app.timers.is_registered(_redraw):
        bpy.app.timers.register(_redraw, first_interval=REDRAW_SECONDS)


_SHOWN = {"status": False}  # whether the status bar holds the warm-up's words


def _status_text(text):
    """Each window's status bar text (None: Blender's own again)."""
    from .import_operators import RUNNING

    if RUNNING:  # an import in the background shows its progress there
        return
    wm = bpy.context.window_manager
    for window in (wm.windows if wm is not None else ()):
        with bpy.context.temp_override(window=window):
            window.workspace.status_text_set(text)
    _SHOWN["status"] = text is not None


def _redraw():
    """While the warm-up works, and once after: the status bar's words and the 3D views (a
    Rendered viewport waiting for the kernels starts when they are ready)."""
    text = WARMUP.status()
    if text is not None:
        _status_text(f"HOVR: {text}")
    elif _SHOWN["status"]:
        _status_text(None)
    wm = bpy.context.window_manager
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type == 'VIEW_3D':
                area.tag_redraw()
    return REDRAW_SECONDS if text is not None else None


def _warm_up_open_file():
    scene = bpy.context.scene
    if scene is not None and scene.render.engine == 'HOVR':
        warm_up_scene(scene)
    return None  # a one-shot timer


@persistent
def warm_up_on_load(*_args):
    _warm_up_open_file()


def register():
    if warm_up_on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(warm_up_on_load)
    if not bpy.app.background:  # register() runs with restricted bpy.data: the open file just after
        bpy.app.timers.register(_warm_up_open_file, first_interval=1.0)


def unregister():
    for fn in (_warm_up_open_file, _redraw):
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
    if _SHOWN["status"]:
        try:
            _status_text(None)
        except Exception:  # a window manager being torn down: nothing left to show it in
            pass
    if warm_up_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(warm_up_on_load)
