"""Nektar++ reader: mesh XML (plain or B64Z-compressed, curved edges and faces, all four 3-D
shapes) and field files (.fld/.chk/.rst in XML or HDF5, multi-part .fld/ directories), following
docs/spec/formats.md §2. The result is a VolumeMesh whose field and geometry are both modal
expansions of Nektar++'s MODIFIED family in Nektar++'s storage order (engine/expansions.py).

Untrusted input (engine/limits.py is the policy): only regular files are opened; the mesh is
read first and every size a field file declares is checked against it before anything is
inflated or allocated; zlib output is bounded; HDF5 objects are followed through hard links
only and their data must lie in the file itself. Every failure is a NektarError naming the file
and the record or element.

Modules, each importing only those above it:
  errors     NektarError, and the guard that makes every failure one
  xmlfile    safe XML parsing, numbers in element text, B64Z blocks and records
  ranges     ID lists ("0-7,12") as ranges, never expanded unchecked
  points     1-D and triangle point sets of curves, Lagrange interpolation
  entities   vertices, edges, faces, elements
  curves     the CURVED section
  composites the COMPOSITE section and the CONDITIONS' boundary regions; a face composite's
             faces as (element, face) for the walls (read_boundaries, after read_mesh)
  domain     the DOMAIN's elements through its composites
  mesh_file  NektarMesh and read_mesh: the above together
  topology   an element's local vertices, edges and faces from the mesh's
  element_geometry  element geometry as modal coefficients, each certified valid (engine/validity.py)
  blocks     a field file's blocks, format-free, sizes checked against the mesh
  hdf5       HDF5 field files, and safe access to HDF5 objects (imports h5py)
  fields     field files and directories -> FieldFile; one field's coefficients
  reader     read_nektar, list_fields, find_solution, mesh_boundaries

This package's read_nektar and list_fields read in a reader process (io/isolation.py), as every
public reading door does: libhdf5 crashes (SIGSEGV) or loops on some damaged HDF5 field files, and
that ends the reader process, never the caller. The parsers themselves, which run in whatever
process calls them, are the modules' (reader.read_nektar, fields.read_field_file): the reader
process and the tests call those.
"""
from .composites import Boundaries, BoundaryRegion, Composite
from .errors import NektarError
from .fields import FieldFile
from .reader import NO_FIELD, SOLUTION_EXTENSIONS, find_solution, mesh_boundaries, pick_solution, solution_candidates

__all__ = ["NO_FIELD", "SOLUTION_EXTENSIONS", "Boundaries", "BoundaryRegion", "Composite", "FieldFile",
           "NektarError", "find_solution", "list_fields", "mesh_boundaries", "read_nektar"]


def read_nektar(mesh_path, solution_path=None, field=None):
    """reader.read_nektar (a mesh and one field of its field file -> VolumeMesh), read in a reader
    process: a crash or a hang there is one NektarError-like line naming the file, here."""
    from .. import isolation

    return isolation.read_files(mesh_path, solution_path, field)


def list_fields(solution_path) -> list[str]:
    """reader.list_fields (the fields a field file holds), read in a reader process."""
    from .. import isolation

    return isolation.list_fields("nektar", solution_path)
