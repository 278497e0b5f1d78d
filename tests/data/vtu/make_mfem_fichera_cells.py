"""Writes mfem_fichera_cells_p4.vtu and its .info.json: a few cells of each kind of MFEM's
curved Fichera corner (../shared/data/vtu/mfem_fichera_poisson_mixed_p4.vtu: Lagrange
tetrahedra, hexahedra and wedges, geometry order 2, field order 4), extracted by VTK's own
vtkExtractCells and written by its vtkXMLUnstructuredGridWriter (appended, zlib-compressed),
Lagrange cells kept, so that the VTU reader's tests read a real solver's cells on a fresh clone.
The info file holds what VTK reads back (the counts, arrays and bounds test_vtu.py checks).

    python -m tests.data.vtu.make_mfem_fichera_cells
"""
import json
from pathlib import Path

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy

from hovr_blender.audit.datasets import SHARED

SOURCE = SHARED / "vtu" / "mfem_fichera_poisson_mixed_p4.vtu"
HERE = Path(__file__).resolve().parent
OUT = HERE / "mfem_fichera_cells_p4.vtu"
PER_KIND = 8  # cells of each kind (71 tetrahedra, 72 hexahedra, 73 wedges) nearest the corner's re-entrant vertex
CORNER = (0.0, 0.0, 0.0)
NAMES = {71: "VTK_LAGRANGE_TETRAHEDRON", 72: "VTK_LAGRANGE_HEXAHEDRON", 73: "VTK_LAGRANGE_WEDGE"}


def read(path):
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    return reader.GetOutput()


def summary(path) -> dict:
    """What VTK reads back: the counts, cell types, point arrays and bounds."""
    grid = read(path)
    types = vtk_to_numpy(grid.GetCellTypes())
    data = grid.GetPointData()
    return {"file": path.name, "size_bytes": path.stat().st_size, "vtk_version": vtk.vtkVersion.GetVTKVersion(),
            "n_points": grid.GetNumberOfPoints(), "n_cells": grid.GetNumberOfCells(),
            "cell_types": {str(t): {"name": NAMES[int(t)], "count": int((types == t).sum()),
                                    "points_per_cell": sorted({grid.GetCell(i).GetNumberOfPoints()
                                                               for i in np.flatnonzero(types == t)})}
                           for t in sorted(set(types.tolist()))},
            "point_data": {data.GetArrayName(i): {"components": data.GetArray(i).GetNumberOfComponents(),
                                                  "range": list(data.GetArray(i).GetRange())}
                           for i in range(data.GetNumberOfArrays())},
            "bounds": list(grid.GetBounds())}


def main():
    grid = read(SOURCE)
    types = vtk_to_numpy(grid.GetCellTypes())
    centres = np.array([np.mean([grid.GetPoint(grid.GetCell(i).GetPointId(j))
                                 for j in range(grid.GetCell(i).GetNumberOfPoints())], axis=0)
                        for i in range(grid.GetNumberOfCells())])
    distance = np.linalg.norm(centres - np.array(CORNER), axis=1)
    keep = sorted(int(i) for t in NAMES for i in np.flatnonzero(types == t)[np.argsort(distance[types == t])[:PER_KIND]])
    ids = vtk.vtkIdList()
    for i in keep:
        ids.InsertNextId(i)
    extract = vtk.vtkExtractCells()
    extract.SetInputData(grid)
    extract.SetCellList(ids)
    extract.Update()
    writer = vtk.vtkXMLUnstructuredGridWriter()
    writer.SetFileName(str(OUT))
    writer.SetInputData(extract.GetOutput())
    writer.SetDataModeToAppended()
    writer.EncodeAppendedDataOff()
    writer.SetCompressorTypeToZLib()
    writer.Write()
    info = {"generator": "VTK's vtkExtractCells and vtkXMLUnstructuredGridWriter (appended raw, zlib)",
            "source": f"../shared/data/vtu/{SOURCE.name} (MFEM 4.10 via PyMFEM 4.10.0.1)",
            "source_cells": keep, "summary": summary(OUT)}
    OUT.with_suffix(".info.json").write_text(json.dumps(info, indent=1) + "\n")
    print(OUT, OUT.stat().st_size, "bytes,", len(keep), "cells")


if __name__ == "__main__":
    main()
