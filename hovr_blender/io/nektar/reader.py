"""The entry points: a mesh and one field of its field file -> VolumeMesh; the fields a file
holds; the field file beside a mesh."""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ...core import expansions as ex
from ...core.cache import LRUCache
from ...core.mesh import MeshError, VolumeMesh
from ...core.shapes import NAMES
from .errors import NektarError, guard
from .fields import read_field_file
from .geometry import mesh_geometry
from .mesh import NektarMesh, read_mesh

SOLUTION_EXTENSIONS = (".fld", ".chk", ".rst")
NO_FIELD = "(none)"  # the field name of a mesh read without a field file

# A mesh file's elements and geometry by (path, mtime, size): a series of field files on one mesh
# (flow_0001.fld, flow_0002.fld, ...) parses the XML and fits the curved geometry once, not once a
# frame (hump3D: 0.8 of the 1.1 s a snapshot took). Read-only once made: from_elements copies.
_GEOMETRY = LRUCache(2)


def _mesh_geometry(mesh_path: Path):
    status = os.stat(mesh_path)
    key = (str(mesh_path.resolve()), status.st_mtime_ns, status.st_size)

    def read():
        mesh = read_mesh(mesh_path)
        warnings: list[str] = []
        return (mesh, *mesh_geometry(mesh, warnings), tuple(warnings))

    return _GEOMETRY.get(key, read)


def find_solution(mesh_path) -> Path | None:
    """The field file beside a mesh: its name with .fld, .chk or .rst (a file or a multi-part
    .fld/ folder), the first that exists; None if there is none."""
    mesh_path = Path(mesh_path)
    return next((p for p in (mesh_path.with_suffix(e) for e in SOLUTION_EXTENSIONS) if p.exists()), None)


def list_fields(solution_path) -> list[str]:
    """Names of the fields in a Nektar++ field file (.fld/.chk/.rst, XML or HDF5, or a .fld/ directory)."""
    return read_field_file(solution_path).names


def read_nektar(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """VolumeMesh of one field of a Nektar++ mesh (.xml) and its field file (.fld/.chk/.rst, XML or
    HDF5, or a multi-part .fld/ directory). Without a field file (none given and none beside the
    mesh: find_solution) the geometry comes with a zero field named "(none)" and has_field False.
    The returned mesh carries ``warnings`` (list of str) and ``has_field``."""
    mesh_path = Path(mesh_path)
    if solution_path is None:
        solution_path = find_solution(mesh_path)
    if solution_path is None and field is not None:
        raise NektarError(f"{mesh_path}: field {field!r} requested but there is no field file "
                          f"(no {', '.join(mesh_path.with_suffix(e).name for e in SOLUTION_EXTENSIONS)} "
                          "beside the mesh)")
    solution = Path(solution_path) if solution_path is not None else None
    return guard(mesh_path, lambda: _read(mesh_path, solution, field))


def _read(mesh_path: Path, solution: Path | None, field):
    mesh, geometry_modes, geometry_coeffs, geometry_warnings = _mesh_geometry(mesh_path)
    shapes = np.array([s for _, s, _ in mesh.elements], dtype=np.int32)
    if solution is None:
        modes = np.full((len(mesh.elements), 3), 2, dtype=np.int32)
        field_coeffs = [np.zeros(ex.num_coeffs(int(s), (2, 2, 2))) for s in shapes]
        field = NO_FIELD
    else:
        field, coeffs = _field(mesh, solution, field)
        modes = np.array([coeffs[e][1] for e, _, _ in mesh.elements], dtype=np.int32)
        field_coeffs = [coeffs[e][2] for e, _, _ in mesh.elements]
    warnings = list(geometry_warnings)
    try:
        out = VolumeMesh.from_elements(shapes, modes, field_coeffs, geometry_modes, geometry_coeffs,
                                       field_name=field, source=str(mesh_path))
    except MeshError as exc:
        # from_elements numbers elements by position: name the Nektar++ element ID too
        match = re.match(r"element (\d+):(.*)", str(exc), re.S)
        if match and int(match.group(1)) < len(mesh.elements):
            raise NektarError(f"{mesh_path}: element {mesh.elements[int(match.group(1))][0]}:{match.group(2)}") from exc
        raise NektarError(f"{mesh_path}: {exc}") from exc
    out.element_ids = np.array([e for e, _, _ in mesh.elements], dtype=np.int64)
    out.has_field = solution is not None
    out.warnings = sorted(set(warnings))
    return out


def _field(mesh: NektarMesh, solution: Path, field):
    """(field name, {element ID: (shape, modes, coefficients)}) for exactly the mesh's elements;
    with field None the file must hold one field only."""
    field_file = read_field_file(solution, len(mesh.elements))
    names = field_file.names
    if field is None:
        if len(names) != 1:
            raise NektarError(f"{solution}: holds fields {', '.join(names) or '(none)'}; name the one to render")
        field = names[0]
    ids = [e for e, _, _ in mesh.elements]
    coeffs = field_file.coefficients(field, ids)
    extra = sorted(set(coeffs) - set(ids))
    if extra:
        raise NektarError(f"{solution}: element(s) {extra[:10]} are not in the mesh {mesh.path.name}")
    for e, shape, _ in mesh.elements:
        if coeffs[e][0] != shape:
            raise NektarError(f"{solution}: element {e} is a {NAMES[coeffs[e][0]]} in the field file but a "
                              f"{NAMES[shape]} in {mesh.path.name}")
    return field, coeffs
