"""Writes scaleHO_cells.npz: the geometry of the cells of Nektar++'s scaleHO
(../shared/data/nektar/scaleHO.xml, 23,848 prisms and tetrahedra, some curved) whose boxes, grown
by PAD, a regression ray of issue 36 crosses, as the Nektar++ reader turns them into modal
expansions (engine/expansions), for tests/engine/test_watertight_real.py. The ray passes an edge
where four curved prisms meet, through slivers of three of them.

    python tests/data/nektar/make_scaleHO_cells.py
"""
from pathlib import Path

import numpy as np

PAD = 0.01
# the audit's oblique camera at 1920x1080, pixel (916, 481) (bench.commits views)
RAY = ([2.5096130475638754, -1.6076904380511008, 1.5567291332947129],
       [-0.7090806396431651, 0.5396405528753079, -0.4538642089608653])

if __name__ == "__main__":
    import sys

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here.parents[2]))
    from hovr_blender.engine import expansions as ex
    from hovr_blender.io.nektar import read_nektar

    mesh = read_nektar(str(here.parents[3] / "shared" / "data" / "nektar" / "scaleHO.xml"))
    o, d = (np.asarray(v, float) for v in RAY)
    lo, hi = mesh.vertices.min(axis=1) - PAD, mesh.vertices.max(axis=1) + PAD
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    t0, t1 = np.nanmax(np.minimum(ta, tb), axis=1), np.nanmin(np.maximum(ta, tb), axis=1)
    cells = np.nonzero(t1 >= np.maximum(t0, 0.0))[0]
    n = max(ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e]) for e in cells)
    geom = np.zeros((len(cells), n, 3))
    for k, e in enumerate(cells):
        g = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e])]
        geom[k, :len(g)] = g
    np.savez_compressed(here / "scaleHO_cells.npz", cells=cells, shape=mesh.shape[cells], geom_modes=mesh.geom_modes[cells],
                        geom=geom, affine=mesh.affine[cells])
    print(len(cells), "cells")
