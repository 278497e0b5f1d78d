"""The VTU format as the registry (io/formats.py) sees it: a VTK XML unstructured grid of
Lagrange or Bezier cells whose point-data arrays are the fields; a vector array renders one
component or its magnitude, derived from the exact component polynomials (io/magnitude.py)."""
from __future__ import annotations

from ...engine.derived_fields import derived_mesh, parse_derived
from ...engine.mesh import VolumeMesh
from ..magnitude import component_reads, magnitude_mesh
from ..format_base import XML_PACKAGE, Format
from .errors import VtuError
from .reader import list_fields, read_vtu


def read_vtu_field(path, field=None, component=None) -> VolumeMesh:
    """vtu.read_vtu, except that a vector array's magnitude (component None or "magnitude")
    is derived here from its exact component polynomials (read_vtu interpolates the nodal
    magnitudes instead, as VTK does); field Q(Velocity) and the other derived fields of
    engine/derived_fields.py from its arrays' exact polynomials."""
    spec = parse_derived(field)
    if spec is not None:
        reads = component_reads(spec, list_fields(path))
        return derived_mesh(spec, [read_vtu(path, name, index) for name, index in reads])
    if component in (None, "magnitude"):
        available = list_fields(path)
        name = field if field is not None else next(iter(available), None)
        ncomp = available.get(name, 1) if name is not None else 1
        if ncomp > 1:
            comps = [read_vtu(path, name, i) for i in range(ncomp)]
            return magnitude_mesh(comps, f"|{name}|")
    return read_vtu(path, field, component)


FORMAT = Format(
    name="vtu", label="VTU", extensions=(".vtu",),
    sniff=lambda head: b"<VTKFile" in head and b"UnstructuredGrid" in head,
    read=lambda path, solution=None, field=None, component=None: read_vtu_field(path, field, component),
    list_fields=list_fields, error=VtuError,
    description="Import a VTK unstructured grid (.vtu, Lagrange or Bezier cells) as a HOVR volume",
    field_help="Point-data array to render; Q(Velocity), vorticity(Velocity), |grad|(Pressure): derived fields; "
               "empty: the file's first one",
    components=True,
    packages=(XML_PACKAGE,),
)
