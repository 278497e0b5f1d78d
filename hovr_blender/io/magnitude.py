"""Derived scalar fields: the magnitude |u| = sqrt(u0^2 + u1^2 + ...) of a vector given as
component fields (Nektar++ velocity u, v, w or momentum rhou, rhov, rhow; a VTU vector array).

The renderer handles per-element polynomial fields (modal expansions, engine/expansions.py),
and |u| is not a polynomial (it has a kink wherever u = 0). Each element's magnitude is
therefore represented by a least-squares fit at an elevated order: Q = min(2P + 1, 15) modes
per direction, P the largest component mode count of the element, to the exact pointwise
magnitudes of the exact component polynomials at the shape's fit points
(expansions.fit_points). Where u stays away from zero this converges spectrally; near a zero of
u the fit has an error of the order of the kink.

Conservative ranges: the per-element range the renderer classifies curved segments with
(mesh.element_field_ranges) encloses both the fit's own certified modal range and the true
magnitude's range: with each component in its certified modal interval [lo_c, hi_c],
|u| lies in [distance from 0 to the box, norm of the box's farthest corner]; this interval is
the mesh's ``field_range_hull``.

Error: every magnitude mesh carries ``derived_error`` (dict) and a line in ``warnings``: the
largest |fit - |u|| measured at random points of every element (SAMPLES_PER_ELEMENT each, up to
MAX_SAMPLE_POINTS in all, then DENSE_SAMPLES more in each of the DENSE_ELEMENTS worst elements),
and the stated bound ``bound`` = ERROR_SAFETY x that maximum + 1e-12 x max |u| (a sample can
miss the worst point, so this is an estimate, not a certificate; tests/io/test_magnitude.py
checks fresh random points against it). Measured with `python -m bench.magnitude_error MESH SOLUTION FIELD` (or FILE.vtu
FIELD), seed 0, 2026-11-22:
- Tet_channel_m3 |u,v,w| (48 tets, 3 -> 7 modes): 9.7e-16 (u, v vanish and w >= 0 there, so
  |u| = w is a polynomial and the fit is exact);
- hump3D |rhou,rhov,rhow| (1,760 curved hexes, 3 -> 7 modes): 1.11 of max 53.7 (2.1 %), stated
  bound 2.22 (1,000 fresh points per element: 0.99);
- PyFR TGV |Velocity| (768 hexes and prisms, 5 -> 11 modes): 0.156 of max 1.08 (14 %, at the
  velocity's zeros), stated bound 0.31; read_vtu's interpolated nodal magnitudes are off the
  true magnitude by up to 0.33 on the same cells.

True range: ``true_range`` (min, max) of the exact |u| at the fit points and the random check
points; the Blender layer takes value ranges and histograms from samples clipped to it, so the
fit's dips below zero near u = 0 never make a negative Value Min (docs/methods.md).

Field syntax: "|a,b,c|" (any number of names, spaces allowed) is the magnitude of those fields.
The formats build their magnitudes with magnitude_mesh (io/nektar/format.py: "|a,b,c|" of a
field file; io/vtu/format.py: a vector array's).
"""
from __future__ import annotations

import dataclasses
import re

import numpy as np

from ..engine import expansions as ex
from ..engine.derived_fields import DerivedFieldError, not_a_velocity, with_reader_notes
from ..engine.shapes import MAX_MODES
from ..engine.mesh import MeshError, VolumeMesh, element_field_ranges

SAMPLES_PER_ELEMENT = 64
MAX_SAMPLE_POINTS = 400_000
DENSE_ELEMENTS = 32  # elements with the largest sampled errors get DENSE_SAMPLES more points
DENSE_SAMPLES = 2048
ERROR_SAFETY = 2.0
_MAGNITUDE = re.compile(r"\A\s*\|([^|]*)\|\s*\Z")


class DerivedError(ValueError):
    """A derived field that cannot be built (bad syntax, components that do not match)."""


def parse_magnitude(field) -> list[str] | None:
    """"|u, v, w|" -> ["u", "v", "w"]; None for a plain field name."""
    if not field:
        return None
    match = _MAGNITUDE.match(str(field))
    if match is None:
        if "|" in str(field):
            raise DerivedError(f"field {field!r}: write a magnitude as |a,b,c| (component names between bars)")
        return None
    names = [n.strip() for n in match.group(1).split(",")]
    if not names or any(not n for n in names):
        raise DerivedError(f"field {field!r}: empty component name (write |a,b,c|)")
    return names


def magnitude_modes(component_modes) -> np.ndarray:
    """Q per element: min(2P + 1, MAX_MODES), P the largest mode count over components and directions."""
    P = np.max(np.stack([np.asarray(m).max(axis=1) for m in component_modes]), axis=0)
    return np.minimum(2 * P + 1, MAX_MODES).astype(np.int32)


def _element_blocks(mesh: VolumeMesh, idx, shape, modes):
    k = ex.num_coeffs(shape, modes)
    return mesh.coeffs[mesh.coeff_offset[idx][:, None] + np.arange(k)[None, :]]


def _random_inside(shape, n, rng) -> np.ndarray:
    """n uniform random points of the reference element (rejection from the cube)."""
    out = np.zeros((0, 3))
    while len(out) < n:
        p = rng.uniform(-1.0, 1.0, (8 * n, 3))
        out = np.concatenate([out, p[ex.inside(shape, p, tol=0.0)]])
    return out[:n]


def _magnitude_at(blocks, shape, component_modes, xi):
    """(n, len(xi)): exact |u| of n elements whose component coefficients are blocks[c] (n, K_c)."""
    squares = 0.0
    for coeffs, modes in zip(blocks, component_modes):
        squares = squares + (coeffs @ ex.basis_matrix(shape, modes, xi).T) ** 2
    return np.sqrt(squares)


class _Extremes:
    """The smallest and largest exact |u| and fitted value seen over every point sampled."""

    def __init__(self):
        self.true_min, self.true_max, self.fit_min = np.inf, -np.inf, np.inf

    def see(self, truth, approx=None):
        self.true_min = min(self.true_min, float(truth.min()))
        self.true_max = max(self.true_max, float(truth.max()))
        if approx is not None:
            self.fit_min = min(self.fit_min, float(approx.min()))


def _fit_error(blocks, fit, shape, q, component_modes, xi, extremes: _Extremes):
    """(per-element max |fit - |u|| at xi, largest |u| seen, number of points)."""
    truth = _magnitude_at(blocks, shape, component_modes, xi)
    approx = fit @ ex.basis_matrix(shape, (q, q, q), xi).T
    extremes.see(truth, approx)
    return np.abs(approx - truth).max(axis=1), float(truth.max()), truth.size


def true_magnitude(components, e: int, xi) -> np.ndarray:
    """|u| at reference points xi (..., 3) of element e from the component meshes' polynomials."""
    xi = np.asarray(xi, dtype=np.float64)
    squares = np.zeros(xi.shape[:-1])
    for component in components:
        squares += ex.eval_modal(int(component.shape[e]), component.modes[e], component.element_coeffs(e), xi) ** 2
    return np.sqrt(squares)


def _check_components(components):
    if not components:
        raise DerivedError("a magnitude needs at least one component field")
    base = components[0]
    for c in components[1:]:
        if c.num_elements != base.num_elements or not np.array_equal(c.shape, base.shape):
            raise DerivedError(f"component {c.field_name!r} has other elements than {base.field_name!r}")
        if not np.array_equal(c.vertices, base.vertices):
            raise DerivedError(f"component {c.field_name!r} lies on other geometry than {base.field_name!r}")


def magnitude_mesh(components, field_name: str | None = None, seed: int = 0) -> VolumeMesh:
    """The magnitude of component fields on one geometry (VolumeMeshes that differ only in
    their field) as one VolumeMesh: fitted modal field, conservative range hull, measured error."""
    components = list(components)
    _check_components(components)
    base = components[0]
    n = base.num_elements
    name = field_name or "|" + ",".join(c.field_name for c in components) + "|"
    Q = magnitude_modes([c.modes for c in components])
    ncoef = np.array([ex.num_coeffs(int(s), (q, q, q)) for s, q in zip(base.shape, Q)], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(ncoef)[:-1]]).astype(np.int64)
    coeffs = np.zeros(int(ncoef.sum()))
    samples_per_element = int(np.clip(MAX_SAMPLE_POINTS // max(n, 1), 8, SAMPLES_PER_ELEMENT))
    rng = np.random.default_rng(seed)
    elem_err = np.zeros(n)
    peak, points, groups = 0.0, 0, []
    extremes = _Extremes()

    keys = np.concatenate([base.shape[:, None], Q[:, None]] + [c.modes for c in components], axis=1)
    for key in np.unique(keys, axis=0):
        idx = np.nonzero((keys == key).all(axis=1))[0]
        shape, q = int(key[0]), int(key[1])
        component_modes = [tuple(int(v) for v in key[2 + 3 * i: 5 + 3 * i]) for i in range(len(components))]
        blocks = [_element_blocks(c, idx, shape, modes) for c, modes in zip(components, component_modes)]
        at_fit_points = _magnitude_at(blocks, shape, component_modes, ex.fit_points(shape, (q, q, q)))
        fit = ex.fit_modal(shape, (q, q, q), at_fit_points.T).T
        extremes.see(at_fit_points, fit @ ex.basis_matrix(shape, (q, q, q), ex.fit_points(shape, (q, q, q))).T)
        coeffs[offsets[idx][:, None] + np.arange(fit.shape[1])[None, :]] = fit
        err, top, count = _fit_error(blocks, fit, shape, q, component_modes,
                                     _random_inside(shape, samples_per_element, rng), extremes)
        elem_err[idx], peak, points = err, max(peak, top), points + count
        groups.append((idx, shape, q, component_modes, blocks, fit))
    # the sample can miss an element's worst point (near a zero of u, where |u| has its kink):
    # sample the elements with the largest errors again, densely
    worst_elements = set(np.argsort(elem_err)[-DENSE_ELEMENTS:].tolist())
    for idx, shape, q, component_modes, blocks, fit in groups:
        sel = np.array([k for k, e in enumerate(idx) if e in worst_elements], dtype=np.int64)
        if sel.size:
            err, top, count = _fit_error([b[sel] for b in blocks], fit[sel], shape, q, component_modes,
                                         _random_inside(shape, DENSE_SAMPLES, rng), extremes)
            elem_err[idx[sel]] = np.maximum(elem_err[idx[sel]], err)
            peak, points = max(peak, top), points + count
    worst = float(elem_err.max())

    # |u| over the box of certified component intervals: nearest point and farthest corner
    ranges = [element_field_ranges(c) for c in components]
    lo, hi = np.stack([r[0] for r in ranges]), np.stack([r[1] for r in ranges])
    near = np.sqrt((np.maximum(0.0, np.maximum(lo, -hi)) ** 2).sum(axis=0))
    far = np.sqrt((np.maximum(np.abs(lo), np.abs(hi)) ** 2).sum(axis=0))

    try:
        out = dataclasses.replace(base, modes=np.stack([Q] * 3, axis=1), coeff_offset=offsets, coeffs=coeffs,
                                  field_name=name, field_range_hull=(near, far))
    except MeshError as exc:
        raise DerivedError(f"{base.source}: {name}: {exc}") from exc
    bound = ERROR_SAFETY * worst + 1e-12 * peak  # the floor covers rounding where the fit is exact
    rel = worst / peak if peak > 0 else 0.0
    out.derived_error = {"max_error": worst, "bound": bound, "max_value": peak, "relative": rel, "points": points,
                         "modes": sorted(set(int(q) for q in Q)), "fit_min": extremes.fit_min,
                         "true_min": extremes.true_min}
    # what Fit Value Range and the histogram read: the exact magnitudes' range, never the fit's dips
    out.true_range = (extremes.true_min, extremes.true_max)
    note = (f"{name}: magnitude fitted with {'/'.join(str(q) for q in sorted(set(Q.tolist())))} modes per "
            f"direction; max error {worst:.3g} ({100 * rel:.3g} % of max {peak:.4g}) at {points} random points, "
            f"stated bound {bound:.3g}")
    if extremes.fit_min < extremes.true_min:
        note += (f"; the fit dips to {extremes.fit_min:.3g} near the vector's zeros, where the true magnitude has "
                 f"a kink (true minimum {extremes.true_min:.3g}): the value range comes from the true magnitudes, "
                 "so those dips show as Value Min")
    return with_reader_notes(out, components, note, rel)


def component_reads(spec, sizes: dict | None) -> list[tuple[str, int | None]]:
    """The (field, component index or None) reads of derived field `spec` (engine/derived_fields.py):
    a velocity's one name is a vector of three (sizes: {name: components} of the file's fields;
    None: scalars only, the reader checks the names), the density last."""
    names = spec.components
    if sizes is not None:
        for n in names + ((spec.density,) if spec.density else ()):
            if n not in sizes:
                raise DerivedFieldError(f"{spec.name}: no field {n!r} in the file (it has {', '.join(sizes)})")
    sizes = sizes or {}
    if spec.velocity and len(names) == 1:
        if sizes.get(names[0], 1) != 3:
            raise not_a_velocity(spec, names[0], sizes.get(names[0], 1))
        reads = [(names[0], i) for i in range(3)]
    else:
        for n in names:
            if sizes.get(n, 1) != 1:
                raise DerivedFieldError(f"{spec.name}: {n!r} is a vector of {sizes[n]} components; "
                                        f"name its components or the vector alone")
        reads = [(n, None) for n in names]
    return reads + ([(spec.density, None)] if spec.density else [])
