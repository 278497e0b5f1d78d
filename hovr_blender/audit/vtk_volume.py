"""A volume as VTK sees it: an unstructured grid of Lagrange cells with one point field, for the
independent reference (reference.py).

A .vtu file is read by VTK's own reader. A Nektar++ (or any) VolumeMesh is converted to VTK
Lagrange cells where the polynomial spaces coincide: a hexahedron of m modes per direction is
Q_(m-1), a tetrahedron P_(m-1), a prism P_p(triangle) x P_p(line), each inside VTK's Lagrange
cell of the same degree, so the conversion is exact. The only project code it uses is the
evaluation of the mesh's expansion at VTK's node positions (node positions and order come from
VTK); tests/audit/test_audit_reference.py checks converted Nektar++ files against their analytic
solutions through VTK's own interpolation. Pyramids have no VTK counterpart and are refused.
"""
from __future__ import annotations

import numpy as np

from ..engine import expansions, shapes
from ..engine.mesh import VolumeMesh

FIELD = "f"


class AuditError(ValueError):
    """Data the independent reference cannot represent."""


def import_vtk():
    """The VTK the reference uses: its data model, XML files and core (vtkmodules, not the `vtk`
    package that loads every module), so that a GPU machine needs only those
    (scripts/pack-vtk.sh's reference subset). A test and audit dependency only: the product never
    imports it."""
    from types import SimpleNamespace

    from vtkmodules import vtkCommonCore, vtkCommonDataModel, vtkIOXML

    names = {}
    for module in (vtkCommonCore, vtkCommonDataModel, vtkIOXML):
        names.update({k: getattr(module, k) for k in dir(module) if not k.startswith("_")})
    return SimpleNamespace(**names)


def read_vtu(path: str, field: str, component: int | None = None):
    """(vtkUnstructuredGrid with the scalar point array FIELD, its name) of a .vtu, read by VTK."""
    vtk = import_vtk()
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    grid = r.GetOutput()
    arr = grid.GetPointData().GetArray(field)
    if arr is None:
        raise AuditError(f"{path}: no point array {field!r}")
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    values = vtk_to_numpy(arr).astype(np.float64)
    if values.ndim == 2:
        values = values[:, component] if component is not None else np.linalg.norm(values, axis=1)
    out = numpy_to_vtk(np.ascontiguousarray(values), deep=True)
    out.SetName(FIELD)
    grid.GetPointData().AddArray(out)
    return grid


def _lattice(shape: int, degree: int) -> tuple[int, np.ndarray]:
    """(VTK cell type, (N, 3) VTK parametric coordinates of its N nodes in VTK's order), asked
    of VTK itself."""
    vtk = import_vtk()
    p = degree
    if shape == shapes.HEX:
        hexa = vtk.vtkLagrangeHexahedron
        n = (p + 1) ** 3
        pc = np.zeros((n, 3))
        for k in range(p + 1):
            for j in range(p + 1):
                for i in range(p + 1):
                    pc[hexa.PointIndexFromIJK(i, j, k, [p, p, p])] = (i / p, j / p, k / p)
        return vtk.VTK_LAGRANGE_HEXAHEDRON, pc
    cls, kind = {shapes.TET: (vtk.vtkLagrangeTetra, vtk.VTK_LAGRANGE_TETRAHEDRON),
                 shapes.PRISM: (vtk.vtkLagrangeWedge, vtk.VTK_LAGRANGE_WEDGE)}[shape]
    n = (p + 1) * (p + 2) * (p + 3) // 6 if shape == shapes.TET else (p + 1) ** 2 * (p + 2) // 2
    cell = cls()
    cell.GetPointIds().SetNumberOfIds(n)
    cell.GetPoints().SetNumberOfPoints(n)
    for i in range(n):
        cell.GetPointIds().SetId(i, i)
        cell.GetPoints().SetPoint(i, 0.0, 0.0, 0.0)
    if hasattr(cell, "SetUniformOrderFromNumPoints"):  # VTK's wedge cannot tell its order from the
        cell.SetUniformOrderFromNumPoints(n)  # count alone at some degrees (6: 196 nodes); say it
    cell.Initialize()
    return kind, np.array(cell.GetParametricCoords(), dtype=np.float64).reshape(n, 3)


def _reference_xi(shape: int, pc: np.ndarray) -> np.ndarray:
    """Our reference coordinates of VTK parametric points: any affine map that takes VTK's
    corners onto ours gives the same polynomials. Hexahedron and tetrahedron: xi = 2r - 1; the
    prism's triangle is (xi0, xi2) and its line xi1, VTK's wedge has the triangle in (r, s)."""
    xi = 2.0 * pc - 1.0
    if shape == shapes.PRISM:
        return xi[:, [0, 2, 1]]
    return xi


def _degree(shape: int, modes, geom_modes) -> int:
    m = max(int(np.max(modes)), int(np.max(geom_modes)))
    return max(m - 1, 1)


def _geometry(mesh: VolumeMesh, e: int, xi: np.ndarray) -> np.ndarray:
    """World points of element e at reference points xi."""
    sh = int(mesh.shape[e])
    if mesh.geom_coeffs is None:  # affine hexahedra given by their corners: the trilinear blend
        V = shapes.VERTICES[shapes.HEX]
        w = np.prod((1.0 + xi[:, None, :] * V[None, :, :]) / 2.0, axis=2)  # (n, 8)
        return w @ mesh.vertices[e]
    o = int(mesh.geom_offset[e])
    g = mesh.geom_coeffs[o:o + expansions.num_coeffs(sh, mesh.geom_modes[e])]
    return expansions.eval_modal(sh, mesh.geom_modes[e], g, xi)


def from_mesh(mesh: VolumeMesh):
    """vtkUnstructuredGrid of VTK Lagrange cells holding exactly the mesh's geometry and field."""
    vtk = import_vtk()
    from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    if np.any(mesh.shape == shapes.PYR):
        raise AuditError("pyramids have no VTK Lagrange counterpart in the same polynomial space")
    if mesh.geom_coeffs is None and np.any(mesh.shape != shapes.HEX):
        raise AuditError("a mesh without a geometry expansion must hold hexahedra only")
    points, values, conn, offsets, types = [], [], [], [0], []
    lattices = {}
    total = 0
    for e in range(mesh.num_elements):
        sh = int(mesh.shape[e])
        gm = mesh.geom_modes[e] if mesh.geom_coeffs is not None else (2, 2, 2)
        p = _degree(sh, mesh.modes[e], gm)
        if (sh, p) not in lattices:
            kind, pc = _lattice(sh, p)
            lattices[(sh, p)] = (kind, _reference_xi(sh, pc))
        kind, xi = lattices[(sh, p)]
        points.append(_geometry(mesh, e, xi))
        values.append(expansions.eval_modal(sh, mesh.modes[e], mesh.element_coeffs(e), xi))
        n = len(xi)
        conn.append(np.arange(total, total + n))
        total += n
        offsets.append(total)
        types.append(kind)
    pts = vtk.vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(np.concatenate(points)), deep=True))
    cells = vtk.vtkCellArray()
    cells.SetData(numpy_to_vtkIdTypeArray(np.asarray(offsets, dtype=np.int64), deep=True),
                  numpy_to_vtkIdTypeArray(np.concatenate(conn).astype(np.int64), deep=True))
    grid = vtk.vtkUnstructuredGrid()
    grid.SetPoints(pts)
    grid.SetCells(numpy_to_vtk(np.asarray(types, dtype=np.uint8), deep=True, array_type=vtk.VTK_UNSIGNED_CHAR), cells)
    arr = numpy_to_vtk(np.ascontiguousarray(np.concatenate(values)), deep=True)
    arr.SetName(FIELD)
    grid.GetPointData().AddArray(arr)
    return grid
