"""Writes ngsolve_ball_cells.npz: the geometry of a few cells of NGSolve's ball
(../shared/data/vtu/ngsolve_ball_poisson_hex_p6.vtu, 512 curved order-6 hexahedra), as the
VTU reader turns them into modal expansions (engine/expansions), for the watertightness
regressions in tests/engine/test_watertight_real.py. The cells are those the regression rays
cross where the traversal lost length (and, for issue 36's rays, every cell whose box they
cross); several meet the sphere along an edge where their Jacobian vanishes.

    python tests/data/vtu/make_ngsolve_ball_cells.py
"""
from pathlib import Path

import numpy as np

CELLS = [4, 5, 6, 7, 15, 63, 199, 263, 391, 447, 455,
         # issue 36: the cells whose boxes the entry regressions' rays cross
         252, 253, 309, 317, 318, 351, 358, 359, 365, 366, 367, 371, 372, 373, 374, 381, 382, 402, 403, 410, 411,
         415, 418, 419, 422, 423, 426, 430, 431, 434, 435, 436, 437, 438, 439, 442, 443, 444, 446, 450, 451, 458,
         459, 466, 467, 474, 475, 479, 487, 490, 494, 495, 498, 502, 503, 506, 511,
         408, 409, 456, 457, 464, 465, 472]

if __name__ == "__main__":
    import sys

    here = Path(__file__).resolve().parent
    sys.path.insert(0, str(here.parents[2]))
    from hovr_blender.engine import expansions as ex
    from hovr_blender.io.vtu import read_vtu

    mesh = read_vtu(here.parents[3] / "shared" / "data" / "vtu" / "ngsolve_ball_poisson_hex_p6.vtu", "u")
    geom = [mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e])]
            for e in CELLS]
    np.savez_compressed(here / "ngsolve_ball_cells.npz", cells=np.array(CELLS), shape=mesh.shape[CELLS],
                        geom_modes=mesh.geom_modes[CELLS], geom=np.stack(geom))
