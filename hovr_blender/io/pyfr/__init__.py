"""PyFR 3.x reader: a mesh (.pyfrm) and a solution (.pyfrs), both HDF5 (docs/spec/formats.md §6),
all four 3-D element types, curved ones included, the solution brought from its own solution
points to the engine's modal basis exactly (a change of basis, not a resampling).

Untrusted input (engine/limits.py is the policy): read with h5py from the checked descriptor,
hard links only, every dataset's size checked against the file before it is read (the helpers
of io/nektar/hdf5.py). Every failure is a PyFRError naming the file and the record.

Modules, each importing only those above it:
  errors     PyFRError
  elements   PyFR's element types: reference frames, spaces, shape points, the change of basis
  files      the mesh and solution files read and checked (imports h5py): read_mesh, read_solution
  format     fields, the VolumeMesh, the solution beside a mesh, the registry's Format: read_pyfr,
             list_fields

This package's read_pyfr and list_fields read in a reader process (io/isolation.py), as every
public reading door does: libhdf5 crashes (SIGSEGV) on some damaged HDF5 files, and that ends the
reader process, never the caller. The parsers themselves, which run in whatever process calls them,
are the modules' (format.read_pyfr, format.list_fields, files.read_mesh, files.read_solution): the
reader process and the parser's tests call those.
"""
from .errors import PyFRError
from .format import FORMAT

__all__ = ["FORMAT", "PyFRError", "list_fields", "read_pyfr"]


def read_pyfr(mesh_path, solution_path=None, field=None):
    """format.read_pyfr (a field of a PyFR mesh and solution -> VolumeMesh), read in a reader process:
    a crash or a hang there is one PyFRError-like line naming the file, here."""
    from .. import isolation

    return isolation.read_files(mesh_path, solution_path, field)


def list_fields(solution_path) -> list[str]:
    """format.list_fields (the fields a solution file offers), read in a reader process."""
    from .. import isolation

    return isolation.list_fields("pyfr", solution_path)
