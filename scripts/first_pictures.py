"""The user guide's first pictures.

    python -m scripts.first_pictures [--percentage 25] [--out docs]

The worked examples, headless: File > Import with the importer's defaults into Blender's factory
startup scene, then F12 through the scene camera (as tests/blender/test_first_picture.py checks
at 5%); writes docs/first-picture-hump3D.png (Nektar++ hump3D_GLL.xml, solution hump3D.rst found
by name) and docs/first-picture-ngsolve-ball.png (NGSolve's ball, VTU), from ../shared/data.

    python -m scripts.first_pictures looks --device cuda:0 --size 480x270 --out $OUT/looks.png
    python -m scripts.first_pictures looks --device cuda:0 --size 640x360 --looks QUANTILE_TENTS --columns 3 \
        --out $OUT/first-pictures.png                   (the import's look: the user guide's sheet)
    python -m scripts.first_pictures looks --device cpu --size 160x90 --datasets hump3D,ngsolve-ball \
        --looks SMOOTH,QUANTILE_TENTS --out /tmp/looks.png

A contact sheet (issue 30): each first look (ui/scene.FIRST_LOOKS, chosen from the data, and the
smooth ramp of before) on each of the six shared datasets, a row a dataset, a column a look,
every cell with its legend. No Blender: the engine renders what an import with the importer's
defaults gives in Blender's factory scene (engine/first_view.py, what `hovr render FILE` renders): the
importer's field (the file's first, Tet_channel_m3's w: its first, u, is zero), Value Min/Max fitted,
the look's ramp and Density across the volume, the factory camera framed on the volume, the factory
world's grey behind it, Classified at 1000 Steps Across. --json writes each cell's numbers.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from bench.common import DATA, REPO

EXAMPLES = {
    "hump3D": ("hovr_nektar", "nektar/hump3D_GLL.xml"),
    "ngsolve-ball": ("hovr_vtu", "vtu/ngsolve_ball_poisson_hex_p6.vtu"),
}


# (label, path under the shared data (bench.common.DATA), field or None for the importer's default)
SHEET_DATASETS = {
    "hump3D": ("hump3D (Nektar++)", "nektar/hump3D_GLL.xml", None),
    "ngsolve-ball": ("NGSolve ball", "vtu/ngsolve_ball_poisson_hex_p6.vtu", None),
    "ngsolve-post": ("NGSolve post", "vtu/ngsolve_post_heat_tetprism_p4.vtu", None),
    "mfem-fichera": ("MFEM Fichera", "vtu/mfem_fichera_poisson_mixed_p4.vtu", None),
    "pyfr-tgv": ("PyFR TGV", "vtu/pyfr_tgv_hexprism_p4_t4.vtu", None),
    "tet-channel": ("Tet_channel_m3 (Nektar++)", "nektar/Tet_channel_m3.xml", "w"),
}


def default_field(path) -> tuple[str, str]:
    """(solution, field) an import with the importer's defaults shows (io.sources.choose_data: the
    likeliest solution beside the mesh, the file's first field)."""
    from hovr_blender.io.sources import choose_data

    _, choice = choose_data(str(path))
    return choice.solution, choice.field


def look_cells(key: str, device: str, width: int, height: int, looks, out_json: dict):
    """One dataset's cells: (linear RGB image with its legend) per look."""
    import time

    import numpy as np

    from hovr_blender.engine import first_view
    from hovr_blender.engine.image_io import png_pixels
    from hovr_blender.engine.legend import draw_legend, legend_layout
    from hovr_blender.engine.looks import FIRST_LOOKS, field_samples, value_range
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.io.sources import VolumeSource, load_volume

    label, rel, field = SHEET_DATASETS[key]
    path = DATA / rel
    solution, default = default_field(path)
    field = field or default
    mesh = load_volume(VolumeSource.resolve(str(path), solution, field, 1))
    values, weights = field_samples(mesh, weights=True)
    warning = value_range(values)[2]
    diag = first_view.mesh_diagonal(mesh)
    camera, _ = first_view.factory_camera(first_view.framing_points(mesh), width, height)
    background = np.array(first_view.FACTORY_WORLD)
    renderer = Renderer(mesh, device)
    options = RenderOptions(method="classified", h=diag / first_view.DEFAULT_STEPS_ACROSS, device=device)
    cells = []
    for look in looks:
        first = first_view.first_look(values, look, weights)
        stops, density = first.stops, first.density
        tf = first_view.look_transfer_function(first, diag)
        t0 = time.perf_counter()
        result = renderer.render(camera, tf, background, options)
        secs = time.perf_counter() - t0
        shown = png_pixels(result.rgba, background, "view")
        lo, hi = first.value_min, first.value_max
        shown = draw_legend(shown, legend_layout(tf, lo, hi, mesh.field_name or field, width, height, background))
        cells.append(shown[..., :3])
        alpha = result.rgba[..., 3]
        out_json.setdefault(key, {})[look] = {
            "field": field, "value_range": [lo, hi], "range_warning": warning, "density": density, "stops": stops,
            "seconds": secs, "covered": float((alpha > 0.02).mean()), "alpha_mean": float(alpha.mean()),
            "alpha_p99": float(np.quantile(alpha, 0.99)), "warnings": list(result.stats.get("warnings", []))}
        print(f"looks: {key} {look}: {secs:.1f} s, {100 * (alpha > 0.02).mean():.0f} % covered"
              + "".join(f"; {w}" for w in result.stats.get("warnings", [])), flush=True)
    return label, cells


def contact_sheet(rows, looks, width: int, height: int, columns: int = 0):
    """The sheet: a row a dataset (its name on the left), a column a look (its name on top); with
    one look and `columns`, the datasets `columns` to a row, each named above its picture."""
    import numpy as np
    from PIL import Image, ImageDraw, ImageFont

    from hovr_blender.engine.image_io import srgb_encode
    from hovr_blender.engine.looks import FIRST_LOOKS

    font_px = max(10, min(20, height // 9))
    font = ImageFont.load_default(size=font_px)
    gap = 2
    if columns and len(looks) == 1:
        cells = [(label, row[0]) for label, row in rows]
        n_rows = -(-len(cells) // columns)
        pitch_y = height + 2 * font_px
        sheet = Image.new("RGB", (columns * (width + gap), n_rows * pitch_y), (255, 255, 255))
        draw = ImageDraw.Draw(sheet)
        for k, (label, cell) in enumerate(cells):
            x, y = (k % columns) * (width + gap), (k // columns) * pitch_y
            draw.text((x + width // 2, y + font_px), label, fill=(0, 0, 0), font=font, anchor="mm")
            sheet.paste(Image.fromarray(np.round(srgb_encode(cell) * 255).astype(np.uint8), "RGB"), (x, y + 2 * font_px))
        return sheet
    left = int(max(font.getlength(label) for label, _ in rows)) + font_px
    top = 2 * font_px
    sheet = Image.new("RGB", (left + len(looks) * (width + gap), top + len(rows) * (height + gap)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for j, look in enumerate(looks):
        draw.text((left + j * (width + gap) + width // 2, top // 2), FIRST_LOOKS[look][0], fill=(0, 0, 0), font=font,
                  anchor="mm")
    for i, (label, cells) in enumerate(rows):
        y = top + i * (height + gap)
        draw.text((left - font_px // 2, y + height // 2), label, fill=(0, 0, 0), font=font, anchor="rm")
        for j, cell in enumerate(cells):
            px = np.round(srgb_encode(cell) * 255).astype(np.uint8)
            sheet.paste(Image.fromarray(px, "RGB"), (left + j * (width + gap), y))
    return sheet


def looks_main(argv):
    import datetime
    import json

    from hovr_blender.engine.looks import FIRST_LOOKS

    ap = argparse.ArgumentParser(prog="python -m scripts.first_pictures looks")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="480x270", help="of each cell, WxH")
    ap.add_argument("--datasets", default=",".join(SHEET_DATASETS), help=f"of {', '.join(SHEET_DATASETS)}")
    ap.add_argument("--looks", default=",".join(FIRST_LOOKS), help=f"of {', '.join(FIRST_LOOKS)}")
    ap.add_argument("--out", required=True, help="the contact sheet's PNG")
    ap.add_argument("--json", default=None, help="each cell's numbers (range, look, time, coverage)")
    ap.add_argument("--columns", type=int, default=0, help="with one look: the datasets so many to a row")
    args = ap.parse_args(argv)
    width, height = map(int, args.size.lower().split("x"))
    looks = [x.strip() for x in args.looks.split(",") if x.strip()]
    numbers = {"device": args.device, "size": args.size, "date": datetime.datetime.now().isoformat(timespec="seconds"),
               "command": "python -m scripts.first_pictures looks " + " ".join(argv), "cells": {}}
    rows = []
    for key in [x.strip() for x in args.datasets.split(",") if x.strip()]:
        if not (DATA / SHEET_DATASETS[key][1]).exists():
            print(f"looks: {DATA / SHEET_DATASETS[key][1]} not found, {key} skipped")
            continue
        rows.append(look_cells(key, args.device, width, height, looks, numbers["cells"]))
    contact_sheet(rows, looks, width, height, args.columns).save(args.out)
    print(f"looks: {args.out}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(numbers, fh, indent=1)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["looks"]:
        return looks_main(argv[1:])
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
