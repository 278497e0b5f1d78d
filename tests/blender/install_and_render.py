"""Child process of test_extension.py: install the built zip as an extension, render with it.

Run as ``python install_and_render.py SPEC_JSON`` with BLENDER_USER_* pointing at a
throw-away directory (set before bpy is imported). Only the installed copy
(bl_ext.user_default.hovr_blender) may be used, never the repository's hovr_blender.
"""
import json
import sys
import time

import bpy
import numpy as np

from blender_helpers import build_sphere_scene, compat, render_to_exr

REPO_MODULE = "bl_ext.user_default.hovr_blender"


def main():
    spec = json.loads(sys.argv[1])
    result = bpy.ops.extensions.package_install_files(filepath=spec["zip"], repo="user_default", enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert REPO_MODULE in bpy.context.preferences.addons, list(bpy.context.preferences.addons.keys())

    for obj in list(bpy.data.objects):  # the default startup scene's cube, light and camera
        bpy.data.objects.remove(obj)
    scene = bpy.context.scene
    scene.render.engine = "HOVR"
    volume = build_sphere_scene(scene, spec["contract"], spec["width"], spec["height"],
                                [tuple(s) for s in spec["stops"]], spec["value_range"], spec["density_scale"],
                                spec["background"], spec["location"], spec["angle_z"], spec["method"])
    t0 = time.perf_counter()
    rgba = render_to_exr(scene, spec["exr"])
    first_render_seconds = time.perf_counter() - t0
    np.save(spec["out"], rgba)
    if spec.get("out_all_cores"):  # again on All CPU Cores: processes of the installed extension
        scene.hovr.device = "cpu:all"
        np.save(spec["out_all_cores"], render_to_exr(scene, spec["exr"]))
        scene.hovr.device = "cpu"
    if spec.get("out_isosurface"):  # then a look with an isosurface: its own integrate and shade
        iso = volume.hovr_surfaces.isosurfaces.add()
        iso.value, iso.color, iso.opacity = spec["isosurface"], (0.9, 0.3, 0.1), 0.75
        np.save(spec["out_isosurface"], render_to_exr(scene, spec["exr"]))

    engine = next(c for c in bpy.types.RenderEngine.__subclasses__() if getattr(c, "bl_idname", "") == "HOVR")
    loaded = sorted(m for m in sys.modules if "hovr_blender" in m)
    report = {
        "engine_module": engine.__module__,
        "renderer_loaded": f"{REPO_MODULE}.engine.renderer" in sys.modules,
        "foreign_modules": [m for m in loaded if m == "hovr_blender" or m.startswith("hovr_blender.")],
        "user_extensions": bpy.utils.user_resource("EXTENSIONS"),
        "first_render_seconds": first_render_seconds,
    }
    with open(spec["report"], "w", encoding="utf-8") as fh:
        json.dump(report, fh)


def engine_registered():
    """The engine enum only accepts registered engines."""
    try:
        bpy.context.scene.render.engine = "HOVR"
    except TypeError:
        return False
    bpy.context.scene.render.engine = compat().eevee_engine()
    return True


def disable_and_uninstall(spec):
    """Second process on the same user directories: the extension is still installed; enable,
    disable, then uninstall it."""
    bpy.ops.preferences.addon_enable(module=REPO_MODULE)
    report = {"enabled": REPO_MODULE in bpy.context.preferences.addons and engine_registered()}
    # Disable: engine, operators and the Scene/Object properties go away.
    bpy.ops.preferences.addon_disable(module=REPO_MODULE)
    report["disabled"] = {
        "in_addons": REPO_MODULE in bpy.context.preferences.addons,
        "engine": engine_registered(),
        "scene_prop": hasattr(bpy.types.Scene, "hovr"),
    }
    # Uninstall: the extension's directory is removed.
    repo_index = next(i for i, r in enumerate(bpy.context.preferences.extensions.repos) if r.module == "user_default")
    result = bpy.ops.extensions.package_uninstall(repo_index=repo_index, pkg_id="hovr_blender")
    report["uninstalled"] = sorted(result)
    with open(spec["report"], "w", encoding="utf-8") as fh:
        json.dump(report, fh)


if __name__ == "__main__":
    if json.loads(sys.argv[1]).get("mode") == "uninstall":
        disable_and_uninstall(json.loads(sys.argv[1]))
    else:
        main()
    compat().finish_script(0)
