"""The audit's datasets (issue 15), and the views and transfer functions it renders them with:
every real file of ../shared/data the audit checks (skipped where absent) and the two synthetic
benchmark meshes. scripts/audit.py audits them; bench/ (interactive, peers, tf_edit,
classified_step) and the tests time and check on the same scenes.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
# the project's real files beside the checkout; HOVR_DATA: elsewhere (a GPU machine), or nowhere
SHARED = Path(os.environ.get("HOVR_DATA", REPO.parent / "shared" / "data"))


DATASETS = {
    "hump3D": {"path": "nektar/hump3D_GLL.xml", "solution": "nektar/hump3D.rst", "field": "rho"},
    "Hex_CurvedFace": {"path": "nektar/Hex_CurvedFace.xml", "solution": "nektar/Hex_CurvedFace.fld", "field": "u"},
    "Hex_Mushroom": {"path": "nektar/Hex_Mushroom.xml", "solution": "nektar/Hex_Mushroom.fld", "field": "u"},
    "RotPerBcs3D_Annulus": {"path": "nektar/RotPerBcs3D_Annulus.xml"},
    "Pyr_channel_m6": {"path": "nektar/Pyr_channel_m6.xml"},
    "scaleHO": {"path": "nektar/scaleHO.xml"},
    "ngsolve_ball": {"path": "vtu/ngsolve_ball_poisson_hex_p6.vtu", "field": "u"},
    "mfem_fichera": {"path": "vtu/mfem_fichera_poisson_mixed_p4.vtu", "field": "u"},
    "ngsolve_post": {"path": "vtu/ngsolve_post_heat_tetprism_p4.vtu", "field": "temperature"},
    "pyfr_tgv": {"path": "vtu/pyfr_tgv_hexprism_p4_t4.vtu", "field": "Pressure"},
    "paper_scale": {"synthetic": "paper_scale"},
    "curved_mixed_cube": {"synthetic": "curved_mixed_cube"},
}

# the shared datasets of the GPU audit (scripts/audit.py gpu, issue 36) and of bench.commits'
# views: every real file and the paper-scale channel (curved_mixed_cube is the benchmark suite's)
SHARED_DATASETS = tuple(n for n, spec in DATASETS.items() if spec.get("synthetic") in (None, "paper_scale"))


# the velocity's Q-criterion of the CFD datasets (contract §8), and the level drawn of it
Q_FIELDS = {"pyfr_tgv": "Q(Velocity)", "hump3D": "Q(rhou,rhov,rhow/rho)"}


def load_field(name, field: str):
    """The file dataset's `field` instead of its own (e.g. Q_FIELDS[name]): a VolumeMesh."""
    from ..io.sources import VolumeSource, load_volume

    return load_volume(VolumeSource.from_view_data({**view_data(name), "field": field}))


# the Q isosurface's level as a fraction of the 99th percentile of Q's fit at a lattice of points:
# the Taylor-Green vortex's tubes fill the box (a fifth of it shows them whole); hump3D's Q is
# small and positive over most of the channel, its rotation concentrated over the hump
Q_LEVEL_FRACTION = {"pyfr_tgv": 0.2, "hump3D": 1.0}


def q_level(mesh, name: str) -> float:
    """The level of dataset `name`'s Q isosurface (Q_LEVEL_FRACTION)."""
    return Q_LEVEL_FRACTION[name] * float(np.percentile(mesh.field_samples(4), 99))


def q_view(mesh, level: float) -> dict:
    """The oblique camera (views' direction and distance) framing the elements where Q's fit
    exceeds `level` somewhere on a lattice of points: where the isosurface is."""
    from ..engine import expansions as ex

    g = np.linspace(-1.0, 1.0, 4)
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    above = np.zeros(mesh.num_elements, bool)
    keys = np.concatenate([mesh.shape[:, None], mesh.modes], axis=1)
    for key in np.unique(keys, axis=0):
        idx = np.nonzero((keys == key).all(axis=1))[0]
        shape, modes = int(key[0]), tuple(int(v) for v in key[1:])
        C = mesh.coeffs[mesh.coeff_offset[idx][:, None] + np.arange(ex.num_coeffs(shape, modes))[None, :]]
        above[idx] = (C @ ex.basis_matrix(shape, modes, lattice[ex.inside(shape, lattice, tol=1e-12)]).T).max(1) > level
    pts = mesh.vertices[above if above.any() else slice(None)].reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    c, r = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    d = np.array([1.0, -0.8, 0.7]) / np.linalg.norm([1.0, -0.8, 0.7])
    return {"projection": "perspective", "eye": (c + 2.6 * r * d).tolist(), "target": c.tolist(), "up": [0, 0, 1],
            "fov_y_deg": 30.0}


# the colour ramp of the Q isosurfaces' speed, over [0, the speed's 99th percentile]
SPEED_STOPS = ((0.0, 0.05, 0.15, 0.6), (0.35, 0.1, 0.6, 0.8), (0.65, 0.85, 0.85, 0.3), (1.0, 0.9, 0.25, 0.1))


def speed_ramp(mesh) -> tuple:
    """The isosurfaces' colour_ramp of a velocity's derived mesh: SPEED_STOPS over its speed."""
    from ..engine.derived_fields import lattice_values

    top = float(np.percentile(lattice_values(mesh, "speed"), 99)) or 1.0
    return tuple((p * top, r, g, b) for p, r, g, b in SPEED_STOPS)


def load(name):
    """(VolumeMesh, data spec or None) of a dataset."""
    spec = DATASETS[name]
    if "synthetic" in spec:
        if spec["synthetic"] == "paper_scale":
            from ..io.paper_scale import paper_scale_mesh

            return paper_scale_mesh(), None
        from ..io.synthetic import curved_cube

        return curved_cube(4), None  # the benchmark suite's curved mixed cube (full size)
    from ..io.sources import VolumeSource, load_volume

    data = view_data(name)
    return load_volume(VolumeSource.from_view_data(data)), data


def view_data(name) -> dict:
    """A file dataset's view-file `data` (absolute paths); FileNotFoundError where a file is missing."""
    data = {k: str(SHARED / v) if k in ("path", "solution") else v for k, v in DATASETS[name].items()}
    for k in ("path", "solution"):
        if k in data and not os.path.exists(data[k]):
            raise FileNotFoundError(data[k])
    return data


def framing(mesh):
    lo, hi = mesh.vertices.reshape(-1, 3).min(0), mesh.vertices.reshape(-1, 3).max(0)
    return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)), lo, hi


def views(mesh):
    """Three cameras (render contract): oblique (the benchmark suite's direction and distance);
    along the x axis (the mesh lines of axis-aligned meshes); grazing the top of the bounding box."""
    c, r, lo, hi = framing(mesh)
    d = np.array([1.0, -0.8, 0.7]) / np.linalg.norm([1.0, -0.8, 0.7])
    top = np.array([c[0], c[1], hi[2]])
    return {
        "oblique": {"eye": (c + 2.6 * r * d).tolist(), "target": c.tolist(), "up": [0, 0, 1], "fov_y_deg": 30.0},
        "along_x": {"eye": (c + np.array([2.6 * r, 1e-3 * r, 0.0])).tolist(), "target": c.tolist(), "up": [0, 0, 1],
                    "fov_y_deg": 45.0},
        "grazing": {"eye": (top + np.array([0.0, -2.6 * r, 0.02 * r])).tolist(), "target": top.tolist(),
                    "up": [0, 0, 1], "fov_y_deg": 30.0},
    }


def transfer_function(mesh):
    """Three tents over the field's range with an optical depth of a few across the data; a
    constant density where the field is constant (then the image measures the geometry)."""
    from ..engine.transfer_function import TransferFunction

    c, r, lo, hi = framing(mesh)
    vals = mesh.field_samples(4)
    a, b = (float(v) for v in np.percentile(vals, [2, 98]))
    if b - a <= 1e-12 * max(1.0, abs(a)):
        return TransferFunction.from_contract({"color": [[a - 1, 0.2, 0.5, 1.0], [a + 1, 0.2, 0.5, 1.0]],
                                               "density": [[a - 1, 1.0 / r], [a + 1, 1.0 / r]]})
    q = [a + (b - a) * t for t in (0.2, 0.3, 0.4, 0.6, 0.7, 0.8)]
    return TransferFunction.from_contract({
        "color": [[a, 0.1, 0.2, 1.0], [0.5 * (a + b), 0.2, 1.0, 0.3], [b, 1.0, 0.3, 0.1]],
        "density": [[a, 0.0], [q[0], 0.0], [q[1], 3.0 / r], [q[2], 0.0], [q[3], 0.0], [q[4], 6.0 / r], [q[5], 0.0], [b, 0.0]]})
