"""MFEM reader: a mesh (.mesh: MFEM mesh v1.0, v1.2, v1.3, unrefined NC mesh v1.0; straight or
curved by a nodes GridFunction) and a GridFunction (.gf) of an H1 or L2 collection, for
hexahedra, prisms, tetrahedra and the pyramids the engine holds exactly (docs/spec/formats.md §7).
Each element's nodal values become the engine's modal expansion of the same polynomial (an
exact change of basis); each element keeps its own order (a variable-order field saved raised
to its largest order: format.py says how the orders are recovered).

Untrusted input (engine/limits.py is the policy): the text is read whole after its size is
checked, every count is checked against what the file can hold, and anything this reader does
not understand is refused with one MFEMError naming the file and the line.

Modules, each importing only those above it:
  elements   MFEM's geometries, node sets and spaces; the change of basis to the engine's modes
  text       the bounded text cursor (MFEMError)
  files      the mesh and GridFunction files parsed: read_mesh, read_gridfunction
  dofs       MFEM's edge, face and DOF numbering: each element's values at its nodes
  format     fields, element orders, the GridFunction beside a mesh, the registry's Format: read_mfem,
             list_fields

This package's read_mfem and list_fields read in a reader process (io/isolation.py), as every
public reading door does: a parse that blows a limit, loops or crashes ends the reader process,
never the caller. The parsers themselves, which run in whatever process calls them, are the
modules' (format.read_mfem, with own_orders=False for the field as stored, format.list_fields,
files.read_mesh, files.read_gridfunction): the reader process and the parser's tests call those.
"""
from .format import FORMAT
from .text import MFEMError

__all__ = ["FORMAT", "MFEMError", "list_fields", "read_mfem"]


def read_mfem(mesh_path, gf_path=None, field=None, component=None):
    """format.read_mfem (a field of an MFEM mesh and GridFunction -> VolumeMesh; `component`: an
    index, "magnitude" or None), read in a reader process: a crash or a hang there is one
    MFEMError-like line naming the file, here."""
    from .. import isolation

    return isolation.read_files(mesh_path, gf_path, field, component)


def list_fields(gf_path) -> dict:
    """format.list_fields ({name: components} of a GridFunction), read in a reader process."""
    from .. import isolation

    return isolation.list_fields("mfem", gf_path)
