"""The user guide's worked examples, headless: File > Import with the importer's defaults into
Blender's factory startup scene, then F12 through the scene camera (as
tests/blender/test_first_picture.py checks at 5%).

    python -m scripts.first_pictures [--percentage 25] [--out docs]

writes docs/first-picture-hump3D.png (Nektar++ hump3D_GLL.xml, solution hump3D.rst found by
name) and docs/first-picture-ngsolve-ball.png (NGSolve's ball, VTU), from ../shared/data.
"""
from __future__ import annotations

import argparse
import os
import time

from bench.common import DATA, REPO

EXAMPLES = {
    "hump3D": ("hovr_nektar", "nektar/hump3D_GLL.xml"),
    "ngsolve-ball": ("hovr_vtu", "vtu/ngsolve_ball_poisson_hex_p6.vtu"),
}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--percentage", type=int, default=25, help="of Blender's default 1920 x 1080")
    ap.add_argument("--out", default=str(REPO / "docs"))
    ap.add_argument("--only", choices=sorted(EXAMPLES))
    args = ap.parse_args(argv)

    import bpy

    import hovr_blender

    for name, (op, rel) in EXAMPLES.items():
        if args.only and name != args.only:
            continue
        path = next((p for p in (REPO / "tests" / "data" / rel, DATA / rel) if p.exists()),
                    None)
        if path is None:
            print(f"first_pictures: {rel} not found, skipped")
            continue
        bpy.ops.wm.read_factory_settings(use_empty=False)
        hovr_blender.register()
        try:
            scene = bpy.context.scene
            scene.render.engine = "HOVR"
            scene.render.resolution_percentage = args.percentage
            getattr(bpy.ops.import_scene, op)(filepath=str(path))
            scene.render.image_settings.file_format = "PNG"
            scene.render.filepath = os.path.join(args.out, f"first-picture-{name}.png")
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)
            print(f"first_pictures: {scene.render.filepath} in {time.perf_counter() - t0:.1f} s")
        finally:
            hovr_blender.unregister()


if __name__ == "__main__":
    main()
