"""Watertightness at scale (issues 15, 36): a constant density tau over a mesh gives
T = exp(-tau L), L the ray's chord through the mesh, computed without renderer code from the
mesh's boundary faces (hovr_blender/audit/chords.py: every shape's faces, float64 Newton on
nearly flat sub-patches). Every pixel of several full-HD views from random directions, plus small
cameras aimed at the elements' vertices, edge middles and face centres, in float32 and float64.

    python -m scripts.watertight --device cuda:0 --size 1920x1080 --views 5 --out wt.json

covers every curved shared dataset (--datasets curved; `all` adds the straight ones, or name
them): 5 views of 1920x1080 are 10.4 M rays a dataset and precision; `--views 1 --random-views`
over the nine curved datasets, 18.7 M rays a precision. Per dataset and precision it reports:
- rays lost: the length the image implies, -ln(T) / tau, short of the exact chord by more than
  LOST (1e-4) of the mesh's diagonal; rays gained: longer by as much;
- rays over budget: relative error of T above BUDGET (1e-6 float64, 1e-4 float32), and how many
  of those are within float32's rounding of the ray itself (below);
- rays whose chord is undecided (an odd number of crossings found: NaN), not counted above.
Every ray the fast chords call lost or gained, and every undecided one, is decided again by a
denser search (finer sub-patches, 25 Newton starts each, numpy; the DENSE_MAX largest
differences of a group, the rest counted as flagged_not_rechecked): where the two disagree
(chord_disagreements) the dense chord is used.

tau is TAU_DIAG / diagonal (an optical depth of at most about 2 across the mesh), so T stays
far from 0 and -ln(T) / tau keeps float32's alpha to about 3e-7 of the diagonal.

Conditioning: a ray that grazes a curved boundary has a chord that changes fast with the
ray's position (at tangency, without bound), so where the error of T exceeds the budget the
report also gives the chord's spread over rays moved sideways by DISPLACE (a few float32
roundings of the ray's origin), from the dense chords: an error within tau x that spread is
float32's rounding of the ray itself, not a leak. The same goes for lost and gained rays: LOST is
far above that spread except at tangency, where a ray that one such move takes off the mesh
altogether has a chord float32 cannot state. Both numbers are reported (lost, and
lost_beyond_ray_rounding); nothing is hidden behind the second, and each listed ray carries its
spread.

A second verdict adds the surface's rounding: the renderer places a curved face only to within
its map's rounding bound (isosurface_band.map_rounding: MeshArgs.geo_err, the bound the
isosurface band of docs/methods.md is derived from), and a ray moved by that much sideways
meets the face as the renderer's moved face would. The spread over moves of the ray's rounding
plus that bound gives lost_beyond_rounding and the others; each listed ray carries it
(rounding_spread). In float64 the bound is about 1e-14 of the mesh and changes nothing.

The JSON is rewritten after each dataset; at --deadline seconds the run stops with what it has.
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from bench.common import jsonable
from hovr_blender.audit.datasets import SHARED_DATASETS, load
from hovr_blender.audit.isosurface_band import map_rounding
from hovr_blender.audit.scenes import constant_density, constant_field  # the tests' own scene

TAU_DIAG = 2.0  # tau times the mesh's diagonal
BUDGET = {"float64": 1e-6, "float32": 1e-4}
TOLERANCE = {"float64": 1e-9, "float32": 1e-6}  # split's panels: well inside the budgets
LOST = 1e-4  # of the diagonal
DISPLACE = 4.0 * 2.0 ** -24  # relative to the eye's distance from the mesh's centre
DENSE_MAX = 500  # flagged rays decided again per group (the largest differences first): numpy is slow


def is_curved(mesh) -> bool:
    return mesh.affine is not None and not bool(mesh.affine.all())


def dataset_names(spec: str):
    """`curved` (the default), `all`, or names separated by commas."""
    if spec in ("curved", "all"):
        return list(SHARED_DATASETS), spec == "curved"
    return [n for n in spec.split(",") if n], False


def bounds(mesh):
    v = mesh.vertices.reshape(-1, 3)
    lo, hi = v.min(0), v.max(0)
    return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))


def view_directions(n, seed, random_only=False):
    """The tests' three directions (oblique, side, nearly along z: rays along the annulus' axis)
    and seeded random ones (random_only: seeded random ones alone)."""
    fixed = [] if random_only else [(1.0, -0.8, 0.7), (0.3, 1.0, -0.2), (0.0, 0.001, 1.0)]
    rng = np.random.default_rng(seed)
    more = [tuple(v) for v in rng.normal(size=(max(0, n - len(fixed)), 3))]
    return [np.asarray(v, float) / np.linalg.norm(v) for v in (fixed + more)[:n]]


def full_views(mesh, W, H, n, seed, random_only=False):
    from hovr_blender.engine.camera import RayCamera

    c, r = bounds(mesh)
    return [RayCamera.from_contract({"eye": (c + 2.6 * r * d).tolist(), "target": c.tolist(),
                                     "up": [0, 0, 1] if abs(d[2]) < 0.99 else [0, 1, 0], "fov_y_deg": 30.0}, W, H)
            for d in view_directions(n, seed, random_only)]


def targets(mesh, limit, seed):
    """Points where defects live: element vertices, edge middles and face centres of every shape
    (the mesh's straight-sided skeleton, first-order points), deduplicated, at most `limit` of each kind."""
    from hovr_blender.engine import shapes

    rng = np.random.default_rng(seed)
    kinds = {"vertex": [], "edge": [], "face": []}
    for sh in np.unique(mesh.shape):
        V = mesh.vertices[mesh.shape == sh][:, :len(shapes.VERTICES[int(sh)])]
        kinds["vertex"].append(V.reshape(-1, 3))
        kinds["edge"].append(V[:, np.array(shapes.EDGES[int(sh)])].mean(axis=2).reshape(-1, 3))
        kinds["face"] += [V[:, idx].mean(axis=1) for idx in shapes.plane_vertices(int(sh))]
    out = {}
    for k, pts in kinds.items():
        pts = np.unique(np.round(np.concatenate(pts), 9), axis=0)
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


def relative_errors(rgba, L, tau):
    T = 1.0 - rgba[..., 3].astype(np.float64)
    want = np.exp(-tau * L)
    return np.abs(T - want) / want


def image_length(rgba, tau):
    """The chord an image implies: -ln(T) / tau (inf where T is 0)."""
    with np.errstate(divide="ignore"):
        return -np.log(np.clip(1.0 - rgba[..., 3].astype(np.float64), 0.0, None)) / tau


def displaced_spread(fast, o, d, scale):
    """max |L(o + s e) - L(o)| over 4 sideways moves of size `scale` per ray (rows of o, d)."""
    a = np.cross(d, [0.0, 0.0, 1.0])
    a[np.linalg.norm(a, axis=1) < 1e-6] = np.cross(d, [1.0, 0.0, 0.0])[np.linalg.norm(a, axis=1) < 1e-6]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(d, a)
    base = fast(o, d)
    spread = np.zeros(len(o))
    for s in (a, -a, b, -b):
        spread = np.maximum(spread, np.abs(fast(o + scale * s, d) - base))
    return spread


class Chords:
    """The fast chords (Warp kernel) and, built on first need, the dense recheck (numpy)."""

    def __init__(self, mesh, device):
        from hovr_blender.audit import chords

        self.mesh, self.chords = mesh, chords
        self.boundary = chords.Boundary(mesh)
        self.fast = chords.WarpChords(self.boundary, device)
        self._dense = None

    def dense(self, o, d):
        ch = self.chords
        if self._dense is None:
            self._dense = ch.dense_boundary(self.mesh)
        return ch.chords_numpy(self._dense, o, d, starts=ch.dense_starts())


def check_rays(chords, o, d, rgba, tau, diag, precision, centre, surface=0.0):
    """One precision's verdict on rays (o, d) whose image is rgba (rows), against the exact
    chords (the fast ones, flagged rays decided again densely): the report's counts. surface:
    how far the renderer may place a curved boundary face by its map's rounding
    (isosurface_band.map_rounding), for the second verdict (module docstring)."""
    L = chords.fast(o, d)
    Limg = image_length(rgba, tau)
    tol = LOST * diag
    flagged = np.nonzero(np.isnan(L) | (np.abs(Limg - L) > tol))[0]
    unchecked = max(0, len(flagged) - DENSE_MAX)
    flagged = flagged[np.argsort(-np.nan_to_num(np.abs(Limg[flagged] - L[flagged]), nan=np.inf))][:DENSE_MAX]
    disagree = 0
    if len(flagged):
        dense = chords.dense(o[flagged], d[flagged])
        disagree = int((~np.isclose(dense, L[flagged], rtol=0.0, atol=tol, equal_nan=True)).sum())
        L = L.copy()
        L[flagged] = dense
    ok = ~np.isnan(L)
    lost = np.nonzero(ok & (Limg < L - tol))[0]
    gained = np.nonzero(ok & (Limg > L + tol))[0]
    rel = np.where(ok, relative_errors(rgba, np.nan_to_num(L), tau), np.nan)
    k = int(np.nanargmax(rel)) if ok.any() else 0
    over = np.nonzero(rel > BUDGET[precision])[0]
    res = {"rays": int(len(o)), "undecided": int((~ok).sum()), "chord_disagreements": disagree,
           "flagged_not_rechecked": unchecked,
           "lost": int(len(lost)), "gained": int(len(gained)),
           "max_relative_error": float(rel[k]) if ok.any() else None, "over_budget": int(len(over)),
           "worst": {"origin": o[k].tolist(), "direction": d[k].tolist(), "chord": float(L[k]),
                     "image_length": float(Limg[k])}}
    suspects = np.unique(np.concatenate([lost, gained, over]))
    suspects = suspects[np.argsort(-np.abs(Limg[suspects] - L[suspects]))][:DENSE_MAX]  # the rest: not excused
    spreads = {"within_ray_rounding": {}, "within_rounding": {}}
    if len(suspects):
        # the dense chords: at tangency the fast ones' few Newton starts miss a crossing of a move
        scale = DISPLACE * np.linalg.norm(o[suspects] - centre, axis=1)[:, None]
        res["surface_rounding"] = surface
        # the ray's rounding, then the ray's and the surface's (a move of the face by `surface`)
        for suffix, move in (("within_ray_rounding", scale), ("within_rounding", scale + surface)):
            spread = spreads[suffix] = dict(zip(suspects.tolist(),
                                                displaced_spread(chords.dense, o[suspects], d[suspects], move).tolist()))
            within = {i for i in spread if abs(Limg[i] - L[i]) <= spread[i] + tol}
            res[f"over_budget_{suffix}"] = sum(  # |dT| / T = |exp(-tau dL) - 1|, about tau dL
                rel[i] <= tau * spread.get(i, 0.0) + BUDGET[precision] for i in over.tolist())
            res[f"lost_{suffix}"] = sum(i in within for i in lost.tolist())
            res[f"gained_{suffix}"] = sum(i in within for i in gained.tolist())
        rounding = spreads["within_ray_rounding"]
        over = np.array([i for i in over.tolist() if rel[i] > tau * rounding.get(i, 0.0) + BUDGET[precision]], np.int64)
    listed = np.unique(np.concatenate([lost, gained, over]))
    listed = listed[np.argsort(-np.abs(Limg[listed] - L[listed]))][:20]
    res["rays_listed"] = [{"origin": o[i].tolist(), "direction": d[i].tolist(), "chord": float(L[i]),
                           "image_length": float(Limg[i]), "relative_error": float(rel[i]),
                           "ray_rounding_spread": spreads["within_ray_rounding"].get(int(i)),
                           "rounding_spread": spreads["within_rounding"].get(int(i)),
                           "why": "lost" if i in lost else "gained" if i in gained else "over budget"} for i in listed]
    return res


def check_dataset(name, mesh, args, deadline):
    """The report of one dataset (a constant field over its geometry)."""
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions

    W, H = map(int, args.size.split("x"))
    t0 = time.perf_counter()
    c, r = bounds(mesh)
    diag = 2.0 * r
    tau = TAU_DIAG / diag
    chords = Chords(mesh, args.device)
    renderer = Renderer(mesh, args.device)
    entry = {"elements": int(mesh.num_elements), "boundary_faces": len(chords.boundary.faces),
             "sub_patches": len(chords.boundary.face), "tau": tau, "diagonal": diag, "groups": {},
             "seconds_setup": round(time.perf_counter() - t0, 2)}
    groups = [("view%d" % k, [cam]) for k, cam in enumerate(full_views(mesh, W, H, args.views, args.seed,
                                                                        args.random_views))]
    rng = np.random.default_rng(args.seed + 1)
    for kind, pts in targets(mesh, args.targets, args.seed).items():
        dirs = rng.normal(size=(len(pts), 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        groups.append((kind, [aimed_camera(p, dv, r) for p, dv in zip(pts, dirs)]))
    for gname, cams in groups:
        if time.monotonic() > deadline:
            entry["cut_off"] = True
            break
        rays = [cam.rays() for cam in cams]
        o = np.concatenate([ro.reshape(-1, 3) for ro, _ in rays])
        d = np.concatenate([rd.reshape(-1, 3) for _, rd in rays])
        g = {}
        for precision in ("float64", "float32"):
            opts = RenderOptions(method="split", precision=precision, tolerance=TOLERANCE[precision],
                                 min_transmittance=0.0, device=args.device)
            t1 = time.perf_counter()
            rgba = np.concatenate([renderer.render(cam, constant_density(tau), [0, 0, 0], opts).rgba.reshape(-1, 4)
                                   for cam in cams])
            secs = time.perf_counter() - t1
            t1 = time.perf_counter()
            g[precision] = check_rays(chords, o, d, rgba, tau, diag, precision, c,
                                      surface=map_rounding(renderer, precision))
            g[precision].update(seconds_render=round(secs, 2), seconds_check=round(time.perf_counter() - t1, 2))
            p = g[precision]
            print(f"{name} {gname}: {len(o)} rays, {precision}: lost {p['lost']} "
                  f"({p.get('lost_within_ray_rounding', 0)} within ray rounding), gained {p['gained']} "
                  f"({p.get('gained_within_ray_rounding', 0)}), undecided {p['undecided']}, over budget "
                  f"{p['over_budget']} ({p.get('over_budget_within_ray_rounding', 0)}), max rel {p['max_relative_error']:.2e}; "
                  f"beyond the ray's and the surface's rounding: lost {p['lost'] - p.get('lost_within_rounding', 0)}, gained "
                  f"{p['gained'] - p.get('gained_within_rounding', 0)}, over budget "
                  f"{p['over_budget'] - p.get('over_budget_within_rounding', 0)}; {secs:.1f} s render", flush=True)
        entry["groups"][gname] = g
    for precision in ("float64", "float32"):
        gs = [g[precision] for g in entry["groups"].values()]
        entry[precision] = {k: sum(g[k] for g in gs) for k in ("rays", "lost", "gained", "undecided",
                                                               "chord_disagreements", "over_budget")}
        for what in ("over_budget", "lost", "gained"):
            entry[precision][f"{what}_beyond_ray_rounding"] = sum(
                g[what] - g.get(f"{what}_within_ray_rounding", 0) for g in gs)
            entry[precision][f"{what}_beyond_rounding"] = sum(g[what] - g.get(f"{what}_within_rounding", 0) for g in gs)
        entry[precision]["max_relative_error"] = max((g["max_relative_error"] or 0.0 for g in gs), default=None)
    entry["seconds"] = round(time.perf_counter() - t0, 1)
    return entry


def run(args):
    import datetime

    import warp as wp

    from bench.common import command_line, compile_all, git

    wp.config.quiet = True
    t_start = time.monotonic()
    deadline = t_start + args.deadline
    names, curved_only = dataset_names(args.datasets)
    W, H = map(int, args.size.split("x"))
    report = {"command": command_line(), "date": datetime.date.today().isoformat(), "commit": git("rev-parse", "HEAD"),
              "device": args.device, "size": [W, H], "views": args.views, "random_views": args.random_views,
              "targets": args.targets, "tau_times_diagonal": TAU_DIAG,
              "budget": BUDGET, "lost": LOST, "displace": DISPLACE, "meshes": {}}
    meshes = {}
    for name in names:
        try:
            mesh = load(name)[0]
        except FileNotFoundError as exc:
            report["meshes"][name] = {"skipped": f"missing {exc}"}
            continue
        if curved_only and not is_curved(mesh):
            continue
        meshes[name] = constant_field(mesh)
    report["compile_seconds"] = round(compile_all(meshes.values(), args.device), 1)

    def write():
        report["wall_seconds"] = round(time.monotonic() - t_start, 1)
        report["totals"] = {p: {k: sum(m[p][k] for m in report["meshes"].values() if p in m)
                                for k in ("rays", "lost", "gained", "undecided", "lost_beyond_ray_rounding",
                                          "gained_beyond_ray_rounding", "over_budget_beyond_ray_rounding",
                                          "lost_beyond_rounding", "gained_beyond_rounding", "over_budget_beyond_rounding")}
                            for p in ("float64", "float32")}
        with open(args.out + ".part", "w") as f:
            json.dump(report, f, indent=1, default=jsonable)
        os.replace(args.out + ".part", args.out)

    for name, mesh in meshes.items():
        if time.monotonic() > deadline:
            report["meshes"][name] = {"skipped": "deadline"}
            continue
        report["meshes"][name] = check_dataset(name, mesh, args, deadline)
        write()  # after each mesh: a cut-off run keeps it
    write()
    print(json.dumps({"totals": report["totals"], **{m: {p: e[p] for p in ("float64", "float32") if p in e}
                                                     for m, e in report["meshes"].items()}}, indent=1, default=jsonable))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--views", type=int, default=5, help="full views a dataset (5 x 1920 x 1080: 10.4 M rays)")
    ap.add_argument("--random-views", action="store_true", help="every view from a seeded random direction (else the first "
                    "three are the tests' oblique, side and axis views)")
    ap.add_argument("--targets", type=int, default=20, help="aimed cameras per kind (vertex, edge, face) and dataset")
    ap.add_argument("--seed", type=int, default=15)
    ap.add_argument("--datasets", default="curved", help="curved, all, or names separated by commas")
    ap.add_argument("--deadline", type=float, default=1e9, help="seconds: then stop, keeping what was done")
    ap.add_argument("--out", required=True)
    run(ap.parse_args(argv))


if __name__ == "__main__":
    main()
