"""Writes ngsolve_post_vertex_cells.npz: the geometry of the cells of NGSolve's heat post-processing
mesh (../shared/data/vtu/ngsolve_post_heat_tetprism_p4.vtu, curved order-4 tetrahedra and prisms)
whose boxes, grown by PAD, the vertex ray of tests/engine/test_entry_regressions.py crosses, as the
VTU reader turns them into modal expansions (engine/expansions). The ray is scripts.watertight's,
aimed at a vertex that six cells share; on the GPU in float32 its walk left curved cell 2622 there.

    python tests/data/vtu/make_ngsolve_post_cells.py
"""
from pathlib import Path

PAD = 0.01
RAY = ([-2.697116608965861, 1.6554049695974273, -0.9676827644375097],
       [0.8826848651231776, -0.3786950178920877, 0.27831189752899377])

if __name__ == "__main__":
    import sys

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here.parents[2]))
    from hovr_blender.io.vtu import read_vtu
    from tests.data.ray_cells import cells_along, save_cells

    mesh = read_vtu(here.parents[3] / "shared" / "data" / "vtu" / "ngsolve_post_heat_tetprism_p4.vtu", "temperature")
    cells = cells_along(mesh, *RAY, PAD)
    save_cells(here / "ngsolve_post_vertex_cells.npz", mesh, cells)
    print(len(cells), "cells")
