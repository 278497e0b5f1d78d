"""Run by Debian's Blender 3.4 *with a window* (under Xvfb, --enable-event-simulate), factory
startup, a new Warp kernel cache: the first hour of issue 16 as a user does it. hump3D imported
(File > Import > HOVR Nektar++, defaults); the outline in Solid shading, Frame HOVR Volume,
Rendered shading in camera view (the kernels' first use compiled there, then converging), F12,
and the render and object HOVR panels. Screenshots and report.json go to OUT; the pytest side
checks them (and copies them into docs/ on request)."""
import json
import os
import sys
import time

import addon_utils
import bpy

if os.environ.get("HOVR_EXTRA_SITE"):  # warp-lang from the project's venv (Debian has none)
    sys.path.append(os.environ["HOVR_EXTRA_SITE"])

OUT, DATA = sys.argv[sys.argv.index("--") + 1:][:2]
report = {"log": []}
state = {"t0": time.time(), "phase": "setup"}


def log(msg):
    report["log"].append(f"{time.time() - state['t0']:.2f}s {msg}")


def view3d():
    win = bpy.context.window_manager.windows[0]
    area = max((a for a in win.screen.areas if a.type in ('VIEW_3D', 'PROPERTIES')), key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == 'WINDOW')
    return win, area, region


def override():
    win, area, region = view3d()
    return bpy.context.temp_override(window=win, area=area, region=region)


def shot(name):
    path = os.path.join(OUT, name)
    with override():
        bpy.ops.screen.screenshot(filepath=path)
    report[name] = path
    return path


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


def step():
    win, area, region = view3d()
    sc = bpy.context.scene
    phase = state["phase"]
    if phase == "setup":
        sc.render.engine = 'HOVR'
        cube = bpy.data.objects.get("Cube")  # a 2 m cube would hide a 2 cm domain in Solid shading
        if cube is not None:
            bpy.data.objects.remove(cube)
        space = area.spaces.active
        space.show_region_toolbar = space.show_region_ui = False
        bpy.context.preferences.filepaths.use_relative_paths = False  # readable paths in the screenshot
        report["objects_before"] = sorted(o.name for o in bpy.data.objects)
        with override():
            result = bpy.ops.import_scene.hovr_nektar(filepath=DATA)
        report["import_result"] = sorted(result)
        state.update(phase="importing", import_from=time.time())
        return 0.2
    if phase == "importing":
        obj = bpy.context.view_layer.objects.active
        if obj is None or not obj.hovr.is_volume:
            if time.time() - state["import_from"] < 120:
                return 0.2
            raise RuntimeError("the import never finished")
        log(f"imported in {time.time() - state['import_from']:.1f} s")
        space = area.spaces.active
        report.update(volume=obj.name, solution=obj.hovr.solution,
                      field=obj.hovr.field, clip=[sc.camera.data.clip_start, sc.camera.data.clip_end],
                      view_clip=[space.clip_start, space.clip_end],
                      view=[list(space.region_3d.view_location), space.region_3d.view_distance],
                      bounds=[list(obj.matrix_world @ __import__("mathutils").Vector(c)) for c in obj.bound_box][::7],
                      camera=list(sc.camera.location))
        state["phase"] = "solid"
        return 0.5
    if phase == "solid":  # the outline, drawn by Blender's overlays in Solid shading
        obj = bpy.data.objects[report["volume"]]
        if not state.get("solid_shown"):
            from bpy_extras.view3d_utils import location_3d_to_region_2d

            report["region"] = [region.x, region.y, region.width, region.height]
            report["origin_px"] = list(location_3d_to_region_2d(region, area.spaces.active.region_3d,
                                                                obj.matrix_world.translation))
            shot("solid_with_outline.png")
            obj.hide_set(True)
            state["solid_shown"] = True
            return 1.0
        shot("solid_without_outline.png")
        obj.hide_set(False)
        state["phase"] = "frame"
        return 0.5
    if phase == "frame":
        with override():
            bpy.ops.hovr.frame_volume()
        space = area.spaces.active
        space.region_3d.view_perspective = 'CAMERA'
        space.overlay.show_overlays = False
        space.show_gizmo = False
        space.shading.type = 'RENDERED'
        with override():
            bpy.ops.view3d.view_center_camera()
        state.update(phase="wait", wait_from=time.time())
        log("framed, rendered shading")
        return 0.5
    if phase == "wait":
        from hovr_blender.ui import render as re_mod

        states = list(re_mod.VIEWPORTS)
        done = [v for v in states if v.converged]
        report.setdefault("viewport_status", [])
        for v in states:
            text = v.status_text()
            if not report["viewport_status"] or report["viewport_status"][-1] != text:
                report["viewport_status"].append(text)
        if not done and time.time() - state["wait_from"] < 300:
            area.tag_redraw()
            return 0.5
        report["viewport_converged"] = bool(done)
        log(f"viewport converged: {bool(done)}")
        state["phase"] = "viewport_shot"
        return 1.0
    if phase == "viewport_shot":
        shot("rendered_viewport.png")
        sc.render.resolution_percentage = 25
        sc.render.filepath = os.path.join(OUT, "f12.png")
        sc.render.image_settings.file_format = 'PNG'
        bpy.ops.render.render(write_still=True)
        report["f12"] = sc.render.filepath
        log("f12 written")
        area.type = 'PROPERTIES'
        state["phase"] = "render_panels"
        return 1.0
    if phase == "render_panels":  # Render Properties: the engine, Quadrature (the step), Film
        if not state.get("render_panels_ready"):
            area.spaces.active.context = 'RENDER'
            state["render_panels_ready"] = True
            return 1.0
        shot("render_panels.png")
        state["phase"] = "panels"
        return 0.5
    if phase == "panels":
        if not state.get("panels_ready"):
            area.spaces.active.context = 'OBJECT'
            state["panels_ready"] = True
            return 1.0
        if not state.get("scrolled"):  # down to the HOVR Volume and Look panels
            with override():
                for _ in range(3):
                    bpy.ops.view2d.scroll_down(page=True)
            state["scrolled"] = True
            return 1.0
        shot("object_panels.png")
        finish()
        return None
    return None


addon_utils.enable("hovr_blender", default_set=False, handle_error=None)
bpy.app.timers.register(tick, first_interval=2.0)
