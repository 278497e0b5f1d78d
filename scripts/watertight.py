"""Watertightness at scale (issue 15): a constant density tau over a curved mesh gives
T = exp(-tau L), L the ray's chord through the mesh, computed without renderer code from the
mesh's boundary patches (hovr_blender/audit/chords.py, float64 Newton per patch). Every
pixel of several full-HD views, plus small cameras aimed at the mesh's vertices, edge middles
and face centres, in float32 and float64; the report gives each precision's max relative
error of T and where it is.

    python -m scripts.watertight --device cuda:0 --size 1920x1080 --views 5 --out wt.json

Conditioning: a ray that grazes a curved boundary has a chord that changes fast with the
ray's position (at tangency, without bound), so where the float32 error exceeds the budget
the report also gives the chord's spread over rays moved sideways by DISPLACE (a few float32
roundings of the ray's origin): an error within tau x that spread is float32's rounding of
the ray itself, not a leak. Both numbers are reported; nothing is hidden behind the second.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from bench.common import DATA, REPO
from hovr_blender.audit.scenes import constant_density, constant_field  # the tests' own scene
TAU = 1.1  # per world unit; both meshes are about 1 to 2 units across
BUDGET = {"float64": 1e-6, "float32": 1e-4}
DISPLACE = 4.0 * 2.0 ** -24  # relative to the eye's distance from the mesh's centre


def meshes(names=("RotPerBcs3D_Annulus", "ngsolve_ball")):
    from hovr_blender.io.nektar import read_nektar
    from hovr_blender.io.vtu import read_vtu

    out = {}
    if "RotPerBcs3D_Annulus" in names:
        out["RotPerBcs3D_Annulus"] = constant_field(read_nektar(str(REPO / "tests/data/nektar/RotPerBcs3D_Annulus.xml")))
    ball = DATA / "vtu" / "ngsolve_ball_poisson_hex_p6.vtu"
    if "ngsolve_ball" not in names:
        pass
    elif ball.exists():
        out["ngsolve_ball"] = constant_field(read_vtu(str(ball), "u"))
    else:
        print(f"ngsolve_ball: skipped, missing {ball}", flush=True)
    return out


def bounds(mesh):
    v = mesh.vertices.reshape(-1, 3)
    lo, hi = v.min(0), v.max(0)
    return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))


def view_directions(n, seed):
    """The tests' three directions (oblique, side, nearly along z: rays along the annulus' axis)
    and seeded random ones."""
    fixed = [(1.0, -0.8, 0.7), (0.3, 1.0, -0.2), (0.0, 0.001, 1.0)]
    rng = np.random.default_rng(seed)
    more = [tuple(v) for v in rng.normal(size=(max(0, n - len(fixed)), 3))]
    return [np.asarray(v, float) / np.linalg.norm(v) for v in (fixed + more)[:n]]


def full_views(mesh, W, H, n, seed):
    from hovr_blender.engine.camera import RayCamera

    c, r = bounds(mesh)
    return [RayCamera.from_contract({"eye": (c + 2.6 * r * d).tolist(), "target": c.tolist(), "up": [0, 0, 1],
                                     "fov_y_deg": 30.0}, W, H) for d in view_directions(n, seed)]


def targets(mesh, limit, seed):
    """Points where defects live: element vertices, edge middles and face centres (the mesh's
    straight-sided skeleton, first-order points), deduplicated, at most `limit` of each kind."""
    from hovr_blender.engine import shapes

    rng = np.random.default_rng(seed)
    V = mesh.vertices  # (E, 8, 3) for hexahedra
    kinds = {"vertex": V.reshape(-1, 3)}
    if np.all(mesh.shape == shapes.HEX):
        e = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]])
        f = np.array([[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
        kinds["edge"] = V[:, e].mean(axis=2).reshape(-1, 3)
        kinds["face"] = V[:, f].mean(axis=2).reshape(-1, 3)
    out = {}
    for k, pts in kinds.items():
        pts = np.unique(np.round(pts, 9), axis=0)
        if len(pts) > limit:
            pts = pts[rng.choice(len(pts), limit, replace=False)]
        out[k] = pts
    return out


def aimed_camera(point, direction, r):
    """A 3x3 orthographic camera whose centre ray passes through `point` along `direction`,
    its other rays 1e-5 r to the sides (near misses of the same vertex, edge or face)."""
    from hovr_blender.engine.camera import RayCamera

    up = [0, 0, 1] if abs(direction[2]) < 0.9 else [1, 0, 0]
    return RayCamera.from_contract({"projection": "orthographic", "eye": (point - 3.0 * r * direction).tolist(),
                                    "target": point.tolist(), "up": up, "height": 3e-5 * r}, 3, 3)


def relative_errors(rgba, L):
    T = 1.0 - rgba[..., 3].astype(np.float64)
    want = np.exp(-TAU * L)
    return np.abs(T - want) / want


def displaced_spread(boundary, o, d, scale, device):
    """max |L(o + s e) - L(o)| over 4 sideways moves of size `scale` per ray (rows of o, d)."""
    from hovr_blender.audit import chords

    a = np.cross(d, [0.0, 0.0, 1.0])
    a[np.linalg.norm(a, axis=1) < 1e-6] = np.cross(d, [1.0, 0.0, 0.0])[np.linalg.norm(a, axis=1) < 1e-6]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(d, a)
    base = chords.chords_warp(boundary, o, d, device)
    spread = np.zeros(len(o))
    for s in (a, -a, b, -b):
        spread = np.maximum(spread, np.abs(chords.chords_warp(boundary, o + scale * s, d, device) - base))
    return spread


def run(args):
    import warp as wp

    from hovr_blender.audit import chords
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    wp.config.quiet = True
    W, H = map(int, args.size.split("x"))
    report = {"size": [W, H], "device": args.device, "tau": TAU, "budget": BUDGET, "displace": DISPLACE,
              "meshes": {}}
    for name, mesh in meshes(args.meshes.split(",")).items():
        c, r = bounds(mesh)
        t0 = time.perf_counter()
        boundary = chords.Boundary(mesh)
        renderer = Renderer(mesh, args.device)
        entry = {"elements": int(mesh.num_elements), "boundary_patches": len(boundary.faces), "groups": {}}
        groups = [("view%d" % k, [cam]) for k, cam in enumerate(full_views(mesh, W, H, args.views, args.seed))]
        rng = np.random.default_rng(args.seed + 1)
        for kind, pts in targets(mesh, args.targets, args.seed).items():
            dirs = rng.normal(size=(len(pts), 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            groups.append((kind, [aimed_camera(p, dv, r) for p, dv in zip(pts, dirs)]))
        for gname, cams in groups:
            rays = [cam.rays() for cam in cams]
            o = np.concatenate([ro.reshape(-1, 3) for ro, _ in rays])
            d = np.concatenate([rd.reshape(-1, 3) for _, rd in rays])
            t1 = time.perf_counter()
            L = chords.chords_warp(boundary, o, d, args.device)
            t_chords = time.perf_counter() - t1
            g = {"rays": int(len(o)), "odd_crossings": int(np.isnan(L).sum()), "seconds_chords": round(t_chords, 2)}
            for precision, tol in (("float64", 1e-9), ("float32", 1e-6)):
                opts = RenderOptions(method="split", precision=precision, tolerance=tol, min_transmittance=0.0,
                                     device=args.device)
                t1 = time.perf_counter()
                rgba = np.concatenate([renderer.render(cam, constant_density(TAU), [0, 0, 0], opts).rgba.reshape(-1, 4)
                                       for cam in cams])
                secs = time.perf_counter() - t1
                rel = np.where(np.isnan(L), np.nan, relative_errors(rgba, L))
                k = int(np.nanargmax(rel))
                over = np.nonzero(rel > BUDGET[precision])[0]
                res = {"max_relative_error": float(rel[k]), "at_ray": k, "origin": o[k].tolist(),
                       "direction": d[k].tolist(), "chord": float(L[k]), "over_budget": int(len(over)),
                       "seconds": round(secs, 2)}
                if len(over):
                    scale = DISPLACE * np.linalg.norm(o[over] - c, axis=1)[:, None]
                    spread = displaced_spread(boundary, o[over], d[over], scale, args.device)
                    # |dT| / T = |exp(-tau dL) - 1|, about tau dL
                    explained = rel[over] <= TAU * spread + BUDGET[precision]
                    res["over_budget_within_ray_rounding"] = int(explained.sum())
                    worst = over[~explained][np.argsort(-rel[over][~explained])][:20]
                    res["unexplained"] = [{"ray": int(i), "error": float(rel[i]), "origin": o[i].tolist(),
                                           "direction": d[i].tolist(), "chord": float(L[i])} for i in worst]
                g[precision] = res
                print(f"{name} {gname}: {len(o)} rays, {precision} max rel {rel[k]:.2e}, over {len(over)} "
                      f"({res.get('over_budget_within_ray_rounding', 0)} within ray rounding), {secs:.1f} s",
                      flush=True)
            entry["groups"][gname] = g
        for precision in ("float64", "float32"):
            entry[precision] = {
                "rays": sum(g["rays"] for g in entry["groups"].values()),
                "max_relative_error": max(g[precision]["max_relative_error"] for g in entry["groups"].values()),
                "over_budget": sum(g[precision]["over_budget"] for g in entry["groups"].values()),
                "over_budget_unexplained": sum(g[precision]["over_budget"] -
                                               g[precision].get("over_budget_within_ray_rounding", 0)
                                               for g in entry["groups"].values())}
        entry["seconds"] = round(time.perf_counter() - t0, 1)
        report["meshes"][name] = entry
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")  # after each mesh: a cut-off run keeps it
    print(json.dumps({m: {p: e[p] for p in ("float64", "float32")} for m, e in report["meshes"].items()}, indent=1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--targets", type=int, default=400, help="aimed cameras per kind (vertex, edge, face) and mesh")
    ap.add_argument("--seed", type=int, default=15)
    ap.add_argument("--meshes", default="RotPerBcs3D_Annulus,ngsolve_ball")
    ap.add_argument("--out", required=True)
    run(ap.parse_args(argv))


if __name__ == "__main__":
    main()
