"""What the tests share: where the data files are, scenes, cameras, chords and the float32
evaluation check. Plain functions and constants (fixtures are in conftest.py); test modules
import from here, never from each other and never from bench/. bench/ imports the scenes it
shares with the tests from here too (bench/suite.py: the curved mixed cube, framing, tents;
bench/eval_table.py: the evaluation check), so a scene has one definition.

Sections: data files; cameras and chords; meshes and scenes; the Blender sphere scene; float32
device evaluation against the float64 oracle.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import warp as wp

from hovr_blender.audit.chords import box_chord  # noqa: F401  (the tests' slab test: one home)
from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.kernels import element as element_kernels
from hovr_blender.engine.mesh import VolumeMesh, element_boxes
from hovr_blender.engine.transfer_function import TransferFunction

REPO = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------------------ data files
# Real third-party files: the small ones are vendored in tests/data (MANIFEST.md: source, commit,
# licence); the rest are looked up in ../shared/data beside the checkout, where the project keeps
# them. A test that needs a file neither place holds is skipped, naming the file.

DATA_DIRS = (REPO / "tests" / "data", REPO.parent / "shared" / "data")


def find_data(kind: str, name: str) -> Path | None:
    """tests/data/KIND/NAME, else ../shared/data/KIND/NAME, else None (kind: "nektar" or "vtu")."""
    for root in DATA_DIRS:
        path = root / kind / name
        if path.exists():
            return path
    return None


def data_file(kind: str, name: str) -> Path:
    """find_data, or skip the calling test with a reason that names the missing file. Call it
    inside a test or fixture, never at collection time."""
    path = find_data(kind, name)
    if path is None:
        pytest.skip(f"data file {kind}/{name} not found (looked in {', '.join(str(r / kind) for r in DATA_DIRS)})")
    return path


class data_dir:  # noqa: N801  (reads as a function: DATA = data_dir("nektar"))
    """DATA / name is data_file(kind, name): for modules that spell their files as paths."""

    def __init__(self, kind: str):
        self.kind = kind

    def __truediv__(self, name) -> Path:
        return data_file(self.kind, str(name))


# ---------------------------------------------------------------------------- cameras and chords

# the unit cube (mixed_cube and bricks over [0, 1]^3) seen from a corner
UNIT_CUBE_CAM = {"eye": [3.1, 2.3, 2.6], "target": [0.5, 0.45, 0.5], "up": [0, 0, 1], "fov_y_deg": 35}


def mesh_bounds(mesh: VolumeMesh):
    lo, hi = element_boxes(mesh)
    return lo.min(axis=0), hi.max(axis=0)


def framing_contract(mesh: VolumeMesh, direction=(1.0, -0.8, 0.7), distance=2.6, fov=30.0) -> dict:
    """framing's camera as the contract's camera object (for code that computes its own rays)."""
    lo, hi = mesh_bounds(mesh)
    c, r = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo)
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return {"eye": (c + distance * r * d).tolist(), "target": c.tolist(), "up": [0, 0, 1], "fov_y_deg": fov}


def framing(mesh: VolumeMesh, w, h, direction=(1.0, -0.8, 0.7), distance=2.6, fov=30.0) -> RayCamera:
    """A w x h camera looking at the mesh's bounding box from `direction`, `distance` radii away."""
    return RayCamera.from_contract(framing_contract(mesh, direction, distance, fov), w, h)


# ---------------------------------------------------------------------------- meshes and scenes

BACKGROUND = [0.02, 0.02, 0.03]  # the benchmark scenes' background
COLORS = [(0.95, 0.35, 0.1), (0.2, 0.75, 0.3), (0.15, 0.35, 0.95)]


def tents(lo, hi, colors, density) -> TransferFunction:
    """len(colors) tents spread over [lo, hi] (zero density between: empty segments exist)."""
    k = len(colors)
    cs, col, dens = [], [], []
    for i, rgb in enumerate(colors):
        m = lo + (i + 1) * (hi - lo) / (k + 1)
        w = 0.07 * (hi - lo)
        for s, a in ((m - w, 0.0), (m, density), (m + w, 0.0)):
            cs.append(s), col.append(rgb), dens.append(a)
    return TransferFunction(np.array(cs), np.array(col), np.array(cs), np.array(dens))


def constant_field(mesh: VolumeMesh) -> VolumeMesh:
    """The mesh with the field 1 everywhere: with constant_density, images measure geometry."""
    from hovr_blender.io.synthetic import with_field

    return with_field(mesh, lambda x, y, z: 0.0 * x + 1.0, 2)


def constant_density(tau) -> TransferFunction:
    """Density tau at every value (T = exp(-tau L) over a chord L), one colour."""
    return TransferFunction.from_contract({"color": [[-9, 0.3, 0.6, 0.9], [9, 0.3, 0.6, 0.9]],
                                           "density": [[-9, tau], [9, tau]]})


PASCALS = 101_325.0


def pascals(x, y, z):
    """A pressure field in pascals: +-5 Pa around one atmosphere (a field far from zero)."""
    return PASCALS + 5.0 * np.sin(3 * x + 1) * np.cos(2 * y - z) + 2.0 * z * z


def curved_mixed_scene(cells: int):
    """(mesh, transfer function, camera(w, h)) of io/synthetic.curved_cube(cells): three tents
    over the field's 2..98 % range, framed from the default direction, BACKGROUND behind. The
    benchmark's curved dataset (bench/suite.py: cells 2 small, 4 full) and the scene where the
    float32 search and Newton bugs showed (tests/engine/test_precision.py)."""
    from hovr_blender.io.synthetic import curved_cube

    mesh = curved_cube(cells)
    lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
    return mesh, tents(lo, hi, COLORS, 12.0), lambda w, h: framing(mesh, w, h)


def linear_field(x, y, z):
    return 1.0 + 2.0 * x + 3.0 * y - z


def jittered_trilinear_brick(n, jitter, seed=3) -> VolumeMesh:
    """n^3 trilinear hexes over [0,1]^3 carrying linear_field, interior grid nodes moved: faces
    become bilinear patches shared exactly by both neighbours; the outer surface stays the unit cube."""
    from hovr_blender.io.synthetic import straight_geometry

    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(*[np.linspace(0, 1, n + 1)] * 3, indexing="ij"), axis=-1)
    interior = np.zeros(g.shape[:3], bool)
    interior[1:-1, 1:-1, 1:-1] = True
    g[interior] += rng.uniform(-jitter, jitter, (interior.sum(), 3)) / n
    ref = (shapes.VERTICES[shapes.HEX] + 1) / 2
    geoms, coeffs = [], []
    for k in range(n):
        for j in range(n):
            for i in range(n):
                v = np.array([g[i + int(a), j + int(b), k + int(c)] for a, b, c in ref])
                geo = straight_geometry(shapes.HEX, v)
                geoms.append(geo)
                coeffs.append(straight_geometry(shapes.HEX, linear_field(*v.T)[:, None].repeat(3, 1))[:, 0])
    return VolumeMesh.from_elements([shapes.HEX] * n**3, (2, 2, 2), coeffs, (2, 2, 2), geoms)


# ------------------------------------------------------------------------ the Blender sphere scene


class SPHERE:  # noqa: N801  (a namespace of constants)
    """The scene of the F12 tests (tests/blender): the built-in sphere as one HOVR volume, moved
    and turned, seen by a contract camera through a linear ramp; built in Blender by
    build_scene, and through the core API alone by core_render, for comparison. Dyadic values
    survive Blender's float32 storage exactly; ramp positions 0..1 map onto f in [0, 2]."""

    W, H = 64, 48
    # The sphere's inner ball (f < 1, where the ramp is non-zero) seen from outside its box: the
    # density vanishes before the box faces, so the image has no silhouette edge, only smooth
    # shells. Blender keeps camera parameters in float32 (rays differ from the contract's float64
    # ones by ~1e-7); a sharp edge would turn that into more than the 1e-5 the tests demand.
    PERSPECTIVE = {"projection": "perspective", "eye": [4.0, 3.0, 3.5], "target": [0.25, -0.5, 0.5],
                   "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}
    ORTHOGRAPHIC = {"projection": "orthographic", "eye": [4.0, 3.0, 3.5], "target": [0.25, -0.5, 0.5],
                    "up": [0.0, 0.0, 1.0], "height": 3.0}
    STOPS = [(0.0, (1.0, 0.875, 0.25, 0.5)), (0.125, (1.0, 0.5, 0.25, 1.0)), (0.25, (0.25, 1.0, 0.375, 0.25)),
             (0.375, (0.125, 0.5, 1.0, 0.75)), (0.5, (1.0, 0.25, 0.5, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
    VALUE_RANGE, DENSITY_SCALE = (0.0, 2.0), 2.0
    BACKGROUND = (0.0625, 0.03125, 0.125)
    OBJECT_LOCATION, OBJECT_ANGLE_Z = (0.25, -0.5, 0.5), 0.5

    @classmethod
    def object_matrix(cls):
        """The sphere object's transform, built here independently of Blender."""
        c, s = math.cos(cls.OBJECT_ANGLE_Z), math.sin(cls.OBJECT_ANGLE_Z)
        m = np.eye(4)
        m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        m[:3, 3] = cls.OBJECT_LOCATION
        return m

    @classmethod
    def build_scene(cls, scene, contract, method="classified", film_transparent=False, percentage=100):
        """The scene in Blender (needs bpy): camera, world colour, the volume; returns its object."""
        from tests.blender.blender_helpers import build_sphere_scene

        return build_sphere_scene(scene, contract, cls.W, cls.H, cls.STOPS, cls.VALUE_RANGE, cls.DENSITY_SCALE,
                                  cls.BACKGROUND, cls.OBJECT_LOCATION, cls.OBJECT_ANGLE_Z, method, film_transparent,
                                  percentage)

    @classmethod
    def core_render(cls, contract, method, film_transparent, camera=None, matrix=None, h=0.01):
        """The same view through the core API only: contract camera, ramp lists, numpy transform;
        `h` the step in world units."""
        from hovr_blender.engine.renderer import Renderer
        from hovr_blender.engine.view import RenderOptions
        from hovr_blender.io import builtin

        camera = RayCamera.from_contract(contract, cls.W, cls.H) if camera is None else camera
        tf = TransferFunction.from_rgba_ramp([p for p, _ in cls.STOPS], [c for _, c in cls.STOPS], cls.DENSITY_SCALE,
                                             *cls.VALUE_RANGE)
        bg = np.zeros(3) if film_transparent else np.array(cls.BACKGROUND)
        mesh = builtin.sphere().transformed(cls.object_matrix() if matrix is None else matrix)
        options = RenderOptions(method=method, h=h, tolerance=1e-6, device="cpu")
        return Renderer(mesh, device="cpu").render(camera, tf, bg, options).rgba


# ------------------------------------------ float32 device evaluation against the float64 oracle
# For each (family, shape, order) a few random fields are drawn, evaluated by a small Warp kernel
# that calls element.eval_element (the renderer's own evaluator) at random reference points
# inside the element plus points near the collapsed vertex/edges (distance 1e-6..1e-2 in the
# collapsed coordinate) and the vertices, and compared with the oracle:
# - kernel error: the oracle at exactly the kernel's float32 inputs (rounded coefficients and
#   points): the error of the float32 arithmetic alone;
# - end-to-end error: the oracle at the float64 inputs: what a user sees (input rounding too).
# Families (the renderer only ever sees modal coefficients; importers convert nodal data to the
# same polynomial in float64 before upload, io/nektar.py and io/vtu.py):
# - modified:     Nektar++ Modified coefficients, uniform in [-1, 1] (unit max |coefficient|);
# - gll_lagrange: Nektar++ GLL_Lagrange hexahedra, nodal values uniform in [-1, 1] at the GLL
#                 nodes, converted by expansions.gll_lagrange_hex_to_modal; oracle: the tensor
#                 Lagrange interpolant through the GLL nodes, in float64;
# - vtk_lagrange: VTK Lagrange hex / tet / wedge cells, nodal values uniform in [-1, 1] at VTK's
#                 equispaced nodes, converted by io/vtu.conversion_matrix; oracle: vtu.cell_basis
#                 (the cell's own nodal basis) in float64.
# tests/engine/test_stress.py runs it on few points; bench/eval_table.py writes the full table.

EVAL_SHAPES = [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR]
EVAL_FAMILIES = {"modified": EVAL_SHAPES, "gll_lagrange": [shapes.HEX],
                 "vtk_lagrange": [shapes.HEX, shapes.PRISM, shapes.TET]}


wp.set_module_options({"enable_backward": False})


@wp.kernel
def _eval_points_kernel(shape: int, modes: wp.vec3i, coeffs: wp.array(dtype=wp.float32),
                        xi: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = element_kernels.eval_element(shape, coeffs, 0, modes, xi[i])


def device_eval(shape, modes, coeffs32, xi32, device):
    """One element's float32 expansion at float32 reference points, on `device`, as the renderer evaluates it."""
    out = wp.zeros(len(xi32), dtype=wp.float32, device=device)
    wp.launch(_eval_points_kernel, dim=len(xi32), device=device,
              inputs=[int(shape), wp.vec3i(*map(int, modes)), wp.array(coeffs32, dtype=wp.float32, device=device),
                      wp.array(xi32, dtype=wp.vec3, device=device), out])
    return out.numpy().astype(np.float64)


def sample_points(shape, n, rng):
    """n uniform points inside the reference element, n // 4 near the collapse, the vertices."""
    pts = np.empty((0, 3))
    while len(pts) < n:
        p = rng.uniform(-1, 1, (4 * n, 3))
        pts = np.concatenate([pts, p[ex.inside(shape, p, tol=0.0)]])
    pts = pts[:n]
    near = np.empty((0, 3))
    if shape != shapes.HEX:
        m = max(n // 4, 4)
        eta = np.stack([rng.uniform(-1, 1, m), rng.uniform(-1, 1, m), 1.0 - 10.0 ** rng.uniform(-6, -2, m)], axis=1)
        if shape == shapes.TET:  # half of them near the first collapse's edge instead
            h = m // 2
            eta[:h, 1] = 1.0 - 10.0 ** rng.uniform(-6, -2, h)
            eta[:h, 2] = rng.uniform(-1, 1, h)
        near = ex._uncollapse(shape, eta)
    return pts, near, shapes.VERTICES[shape].copy()


def _lagrange_1d(nodes, x):
    """(M, n) Lagrange basis through `nodes` at x (product formula, float64)."""
    out = np.ones((x.size, nodes.size))
    for a in range(nodes.size):
        for b in range(nodes.size):
            if b != a:
                out[:, a] *= (x - nodes[b]) / (nodes[a] - nodes[b])
    return out


def family_field(family, shape, order, rng):
    """(modes, float64 modal coefficients, oracle(xi) -> float64 values)."""
    if family == "modified":
        modes = (order + 1,) * 3
        c = rng.uniform(-1.0, 1.0, ex.num_coeffs(shape, modes))
        return modes, c, lambda xi: ex.eval_modal(shape, modes, c, xi)
    if family == "gll_lagrange":
        n = order + 1
        modes = (n, n, n)
        nodal = rng.uniform(-1.0, 1.0, n**3)  # node (i, j, k), i fastest
        c = ex.gll_lagrange_hex_to_modal(modes, nodal)
        z = ex.gll_points(n)
        grid = nodal.reshape(n, n, n)  # [k, j, i]

        def oracle(xi):
            x = xi.reshape(-1, 3)
            L0, L1, L2 = (_lagrange_1d(z, x[:, d]) for d in range(3))
            return np.einsum("kji,pi,pj,pk->p", grid, L0, L1, L2).reshape(xi.shape[:-1])

        return modes, c, oracle
    if family == "vtk_lagrange":
        from hovr_blender.io import vtu

        degs = (order,) * 3
        T = vtu.conversion_matrix(shape, "lagrange", degs)
        modes = vtu.modes_for(shape, degs)
        nodal = rng.uniform(-1.0, 1.0, T.shape[1])
        c = T @ nodal

        def oracle(xi):
            x = xi.reshape(-1, 3)
            return (vtu.cell_basis(shape, "lagrange", degs, vtu.xi_to_vtk(shape, x)) @ nodal).reshape(xi.shape[:-1])

        return modes, c, oracle
    raise ValueError(family)


def eval_compare(family, shape, order, device="cpu", points=2000, trials=3, seed=0) -> dict:
    """Max errors over `trials` random fields at `points` (+ near-collapse + vertex) points."""
    rng = np.random.default_rng([seed, order, shape, list(EVAL_FAMILIES).index(family)])
    worst = dict(max_abs_kernel=0.0, max_rel_kernel=0.0, max_abs=0.0, max_rel=0.0, max_rel_near_collapse=0.0,
                 nonfinite=0, nonfinite_near_collapse=0, min_range=np.inf, max_abs_coeff=0.0)
    for _ in range(trials):
        modes, c, oracle = family_field(family, shape, order, rng)
        pts, near, verts = sample_points(shape, points, rng)
        xi = np.concatenate([pts, verts, near])
        xi32 = xi.astype(np.float32)
        c32 = c.astype(np.float32)
        got = device_eval(shape, modes, c32, xi32, device)
        want_e2e = oracle(xi)
        want_k = ex.eval_modal(shape, modes, c32.astype(np.float64), xi32.astype(np.float64))
        m = len(pts) + len(verts)  # interior points and vertices first, near-collapse points after
        rng_f = float(want_e2e[:m].max() - want_e2e[:m].min())
        ek = np.abs(got - want_k)[:m]
        ee = np.abs(got - want_e2e)
        fin = np.isfinite(got)
        worst["nonfinite"] += int((~fin[:m]).sum())
        worst["nonfinite_near_collapse"] += int((~fin[m:]).sum())
        worst["max_abs_kernel"] = max(worst["max_abs_kernel"], float(np.nanmax(ek)))
        worst["max_rel_kernel"] = max(worst["max_rel_kernel"], float(np.nanmax(ek)) / rng_f)
        worst["max_abs"] = max(worst["max_abs"], float(np.nanmax(ee[:m])))
        worst["max_rel"] = max(worst["max_rel"], float(np.nanmax(ee[:m])) / rng_f)
        if len(near):
            worst["max_rel_near_collapse"] = max(worst["max_rel_near_collapse"], float(np.nanmax(ee[m:])) / rng_f)
        worst["min_range"] = min(worst["min_range"], rng_f)
        worst["max_abs_coeff"] = max(worst["max_abs_coeff"], float(np.abs(c).max()))
    worst.update(family=family, shape=shapes.NAMES[shape], order=order, modes=list(modes),
                 coefficients=int(len(c)), points_per_trial=int(len(xi)), trials=trials)
    return worst
