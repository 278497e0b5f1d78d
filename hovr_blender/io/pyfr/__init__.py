"""PyFR 3.x reader: a mesh (.pyfrm) and a solution (.pyfrs), both HDF5 (docs/spec/formats.md §6),
all four 3-D element types, curved ones included, the solution brought from its own solution
points to the engine's modal basis exactly (a change of basis, not a resampling).

Untrusted input (engine/limits.py is the policy): read with h5py from the checked descriptor,
hard links only, every dataset's size checked against the file before it is read (the helpers
of io/nektar/hdf5.py). Every failure is a PyFRError naming the file and the record.

Modules, each importing only those above it:
  elements   PyFR's element types: reference frames, spaces, shape points, the change of basis
  files      the mesh and solution files read and checked (imports h5py)
  format     fields, the VolumeMesh, the solution beside a mesh, the registry's Format
"""
from .files import PyFRError, read_mesh, read_solution
from .format import FORMAT, list_fields, read_pyfr

__all__ = ["FORMAT", "PyFRError", "list_fields", "read_mesh", "read_pyfr", "read_solution"]
