"""The scenes the tests, bench/ and scripts/ share, so that each has one definition: the
framing camera, the benchmark scenes' background, colours and tent transfer functions, the
constant field and density of the watertightness checks, a pressure field far from zero, the
curved mixed-shape cube of the benchmark suite and the same cube carrying a field whose level sets
are spheres (the isosurfaces'). Not used by the product.
"""
from __future__ import annotations

import numpy as np

from ..engine.camera import RayCamera
from ..engine.mesh import VolumeMesh, element_boxes
from ..engine.transfer_function import TransferFunction


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
    from ..io.synthetic import with_field

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
    from ..io.synthetic import curved_cube

    mesh = curved_cube(cells)
    lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
    return mesh, tents(lo, hi, COLORS, 12.0), lambda w, h: framing(mesh, w, h)


BALL_CENTRE = np.array([0.5, 0.5, 0.45])
BALL_RADIUS = 0.3


def ball_field(x, y, z):
    """|x - BALL_CENTRE|^2: its level BALL_RADIUS^2 is a sphere inside the curved cube."""
    return (x - BALL_CENTRE[0]) ** 2 + (y - BALL_CENTRE[1]) ** 2 + (z - BALL_CENTRE[2]) ** 2


def ball_mesh() -> VolumeMesh:
    """io/synthetic.curved_cube(2) carrying ball_field: curved elements of all four shapes whose
    level sets are exact spheres (f(x(xi)) has degree 4 in xi on curved_cube's quadratic
    elements: 5 modes hold it exactly). The isosurface tests' scene (contract §7) and the tangency
    band's (audit/isosurface_band.py)."""
    from ..io.synthetic import curved_cube, with_field

    return with_field(curved_cube(2), ball_field, 5)
