"""The .vtu importer: VTK node orders and bases against vtk's own cells, files written by vtk's
writer (Lagrange and Bézier tetrahedra, hexahedra, wedges, both hexahedron numberings, every
encoding) reproducing analytic fields, the four real solver exports, malformed input and hostile
input (decompression bombs, lying block headers, huge counts, FIFOs and devices)."""
from __future__ import annotations

import json
import lzma
import math
import os
import re
import threading
import time
import zlib
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine import limits
from hovr_blender.io import vtu
from hovr_blender.io.vtu import cells as vtu_cells, decoding, vtkfile
from hovr_blender.io.vtu import VtuError, list_fields, read_vtu

from ..helpers import data_dir, data_file as shared_file

VTU_DATA = data_dir("vtu")  # VTU_DATA / name: the file, or the test skipped naming it
# mfem_fichera_cells_p4: 24 of MFEM's cells written by VTK, vendored in tests/data (a fresh clone reads it)
REAL = ["mfem_fichera_cells_p4", "mfem_fichera_poisson_mixed_p4", "ngsolve_ball_poisson_hex_p6",
        "pyfr_tgv_hexprism_p4_t4", "ngsolve_post_heat_tetprism_p4"]
SHAPE_OF_TYPE = {71: shapes.TET, 72: shapes.HEX, 73: shapes.PRISM}
LAGRANGE = {shapes.HEX: 72, shapes.TET: 71, shapes.PRISM: 73}
BEZIER = {shapes.HEX: 79, shapes.TET: 78, shapes.PRISM: 80}


def need_vtk():
    return pytest.importorskip("vtk", reason="the vtk package (third-party writer/reader used as the oracle) is not installed")


def vtk_cell(vtk, cell_type, n, degs=None):
    """An initialised vtk cell of the type with n nodes (random coordinates)."""
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    rng = np.random.default_rng(n)
    for x in rng.random((n, 3)):
        pts.InsertNextPoint(*x)
    ug.SetPoints(pts)
    ug.InsertNextCell(cell_type, n, list(range(n)))
    if degs is not None:
        arr = vtk.vtkIntArray()
        arr.SetName("HigherOrderDegrees")
        arr.SetNumberOfComponents(3)
        arr.InsertNextTuple3(*degs)
        ug.GetCellData().SetHigherOrderDegrees(arr)
    return ug.GetCell(0), ug


def random_params(shape, m, rng):
    """m VTK parametric points strictly inside the reference cell."""
    out = []
    while len(out) < m:
        r = rng.uniform(0.02, 0.98, 3)
        if shape == shapes.TET and r.sum() >= 0.98 or shape == shapes.PRISM and r[0] + r[1] >= 0.98:
            continue
        out.append(r)
    return np.array(out)


# ---------------------------------------------------------------------------------------------
# Node orders and bases against vtk's own cells

@pytest.mark.parametrize("cell_type", [71, 72, 73, 78, 79, 80])
def test_node_order_and_basis_match_vtk(cell_type):
    vtk = need_vtk()
    _, shape, family = vtu.CELL_TYPES[cell_type]
    rng = np.random.default_rng(cell_type)
    for p in range(1, 7):
        degs = (p, p, p)
        n = vtu_cells.node_count(shape, degs)
        cell, _ = vtk_cell(vtk, cell_type, n)
        pc = np.array(cell.GetParametricCoords()).reshape(n, 3)
        assert np.abs(vtu.vtk_node_params(shape, degs) - pc).max() < 1e-14, (cell_type, p)
        r = random_params(shape, 10, rng)
        B = vtu.cell_basis(shape, family, degs, r)
        W = np.zeros_like(B)
        for m in range(len(r)):
            w = [0.0] * n
            cell.InterpolateFunctions(list(r[m]), w)
            W[m] = w
        assert np.abs(B - W).max() < 1e-12, (cell_type, p)


def test_anisotropic_hex_and_wedge_orders_match_vtk():
    vtk = need_vtk()
    for cell_type, degs in [(72, (2, 3, 1)), (72, (1, 4, 2)), (73, (2, 2, 3)), (73, (3, 3, 1))]:
        shape = vtu.CELL_TYPES[cell_type][1]
        n = vtu_cells.node_count(shape, degs)
        cell, _ = vtk_cell(vtk, cell_type, n, degs)
        pc = np.array(cell.GetParametricCoords()).reshape(n, 3)
        assert np.abs(vtu.vtk_node_params(shape, degs) - pc).max() < 1e-14, (cell_type, degs)


def test_vtk8_hex_order_is_vtks_own_conversion():
    vtk = need_vtk()
    for degs in [(2, 2, 2), (3, 3, 3), (4, 2, 3)]:
        new = vtu.hex_order(*degs)
        old = vtu.hex_order(*degs, vtk8=True)
        for j in range(len(new)):
            # VTK: point j of the new order is point NodeNumberingMappingFromVTK8To9(j) of the old
            assert new[j] == old[vtk.vtkHigherOrderHexahedron.NodeNumberingMappingFromVTK8To9(list(degs), j)]


# ---------------------------------------------------------------------------------------------
# Files written by vtk's writer, filled from analytic polynomials of each cell's space

def space_exponents(shape, degs):
    p, q, r = degs
    if shape == shapes.HEX:
        return [(a, b, c) for a in range(p + 1) for b in range(q + 1) for c in range(r + 1)]
    if shape == shapes.TET:
        return [(a, b, c) for a in range(p + 1) for b in range(p + 1 - a) for c in range(p + 1 - a - b)]
    return [(a, b, c) for a in range(p + 1) for b in range(p + 1 - a) for c in range(r + 1)]


class Poly:
    """A random polynomial of the cell's space, in VTK parametric coordinates."""

    def __init__(self, shape, degs, rng, scale=1.0, ncomp=None):
        self.e = np.array(space_exponents(shape, degs))
        self.c = scale * rng.uniform(-1, 1, (len(self.e),) + (() if ncomp is None else (ncomp,)))
        if ncomp is not None:  # a geometry bump: keep dx/dr diagonally dominant (no tangling)
            self.c /= len(self.e)

    def __call__(self, r):
        mono = np.prod(np.asarray(r)[:, None, :] ** self.e[None], axis=-1)  # (M, terms)
        return mono @ self.c


class Cell:
    """One curved cell: x(r) = x0 + 0.6 r (+ a small polynomial bump), field g(r)."""

    def __init__(self, cell_type, degs, x0, rng):
        self.type = cell_type
        _, self.shape, self.family = vtu.CELL_TYPES[cell_type]
        self.degs = degs
        self.x0 = np.asarray(x0, dtype=float)
        self.bump = Poly(self.shape, degs, rng, 0.2, 3)
        self.g = Poly(self.shape, degs, rng)

    def x(self, r):
        return self.x0 + 0.6 * r + self.bump(r)

    def nodal(self, vtk, hod=False):
        """(node coordinates, node values) in VTK order: Lagrange nodes, or Bézier control points
        solved through vtk's own Bernstein basis."""
        r = vtu.vtk_node_params(self.shape, self.degs)
        X, V = self.x(r), self.g(r)
        if self.family == "bezier":
            cell, _ = vtk_cell(vtk, self.type, len(r), self.degs if hod else None)
            W = np.zeros((len(r), len(r)))
            for m in range(len(r)):
                w = [0.0] * len(r)
                cell.InterpolateFunctions(list(r[m]), w)
                W[m] = w
            X, V = np.linalg.solve(W, X), np.linalg.solve(W, V)
        return X, V


def write_vtk(vtk, path, cells, mode="appended", vtk8=False, hod=False):
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetDataTypeToDouble()
    val = vtk.vtkDoubleArray()
    val.SetName("g")
    vec = vtk.vtkDoubleArray()
    vec.SetName("gvec")
    vec.SetNumberOfComponents(3)
    degs_arr = vtk.vtkIntArray()
    degs_arr.SetName("HigherOrderDegrees")
    degs_arr.SetNumberOfComponents(3)
    for c in cells:
        X, V = c.nodal(vtk, hod)
        ids = [pts.InsertNextPoint(*x) for x in X]
        for v in V:
            val.InsertNextValue(v)
            vec.InsertNextTuple3(2 * v, -v, 0.5)
        if vtk8 and c.shape == shapes.HEX and c.type in (72, 79):
            # the same nodes listed in VTK 8 order: node (i, j, k) goes to its old position
            new, old = vtu.hex_order(*c.degs), vtu.hex_order(*c.degs, vtk8=True)
            pos = {ijk: ids[n] for n, ijk in enumerate(new)}
            ids = [pos[ijk] for ijk in old]
        ug.InsertNextCell(c.type, len(ids), ids)
        degs_arr.InsertNextTuple3(*c.degs)
    ug.SetPoints(pts)
    ug.GetPointData().AddArray(val)
    ug.GetPointData().AddArray(vec)
    if hod:
        ug.GetCellData().SetHigherOrderDegrees(degs_arr)
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(path))
    w.SetInputData(ug)
    if mode == "ascii":
        w.SetDataModeToAscii()
    elif mode == "binary":
        w.SetDataModeToBinary()
    elif mode in ("raw", "raw-uncompressed"):
        w.SetEncodeAppendedData(False)
        if mode == "raw-uncompressed":
            w.SetCompressorTypeToNone()
    assert w.Write() == 1
    return path


def set_version(path, version):
    raw = path.read_bytes()
    head, sep, rest = raw.partition(b"<UnstructuredGrid")
    head = re.sub(rb'version="[0-9.]+"', f'version="{version}"'.encode(), head.replace(b'<?xml version="1.0"?>', b"<?xml?>"))
    path.write_bytes(head.replace(b"<?xml?>", b'<?xml version="1.0"?>') + sep + rest)


def check_analytic(mesh, cells, rng, per_cell=12, component=None):
    """Each element at random points (found through invert_map from the analytic x(r)) equals
    the analytic field; returns the largest error."""
    worst = 0.0
    for e, c in enumerate(cells):
        r = random_params(c.shape, per_cell, rng)
        x = c.x(r)
        sh, gm = int(mesh.shape[e]), mesh.geom_modes[e]
        g = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]
        xi, conv, inside = ex.invert_map(sh, gm, g, x)
        assert conv.all() and inside.all(), (e, c.type, c.degs)
        k = ex.num_coeffs(sh, mesh.modes[e])
        f = ex.eval_modal(sh, mesh.modes[e], mesh.coeffs[mesh.coeff_offset[e]: mesh.coeff_offset[e] + k], xi)
        want = c.g(r)
        if component == 0:  # gvec = (2 g, -g, 0.5)
            want = 2 * want
        worst = max(worst, float(np.abs(f - want).max()))
    return worst


def mixed_cells(rng, family="lagrange", degrees=range(1, 5)):
    types = LAGRANGE if family == "lagrange" else BEZIER
    cells = []
    for p in degrees:
        for k, shape in enumerate((shapes.HEX, shapes.TET, shapes.PRISM)):
            cells.append(Cell(types[shape], (p, p, p), (1.5 * p, 1.5 * k, 0.0), rng))
    return cells


@pytest.mark.parametrize("mode", ["appended", "raw", "raw-uncompressed", "binary", "ascii"])
def test_vtk_written_lagrange_cells_reproduce_analytic_fields(tmp_path, mode):
    vtk = need_vtk()
    rng = np.random.default_rng(1)
    cells = mixed_cells(rng)
    path = write_vtk(vtk, tmp_path / f"lagrange_{mode}.vtu", cells, mode)
    assert list_fields(path) == {"g": 1, "gvec": 3}
    mesh = read_vtu(path, "g")
    assert mesh.num_elements == len(cells)
    assert [int(s) for s in mesh.shape] == [c.shape for c in cells]
    err = check_analytic(mesh, cells, rng)
    print(f"lagrange {mode}: max error {err:.2e}")
    assert err < 1e-10


def encodings():
    """(label, write_vtk_lagrange settings) of every encoding vtk writes: ascii; inline base64,
    appended base64 and appended raw, each uncompressed, zlib and lzma, with UInt32 and UInt64
    headers, in both byte orders."""
    yield "ascii", dict(mode="ascii")
    for mode in ("binary", "appended", "raw"):
        for comp in (None, "zlib", "lzma"):
            for header in (32, 64):
                for big in (False, True):
                    yield (f"{mode}-{comp}-uint{header}-{'big' if big else 'little'}",
                           dict(mode=mode, compressor=comp, header=header, big_endian=big))


def test_every_encoding_decodes_what_vtk_wrote(vm, tmp_path):
    """Each array of each encoding decodes to exactly what vtk's reader reads from the same file
    (so what vtk wrote), and every encoding gives the same mesh."""
    vtk = need_vtk()
    from vtk.util.numpy_support import vtk_to_numpy

    first = None
    for label, kw in encodings():
        path = vm.write_vtk_lagrange(tmp_path / f"{label}.vtu", hod=True, **kw)
        reader = vtk.vtkXMLUnstructuredGridReader()
        reader.SetFileName(str(path))
        reader.Update()
        ug = reader.GetOutput()
        want = {"Points": vtk_to_numpy(ug.GetPoints().GetData()),
                "connectivity": vtk_to_numpy(ug.GetCells().GetConnectivityArray()),
                "offsets": vtk_to_numpy(ug.GetCells().GetOffsetsArray())[1:],  # vtk keeps a leading 0
                "types": vtk_to_numpy(ug.GetCellTypes()),
                "g": vtk_to_numpy(ug.GetPointData().GetArray("g")),
                "gvec": vtk_to_numpy(ug.GetPointData().GetArray("gvec")),
                "HigherOrderDegrees": vtk_to_numpy(ug.GetCellData().GetArray("HigherOrderDegrees"))}
        root, src = vtkfile.load(path)
        piece = vtkfile.pieces(path, root)[0]
        for el in piece.iter("DataArray"):
            name = el.attrib.get("Name") or "Points"
            got = decoding.decode(src, el, name, want[name].size, "vtk's count")
            assert np.array_equal(got, want[name].ravel()), (label, name)
        mesh = read_vtu(path, "g")
        first = first or mesh
        assert np.array_equal(mesh.coeffs, first.coeffs) and np.array_equal(mesh.geom_coeffs, first.geom_coeffs), label


@pytest.mark.parametrize("version,old", [("2.2", False), ("2.1", False), ("2.0", True), ("1.0", True), ("0.1", True)])
def test_both_hexahedron_numberings(tmp_path, version, old):
    """Files older than 2.1 list hexahedron nodes in VTK 8 order; vtk's own reader is the judge
    of what each version means, the reader must agree with it."""
    vtk = need_vtk()
    rng = np.random.default_rng(2)
    cells = [Cell(t, (p, p, p), (1.5 * p, 1.5 * k, 0.0), rng)
             for p in range(1, 5) for k, t in enumerate((72, 79))]
    path = write_vtk(vtk, tmp_path / "hex.vtu", cells, "raw", vtk8=old)
    set_version(path, version)
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    ug = reader.GetOutput()
    for e, c in enumerate(cells):
        ids = ug.GetCell(e).GetPointIds()
        got = np.array([ug.GetPoint(ids.GetId(j)) for j in range(ids.GetNumberOfIds())])
        assert np.abs(got - c.nodal(vtk)[0]).max() < 1e-13  # vtk reads the nodes back in VTK 9 order
    assert check_analytic(read_vtu(path), cells, rng) < 1e-10


def test_bezier_cells_and_higher_order_degrees(tmp_path):
    vtk = need_vtk()
    rng = np.random.default_rng(3)
    cells = mixed_cells(rng, "bezier", range(1, 4))
    cells += [Cell(72, (2, 3, 1), (0, 5, 0), rng), Cell(79, (1, 2, 4), (2, 5, 0), rng),
              Cell(73, (2, 2, 3), (4, 5, 0), rng), Cell(80, (3, 3, 1), (6, 5, 0), rng)]
    path = write_vtk(vtk, tmp_path / "bezier.vtu", cells, "appended", hod=True)
    mesh = read_vtu(path)
    assert mesh.geom_modes[-4].tolist() == [3, 4, 2]
    assert mesh.geom_modes[-2].tolist() == [3, 4, 3]  # our prism triangle is (xi1, xi3)
    assert check_analytic(mesh, cells, rng) < 1e-10


def test_vector_components_and_magnitude(tmp_path):
    vtk = need_vtk()
    rng = np.random.default_rng(4)
    cells = mixed_cells(rng, degrees=[2])
    path = write_vtk(vtk, tmp_path / "vec.vtu", cells)
    m0 = read_vtu(path, "gvec", 0)
    assert m0.field_name == "gvec[0]"
    assert check_analytic(m0, cells, rng, component=0) < 1e-10
    mag = read_vtu(path, "gvec")  # vectors default to the magnitude, taken at the nodes
    assert mag.field_name == "|gvec|" and read_vtu(path, "gvec", "magnitude").field_name == "|gvec|"
    # the magnitude is interpolated from the nodes: exact there
    for e, c in enumerate(cells):
        r = vtu.vtk_node_params(c.shape, c.degs)
        sh = int(mag.shape[e])
        gm = mag.geom_modes[e]
        g = mag.geom_coeffs[mag.geom_offset[e]: mag.geom_offset[e] + ex.num_coeffs(sh, gm)]
        xi, conv, _ = ex.invert_map(sh, gm, g, c.x(r))
        k = ex.num_coeffs(sh, mag.modes[e])
        f = ex.eval_modal(sh, mag.modes[e], mag.coeffs[mag.coeff_offset[e]: mag.coeff_offset[e] + k], xi)
        assert conv.all() and np.abs(f - np.sqrt(5 * c.g(r) ** 2 + 0.25)).max() < 1e-10


def test_mirrored_cells_are_read_right_handed(tmp_path):
    """Writers differ in handedness (NGSolve's hexahedra are left-handed in VTK's frame): a cell
    whose Jacobian is negative throughout is valid and comes out with a positive one."""
    vtk = need_vtk()
    rng = np.random.default_rng(5)
    cells = mixed_cells(rng, degrees=[3])
    for c in cells:  # mirror x -> -x: every Jacobian changes sign
        c.x0 = -c.x0
        c.bump.c[:, 0] *= -1
        c.x = (lambda cc: lambda r: (cc.x0 + 0.6 * r + cc.bump(r)) * np.array([-1, 1, 1]))(c)
    path = write_vtk(vtk, tmp_path / "mirrored.vtu", cells)
    mesh = read_vtu(path)
    assert check_analytic(mesh, cells, rng) < 1e-10
    for e in range(mesh.num_elements):
        sh, gm = int(mesh.shape[e]), mesh.geom_modes[e]
        g = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]
        J = ex.eval_modal_grad(sh, gm, g, ex.fit_points(sh, gm))
        assert np.linalg.det(J).min() > 0


# ---------------------------------------------------------------------------------------------
# Real solver exports

def real(name):
    path = VTU_DATA / f"{name}.vtu"
    if not path.exists():
        pytest.skip(f"shared VTU data not present: {path}")
    return path, json.loads((VTU_DATA / f"{name}.info.json").read_text())


# one field per file, each file read once (reading is dominated by VolumeMesh.from_elements)
REAL_FIELD = {"mfem_fichera_cells_p4": ("u", None), "mfem_fichera_poisson_mixed_p4": ("u", None), "ngsolve_ball_poisson_hex_p6": ("u", None),
              "pyfr_tgv_hexprism_p4_t4": ("Velocity", "magnitude"),
              "ngsolve_post_heat_tetprism_p4": ("temperature", None)}


@lru_cache(maxsize=None)
def real_mesh(name):
    path, _ = real(name)
    return read_vtu(path, *REAL_FIELD[name])


def element_geom(mesh, e):
    sh, gm = int(mesh.shape[e]), mesh.geom_modes[e]
    return sh, gm, mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]


def element_eval(mesh, e, xi):
    sh, m = int(mesh.shape[e]), mesh.modes[e]
    k = ex.num_coeffs(sh, m)
    return ex.eval_modal(sh, m, mesh.coeffs[mesh.coeff_offset[e]: mesh.coeff_offset[e] + k], xi)


def node_xi(shape, P):
    """Our reference coordinates of VTK parametric points P, for the direct and the mirrored
    correspondence (the reader picks the one that makes the element right-handed)."""
    xi = 2 * P - 1
    if shape == shapes.HEX:
        return xi, xi * [1, 1, -1]
    if shape == shapes.TET:
        return xi, xi[:, [1, 0, 2]]
    return xi[:, [1, 2, 0]], xi[:, [0, 2, 1]]


@pytest.mark.parametrize("name", REAL)
def test_real_files_load_with_their_counts(name):
    path, info = real(name)
    s = info["summary"]
    assert list_fields(path) == {k: v["components"] for k, v in s["point_data"].items()}
    mesh = real_mesh(name)
    assert mesh.num_elements == s["n_cells"]
    for t, d in s["cell_types"].items():
        assert int((mesh.shape == SHAPE_OF_TYPE[int(t)]).sum()) == d["count"]
    lo, hi = np.array(s["bounds"][0::2]), np.array(s["bounds"][1::2])
    assert np.all(mesh.vertices.reshape(-1, 3).min(0) >= lo - 1e-12)
    assert np.all(mesh.vertices.reshape(-1, 3).max(0) <= hi + 1e-12)


@pytest.mark.parametrize("name", REAL)
def test_real_files_match_vtks_own_interpolation(name):
    """At every node and at random points of sampled cells, the converted element equals what
    vtk makes of the file (its reader, its cells' interpolation): the solver's polynomial."""
    vtk = need_vtk()
    path, info = real(name)
    field, comp = REAL_FIELD[name]
    mesh = real_mesh(name)
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    ug = reader.GetOutput()
    arr = ug.GetPointData().GetArray(field)
    vals = np.array([arr.GetTuple(i) for i in range(arr.GetNumberOfTuples())])
    vals = np.linalg.norm(vals, axis=1) if comp == "magnitude" else vals[:, 0]
    scale = np.abs(vals).max()
    rng = np.random.default_rng(6)
    worst_node = worst_rand = 0.0
    for e in rng.choice(mesh.num_elements, 12, replace=False):
        cell = ug.GetCell(int(e))
        ids = [cell.GetPointIds().GetId(j) for j in range(cell.GetNumberOfPoints())]
        X = np.array([ug.GetPoint(i) for i in ids])
        sh, gm, g = element_geom(mesh, e)
        P = np.array(cell.GetParametricCoords()).reshape(-1, 3)
        # nodes: no inversion (some of NGSolve's corners have a vanishing Jacobian)
        hits = [xi for xi in node_xi(sh, P) if np.abs(ex.eval_modal(sh, gm, g, xi) - X).max() < 1e-12 * np.ptp(X)]
        assert len(hits) == 1, e
        worst_node = max(worst_node, np.abs(element_eval(mesh, e, hits[0]) - vals[ids]).max())
        for r in random_params(sh, 4, rng):
            w = [0.0] * len(ids)
            x = [0.0] * 3
            cell.EvaluateLocation(vtk.reference(0), list(r), x, w)
            xi1, conv1, _ = ex.invert_map(sh, gm, g, np.array(x)[None])
            assert conv1.all()
            worst_rand = max(worst_rand, abs(element_eval(mesh, e, xi1)[0] - np.dot(w, vals[ids])))
    print(f"{name}: nodes {worst_node / scale:.2e}, random points {worst_rand / scale:.2e} (relative)")
    assert worst_node < 1e-12 * scale and worst_rand < 1e-11 * scale, (worst_node, worst_rand, scale)


def test_ngsolve_ball_volume():
    """The converted geometry encloses the volume NGSolve reports for its order-6 curved mesh."""
    _, info = real("ngsolve_ball_poisson_hex_p6")
    mesh = real_mesh("ngsolve_ball_poisson_hex_p6")
    assert np.all(mesh.geom_modes == 7)
    k = ex.num_coeffs(shapes.HEX, (7, 7, 7))
    G = mesh.geom_coeffs.reshape(-1, k, 3)
    vols = []
    for n in (9, 11):  # det J has degree <= 17 per direction: both rules are exact
        gx, gw = np.polynomial.legendre.leggauss(n)
        P = np.stack(np.meshgrid(gx, gx, gx, indexing="ij"), -1).reshape(-1, 3)
        W = np.einsum("i,j,k->ijk", gw, gw, gw).ravel()
        D = ex.eval_modal_grad(shapes.HEX, (7, 7, 7), np.eye(k), P)  # (S, K, 3)
        J = (G.transpose(0, 2, 1).reshape(-1, k) @ D.transpose(1, 0, 2).reshape(k, -1))
        J = J.reshape(len(G), 3, len(P), 3).transpose(0, 2, 1, 3)  # J[e, s, c, d] = dx_c/dxi_d
        vols.append(float((np.linalg.det(J) * W).sum()))
    print(f"volume {vols[0]!r} (NGSolve {info['volume']!r}, ball {4 * math.pi / 3!r})")
    assert abs(vols[0] - vols[1]) < 1e-13
    # NGSolve's figure comes from its own quadrature rule; the exact ball is 4 pi / 3
    assert abs(vols[0] - info["volume"]) < 2e-7 * info["volume"], vols
    assert abs(vols[0] - 4 * math.pi / 3) < 1e-6, vols


def test_pyfr_straight_cells_are_affine_and_components_checked():
    path, info = real("pyfr_tgv_hexprism_p4_t4")
    mesh = real_mesh("pyfr_tgv_hexprism_p4_t4")
    assert mesh.affine.all()  # PyFR's mesh is straight-sided
    assert mesh.field_name == "|Velocity|"
    with pytest.raises(VtuError, match="component must be 0..2"):
        read_vtu(path, "Velocity", 3)


def test_ngsolve_post_file_agrees_with_vtk_at_every_node():
    """The NGSolve post file (raw appended, UInt32 headers, Int32 connectivity, Float32 points and
    values; meshio's raw-appended parser misread it) loads, and at every node of every cell the
    converted geometry and temperature are what vtk's own reader reads there."""
    vtk = need_vtk()
    from vtk.util.numpy_support import vtk_to_numpy

    path = shared_file("vtu", "ngsolve_post_heat_tetprism_p4.vtu")
    mesh = read_vtu(path, "temperature")
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    ug = reader.GetOutput()
    P = vtk_to_numpy(ug.GetPoints().GetData()).astype(np.float64)
    T = vtk_to_numpy(ug.GetPointData().GetArray("temperature")).astype(np.float64)
    conn = vtk_to_numpy(ug.GetCells().GetConnectivityArray())
    offs = vtk_to_numpy(ug.GetCells().GetOffsetsArray())
    types = vtk_to_numpy(ug.GetCellTypes())
    assert mesh.num_elements == ug.GetNumberOfCells() == 3884
    assert [int(s) for s in mesh.shape] == [SHAPE_OF_TYPE[int(t)] for t in types]
    worst_x = worst_t = 0.0
    for shape in (shapes.TET, shapes.PRISM):
        members = np.flatnonzero(mesh.shape == shape)
        n = int(offs[members[0] + 1] - offs[members[0]])
        ids = np.stack([conn[offs[e]:offs[e + 1]] for e in members])  # (cells, nodes)
        gm, fm = tuple(mesh.geom_modes[members[0]]), tuple(mesh.modes[members[0]])
        kg, kf = ex.num_coeffs(shape, gm), ex.num_coeffs(shape, fm)
        G = np.stack([mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] + kg] for e in members])
        C = np.stack([mesh.coeffs[mesh.coeff_offset[e]:mesh.coeff_offset[e] + kf] for e in members])
        params = vtu.vtk_node_params(shape, vtu_cells.infer_degrees(shape, n))
        # each cell is read directly or mirrored (whichever is right-handed): take the variant whose
        # geometry lands on the nodes, then its field must be the node values
        err_x, err_t = [], []
        for xi in node_xi(shape, params):
            Bg = np.asarray(ex.eval_modal(shape, gm, np.eye(kg), xi))  # (nodes, kg)
            Bf = np.asarray(ex.eval_modal(shape, fm, np.eye(kf), xi))
            err_x.append(np.abs(np.einsum("pk,ekc->epc", Bg, G) - P[ids]).max(axis=(1, 2)))
            err_t.append(np.abs(C @ Bf.T - T[ids]).max(axis=1))
        pick = np.argmin(np.stack(err_x), axis=0)
        worst_x = max(worst_x, float(np.choose(pick, err_x).max()))
        worst_t = max(worst_t, float(np.choose(pick, err_t).max()))
    print(f"NGSolve post file: nodes {worst_x:.2e} (geometry), {worst_t:.2e} (temperature)")
    assert worst_x < 1e-12 and worst_t < 1e-12, (worst_x, worst_t)


# ---------------------------------------------------------------------------------------------
# Malformed input: every failure a VtuError naming the file (and the cell where there is one)

def meshio_file(tmp_path, name="m.vtu", cells=None, points=None, u=None, **kw):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1],
                    [2, 0, 0], [2, 1, 0], [2, 0, 1], [2, 1, 1]], dtype=float) if points is None else points
    cells = cells or [("hexahedron", np.array([[0, 1, 2, 3, 4, 5, 6, 7], [1, 8, 9, 2, 5, 10, 11, 6]]))]
    u = pts[:, 0] + 2 * pts[:, 1] if u is None else u
    path = tmp_path / name
    meshio.write(str(path), meshio.Mesh(pts, cells, point_data={"u": u, "v": np.c_[u, u, u]}), binary=False, **kw)
    return path


def expect_error(path, match, **kw):
    with pytest.raises(VtuError) as info:
        read_vtu(path, **kw)
    assert str(path) in str(info.value) and type(info.value) is VtuError
    assert match in str(info.value), str(info.value)


def test_meshio_written_file_reads(tmp_path):
    path = meshio_file(tmp_path)
    mesh = read_vtu(path, "u")
    assert mesh.num_elements == 2 and mesh.affine.all()
    xi = np.array([[0.3, -0.2, 0.5]])
    for e in range(2):
        sh, gm, g = element_geom(mesh, e)
        x = ex.eval_modal(sh, gm, g, xi)
        assert abs(element_eval(mesh, e, xi)[0] - (x[0, 0] + 2 * x[0, 1])) < 1e-13


def test_malformed_inputs_raise_vtu_error(tmp_path):
    good = meshio_file(tmp_path)
    text = good.read_text()
    expect_error(good, "no point-data field 'w'", field="w")
    expect_error(good, "is a scalar", field="u", component=2)
    expect_error(good, "component must be", field="v", component="x")
    expect_error(tmp_path / "missing.vtu", "cannot read")

    def variant(name, new):
        p = tmp_path / name
        p.write_text(new) if isinstance(new, str) else p.write_bytes(new)
        return p

    expect_error(variant("trunc.vtu", text[: len(text) // 2]), "")
    expect_error(variant("notxml.vtu", "hello"), "not a VTK XML file")
    expect_error(variant("dtd.vtu", '<!DOCTYPE x [<!ENTITY a "b">]>' + text), "DOCTYPE")
    expect_error(variant("polydata.vtu", text.replace('type="UnstructuredGrid"', 'type="PolyData"')), "PolyData")
    expect_error(variant("garbage.vtu", text.replace("1.00000000000e+00", "1.0zz", 1)), "points")
    conn = re.search(r'(Name="connectivity"[^>]*>)([^<]*)<', text)
    expect_error(variant("range.vtu", text.replace(conn.group(0), conn.group(1) + conn.group(2).replace("11", "99") + "<")),
                 "cell 1: point index out of range")
    offs = re.search(r'(Name="offsets"[^>]*>)([^<]*)<', text)
    expect_error(variant("offsets.vtu", text.replace(offs.group(0), offs.group(1) + "8 15<")), "offsets end at 15")
    expect_error(variant("offsets2.vtu", text.replace(offs.group(0), offs.group(1) + "8 8<")), "cell 1: offsets")
    types = re.search(r'(Name="types"[^>]*>)([^<]*)<', text)
    expect_error(variant("pyr.vtu", text.replace(types.group(0), types.group(1) + "12 14<")), "cell 1: VTK_PYRAMID")
    expect_error(variant("t74.vtu", text.replace(types.group(0), types.group(1) + "74 12<")), "cell 0: VTK_LAGRANGE_PYRAMID")
    expect_error(variant("t25.vtu", text.replace(types.group(0), types.group(1) + "12 25<")), "cell 1: VTK cell type 25")
    expect_error(variant("nodes.vtu", text.replace(types.group(0), types.group(1) + "12 71<")),
                 "cell 1: VTK_LAGRANGE_TETRAHEDRON with 8 nodes")

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1],
                    [2, 0, 0], [2, 1, 0], [2, 0, 1], [2, 1, 1]], dtype=float)
    bad = pts.copy()
    bad[10] = np.nan
    expect_error(meshio_file(tmp_path, "nan.vtu", points=bad), "cell 1: node coordinates are NaN")
    u = pts[:, 0].copy()
    u[3] = np.inf
    expect_error(meshio_file(tmp_path, "inf.vtu", u=u), "cell 0: field 'u' is NaN or Inf")
    flat = pts.copy()
    flat[[10, 11], 2] = 0.0  # cell 1 squashed onto z = 0 on one side: Jacobian vanishes there
    expect_error(meshio_file(tmp_path, "degen.vtu", points=flat), "cell 1: degenerate")
    allflat = pts.copy()
    allflat[:, 2] = 0.0
    expect_error(meshio_file(tmp_path, "zero.vtu", points=allflat), "cell 0: degenerate")
    tangled = pts.copy()
    tangled[11] = [-0.5, 1.2, 1.2]  # a corner of cell 1 pushed through the opposite face
    expect_error(meshio_file(tmp_path, "tangled.vtu", points=tangled), "cell 1: inverted or tangled")
    hexes = [("VTK_LAGRANGE_HEXAHEDRON", np.arange(12)[None, :12] % 12)]
    expect_error(meshio_file(tmp_path, "count.vtu", cells=hexes), "cell 0: VTK_LAGRANGE_HEXAHEDRON with 12 nodes")


# ---------------------------------------------------------------------------------------------
# Hostile input: every refusal a VtuError naming the file, made before the harm (the time and
# memory a bomb or a lying header would take)

HOSTILE = {"raw-zlib-uint32": dict(mode="raw", compressor="zlib", header=32),
           "appended-zlib-uint64": dict(mode="appended", compressor="zlib", header=64),
           "binary-zlib-uint32": dict(mode="binary", compressor="zlib", header=32),
           "raw-lzma-uint64": dict(mode="raw", compressor="lzma", header=64),
           "binary-lzma-uint64": dict(mode="binary", compressor="lzma", header=64)}


@pytest.fixture(scope="module")
def hostile_docs(vm, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("hostile_sources")
    return {k: vm.Doc(vm.write_vtk_lagrange(tmp / f"{k}.vtu", **kw).read_bytes()) for k, kw in HOSTILE.items()}


def zlib_zeros(mib):
    """A valid zlib stream of mib MiB of zeros, made in milliseconds: after a full flush every
    MiB compresses to the same bytes, so the middle is one piece repeated."""
    z = bytes(1 << 20)
    c = zlib.compressobj(9)
    first = c.compress(z) + c.flush(zlib.Z_FULL_FLUSH)
    middle = c.compress(z) + c.flush(zlib.Z_FULL_FLUSH)
    end = c.flush()[:-4]  # the final block without its checksum; Adler-32 of n zeros is (n % 65521) << 16 | 1
    return first + middle * (mib - 1) + end + ((((mib << 20) % 65521) << 16) | 1).to_bytes(4, "big")


@pytest.fixture(scope="module")
def bombs():
    out = {"zlib": zlib_zeros(3 << 10), "lzma": lzma.compress(bytes(256 << 20), preset=0)}
    assert 3e6 < len(out["zlib"]) < 3.3e6 and len(out["lzma"]) < 50_000
    assert zlib.decompress(zlib_zeros(3)) == bytes(3 << 20)
    return out


def points_block(doc, header, payload):
    """The file with piece 0's points replaced by a block of this header and payload, in the
    file's own encoding."""
    pts = doc.find(0, "Points")
    blk = doc.block(pts)
    blk.header, blk.payload = header, payload
    return doc.build((), {pts.index: doc.encode_block(blk)})


def refused(path, data, pattern, seconds=2.0):
    """data, written to path, is refused by read_vtu within `seconds` with a VtuError that names
    the file and matches pattern."""
    path.write_bytes(data)
    t0 = time.perf_counter()
    with pytest.raises(VtuError) as info:
        read_vtu(path, "g")
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    assert type(info.value) is VtuError and msg.startswith(f"{path}: ") and ": unreadable (" not in msg, msg
    assert re.search(pattern, msg), msg
    assert elapsed < seconds, (elapsed, msg)
    return info.value


@pytest.mark.parametrize("enc", ["raw-zlib-uint32", "appended-zlib-uint64", "binary-zlib-uint32"])
def test_block_flood_is_refused_before_inflating(hostile_docs, tmp_path, enc):
    """800 blocks of 1 MiB of zeros (meshio inflated them in quadratic time, past 120 s): the
    header declares 800 MiB where the piece's points take a few KiB."""
    doc = hostile_docs[enc]
    block = zlib.compress(bytes(1 << 20), 9)
    data = points_block(doc, [800, 1 << 20, 0] + [len(block)] * 800, block * 800)
    assert len(data) < 2 << 20
    need = doc.piece_attr(0, "NumberOfPoints") * 24
    refused(tmp_path / "flood.vtu", data, rf"piece 0 points: its data header declares {800 << 20} bytes, the "
            rf"piece needs {need} \(\d+ points x 3: \d+ x Float64\)", seconds=0.5)


def test_huge_point_count_is_refused_by_the_memory_limit(hostile_docs, tmp_path):
    """10^9 points and a block header that agrees (24 GB in one block): the memory limit refuses
    the array before its header is even read."""
    doc = hostile_docs["raw-lzma-uint64"]
    pts = doc.find(0, "Points")
    blk = doc.block(pts)
    blk.header = [1, 24 * 10**9, 24 * 10**9, len(blk.payload)]
    data = doc.build([doc.attr_edit(doc.pieces[0], "NumberOfPoints", 10**9)], {pts.index: doc.encode_block(blk)})
    with limits.using(limits.ResourceLimits(max_memory=4 << 30)):
        err = refused(tmp_path / "huge.vtu", data, r"piece 0 points would need 22.4 GiB, more than the memory "
                      r"limit of 4 GiB \(raise it with --max-memory or HOVR_MAX_MEMORY\)", seconds=0.5)
    assert isinstance(err.__cause__, limits.ResourceLimitError)


@pytest.mark.parametrize("enc", list(HOSTILE))
def test_bomb_in_one_block_stops_at_the_declared_size(hostile_docs, bombs, tmp_path, enc):
    """The header tells the piece's truth (one block of the points' size) but the block inflates
    to 3 GiB (zlib, 3 MB) or 256 MiB (lzma, 39 KB): inflation stops one byte past the size."""
    doc = hostile_docs[enc]
    bomb = bombs[doc.compressor]
    need = doc.piece_attr(0, "NumberOfPoints") * 24
    refused(tmp_path / "bomb.vtu", points_block(doc, [1, need, need, len(bomb)], bomb),
            rf"piece 0 points block 0: inflates to more than the {need} bytes it declares or needs")


def test_damaged_compressed_data_is_diagnosed(hostile_docs, tmp_path):
    p = tmp_path / "damaged.vtu"
    doc = hostile_docs["raw-zlib-uint32"]
    pts = doc.find(0, "Points")
    head, payload = doc.block(pts).header, doc.block(pts).payload
    assert head[0] == 1  # one block: [1, block size, its size, compressed size]
    refused(p, points_block(doc, head[:3] + [head[3] // 2], payload[:head[3] // 2]),
            r"piece 0 points block 0: zlib stream is truncated")
    refused(p, points_block(doc, head[:3] + [10**9], payload), r"piece 0 points: its compressed blocks "
            r"\(1000000000 bytes\) run past the end of the appended data \(\d+ bytes left\)")
    # two blocks adding up to the points' size, the first inflating to less than its header says
    raw = doc.values(pts).tobytes()
    first, second = zlib.compress(raw[:4000]), zlib.compress(raw[4096:])
    refused(p, points_block(doc, [2, 4096, len(raw) - 4096, len(first), len(second)], first + second),
            r"piece 0 points block 0: inflates to 4000 bytes, its header says 4096")
    refused(p, doc.build([doc.attr_edit(doc.vtkfile_tag, "compressor", "vtkLZ4DataCompressor")]),
            r"compressor 'vtkLZ4DataCompressor' is not supported")
    for offset in (-1, 10**15):
        refused(p, doc.build([doc.attr_edit(pts.tag, "offset", offset)]),
                rf"piece 0 points: offset {offset} is outside the appended data \(\d+ bytes\)")
    refused(p, doc.raw[:doc.app_start + 100], r"truncated \(<AppendedData> has no closing tag\)")
    inline = hostile_docs["binary-zlib-uint32"]
    head, payload = inline.block(inline.find(0, "Points")).header, inline.block(inline.find(0, "Points")).payload
    refused(p, points_block(inline, head[:3] + [head[3] + 3000], payload),
            r"piece 0 points: its compressed blocks \(\d+ bytes\) run past the end of its inline data")


@pytest.mark.skipif(not hasattr(os, "mkfifo") or not os.path.exists("/dev/zero"),
                    reason="needs POSIX FIFOs and /dev/zero")
def test_fifo_device_and_folder_paths_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.vtu"
    os.mkfifo(fifo)
    folder = tmp_path / "folder.vtu"
    folder.mkdir()
    paths = {fifo: "a FIFO (named pipe)", Path("/dev/zero"): "a device", folder: "a folder"}
    got = {}

    def attempt():  # in a thread: a reader that opened the FIFO for reading would block here
        for path in paths:
            for fn in (list_fields, read_vtu):
                try:
                    fn(path)
                    got[path, fn.__name__] = "loaded"
                except VtuError as exc:
                    got[path, fn.__name__] = str(exc)

    t = threading.Thread(target=attempt, daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive(), "reading a FIFO or /dev/zero blocked"
    for path, what in paths.items():
        for fn in ("list_fields", "read_vtu"):
            assert got[path, fn] == f"{path}: VTU file {path} is {what}, not a regular file; refused", got
