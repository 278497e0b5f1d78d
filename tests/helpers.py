"""What the tests share: where the data files are, scenes, cameras, chords and the float32
evaluation check. Plain functions and constants (fixtures are in conftest.py); test modules
import from here, never from bench/ (docs/architecture.md names the few Blender tests that reuse
another test module's builders). The scenes and the evaluation
check that bench/ and scripts/ use too have their one definition in the package
(hovr_blender/audit/scenes.py, hovr_blender/audit/evaluation.py) and are imported here.

Sections: data files; cameras and chords; meshes and scenes; the Blender sphere scene.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hovr_blender.audit.chords import box_chord  # noqa: F401  (the tests' slab test: one home)
from hovr_blender.audit.datasets import SHARED
from hovr_blender.audit.evaluation import EVAL_FAMILIES, device_eval, eval_compare, sample_points  # noqa: F401
from hovr_blender.audit.scenes import (BACKGROUND, COLORS, PASCALS, constant_density, constant_field,  # noqa: F401
                                       curved_mixed_scene, framing, framing_contract, mesh_bounds, pascals, tents)
from hovr_blender.engine import shapes
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import VolumeMesh
from hovr_blender.engine.transfer_function import TransferFunction

REPO = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------------------ data files
# Real third-party files: the small ones are vendored in tests/data (MANIFEST.md: source, commit,
# licence); the rest are looked up in ../shared/data beside the checkout, where the project keeps
# them (HOVR_DATA=folder: elsewhere; HOVR_DATA=/nonexistent: a fresh clone's view, tests/data
# alone). A test that needs a file neither place holds is skipped, naming the file.

DATA_DIRS = (REPO / "tests" / "data", SHARED)


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


# ---------------------------------------------------------------------------- meshes and scenes

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


def folded_hex_map(xi, fold=1.4):
    """A quadratic hexahedron folded between its fit points (issue 29): x0 = xi0 (1 - fold (1 -
    xi1^2)(1 - xi2^2)), x1 = xi1, x2 = xi2, so det J = 1 - fold (1 - xi1^2)(1 - xi2^2): 1 - fold
    (-0.40) along the axis xi1 = xi2 = 0 and 1 - 0.64 fold (0.104) or more wherever |xi1| and |xi2|
    are 1/sqrt(5) or 1, as at every point of the 4 x 4 x 4 fit grid. fold < 1: valid and strongly
    curved (det J from 1 - fold to 1)."""
    xi = np.asarray(xi, dtype=np.float64)
    x = xi.copy()
    x[..., 0] = xi[..., 0] * (1.0 - fold * (1.0 - xi[..., 1] ** 2) * (1.0 - xi[..., 2] ** 2))
    return x


def lagrange_hex_vtu(mapping, degree=2) -> bytes:
    """An ASCII .vtu of one VTK Lagrange hexahedron of `degree` whose nodes lie at mapping(xi),
    with the point field f = x0."""
    from hovr_blender.io.vtu.cells import vtk_node_params

    nodes = mapping(2.0 * vtk_node_params(shapes.HEX, (degree,) * 3) - 1.0)
    n = len(nodes)

    def array(kind, name, values, components=1):
        text = " ".join(repr(float(v)) if kind == "Float64" else str(int(v)) for v in np.ravel(values))
        return (f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" format="ascii">'
                f'{text}</DataArray>')

    return (f'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="2.2" byte_order="LittleEndian">'
            f'<UnstructuredGrid><Piece NumberOfPoints="{n}" NumberOfCells="1">'
            f'<Points>{array("Float64", "Points", nodes, 3)}</Points>'
            f'<Cells>{array("Int64", "connectivity", range(n))}{array("Int64", "offsets", [n])}'
            f'{array("UInt8", "types", [72])}</Cells>'
            f'<PointData>{array("Float64", "f", nodes[:, 0])}</PointData>'
            f'</Piece></UnstructuredGrid></VTKFile>\n').encode()


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


def tree_listing(folder, skip=()) -> dict:
    """Everything under `folder` but the folders in `skip`: relative path -> (file type, size,
    mtime, link target), to compare a tree before and after a run (what a hostile input wrote)."""
    import os

    out = {}
    skip = {Path(s) for s in skip}
    for dirpath, dirnames, filenames in os.walk(folder):
        dirnames[:] = [d for d in dirnames if Path(dirpath, d) not in skip]
        for name in dirnames + filenames:
            p = Path(dirpath, name)
            st = p.lstat()
            plain = not p.is_dir() or p.is_symlink()
            out[str(p.relative_to(folder))] = (st.st_mode >> 12, st.st_size if plain else 0,
                                               st.st_mtime_ns if plain else 0,
                                               os.readlink(p) if p.is_symlink() else None)
    return out


def ctrl_c_as_at_a_terminal():
    """Popen's preexec_fn for a child a test stops with SIGINT: SIGINT at its default, as a
    command started at a terminal has it. A shell's background job (`pytest ... &`) starts with
    SIGINT ignored, and its children inherit that: Python then never raises KeyboardInterrupt."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
