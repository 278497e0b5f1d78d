"""`hovr`: render a view file exactly per the render contract, without Blender.

    hovr render VIEW.json -o out.npy [--png out.png] [--stats stats.json]
                [--method NAME] [--h STEP] [--tolerance TOL] [--device cpu|cuda:0]
    hovr reference VIEW.json -o ref.npy [--png ref.png]    (float64 certifying reference)
"""
from __future__ import annotations

import argparse
import sys
import time

from .engine.view import METHODS


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hovr", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a view file with the Warp kernels")
    r.add_argument("view", help="view JSON (render contract §1)")
    r.add_argument("-o", "--output", required=True, help="float32 (H, W, 4) RGBA .npy")
    r.add_argument("--png", help="also write an sRGB 8-bit PNG")
    r.add_argument("--stats", help="write render statistics JSON")
    r.add_argument("--method", choices=METHODS, help="quadrature (default: the view's, else classified)")
    r.add_argument("--h", type=float, help="step in world units for Riemann/trapezoid/piecewise-smooth segments")
    r.add_argument("--tolerance", type=float, help="absolute error per adaptive Gauss-Kronrod panel")
    r.add_argument("--min-transmittance", type=float, help="early ray termination threshold")
    r.add_argument("--inner", choices=("spectral", "trapezoid"), help="inner integral on smooth segments")
    r.add_argument("--device", help="Warp device: cpu or cuda:0")
    r.add_argument("--precision", choices=("float32", "float64"), help="kernel arithmetic (default float32)")
    f = sub.add_parser("reference", help="render the float64 reference (affine hexahedra)")
    f.add_argument("view")
    f.add_argument("-o", "--output", required=True)
    f.add_argument("--png")
    f.add_argument("--stats")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from .engine.image_io import write_json, write_npy, write_png
    from .engine.view import View

    try:
        view = View.load(args.view)
        t0 = time.perf_counter()
        mesh = view.load_mesh()
        load_s = time.perf_counter() - t0
        if args.command == "render":
            from .engine.renderer import render_view

            view.options = view.options.with_(
                method=args.method, h=args.h, tolerance=args.tolerance,
                min_transmittance=args.min_transmittance, inner=args.inner, device=args.device,
                precision=args.precision,
            )
            result = render_view(view, mesh)
            rgba, stats = result.rgba, result.stats
        else:
            from .engine.reference import reference_render

            t0 = time.perf_counter()
            rgba, info = reference_render(mesh, view.camera, view.transfer_function, view.background)
            stats = {"device": "cpu (numpy float64)", "render_seconds": time.perf_counter() - t0,
                     "method": "reference", "parameters": {}, **info}
        stats["load_seconds"] = load_s
        write_npy(args.output, rgba)
        if args.png:
            write_png(args.png, rgba)
        if args.stats:
            write_json(args.stats, stats)
    except (ValueError, RuntimeError, OSError) as exc:
        print(f"hovr: error: {exc}", file=sys.stderr)
        return 2
    print(f"hovr: {view.camera.width}x{view.camera.height} {stats['method']} in {stats['render_seconds']:.3f} s "
          f"on {stats['device']} -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
