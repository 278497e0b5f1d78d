"""Child process of test_extension.py's clean-install test, run by the base Python (no venv):
only bpy and its own dependencies are importable (spec["site"]). Install the platform zip,
enable it, import a Nektar++ mesh with an HDF5 solution and a VTU, render one frame."""
import importlib.util
import json
import sys

spec = json.loads(sys.argv[1])
sys.path.insert(0, spec["site"])
sys.path.insert(0, spec["helpers"])

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from blender_helpers import compat, render_to_exr  # noqa: E402

MODULE = "bl_ext.user_default.hovr_blender"
DEPS = ("warp", "h5py")


def main():
    report = {"before": {m: importlib.util.find_spec(m) is not None for m in DEPS}}
    result = bpy.ops.extensions.package_install_files(filepath=spec["zip"], repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}, result
    assert MODULE in bpy.context.preferences.addons
    deps = __import__(MODULE + ".ui.dependencies", fromlist=["missing"])
    report["missing_after_enable"] = [m for m, *_ in deps.missing()]
    report["origins"] = {m: str(importlib.util.find_spec(m).origin) for m in DEPS}

    scene = bpy.context.scene
    scene.render.engine = "HOVR"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 64, 36, 100
    imports, fields = [], []
    imports += bpy.ops.import_scene.hovr_nektar(filepath=spec["xml"], field="u")  # solution m.fld (HDF5)
    fields.append(bpy.context.active_object.hovr.field)
    obj = bpy.context.active_object
    assert obj.hovr.solution.endswith("m.fld"), obj.hovr.solution
    imports += bpy.ops.import_scene.hovr_vtu(filepath=spec["vtu"], field="vel", component="1")
    src = bpy.context.active_object
    src.location.x += 2.0
    fields.append(__import__(MODULE + ".io.sources", fromlist=["x"]).cached_volume(
        __import__(MODULE + ".io.sources", fromlist=["x"]).VolumeSource.resolve(
            src.hovr.source, "", src.hovr.field, 1, component=src.hovr.component)).field_name)
    bpy.ops.hovr.frame_volume()
    scene.render.film_transparent = True
    img = render_to_exr(scene, spec["report"] + ".exr")
    report.update(imports=sorted(imports), fields=fields, alpha_max=float(img[..., 3].max()))
    with open(spec["report"], "w", encoding="utf-8") as fh:
        json.dump(report, fh)


if __name__ == "__main__":
    main()
    compat().finish_script(0)
