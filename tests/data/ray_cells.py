"""The cells files of tests/engine/test_entry_regressions.py (written by the make_*_cells.py
beside the data): the cells whose boxes, grown by a pad, a ray crosses, and their geometry as the
readers turn it into modal expansions (engine/expansions), padded to one length."""
import numpy as np


def cells_along(mesh, o, d, pad: float) -> np.ndarray:
    """The cells whose vertex boxes, grown by `pad`, the ray o + t d (t >= 0) crosses."""
    o, d = np.asarray(o, float), np.asarray(d, float)
    lo, hi = mesh.vertices.min(axis=1) - pad, mesh.vertices.max(axis=1) + pad
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    t0, t1 = np.nanmax(np.minimum(ta, tb), axis=1), np.nanmin(np.maximum(ta, tb), axis=1)
    return np.nonzero(t1 >= np.maximum(t0, 0.0))[0]


def save_cells(path, mesh, cells, **extra):
    """cells' shapes, geometry modes and geometry coefficients (zero-padded) into `path` (.npz),
    with `extra` arrays after them."""
    from hovr_blender.engine import expansions as ex

    sizes = [ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e]) for e in cells]
    geom = np.zeros((len(cells), max(sizes), 3))
    for k, (e, n) in enumerate(zip(cells, sizes)):
        geom[k, :n] = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + n]
    np.savez_compressed(path, cells=cells, shape=mesh.shape[cells], geom_modes=mesh.geom_modes[cells], geom=geom,
                        **extra)
