"""Writes ngsolve_post_vertex_cells.npz: the geometry of the cells of NGSolve's heat post-processing
mesh (../shared/data/vtu/ngsolve_post_heat_tetprism_p4.vtu, curved order-4 tetrahedra and prisms)
whose boxes, grown by PAD, the vertex ray of tests/engine/test_entry_regressions.py crosses, as the
VTU reader turns them into modal expansions (engine/expansions). The ray is scripts.watertight's,
aimed at a vertex that six cells share; on the GPU in float32 its walk left curved cell 2622 there.

    python tests/data/vtu/make_ngsolve_post_cells.py
"""
from pathlib import Path

import numpy as np

PAD = 0.01
RAY = ([-2.697116608965861, 1.6554049695974273, -0.9676827644375097],
       [0.8826848651231776, -0.3786950178920877, 0.27831189752899377])

if __name__ == "__main__":
    import sys

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here.parents[2]))
    from hovr_blender.engine import expansions as ex
    from hovr_blender.io.vtu import read_vtu

    mesh = read_vtu(here.parents[3] / "shared" / "data" / "vtu" / "ngsolve_post_heat_tetprism_p4.vtu", "temperature")
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
    np.savez_compressed(here / "ngsolve_post_vertex_cells.npz", cells=cells, shape=mesh.shape[cells],
                        geom_modes=mesh.geom_modes[cells], geom=geom)
    print(len(cells), "cells")
