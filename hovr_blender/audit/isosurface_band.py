"""The tangency band of an isosurface (render contract §7, docs/methods.md "Near tangency") and
the check of a render against it on the sphere scene (scenes.ball_mesh), where every ray's
exact answer is known.

Along a ray that passes close to tangent to the level set f = c, phi(t) = f(x(t)) - c has its
extremum phi* = |grad f| delta at the closest approach t* (delta: the signed distance of that
point from the surface, > 0 on the side the ray stays on; to second order in delta). The
renderer knows phi along a segment to within eps (level_rounding: its arithmetic, the samples'
and the located points' rounding, a curved interpolant's tail), so it meets the surface exactly
where the exact ray does, except where |phi*| <= 2 eps: a touch is decided on the series' own
rounding (<= eps) and the computed extremum is within eps of the exact one. In distance:

    |delta| <= eta = 2 eps / |grad f| + 4 u (|o| + |t*|)

the last term the float rounding of the ray itself (u the precision's epsilon). Outside the
band a ray that misses draws nothing, and one that crosses meets the surface at each crossing,
the first at its exact depth within

    2 eps / (|grad f| |n . d|) + STRETCH_RTOL (|t| + chord) + 4 u |t|

(|n . d| the cosine between the ray and the normal there: a root moved by eps; a crossing in the
rounding gap between two elements' segments is met at the later one's start).
"""
from __future__ import annotations

import numpy as np

from ..engine.kernels import isosurface, tolerances


def precision_eps(precision: str) -> float:
    """The kernels' epsilon of `precision` (tolerances.ROOT_EPS)."""
    return tolerances.ROOT_EPS_FLOAT64 if precision == "float64" else tolerances.ROOT_EPS


def map_rounding(renderer, precision: str) -> float:
    """How far the renderer may place a point of a curved element, by the rounding of its map
    (MeshArgs.geo_err; a pyramid's x = G / w^2 by geo_err / w^2, taken at w >= 1/2): the
    largest curved element's; 0 on an affine mesh. The same move of a curved boundary face."""
    from ..engine import shapes

    m = renderer.mesh_args(precision)
    curved = m.affine.numpy() == 0
    if not curved.any():
        return 0.0
    w2 = np.where(m.shape.numpy() == shapes.PYR, 0.25, 1.0)
    return float((m.geo_err.numpy() / w2)[curved].max())


def level_rounding(renderer, precision: str, level: float, grad: float, map_error: float = 0.0) -> float:
    """eps: how far the renderer's f - c along a segment can be from the exact one, in the field's
    own units (a transfer function whose frame is the identity), from the engine's own rounding
    bounds: the series' rounding ROUNDING_FACTOR u S (S = 2 (max |f| + |c|) bounds a segment's
    sum |p_k|), the samples' rounding (MeshArgs.field_err), a curved interpolant's tail
    (CURVED_TAIL_RTOL S), and the sample points' place: a point located in a curved element is
    off by the map's rounding (MeshArgs.geo_err; a pyramid's x = G / w^2 by geo_err / w^2, taken
    at w >= 1/2) and by `map_error`, the device map's fit to the mesh's (device_map_error), each
    moving f by grad (|grad f| there) times that. The largest element's terms."""
    u = precision_eps(precision)
    m = renderer.mesh_args(precision)
    size = 2.0 * (max(np.abs(m.field_lo.numpy()).max(), np.abs(m.field_hi.numpy()).max()) + abs(level))
    tail = tolerances.CURVED_TAIL_RTOL_FLOAT64 if precision == "float64" else tolerances.CURVED_TAIL_RTOL
    place = map_rounding(renderer, precision)
    return isosurface.ROUNDING_FACTOR * u * size + float(m.field_err.numpy().max()) + tail * size \
        + grad * (place + map_error)


def device_map_error(mesh, near, samples: int = 20000, seed: int = 0) -> float:
    """The largest distance between the device's map of a curved element (engine/tensor_geometry.py:
    x w^2 re-expressed as a tensor polynomial) and the mesh's own, at random reference points
    whose image satisfies near(x) (where the level set lies), in float64. It is rounding where
    the re-expression is the same polynomial; a pyramid's, fitted on a box in its reference
    element, is off by up to 2e-5 at its base's far corners on the curved cube (the solve's
    rounding, extrapolated), 1e-9 where the ball's sphere crosses them."""
    from ..engine import expansions as ex
    from ..engine.tensor_geometry import mesh_tensor_geometry, tensor_matrix, weight

    degree, offset, coeffs, centre = mesh_tensor_geometry(mesh)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for e in np.nonzero(~np.asarray(mesh.affine, bool))[0] if mesh.affine is not None else ():
        sh, gm = int(mesh.shape[e]), tuple(int(v) for v in mesh.geom_modes[e])
        G = mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]
        xi = rng.uniform(-1.0, 1.0, (samples, 3))
        xi = xi[ex.inside(sh, xi) & (xi[:, 2] < 0.999)]
        x = np.stack([ex.eval_modal(sh, gm, G[:, k], xi) for k in range(3)], axis=1)
        keep = near(x)
        if not keep.any():
            continue
        n = (int(degree[e]) + 1) ** 3
        y = tensor_matrix(int(degree[e]), xi[keep]) @ coeffs[offset[e]:offset[e] + n]
        y = y / (weight(sh, xi[keep]) ** 2)[:, None] + centre[e]
        worst = max(worst, float(np.linalg.norm(y - x[keep], axis=1).max()))
    return worst


def near_sphere(centre, radius, width: float = 0.02):
    """device_map_error's `near` for a sphere: points within width of it."""
    return lambda x: np.abs(np.linalg.norm(x - centre, axis=-1) - radius) < width


def sphere_rays(o, d, centre, radius):
    """Per ray (o, d unit, float64): delta (closest approach's distance from the sphere, > 0
    outside), t* (the closest approach), t1 (the first crossing, nan where none) and the cosine
    between the ray and the normal there."""
    oc = o - centre
    b = np.einsum("...k,...k", d, oc)
    closest2 = np.maximum(np.einsum("...k,...k", oc, oc) - b * b, 0.0)
    delta = np.sqrt(closest2) - radius
    half = np.sqrt(np.maximum(radius * radius - closest2, 0.0))
    t1 = np.where(delta < 0, -b - half, np.nan)
    return delta, -b, t1, half / radius


def classify(rgba, depth, o, d, centre, radius, eps: float, precision: str, alpha: float = 0.5) -> dict:
    """A render of the sphere level (opacity `alpha`, alone: no volume) against the exact rays
    o, d (float64, unit d; the pixels'): outside the band (|delta| > eta) a ray that misses must
    draw nothing, and one that crosses must meet the sphere twice (opacity 1 - (1 - alpha)^2)
    with its depth at the first crossing within the depth tolerance. Returns the counts, the
    widest delta where a ray inside the band came out otherwise than the exact one (the band
    measured), and every pixel outside the band that failed, with its ray."""
    u = precision_eps(precision)
    grad = 2.0 * radius  # |grad f| on the sphere, f = |x - C|^2
    delta, t_star, t1, cosine = sphere_rays(o, d, centre, radius)
    eta = 2.0 * eps / grad + 4.0 * u * (np.linalg.norm(o, axis=-1) + np.abs(t_star))
    a = rgba[..., 3]
    chord = 2.0 * radius * cosine
    stretch = tolerances.STRETCH_RTOL_FLOAT64 if precision == "float64" else tolerances.STRETCH_RTOL
    with np.errstate(divide="ignore", invalid="ignore"):
        tol = 2.0 * eps / (grad * cosine) + stretch * (np.abs(t1) + chord) + 4.0 * u * np.abs(t1)
    two = 1.0 - (1.0 - alpha) ** 2
    misses, hits = delta > eta, delta < -eta
    band = ~misses & ~hits
    drawn = misses & (a > 0.0)
    count = hits & (np.abs(a - two) > 1e-5)
    err = np.where(hits, np.abs(depth - t1), 0.0)
    deep = hits & ~count & (err > tol)
    exact_drawn = delta < 0
    disagree = band & ((a > 0.0) != exact_drawn)
    out = {"pixels": int(a.size), "misses_outside_band": int(misses.sum()), "hits_outside_band": int(hits.sum()),
           "in_band": int(band.sum()), "drawn_outside_band": int(drawn.sum()), "wrong_meetings": int(count.sum()),
           "depth_beyond_tolerance": int(deep.sum()), "eta_max": float(eta.max()),
           "in_band_disagreeing": int(disagree.sum()),
           "measured_band": float(np.abs(delta[disagree]).max()) if disagree.any() else 0.0,
           "depth_error_over_tolerance_max": float((err[hits & ~count] / tol[hits & ~count]).max())
           if (hits & ~count).any() else 0.0}
    bad = drawn | count | deep
    out["outside_band"] = int(bad.sum())
    out["failures"] = [{"pixel": [int(v) for v in idx[::-1]], "delta": float(delta[idx]), "eta": float(eta[idx]),
                        "alpha": float(a[idx]), "depth": float(depth[idx]), "exact_t": float(t1[idx]),
                        "tolerance": float(tol[idx]), "o": o[idx].tolist(), "d": d[idx].tolist()}
                       for idx in zip(*np.nonzero(bad))][:200]
    return out
