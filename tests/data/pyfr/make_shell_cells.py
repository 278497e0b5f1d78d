"""Writes shell_lagrange_p2.vtu: the Lagrange cells of PyFR's own high-order export of the shell
case (`pyfr export volume -p double shell.pyfrm shell-0.02.pyfrs shell-0.02.vtu`, MANIFEST.md),
its one <Piece> of subdivided pyramids left out (PyFR writes pyramids as linear sub-cells, which
the VTU reader refuses), extracted by VTK's vtkExtractCells (points kept in float64) and written by its
vtkXMLUnstructuredGridWriter (appended, zlib), values unchanged (float64).

    python -m tests.data.pyfr.make_shell_cells PATH/TO/shell-0.02.vtu
"""
import sys
from pathlib import Path

import vtk

HERE = Path(__file__).resolve().parent
OUT = HERE / "shell_lagrange_p2.vtu"
LAGRANGE = (71, 72, 73)  # tetrahedra, hexahedra, wedges


def main(source):
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(source))
    reader.Update()
    grid = reader.GetOutput()
    ids = vtk.vtkIdList()
    for cell in range(grid.GetNumberOfCells()):
        if grid.GetCellType(cell) in LAGRANGE:
            ids.InsertNextId(cell)
    extract = vtk.vtkExtractCells()
    extract.SetInputData(grid)
    extract.SetCellList(ids)
    extract.SetOutputPointsPrecision(vtk.vtkAlgorithm.DOUBLE_PRECISION)  # PyFR's float64 nodes, unrounded
    extract.Update()
    writer = vtk.vtkXMLUnstructuredGridWriter()
    writer.SetFileName(str(OUT))
    writer.SetInputData(extract.GetOutput())
    writer.SetCompressorTypeToZLib()
    writer.Write()
    print(OUT, OUT.stat().st_size, "bytes,", extract.GetOutput().GetNumberOfCells(), "cells")


if __name__ == "__main__":
    main(sys.argv[1])
