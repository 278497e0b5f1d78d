"""The first and the second F12 after a ramp edit (issue 40), inside Blender (the bpy module): a
dataset imported with the defaults into the factory scene, F12 (which traces and keeps the view's
segments, ui/render.FINAL), a colour-ramp edit, F12 again (shaded from the kept segments), on each
device setting asked for, each in a fresh session.

    python -m bench.f12_reshade --data nektar/hump3D_GLL.xml --size 240x135 --devices cpu,cpu:all \\
        --out bench/results/cpu/f12_reshade.json
    python -m bench.f12_reshade --devices cuda:0,cuda:all --size 1920x1080 --out $OUT/f12_reshade.json
    python -m bench.f12_reshade --data shared --size 320x180 --out bench/results/cpu/issue37/f12_320x180.json

Each row: the device, the two F12s' wall seconds (bpy.ops.render.render, data loading and kernel
loads included in the first: a session's first F12), the status line each ended with, and the
second's share of the first. The kernels are compiled before the timing (a warm-up F12 of another
size), so the first F12 is what a user's first F12 of a new view costs in a session that rendered
before.
"""
from __future__ import annotations

import argparse
import time

from bench.common import DATA, REPO, command_line, git, write_report


def measure(path: str, device: str, width: int, height: int) -> dict:
    import bpy

    import hovr_blender
    from hovr_blender.ui import render

    bpy.ops.wm.read_factory_settings(use_empty=False)
    hovr_blender.register()
    try:
        scene = bpy.context.scene
        scene.render.engine = "HOVR"
        scene.hovr.device = device
        scene.render.resolution_percentage = 100
        importers = {"xml": "hovr_nektar", "vtu": "hovr_vtu", "pyfrm": "hovr_pyfr", "mesh": "hovr_mfem"}
        op = importers[path.rsplit(".", 1)[1]]
        getattr(bpy.ops.import_scene, op)(filepath=path)
        obj = bpy.context.active_object
        lines = []
        original = render.render_stats

        def keep(*a, **k):
            text = original(*a, **k)
            lines.append(text)
            return text

        render.render_stats = keep
        scene.render.resolution_x, scene.render.resolution_y = 32, 18  # warm-up: the kernels compiled and loaded
        bpy.ops.render.render()
        scene.render.resolution_x, scene.render.resolution_y = width, height
        t0 = time.perf_counter()
        bpy.ops.render.render()
        first = time.perf_counter() - t0
        ramp = obj.hovr.transfer_function.color_ramp
        ramp.elements[len(ramp.elements) // 2].color = (1.0, 0.2, 0.1, ramp.elements[len(ramp.elements) // 2].color[3])
        t0 = time.perf_counter()
        bpy.ops.render.render()
        second = time.perf_counter() - t0
        render.render_stats = original
        return {"device": device, "first_f12_seconds": first, "second_f12_seconds": second,
                "second_over_first": second / first, "first_status": lines[-2], "second_status": lines[-1]}
    finally:
        from hovr_blender.ui import render

        render.clear_cache()
        hovr_blender.unregister()


def shared_files() -> list[str]:
    """Every audit dataset that is a file, as --data takes it (under the shared data)."""
    from hovr_blender.audit.datasets import DATASETS

    return [d["path"] for d in DATASETS.values() if "path" in d]


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m bench.f12_reshade")
    ap.add_argument("--data", default="nektar/hump3D_GLL.xml",
                    help="under the shared data (bench.common.DATA), a comma list, or 'shared': every audit dataset's file")
    ap.add_argument("--size", default="240x135")
    ap.add_argument("--devices", default="cpu,cpu:all")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    width, height = map(int, args.size.lower().split("x"))
    names = shared_files() if args.data == "shared" else [d.strip() for d in args.data.split(",") if d.strip()]
    runs = []
    for name in names:
        path = next(p for p in (REPO / "tests" / "data" / name, DATA / name) if p.exists())
        rows = []
        for device in args.devices.split(","):
            row = measure(str(path), device.strip(), width, height)
            print(f"f12_reshade: {name}: {row['device']}: first {row['first_f12_seconds']:.2f} s, second after a ramp "
                  f"edit {row['second_f12_seconds']:.2f} s ({100 * row['second_over_first']:.0f} %)", flush=True)
            rows.append(row)
        runs.append({"data": name, "rows": rows})
    write_report({"command": command_line(), "git_commit": git("rev-parse", "HEAD"), "date": time.strftime("%Y-%m-%d"),
                  "size": args.size, "runs": runs}, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
