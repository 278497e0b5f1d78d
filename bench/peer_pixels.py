"""Whose error is it? One pixel of a peers run (bench/peers.py) traced again on any device:
ours in float32 (the peers' `split` setting) and in float64 (the pixel-exact preset), each in
its own image row (Renderer.render(rows=...): the very ray the whole frame traces), the
independent VTK reference (hovr_blender/audit/vtk_reference.py) with the stretches of the ray it
found inside the cells, and, on hexahedral meshes, the exact chord of the ray through the mesh's
boundary (hovr_blender/audit/chords.py). Then the same along a sub-pixel scan (the ray moved
by fractions of a pixel, across and along the row), which shows whether the pixel's value is a
steep function of its ray (a ray grazing a boundary) or a step no neighbour shares.

    python -m bench.peer_pixels --dataset Hex_Mushroom --pixel 559,285 --out bench/results/cpu/peer_pixels
    python -m bench.peer_pixels --dataset ngsolve_ball --pixel 1314,248 --out bench/results/cpu/peer_pixels

Writes OUT/<dataset>_<i>_<j>.json and prints a summary. Size and view are the peers' defaults of
the GPU run (1920x1080, "oblique").
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench import common
from bench.peers import vtk_grid
from hovr_blender.audit import datasets


def scan_camera(camera, i, j, offsets, axis):
    """A RayCamera of len(offsets) x 1 pixels whose rays are pixel (i, j)'s moved by `offsets`
    pixels along `axis` ("i": across the row, "j": down the column) of `camera`'s image."""
    from hovr_blender.engine.camera import RayCamera

    W, H = camera.width, camera.height
    off = np.asarray(offsets, float)
    n = len(off)
    step = off[1] - off[0] if n > 1 else 1.0
    if not np.allclose(np.diff(off), step):
        raise ValueError("offsets must be evenly spaced")
    u = (2.0 * (i + 0.5 + (off[0] + off[-1]) / 2 * (axis == "i")) / W - 1.0) * (W / H)
    v = 1.0 - 2.0 * (j + 0.5 + (off[0] + off[-1]) / 2 * (axis == "j")) / H
    # the scan's own u runs 2k + 1 - n over its pixels k: one of its pixels = step image pixels
    along_u, along_v = (camera.ou, camera.du) if axis == "i" else (-camera.ov, -camera.dv)
    s = step / H
    return RayCamera(n, 1, camera.o0 + u * camera.ou + v * camera.ov, s * along_u, 0.0 * camera.ov,
                     camera.d0 + u * camera.du + v * camera.dv, s * along_v, 0.0 * camera.dv)


def trace(dataset, i, j, size=(1920, 1080), view="oblique", device="cpu", offsets=None, scan_independent=True,
          log=print):
    from hovr_blender.audit import chords
    from hovr_blender.audit import vtk_reference as R
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.reference import pixel_exact_reference
    from hovr_blender.engine.view import RenderOptions

    W, H = size
    mesh, data = datasets.load(dataset)
    tf = datasets.transfer_function(mesh)
    cam = dict(datasets.views(mesh)[view], projection="perspective")
    camera = RayCamera.from_contract(cam, W, H)
    renderer, _ = common.compiled_renderer(mesh, device)
    bg = np.zeros(3)
    split = RenderOptions(device=device, method="split", tolerance=1e-3)
    t0 = time.perf_counter()
    f32 = renderer.render(camera, tf, bg, split, rows=(j, j + 1)).rgba[0, i].astype(np.float64)
    f64 = renderer.render(camera, tf, bg, RenderOptions.pixel_exact(device), rows=(j, j + 1)).rgba[0, i]
    log(f"ours (row {j}): {time.perf_counter() - t0:.1f} s")
    grid, why = vtk_grid(dataset, mesh, data)
    ind = R.IndependentReference(grid, tf.color_s, tf.color_rgb, tf.density_s, tf.density_tau, tol=1e-10) \
        if grid is not None else None
    boundary = chords.Boundary(mesh)

    def independent(di, dj, colour=True):
        """(independent RGBA and its error estimate, or None; its inside stretches; exact chord)."""
        o, d = R.contract_ray(cam, W, H, i + di, j + dj)
        t = time.perf_counter()
        r = ind.pixel(o, d, bg) if colour else None
        inside = [(a, b) for a, b, _ in ind.stretches(o, d, 0.0, np.inf)]
        chord = float(chords.chords_numpy(boundary, o[None], d[None])[0]) if boundary is not None else None
        log(f"    independent ({i + di:.3f}, {j + dj:.3f}): {time.perf_counter() - t:.1f} s")
        return (r.rgba, r.error) if r is not None else (None, None), inside, chord

    (ref, err), inside, chord = independent(0.0, 0.0)
    out = {"dataset": dataset, "pixel": [i, j], "size": [W, H], "view": view, "device": device,
           "git_commit": common.git("rev-parse", "HEAD"), "command": common.command_line(),
           "ours_float32": f32.tolist(), "ours_float64": f64.tolist(), "independent": ref.tolist(),
           "independent_error_estimate": err, "independent_inside": inside, "exact_chord": chord,
           "float32_minus_independent": float(np.abs(f32[:3] - ref[:3]).max()),
           "float64_minus_independent": float(np.abs(f64[:3] - ref[:3]).max()),
           "float32_minus_float64": float(np.abs(f32[:3] - f64[:3]).max()), "scans": {}}
    log(f"pixel ({i}, {j}): float32 {np.round(f32, 6)}, float64 {np.round(f64, 6)}, independent {np.round(ref, 6)}"
        f" (its inside stretches {inside}), exact chord {chord}")
    offsets = np.linspace(-0.5, 0.5, 21) if offsets is None else np.asarray(offsets, float)
    for axis in ("i", "j"):
        sc = scan_camera(camera, i, j, offsets, axis)
        o32 = renderer.render(sc, tf, bg, split).rgba[0].astype(np.float64)
        o64, _ = pixel_exact_reference(mesh, sc, tf, bg, device, renderer=renderer)
        rows = []
        for k, off in enumerate(offsets):
            di, dj = (off, 0.0) if axis == "i" else (0.0, off)
            (r_ind, _), ins, ch = independent(di, dj, scan_independent)
            rows.append({"offset_pixels": float(off), "float32": o32[k].tolist(), "float64": o64[0, k].tolist(),
                         "independent": None if r_ind is None else r_ind.tolist(), "independent_inside": ins,
                         "exact_chord": ch})
            g = "-" if r_ind is None else f"{r_ind[1]:.5f}"
            log(f"  {axis} {off:+.3f} px: G float32 {o32[k, 1]:.5f} float64 {o64[0, k, 1]:.5f} "
                f"independent {g}; stretches {[(round(a, 6), round(b, 6)) for a, b in ins]} chord {ch}")
        out["scans"][axis] = rows
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--pixel", required=True, help="i,j (column, row from the top)")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--view", default="oblique")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--scan", type=int, default=21, help="rays of each sub-pixel scan, over -0.5..0.5 pixel")
    ap.add_argument("--no-scan-independent", action="store_true",
                    help="along the scans, only the independent reference's stretches and the exact chord "
                         "(its colour costs a second or more a ray)")
    ap.add_argument("--out", default=str(common.RESULTS / "cpu" / "peer_pixels"))
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    i, j = (int(v) for v in args.pixel.split(","))
    W, H = (int(v) for v in args.size.split("x"))
    out = trace(args.dataset, i, j, (W, H), args.view, args.device, np.linspace(-0.5, 0.5, args.scan),
                not args.no_scan_independent)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    p = Path(args.out) / f"{args.dataset}_{i}_{j}.json"
    p.write_text(json.dumps(out, indent=1, default=common.jsonable) + "\n")
    print("wrote", p)


if __name__ == "__main__":
    main()
