"""Run by Debian's Blender 3.4 *with a window* (under Xvfb) on the scene legacy_make_scene.py
saved: switch the 3D view to camera view in Rendered shading with overlays off, wait for the
HOVR viewport to converge, screenshot the window, then F12 the same view at the region's
size, and again on All CPU Cores. Writes report.json beside the images; the pytest side compares the pixels."""
import json
import os
import sys
import time

import addon_utils
import bpy

# warp-lang is not packaged by Debian: take it from the project's venv (same Python 3.11 ABI),
# appended so Debian's numpy, which its Blender was built with, still comes first.
if os.environ.get("HOVR_EXTRA_SITE"):
    sys.path.append(os.environ["HOVR_EXTRA_SITE"])
from bpy_extras.view3d_utils import location_3d_to_region_2d

OUT = sys.argv[sys.argv.index("--") + 1]
report = {"log": []}
state = {"t0": time.time(), "phase": "setup"}


def log(msg):
    report["log"].append(f"{time.time() - state['t0']:.2f}s {msg}")


def view3d():
    win = bpy.context.window_manager.windows[0]
    area = max((a for a in win.screen.areas if a.type == 'VIEW_3D'), key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == 'WINDOW')
    return win, area, region


def finish():
    with open(os.path.join(OUT, "report.json"), "w") as fh:
        json.dump(report, fh, indent=1)
    bpy.ops.wm.quit_blender()


def tick():
    try:
        return step()
    except Exception as exc:  # report anything to the test, then quit instead of hanging
        import traceback
        report["error"] = traceback.format_exc()
        finish()
        return None


def step():
    if state["phase"] == "panels":
        return panels()
    win, area, region = view3d()
    space = area.spaces.active
    sc = bpy.context.scene
    if state["phase"] == "setup":
        sc.hovr.show_legend = False  # the viewport against F12 without the legend (drawn in its own phase)
        space.overlay.show_overlays = False
        space.show_gizmo = False
        space.show_region_toolbar = False
        space.show_region_ui = False
        space.show_region_header = False
        space.show_region_tool_header = False
        space.region_3d.view_perspective = 'CAMERA'
        space.shading.type = 'RENDERED'
        state["phase"] = "size"
        return 1.0
    if state["phase"] == "size":
        sc.render.resolution_x, sc.render.resolution_y = region.width, region.height
        sc.render.resolution_percentage = 100
        with bpy.context.temp_override(window=win, area=area, region=region):
            bpy.ops.view3d.view_center_camera()
        log(f"region {region.width}x{region.height} at {region.x},{region.y}")
        state["phase"] = "wait"
        state["wait_from"] = time.time()
        return 0.5
    if state["phase"] == "wait":
        from hovr_blender.ui import render as re_mod

        states = list(re_mod.VIEWPORTS)
        done = [v for v in states if v.converged]
        if not done and time.time() - state["wait_from"] < 120:
            area.tag_redraw()
            return 0.5
        report["viewport_converged"] = bool(done)
        report["viewport_log"] = [(r.kind, r.scale, list(r.rows), r.seconds) for v in states for r in v.log][:50]
        log(f"viewport states {len(states)}, converged {len(done)}")
        state["phase"] = "shot"
        return 1.0  # let the final frame reach the screen
    if state["phase"] == "shot":
        shot = os.path.join(OUT, "screenshot.png")
        with bpy.context.temp_override(window=win, area=area, region=region):
            bpy.ops.screen.screenshot(filepath=shot)
        rv3d = space.region_3d
        cam = sc.camera
        frame = [cam.matrix_world @ v for v in cam.data.view_frame(scene=sc)]
        px = [tuple(location_3d_to_region_2d(region, rv3d, p)) for p in frame]
        report.update(screenshot=shot, window=[win.width, win.height],
                      region=[region.x, region.y, region.width, region.height], camera_frame_px=px)
        log("screenshot taken")
        f12 = os.path.join(OUT, "f12.png")
        sc.render.filepath = f12
        sc.render.image_settings.file_format = 'PNG'
        sc.render.image_settings.color_mode = 'RGBA'
        sc.render.image_settings.color_depth = '8'
        bpy.ops.render.render(write_still=True)
        report["f12"] = f12
        log("f12 written")
        # the same F12 on "All CPU Cores": processes started from the Blender program
        sc.hovr.device = "cpu:all"
        sc.render.filepath = report["f12_all_cores"] = os.path.join(OUT, "f12_all_cores.png")
        bpy.ops.render.render(write_still=True)
        sc.hovr.device = "cpu"
        log("f12 on all cores written")
        # The HOVR render panels (ramp, presets, value range, histogram) for the user guide.
        with bpy.context.temp_override(window=win, area=area, region=region):
            bpy.ops.hovr.fit_value_range()
        # the colour legend overlay (drawn with the viewport's overlays): off, then on
        space.overlay.show_overlays = True
        sc.hovr.show_legend = False
        state["phase"] = "legend_off"
        return 1.0
    if state["phase"] in ("legend_off", "legend_on"):
        name = state["phase"] + ".png"
        with bpy.context.temp_override(window=win, area=area, region=region):
            bpy.ops.screen.screenshot(filepath=os.path.join(OUT, name))
        report[state["phase"]] = os.path.join(OUT, name)
        if state["phase"] == "legend_off":
            sc.hovr.show_legend = True
            state["phase"] = "legend_on"
            return 1.0
        from hovr_blender.engine.legend import legend_layout  # noqa: F401  (the layout the overlay drew)
        from hovr_blender.ui import legend_overlay

        report["legend_bar"] = list(legend_overlay.legend_for_region(sc, region, area.spaces.active).bar)
        area.type = 'PROPERTIES'  # the big 3D view area becomes a Properties editor: legible panels
        state["phase"] = "panels"
        return 1.0
    return None



def panels():
    win = bpy.context.window_manager.windows[0]
    area = max(win.screen.areas, key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == 'WINDOW')
    if not state.get("panels_ready"):  # the new editor exists only after a redraw
        area.spaces.active.context = 'RENDER'
        state["panels_ready"] = True
        return 1.0
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.screen.screenshot(filepath=os.path.join(OUT, "panels.png"))
    report["panels"] = os.path.join(OUT, "panels.png")
    finish()
    return None


addon_utils.enable("hovr_blender", default_set=False, handle_error=None)
bpy.app.timers.register(tick, first_interval=2.0)
