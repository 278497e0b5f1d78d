"""The Nektar++ format as the registry (io/formats.py) sees it: a mesh .xml whose fields are in
solution files beside it (.fld/.chk/.rst, XML or HDF5), composites and boundary regions for the
walls; a field "|a,b,c|" is the magnitude of fields a, b, c (io/magnitude.py)."""
from __future__ import annotations

import dataclasses

import numpy as np

from ...engine.derived_fields import derived_mesh, parse_derived
from ...engine.mesh import VolumeMesh
from ..magnitude import component_reads, magnitude_mesh, parse_magnitude
from ..format_base import XML_PACKAGE, Format
from .errors import NektarError
from .fields import FieldFile, read_field_file
from .reader import find_solution, list_fields, mesh_boundaries, pick_solution, read_nektar


def _nektar_component(first: VolumeMesh, field_file: FieldFile, name: str) -> VolumeMesh:
    """Field `name` of the field file on the geometry of `first` (read with read_nektar)."""
    ids = first.element_ids.tolist()
    coeffs = field_file.coefficients(name, ids)
    for k, e in enumerate(ids):
        if coeffs[e][0] != int(first.shape[k]):
            raise NektarError(f"{field_file.path}: element {e} has another shape for field {name!r}")
    modes = np.array([coeffs[e][1] for e in ids], dtype=np.int32)
    flat = [np.asarray(coeffs[e][2], dtype=np.float64) for e in ids]
    sizes = np.array([f.size for f in flat], dtype=np.int64)
    out = dataclasses.replace(first, modes=modes, coeff_offset=np.concatenate([[0], np.cumsum(sizes)[:-1]]),
                              coeffs=np.concatenate(flat), field_name=name, field_range_hull=None)
    out.element_ids = first.element_ids
    return out


def read_nektar_field(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """nektar.read_nektar, plus field "|a,b,c|": the magnitude of fields a, b, c, and the derived
    fields of engine/derived_fields.py (Q(u,v,w), vorticity(rhou,rhov,rhow/rho), |grad|(p), ...)."""
    spec = parse_derived(field)
    names = [n for n, _ in component_reads(spec, None)] if spec is not None else parse_magnitude(field)
    if names is None:
        return read_nektar(mesh_path, solution_path, field)
    first = read_nektar(mesh_path, solution_path, names[0])
    solution = solution_path if solution_path is not None else find_solution(mesh_path)
    field_file = read_field_file(solution, first.num_elements)
    components = [first] + [_nektar_component(first, field_file, n) for n in names[1:]]
    if spec is not None:
        return derived_mesh(spec, components)
    return magnitude_mesh(components, "|" + ",".join(names) + "|")


FORMAT = Format(
    name="nektar", label="Nektar++", extensions=(".xml",),
    sniff=lambda head: b"<NEKTAR" in head,
    read=lambda path, solution=None, field=None, component=None: read_nektar_field(path, solution, field),
    list_fields=list_fields, error=NektarError,
    description="Import a Nektar++ mesh (.xml) and its solution (.fld/.chk/.rst) as a HOVR volume",
    packages=(XML_PACKAGE, ("h5py", "h5py", "Nektar++ HDF5 solution files (.fld/.chk in HDF5)")),
    field_help='Field to render; "|u,v,w|" is the magnitude of u, v, w; Q(u,v,w), vorticity(rhou,rhov,rhow/rho), '
               '|grad|(p): derived fields. Empty: the file\'s first field',
    find_solution=find_solution, pick_solution=pick_solution,
    solution_help=("Field file (.fld/.chk/.rst or a .fld/ folder), relative to the mesh's folder; empty: the "
                   "likeliest field file in the mesh's folder (its name like the mesh's, the latest of a numbered "
                   "series), as listed below"),
    boundaries=mesh_boundaries,
)
