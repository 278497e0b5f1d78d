"""Run by Debian's Blender 3.4 *with a window* (under Xvfb, --enable-event-simulate): File >
Import > HOVR Nektar++ as a user does it, keys pressed through Blender's own event queue. The
file browser opens on the mesh, Return confirms it, and the import reads modally until the
volume appears; then a second import whose reader process is stopped (SIGSTOP: as good as
libhdf5's endless loop) shows its stage in the status bar until Esc cancels it. report.json goes
to OUT; the pytest side checks it."""
import json
import os
import signal
import sys
import time

import addon_utils
import bpy

if os.environ.get("HOVR_EXTRA_SITE"):  # warp-lang and h5py from the project's venv (Debian has none)
    sys.path.append(os.environ["HOVR_EXTRA_SITE"])

OUT, DATA, OTHER = sys.argv[sys.argv.index("--") + 1:][:3]  # OTHER: a copy of DATA (not in the mesh cache)
report = {"log": []}
state = {"t0": time.time(), "phase": "setup"}


def log(msg):
    report["log"].append(f"{time.time() - state['t0']:.2f}s {msg}")


def main_window():
    return bpy.context.window_manager.windows[0]


def view3d():
    win = main_window()
    area = max((a for a in win.screen.areas if a.type == 'VIEW_3D'), key=lambda a: a.width * a.height)
    return win, area, next(r for r in area.regions if r.type == 'WINDOW')


X11_KEYS = {'RET': "Return", 'ESC': "Escape"}


def press(win, key, x=None, y=None, title=""):
    """A key pressed and released with the mouse over (x, y) of `win` (its middle by default):
    through Blender's event queue (event_simulate), or with HOVR_KEYS=xdotool as X11 input to
    the window titled `title`, which Blender reads when it next handles events."""
    x = win.width // 2 if x is None else x
    y = win.height // 2 if y is None else y
    if os.environ.get("HOVR_KEYS") == "xdotool":
        import subprocess

        found = subprocess.run(["xdotool", "search", "--onlyvisible", "--name", title], capture_output=True,
                               text=True, timeout=30).stdout.split()
        if not found:
            raise RuntimeError(f"no X11 window titled {title!r}")
        # no window manager under Xvfb: the keyboard focus is given to the window by hand
        subprocess.run(["xdotool", "windowfocus", "--sync", found[-1], "mousemove", "--window", found[-1], str(x),
                        str(win.height - y), "key", X11_KEYS[key]], check=True, timeout=30)
        return
    win.event_simulate(type='MOUSEMOVE', value='NOTHING', x=x, y=y)
    win.event_simulate(type=key, value='PRESS', x=x, y=y)
    win.event_simulate(type=key, value='RELEASE', x=x, y=y)


def volumes():
    return sorted(o.name for o in bpy.data.objects if o.hovr.is_volume)


def browser():
    """The file browser's window (Blender 3.4 opens it as a window of its own) and area."""
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            if area.type == 'FILE_BROWSER':
                return win, area
    return None, None


def invoke_import(path, solution=""):
    win, area, region = view3d()
    with bpy.context.temp_override(window=win, area=area, region=region):
        return sorted(bpy.ops.import_scene.hovr_nektar('INVOKE_DEFAULT', filepath=path, field="|u,v,w|",
                                                       solution=solution))


def reports():
    """The session's reports, as the Info editor lists them (copied through the clipboard)."""
    win, area, region = view3d()
    area.type = 'INFO'
    region = next(r for r in area.regions if r.type == 'WINDOW')
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.info.select_all(action='SELECT')
        bpy.ops.info.report_copy()
    area.type = 'VIEW_3D'
    return [line for line in bpy.context.window_manager.clipboard.splitlines() if line.strip()]


def running_import_phases():
    """The phases the running modal imports showed in the status bar (which Python cannot read
    back): found among the live objects."""
    import gc

    from hovr_blender.ui.import_operators import ModalImport

    return [m.phases for m in gc.get_objects() if type(m) is ModalImport and not m.job.done]  # not isinstance:
    # the live objects include the operators Blender has freed, which refuse attribute lookups


def finish():
    with open(os.path.join(OUT, "report.json"), "w") as fh:
        json.dump(report, fh, indent=1)
    bpy.ops.wm.quit_blender()


def tick():
    try:
        return step()
    except Exception:  # report anything to the test, then quit instead of hanging
        import traceback
        report["error"] = traceback.format_exc()
        finish()
        return None


def waited(seconds):
    return time.time() - state.get("since", time.time()) > seconds


def step():
    phase = state["phase"]
    if phase == "setup":
        report["volumes_before"] = volumes()
        report["invoke_result"] = invoke_import(DATA)
        state.update(phase="confirm", since=time.time(), run=1)
        return 0.5
    if phase == "confirm":  # the browser is open on the mesh: Return imports it
        win, area = browser()
        if win is None:
            if waited(30):
                raise RuntimeError("the file browser did not open")
            return 0.2
        if state["run"] == 2:  # the reader the import will use, stopped before it is asked
            from hovr_blender.io import isolation

            state["reader"] = isolation._IDLE[0].proc.pid
            os.kill(state["reader"], signal.SIGSTOP)
        press(win, 'RET', area.x + area.width // 2, area.y + area.height // 2, title="File View")
        log(f"run {state['run']}: Return in the file browser")
        state.update(phase="reading", since=time.time())
        return 0.2
    if phase == "reading" and state["run"] == 1:  # the import reads, then makes the volume
        if volumes() == report["volumes_before"]:
            if waited(120):
                raise RuntimeError("the modal import never finished")
            return 0.2
        report["volumes_after_import"] = volumes()
        log("run 1: the volume appeared")
        from hovr_blender.io import sources

        sources.clear_cache()  # the redo reads again: the reader process, not the cached mesh
        win, area, region = view3d()  # a redo (undo, then the operator again) reads to the end at once
        with bpy.context.temp_override(window=win, area=area, region=region):
            report["redo_result"] = sorted(bpy.ops.ed.undo_redo())
        report["volumes_after_redo"] = volumes()
        # the Solution given: the browser's options list no fields (that listing would take the
        # stopped reader, which the import is to wait on)
        report["invoke_result_2"] = invoke_import(OTHER, os.path.splitext(OTHER)[0] + ".fld")
        state.update(phase="confirm", since=time.time(), run=2)
        return 0.5
    if phase == "reading":  # run 2: the stopped reader holds the import; the status bar says so
        phases = running_import_phases()
        if not phases or not phases[0][-1].endswith("starting the reader"):  # Return not handled yet
            if waited(60):
                raise RuntimeError(f"the second import did not start reading: {phases}")
            return 0.2
        report["volumes_while_reading"] = volumes()
        report["reader_alive_before_esc"] = _alive(state["reader"])
        report["phases"] = phases
        press(main_window(), 'ESC', title="factory.blend")
        log("run 2: Esc")
        state.update(phase="cancelled", since=time.time())
        return 0.2
    if phase == "cancelled":
        if running_import_phases() and not waited(30):  # Esc not handled yet
            return 0.2
        report["volumes_after_esc"] = volumes()
        report["reader_alive_after_esc"] = _alive(state["reader"])
        report["reports"] = reports()
        report["phases_after_esc"] = running_import_phases()
        finish()
        return None
    return None


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


addon_utils.enable("hovr_blender", default_set=False, handle_error=None)
bpy.app.timers.register(tick, first_interval=2.0)
