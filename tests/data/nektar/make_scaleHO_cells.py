"""Writes the cells files of Nektar++'s scaleHO (../shared/data/nektar/scaleHO.xml, 23,848 prisms
and tetrahedra, some curved) for tests/engine/test_entry_regressions.py: for each regression ray
of issue 36, the geometry of the cells whose boxes, grown by PAD, the ray crosses, as the
Nektar++ reader turns them into modal expansions (engine/expansions).

- scaleHO_cells.npz: the ray passes an edge where four curved prisms meet, through slivers of
  three of them.
- scaleHO_grazing_cells.npz: the ray runs nearly along the face affine prisms 19785 and 20193
  share (it crosses at 0.02 reference units per unit length), where float32's two clips of the
  face lie 3.5e-5 apart.

    python tests/data/nektar/make_scaleHO_cells.py
"""
from pathlib import Path

PAD = 0.01
RAYS = {
    # the audit's oblique camera at 1920x1080, pixel (916, 481) (bench.commits views)
    "scaleHO_cells.npz": ([2.5096130475638754, -1.6076904380511008, 1.5567291332947129],
                          [-0.7090806396431651, 0.5396405528753079, -0.4538642089608653]),
    # a random ray of scripts.watertight's view 0 (bench/results/h200/issue36/watertight-754531d.*)
    "scaleHO_grazing_cells.npz": ([-1.8913803867747045, -1.5652275249487082, 0.8083787974200003],
                                  [0.8445091565253693, 0.4568572689816162, -0.27943822273173047]),
}

if __name__ == "__main__":
    import sys

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here.parents[2]))
    from hovr_blender.io.nektar import read_nektar
    from tests.data.ray_cells import cells_along, save_cells

    mesh = read_nektar(str(here.parents[3] / "shared" / "data" / "nektar" / "scaleHO.xml"))
    for name, (o, d) in RAYS.items():
        cells = cells_along(mesh, o, d, PAD)
        save_cells(here / name, mesh, cells, affine=mesh.affine[cells])
        print(name, len(cells), "cells")
