"""The PyFR format as the registry (io/formats.py) sees it: a mesh .pyfrm whose solutions
(.pyfrs) lie beside it.

Fields: the solver's stored variables, exactly (Euler and Navier-Stokes: rho, rhou, rhov, rhow,
E; the artificial-compressibility systems: p, u, v, w), and for the compressible systems the
primitive variables u, v, w, p as PyFR computes them, at its solution points (the polynomial
through their values there, as PyFR's solver holds them). The derived fields of
engine/derived_fields.py take the velocity from the momenta over the density exactly:
Q(rhou,rhov,rhow/rho), vorticity(...), speed(...).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ...engine.derived_fields import derived_mesh, parse_derived
from ...engine.mesh import MeshError, VolumeMesh
from ...engine import limits, validity
from ..magnitude import component_reads, magnitude_mesh, parse_magnitude
from ..format_base import Format
from . import elements as el
from .errors import PyFRError

PRIMITIVES = ("u", "v", "w", "p")
COMPRESSIBLE = ("rho", "rhou", "rhov", "rhow", "E")


def list_fields(solution_path) -> list[str]:
    """The fields a solution file offers: rho, u, v, w, p first where it has them."""
    from .files import read_solution  # imports h5py: only where a file is read (the reader process)

    return _offered(read_solution(solution_path, headers_only=True))


def _offered(solution) -> list[str]:
    stored = list(solution.fields)
    if stored == list(COMPRESSIBLE) and solution.gamma is not None:
        return ["rho", "u", "v", "w", "p"] + stored[1:]
    return stored


def _values(solution, values: np.ndarray, name: str) -> np.ndarray:
    """(elements, points) of field `name` from a block's (elements, fields, points) values."""
    stored = solution.fields
    if name in stored:
        return values[:, stored.index(name)]
    rho = values[:, 0]
    if name in ("u", "v", "w"):
        return values[:, 1 + "uvw".index(name)] / rho
    momentum = values[:, 1:4]
    return (solution.gamma - 1.0) * (values[:, 4] - 0.5 * np.einsum("eip,eip->ep", momentum, momentum) / rho)


def _geometry(mesh, solution):
    """[(etype, element indices, modes, geometry coefficients (n, K, 3))] of the solution's elements,
    each element's geometry certified (engine/validity.py)."""
    out, first = [], 0
    for etype, points in mesh.points.items():
        limits.progress()
        order, index = solution.blocks[etype][0], solution.blocks[etype][1]
        sorder = el.order_from_npts(etype, points.shape[1])
        gmodes = el.modes(etype, sorder)
        G = np.matmul(el.conversion(etype, sorder, el.std_ele(etype, sorder)), points[index])
        limits.progress()
        try:
            validity.check_elements(el.ETYPES[etype], gmodes, G, first + np.arange(len(index)))
        except MeshError as exc:
            raise PyFRError(f"{mesh.path}: {el.NAMES[etype]}s: {exc}") from exc
        out.append((etype, index, gmodes, G))
        first += len(index)
    return out


def _meshes(mesh_path, solution_path, names) -> list[VolumeMesh]:
    """One VolumeMesh per field name, on one reading of the files (sharing the geometry)."""
    from .files import read_mesh, read_solution  # imports h5py: only where a file is read

    mesh = read_mesh(mesh_path)
    solution = read_solution(solution_path, mesh)
    offered = _offered(solution)
    for name in names:
        if name not in offered:
            raise PyFRError(f"{solution_path}: no field {name!r}; it has {', '.join(offered)}")
    geometry = _geometry(mesh, solution)
    out = []
    for name in names:
        shapes, modes, coeffs, gmodes, gcoeffs = [], [], [], [], []
        for etype, index, gm, G in geometry:
            limits.progress()
            order, _, values, pts = solution.blocks[etype]
            C = _values(solution, values, name) @ el.conversion(etype, order, pts).T
            limits.progress()
            shapes += [el.ETYPES[etype]] * len(index)
            modes += [el.modes(etype, order)] * len(index)
            coeffs += list(C)
            gmodes += [gm] * len(index)
            gcoeffs += list(G)
        try:
            out.append(VolumeMesh.from_elements(shapes, modes, coeffs, gmodes, gcoeffs, field_name=name,
                                                source=str(solution_path)))
        except MeshError as exc:
            raise PyFRError(f"{solution_path}: {exc}") from exc
    return out


def read_pyfr(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """A field of a PyFR mesh and solution: a stored or primitive variable, "|a,b,c|" (a
    magnitude), or a derived field of engine/derived_fields.py."""
    if solution_path is None:
        solution_path = find_solution(mesh_path)
    if solution_path is None:
        raise PyFRError(f"{mesh_path}: no solution (.pyfrs) given or found beside the mesh")
    spec = parse_derived(field)
    if spec is not None:
        names = [n for n, _ in component_reads(spec, {n: 1 for n in list_fields(solution_path)})]
        return derived_mesh(spec, _meshes(mesh_path, solution_path, names))
    names = parse_magnitude(field)
    if names is not None:
        return magnitude_mesh(_meshes(mesh_path, solution_path, names), "|" + ",".join(names) + "|")
    return _meshes(mesh_path, solution_path, [field or list_fields(solution_path)[0]])[0]


_TIME = re.compile(r"[-_]([0-9]+(?:\.[0-9]*)?)$")


def solution_candidates(mesh_path) -> list[Path]:
    """The .pyfrs files beside a mesh, likeliest first: those named after the mesh
    ("shell.pyfrm" -> "shell-0.02.pyfrs"), the latest time first, then the others."""
    mesh_path = Path(mesh_path)
    try:
        found = [p for p in mesh_path.parent.iterdir() if p.suffix.lower() == ".pyfrs" and p.is_file()]
    except OSError:
        return []

    def rank(p: Path):
        match = _TIME.search(p.stem)
        base = p.stem[: match.start()] if match else p.stem
        return (base != mesh_path.stem, -float(match.group(1)) if match else 0.0, p.name)

    return sorted(found, key=rank)


def find_solution(mesh_path) -> Path | None:
    picked, _, _ = pick_solution(mesh_path)
    return picked


def pick_solution(mesh_path):
    """(the likeliest .pyfrs or None, why, all candidates): by name only (no file is opened here:
    this runs in Blender's process)."""
    cands = solution_candidates(mesh_path)
    if not cands:
        return None, "no .pyfrs file in the folder", cands
    best = cands[0]
    if _TIME.sub("", best.stem) == Path(mesh_path).stem or best.stem == Path(mesh_path).stem:
        return best, "named after the mesh, the latest time", cands
    if len(cands) == 1:
        return best, "the only .pyfrs file in the folder", cands
    return None, f"{len(cands)} .pyfrs files in the folder, none named after the mesh", cands


FORMAT = Format(
    name="pyfr", label="PyFR", extensions=(".pyfrm",),
    sniff=lambda head: head.startswith(b"\x89HDF\r\n\x1a\n"),
    read=lambda path, solution=None, field=None, component=None: read_pyfr(path, solution, field),
    list_fields=list_fields, error=PyFRError,
    description="Import a PyFR mesh (.pyfrm) and its solution (.pyfrs) as a HOVR volume",
    packages=(("h5py", "h5py", "PyFR mesh and solution files (HDF5)"),),
    field_help='Field to render: rho, u, v, w, p or a stored variable (rhou, E, ...); Q(rhou,rhov,rhow/rho), '
               'vorticity(rhou,rhov,rhow/rho), |grad|(p): derived fields. Empty: the file\'s first field',
    find_solution=find_solution, pick_solution=pick_solution,
    solution_help=("Solution file (.pyfrs), relative to the mesh's folder; empty: the latest .pyfrs named after "
                   "the mesh (shell.pyfrm -> shell-0.02.pyfrs)"),
)
