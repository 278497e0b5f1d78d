"""VTK XML unstructured grids (.vtu) with Lagrange and Bézier cells -> VolumeMesh.

Cells: VTK_LAGRANGE_{TETRAHEDRON 71, HEXAHEDRON 72, WEDGE 73}, VTK_BEZIER_{TETRAHEDRON 78,
HEXAHEDRON 79, WEDGE 80} of any degree (HigherOrderDegrees cell data, else inferred from the
node count), and the linear VTK_TETRA 10 / VTK_HEXAHEDRON 12 / VTK_WEDGE 13 as degree 1.
Pyramids (14, 74, 81) are refused: VTK's higher-order pyramid space is not Nektar++'s.
Field and geometry are converted exactly to modal expansions (docs/spec/formats.md §4).

Untrusted input (engine/limits.py is the policy): the file is opened as a regular file within
the memory limit; every DataArray is decoded to the size the piece's counts give it: a block
header that declares another size is refused before anything is allocated or inflated, and
each block is inflated, bounded, to exactly its declared size. Every failure is a VtuError.

Modules, each importing only those above it:
  errors      VtuError
  cells       cell types, degrees, VTK node orders
  conversion  a cell's basis, its conversion to modal coefficients, orientation
  decoding    one DataArray's values, from any encoding VTK writes
  vtkfile     the file opened: header, XML, appended data, pieces, point arrays
  reader      read_vtu, list_fields
"""
from .cells import CELL_TYPES, hex_order, tet_order, vtk_node_params, wedge_order
from .conversion import cell_basis, conversion_matrix, modes_for, xi_to_vtk
from .errors import VtuError
from .reader import list_fields, read_vtu

__all__ = ["CELL_TYPES", "VtuError", "cell_basis", "conversion_matrix", "hex_order", "list_fields", "modes_for",
           "read_vtu", "tet_order", "vtk_node_params", "wedge_order", "xi_to_vtk"]
