"""Writes the MFEM cases of tests/data/mfem with MFEM itself (PyMFEM 4.10; MANIFEST.md): every
mesh and GridFunction here is MFEM's own Mesh::Print and GridFunction::Save output, the .vtu files
its ParaViewDataCollection's, and the .npz files hold MFEM's own values, MFEM reading back the
files it wrote as GLVis does (Mesh(file, 1, 0, false), GridFunction(mesh, file)) and evaluating
them at points of every element.

    python make_cases.py PATH/TO/mfem/data    (MFEM's data folder: fichera-mixed.mesh, tinyzoo-3d.mesh)

Cases:
- fichera: MFEM's mixed Fichera corner (tetrahedra, hexahedra, prisms) refined once, its nodes of
  order 2 bent by a smooth map (MFEM mesh v1.0 with curved nodes); fichera-u.gf an H1 field of
  order 3, fichera-w.gf an L2 field of order 2, fichera-vel.gf a vector H1 field of order 2
  (VDim 3, by vector dimension); fichera_lagrange_p3.vtu the same mesh and u, w exported by
  ParaViewDataCollection at high order (levels of detail 3).
- fichera-part0: the first of two parts of the same mesh from MFEM's MeshPartitioner (MFEM mesh
  v1.2, a parallel rank's piece, curved) and u projected on it (fichera-part0-u.gf).
- zoo: MFEM's tiny zoo (one hexahedron, prism, pyramid, tetrahedron) refined once, nodes of order
  2 in Bergot's pyramid space (H1_3D_P2_Pyr0), bent; zoo-u.gf H1_3D_P2_Pyr0, zoo-w.gf L2_3D_P2_Pyr0;
  zoo-sets.mesh the same mesh with named attribute sets (MFEM mesh v1.3).
- var: the Fichera corner as a nonconforming mesh (EnsureNCMesh: MFEM NC mesh v1.0) carrying an H1
  field of a different order per element (1..4, VAR_ORDERS), saved raised to order 4 (var.gf: MFEM's
  interpolation of the variable-order field at the order-4 nodes, as ProlongateToMaxOrder does);
  var-raw.gf as GridFunction::Save writes the variable-order field itself (header H1_3D_P1, each
  element at its own order: MFEM cannot read it back); var_lagrange_p4.vtu ParaViewDataCollection's
  export of the variable-order field (levels of detail 4).
"""
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

import mfem.ser as mfem

HERE = Path(__file__).resolve().parent
POINTS_PER_ELEMENT = 4
KEEP = []  # MFEM objects a mesh or GridFunction points to: Python must not free them


def var_order(e):
    return 1 + (7 * e) % 4


class Bend(mfem.VectorPyCoefficient):
    """A smooth map of the corner onto a curved body (the elements' faces become curved)."""

    def EvalValue(self, x):
        return [x[0] + 0.08 * np.sin(1.7 * x[1] + 0.3) * (1 + 0.5 * x[2]),
                x[1] + 0.06 * np.cos(1.3 * x[0] - 0.4 * x[2]),
                x[2] + 0.05 * np.sin(1.1 * x[0] + 0.9 * x[1])]


class U(mfem.PyCoefficient):
    def EvalValue(self, x):
        return np.sin(2.1 * x[0] + 0.3) * np.cos(1.7 * x[1] - 0.2) + 0.6 * x[2] ** 3 + x[0] * x[1] * x[2]


class W(mfem.PyCoefficient):
    def EvalValue(self, x):
        return np.exp(-2.0 * ((x[0] - 0.3) ** 2 + (x[1] + 0.2) ** 2 + (x[2] - 0.4) ** 2))


class Vel(mfem.VectorPyCoefficient):
    def EvalValue(self, x):
        return [np.sin(1.5 * x[1]) + x[2], x[0] ** 2 - 0.5 * x[2], np.cos(x[0] * x[1])]


def bend(mesh, nodes_fec):
    """Curved nodes: `nodes_fec`'s space of the mesh, the vertices moved by Bend."""
    fes = mfem.FiniteElementSpace(mesh, nodes_fec, 3, mfem.Ordering.byVDIM)
    KEEP.extend([nodes_fec, fes])
    mesh.SetNodalFESpace(fes)
    nodes = mesh.GetNodes()
    moved = mfem.GridFunction(nodes.FESpace())
    moved.ProjectCoefficient(Bend(3))
    nodes.Assign(moved)


def field(mesh, fec, coefficient, vdim=1, ordering=mfem.Ordering.byNODES):
    fes = mfem.FiniteElementSpace(mesh, fec, vdim, ordering)
    KEEP.extend([fec, fes, coefficient])
    gf = mfem.GridFunction(fes)
    gf.ProjectCoefficient(coefficient)
    return fes, gf


def reference(mesh_file, gf_files, out, seed):
    """MFEM's values of each GridFunction, read back as GLVis reads them, at random points of
    every element: element, reference point, physical point, value (per file)."""
    mesh = mfem.Mesh(str(mesh_file), 1, 0, False)
    rng = np.random.default_rng(seed)
    gfs = [mfem.GridFunction(mesh, str(f)) for f in gf_files]
    E, X, XP = [], [], []
    values = {Path(f).stem: [] for f in gf_files}
    for e in range(mesh.GetNE()):
        geom = mesh.GetElementGeometry(e)
        T = mesh.GetElementTransformation(e)
        for _ in range(POINTS_PER_ELEMENT):
            while True:
                r = rng.uniform(0.01, 0.99, 3)
                if geom == mfem.Geometry.TETRAHEDRON and r.sum() > 0.99:
                    continue
                if geom == mfem.Geometry.PRISM and r[0] + r[1] > 0.99:
                    continue
                if geom == mfem.Geometry.PYRAMID and max(r[0], r[1]) + r[2] > 0.99:
                    continue
                break
            ip = mfem.IntegrationPoint()
            ip.Set3(*r)
            T.SetIntPoint(ip)
            E.append(e)
            X.append(r)
            XP.append(np.array(T.Transform(ip), dtype=float))
            for f, gf in zip(gf_files, gfs):
                vdim = gf.VectorDim()
                if vdim == 1:
                    values[Path(f).stem].append([gf.GetValue(e, ip)])
                else:
                    v = mfem.Vector(vdim)
                    gf.GetVectorValue(e, ip, v)
                    values[Path(f).stem].append(v.GetDataArray().copy())
    np.savez_compressed(out, element=np.array(E), X=np.array(X), x=np.array(XP),
                        geom=np.array([mesh.GetElementGeometry(e) for e in range(mesh.GetNE())]),
                        **{k: np.array(v) for k, v in values.items()})


def paraview(mesh, name, fields, lod, out):
    with tempfile.TemporaryDirectory() as tmp:
        dc = mfem.ParaViewDataCollection(name, mesh)
        dc.SetPrefixPath(tmp)
        dc.SetHighOrderOutput(True)
        dc.SetLevelsOfDetail(lod)
        dc.SetDataFormat(mfem.VTKFormat_BINARY)
        dc.SetCompression(True)
        for key, gf in fields.items():
            dc.RegisterField(key, gf)
        dc.SetCycle(0)
        dc.SetTime(0.0)
        dc.Save()
        shutil.copy(Path(tmp) / name / "Cycle000000" / "proc000000.vtu", out)


def fichera(data):
    mesh = mfem.Mesh(str(Path(data) / "fichera-mixed.mesh"), 1, 0, False)
    mesh.UniformRefinement()
    bend(mesh, mfem.H1_FECollection(2, 3))
    mesh.Print(str(HERE / "fichera.mesh"))
    _, u = field(mesh, mfem.H1_FECollection(3, 3), U())
    _, w = field(mesh, mfem.L2_FECollection(2, 3), W())
    _, vel = field(mesh, mfem.H1_FECollection(2, 3), Vel(3), 3, mfem.Ordering.byVDIM)
    for name, gf in (("fichera-u", u), ("fichera-w", w), ("fichera-vel", vel)):
        gf.Save(str(HERE / f"{name}.gf"))
    paraview(mesh, "fichera", {"u": u, "w": w}, 3, HERE / "fichera_lagrange_p3.vtu")
    reference(HERE / "fichera.mesh", [HERE / f"fichera-{k}.gf" for k in ("u", "w", "vel")], HERE / "fichera-values.npz", 1)
    # a parallel rank's piece (MFEM mesh v1.2) of the same mesh and u
    # two parts by the elements' centres (MFEM's METIS partitioner is not in the PyMFEM wheel)
    centres = [np.mean([mesh.GetVertexArray(v) for v in mesh.GetElementVertices(e)], axis=0)
               for e in range(mesh.GetNE())]
    split = mfem.intArray([int(c[0] + 0.3 * c[1] > 0.0) for c in centres])
    KEEP.append(split)
    parts = mfem.MeshPartitioner(mesh, 2, split.GetData())
    part = mfem.MeshPart()
    parts.ExtractPart(0, part)
    part.Print(str(HERE / "fichera-part0.mesh"))
    # a field on the piece: MFEM reads the piece back and projects u's function on it (PyMFEM 4.10
    # does not wrap the unique_ptr MeshPartitioner::ExtractGridFunction returns)
    piece = mfem.Mesh(str(HERE / "fichera-part0.mesh"), 1, 0, False)
    KEEP.append(piece)
    _, lu = field(piece, mfem.H1_FECollection(3, 3), U())
    lu.Save(str(HERE / "fichera-part0-u.gf"))
    reference(HERE / "fichera-part0.mesh", [HERE / "fichera-part0-u.gf"], HERE / "fichera-part0-values.npz", 2)


def zoo(data):
    mesh = mfem.Mesh(str(Path(data) / "tinyzoo-3d.mesh"), 1, 0, False)
    mesh.UniformRefinement()
    bergot = mfem.H1_FECollection(2, 3, mfem.BasisType.GaussLobatto, 0)
    bend(mesh, bergot)
    mesh.Print(str(HERE / "zoo.mesh"))
    # the same mesh with named attribute sets: MFEM mesh v1.3
    mesh.attribute_sets.SetAttributeSet("hot corner", mfem.intArray([1]))
    mesh.bdr_attribute_sets.SetAttributeSet("walls", mfem.intArray([1]))
    mesh.Print(str(HERE / "zoo-sets.mesh"))
    _, u = field(mesh, mfem.H1_FECollection(2, 3, mfem.BasisType.GaussLobatto, 0), U())
    _, w = field(mesh, mfem.L2_FECollection(2, 3, mfem.BasisType.GaussLegendre, 0, 0), W())
    u.Save(str(HERE / "zoo-u.gf"))
    w.Save(str(HERE / "zoo-w.gf"))
    reference(HERE / "zoo.mesh", [HERE / "zoo-u.gf", HERE / "zoo-w.gf"], HERE / "zoo-values.npz", 3)


def var(data):
    mesh = mfem.Mesh(str(Path(data) / "fichera-mixed.mesh"), 1, 0, False)
    mesh.EnsureNCMesh()
    bend(mesh, mfem.H1_FECollection(2, 3))
    mesh.Print(str(HERE / "var.mesh"))
    fec = mfem.H1_FECollection(1, 3)
    fes = mfem.FiniteElementSpace(mesh, fec)
    KEEP.extend([fec, fes])
    for e in range(mesh.GetNE()):
        fes.SetElementOrder(e, var_order(e))
    fes.Update(False)
    x = mfem.GridFunction(fes)
    x.ProjectCoefficient(U())
    # a member of the conforming space: its true DOFs, prolongated (an interface between orders
    # takes the lower order's trace there; the projection alone left the higher order's)
    true_dofs = mfem.Vector(fes.GetTrueVSize())
    x.GetTrueDofs(true_dofs)
    x.SetFromTrueDofs(true_dofs)
    orders = [fes.GetElementOrder(e) for e in range(mesh.GetNE())]
    top = max(orders)
    # the field raised to its largest order: MFEM interpolates it at the order-4 nodes of every
    # element, which holds each element's polynomial exactly (GridFunction::ProlongateToMaxOrder's
    # result; PyMFEM 4.10 does not wrap the unique_ptr that returns)
    _, raised = field(mesh, mfem.H1_FECollection(top, 3), mfem.GridFunctionCoefficient(x))
    raised.Save(str(HERE / "var.gf"))
    x.Save(str(HERE / "var-raw.gf"))
    (HERE / "var-orders.json").write_text(json.dumps({"orders": orders, "max_order": top,
                                                      "by": "FiniteElementSpace::GetElementOrder"}) + "\n")
    paraview(mesh, "var", {"u": x}, top, HERE / "var_lagrange_p4.vtu")
    # MFEM's values of the variable-order field itself, at points (it cannot be read back)
    rng = np.random.default_rng(4)
    E, X, V = [], [], []
    for e in range(mesh.GetNE()):
        for _ in range(POINTS_PER_ELEMENT):
            r = rng.uniform(0.01, 0.3, 3)
            ip = mfem.IntegrationPoint()
            ip.Set3(*r)
            E.append(e)
            X.append(r)
            V.append(x.GetValue(e, ip))
    np.savez_compressed(HERE / "var-values.npz", element=np.array(E), X=np.array(X), u=np.array(V),
                        geom=np.array([mesh.GetElementGeometry(e) for e in range(mesh.GetNE())]))


if __name__ == "__main__":
    folder = sys.argv[1]
    fichera(folder)
    zoo(folder)
    var(folder)
    for p in sorted(HERE.iterdir()):
        if p.suffix != ".py":
            print(f"{p.name:28s} {os.path.getsize(p):8d}")
