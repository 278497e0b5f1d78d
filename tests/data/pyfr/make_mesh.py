"""A small curved mixed mesh for PyFR, made by gmsh: a rectangle [0,1] x [0,0.5] and the half
disc above it (centre (0.5, 0.5), radius 0.5), extruded to height 1. The lower half is extruded
in two layers: the rectangle's quadrilaterals give hexahedra, the half disc's triangles prisms; the upper half is
meshed with tetrahedra, and gmsh joins them to the hexahedra's quadrilateral faces with
pyramids. Second order, so the arcs are curved."""
import sys

import gmsh

size = float(sys.argv[1]) if len(sys.argv) > 1 else 0.3
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("shell")
geo = gmsh.model.geo
p = {k: geo.addPoint(x, y, 0, size) for k, (x, y) in
     {"a": (0, 0), "b": (1, 0), "c": (1, 0.5), "d": (0, 0.5), "m": (0.5, 0.5)}.items()}
l = {"ab": geo.addLine(p["a"], p["b"]), "bc": geo.addLine(p["b"], p["c"]),
     "cd": geo.addLine(p["c"], p["d"]), "da": geo.addLine(p["d"], p["a"])}
top = geo.addPoint(0.5, 1.0, 0, size)
l["arc1"] = geo.addCircleArc(p["c"], p["m"], top)
l["arc2"] = geo.addCircleArc(top, p["m"], p["d"])
sa = geo.addPlaneSurface([geo.addCurveLoop([l["ab"], l["bc"], l["cd"], l["da"]])])
sb = geo.addPlaneSurface([geo.addCurveLoop([-l["cd"], l["arc1"], l["arc2"]])])
for k, n in (("ab", 4), ("cd", 4), ("bc", 3), ("da", 3)):
    geo.mesh.setTransfiniteCurve(l[k], n)
geo.mesh.setTransfiniteSurface(sa)
geo.mesh.setRecombine(2, sa)
low = geo.extrude([(2, sa), (2, sb)], 0, 0, 0.5, numElements=[2], recombine=True)
tops = [low[0], low[6]]  # the extruded copies of sa and sb
high = geo.extrude(tops, 0, 0, 0.5)
geo.synchronize()
vols = [t for d, t in gmsh.model.getEntities(3)]
# the upper half: tetrahedra (an unstructured volume next to the quadrilaterals: pyramids)
gmsh.model.addPhysicalGroup(3, vols, name="fluid")
gmsh.model.addPhysicalGroup(2, [t for d, t in gmsh.model.getBoundary([(3, v) for v in vols], oriented=False)],
                            name="wall")
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.model.mesh.generate(3)
gmsh.model.mesh.setOrder(2)
types, tags, _ = gmsh.model.mesh.getElements(3)
for t, tg in zip(types, tags):
    print(gmsh.model.mesh.getElementProperties(t)[0], len(tg))
gmsh.write("shell.msh")
gmsh.finalize()
