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
  files      the mesh and GridFunction files parsed
  dofs       MFEM's edge, face and DOF numbering: each element's values at its nodes
  format     fields, element orders, the GridFunction beside a mesh, the registry's Format
"""
from .files import read_gridfunction, read_mesh
from .format import FORMAT, list_fields, read_mfem
from .text import MFEMError

__all__ = ["FORMAT", "MFEMError", "list_fields", "read_gridfunction", "read_mesh", "read_mfem"]
