"""Blender's relative step (Steps Across: h = the volume's bounding-box diagonal / N) against the
old world default h = 0.01: classified's largest pixel error against split (tolerance 1e-7) and
its time, on a small first picture (the importer's defaults: the Smooth Ramp over the sampled
range, density 4 across the volume, Blender's default view direction framed).

    python -m bench.relative_step --out bench/results/cpu/relative_step.json

The user guide's numbers for the default N = 1000 come from here (hump3D, PyFR's Taylor-Green
pressure). On a shared machine the times are for comparison within one run only.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.common import DATA
from hovr_blender.ui import framing  # bpy-free
from hovr_blender.engine import first_view
from hovr_blender.engine.looks import TF_PRESETS, field_samples
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.sources import VolumeSource, load_volume

DATASETS = {  # name: (mesh, solution, field)
    "hump3D": ("nektar/hump3D_GLL.xml", "nektar/hump3D.rst", "rho"),
    "pyfr_tgv_pressure": ("vtu/pyfr_tgv_hexprism_p4_t4.vtu", "", "Pressure"),
}
STEPS_ACROSS = (250, 500, 1000, 2000)
DEFAULT_VIEW = first_view.FACTORY_FORWARD  # Blender's default camera direction


def first_picture(mesh, width: int, height: int):
    """(camera, transfer function, diagonal) as the importer's defaults give them."""
    v = mesh.vertices.reshape(-1, 3)
    lo, hi = v.min(axis=0), v.max(axis=0)
    diag = first_view.volume_diagonal(lo, hi)
    values = field_samples(mesh)
    stops = TF_PRESETS["SMOOTH"][2]
    tf = TransferFunction.from_rgba_ramp([p for p, _ in stops], [c for _, c in stops],
                                         first_view.density_per_world_unit(4.0, "RELATIVE", diag),
                                         float(values.min()), float(values.max()))
    forward = np.asarray(DEFAULT_VIEW, float)
    forward /= np.linalg.norm(forward)
    tan_y = np.tan(np.radians(39.6) / 2) * height / width  # Blender's 50 mm lens, sensor fit along x
    eye, _, _, _ = first_view.fit_view(framing.box_corners(lo, hi), forward, (0, 0, 1), tan_y * width / height, tan_y)
    camera = RayCamera.from_contract({"projection": "perspective", "eye": eye.tolist(),
                                      "target": (eye + forward).tolist(), "up": [0.0, 0.0, 1.0],
                                      "fov_y_deg": float(np.degrees(2 * np.arctan(tan_y)))}, width, height)
    return camera, tf, diag


def run(name: str, width: int, height: int) -> dict:
    mesh_path, solution, field = DATASETS[name]
    mesh = load_volume(VolumeSource.resolve(str(DATA / mesh_path), str(DATA / solution) if solution else "", field))
    camera, tf, diag = first_picture(mesh, width, height)
    renderer = Renderer(mesh, "cpu")
    background = np.full(3, 0.05)
    exact = renderer.render(camera, tf, background, RenderOptions(method="split", tolerance=1e-7)).rgba
    rows = []
    for label, h in [("h=0.01", 0.01)] + [(f"N={n}", diag / n) for n in STEPS_ACROSS]:
        t0 = time.perf_counter()
        res = renderer.render(camera, tf, background, RenderOptions(method="classified", h=h))
        rows.append({"step": label, "h": h, "max_error": float(np.abs(res.rgba - exact).max()),
                     "seconds": time.perf_counter() - t0, "samples_per_ray": res.stats.get("samples_per_ray")})
        print(f"{name:18s} {label:7s} h={h:.3g} error={rows[-1]['max_error']:.2e} {rows[-1]['seconds']:.2f} s",
              flush=True)
    return {"dataset": name, "diagonal": diag, "width": width, "height": height, "rows": rows}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", default="96x54", help="image WIDTHxHEIGHT (default 96x54)")
    p.add_argument("--out", type=Path, help="write the results as JSON here")
    args = p.parse_args(argv)
    width, height = (int(x) for x in args.size.split("x"))
    results = [run(name, width, height) for name in DATASETS]
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
