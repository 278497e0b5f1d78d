"""Derived fields from the expansion (render contract §8): |grad f| of a scalar, and of a
velocity (three components, or momenta over a density) its vorticity magnitude, its
Q-criterion Q = 1/2 (|Omega|^2 - |S|^2) and its speed |u|.

The name grammar (contract §8), one derived field per name:

    |grad|(f)            the gradient's magnitude of scalar field f
    vorticity(V)         |curl u|
    Q(V)                 1/2 (|Omega|^2 - |S|^2), Omega and S the antisymmetric and symmetric
                         parts of grad u
    speed(V)             |u|
    V = NAME             a vector field of three components (a VTU vector array: Velocity)
      | A,B,C            three scalar fields (Nektar++: u,v,w)
      | NAME/R, A,B,C/R  momenta over the density R (rhou,rhov,rhow/rho): u = m / R

The renderer samples a derived field exactly at each sample point (kernels/derived.py) from
the components' expansions, their reference gradients and the geometry map's Jacobian: exact
per sample, to rounding; the segment's series interpolates those samples and is refined to
tolerance like a curved element's. A quotient or a magnitude is no polynomial: "exact" is per
sample, not a polynomial of the element.

Each derived mesh also carries a least-squares fit of the derived field in its elements'
modes (fit_modes: 2P - 1 per direction, at most MAX_MODES), used for what needs a field as
coefficients: the element ranges that classify segments (the fit's certified range widened by
its measured error, field_range_hull), the data range, the field frame, and the isosurfaces'
normals. Its error is measured at random points against the exact values (derived_values, the
host oracle) and stated, as io/magnitude.py does for magnitudes: an estimate, not a certificate.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

import numpy as np

from . import expansions as ex
from .mesh import element_field_ranges
from .mesh_base import DerivedFieldError, MeshError
from .shapes import MAX_MODES
from .words import plural

OPERATIONS = ("|grad|", "vorticity", "Q", "speed")
SAMPLES_PER_ELEMENT = 64  # random points per element where the fit's error is measured
MAX_SAMPLE_POINTS = 400_000
ERROR_SAFETY = 2.0  # the hull widens the fit's range by this times its largest measured error
_CALL = re.compile(r"\A\s*(\|grad\||vorticity|Q|speed)\s*\((.*)\)\s*\Z")
_NAME = re.compile(r"\A[^,/()|]+\Z")


@dataclass(frozen=True)
class DerivedSpec:
    """A parsed derived-field name: the operation, its component names (one name may be a vector
    the reader splits in three) and the density the components are divided by (or None)."""

    operation: str
    components: tuple
    density: str | None = None

    @property
    def name(self) -> str:
        """The canonical spelling: Q(u,v,w), vorticity(rhou,rhov,rhow/rho), |grad|(p)."""
        inner = ",".join(self.components) + (f"/{self.density}" if self.density else "")
        return f"{self.operation}({inner})"

    @property
    def velocity(self) -> bool:
        return self.operation != "|grad|"


def parse_derived(text) -> DerivedSpec | None:
    """The DerivedSpec of a derived-field name; None for a plain field name; DerivedFieldError
    (one line) for a malformed one."""
    if text is None:
        return None
    text = str(text)
    match = _CALL.match(text)
    if match is None:
        if re.match(r"\A\s*(\|grad\||vorticity|Q|speed)\s*\(", text):
            raise DerivedFieldError(f"field {text!r}: a derived field is OPERATION(components), e.g. Q(u,v,w)")
        return None
    operation, inner = match.group(1), match.group(2)
    parts, _, density = inner.partition("/")
    names = tuple(n.strip() for n in parts.split(","))
    density = density.strip() or None
    if not all(names) or any(_NAME.match(n) is None for n in names) or (density is not None
                                                                       and _NAME.match(density) is None):
        raise DerivedFieldError(f"field {text!r}: components are field names separated by commas, "
                                f"optionally /DENSITY (e.g. {operation}(rhou,rhov,rhow/rho))")
    if operation == "|grad|":
        if len(names) != 1 or density is not None:
            raise DerivedFieldError(f"field {text!r}: |grad| takes one scalar field, e.g. |grad|(p)")
    elif len(names) not in (1, 3):
        raise DerivedFieldError(f"field {text!r}: {operation} needs a velocity: three components "
                                f"({operation}(u,v,w)), a vector field ({operation}(Velocity)) or momenta over a "
                                f"density ({operation}(rhou,rhov,rhow/rho)); got {len(names)} names")
    return DerivedSpec(operation, names, density)


# component names a Nektar++ (or any scalar-field) file gives a velocity or momenta by
VELOCITY_NAMES = (("u", "v", "w"), ("rhou", "rhov", "rhow"))
DENSITY_NAMES = ("rho",)


def derived_field_names(fields) -> list[str]:
    """The derived fields a file's fields can give (a field chooser's list, after the fields
    themselves): fields {name: components} (or a list of scalar names). Per 3-vector V and per
    velocity triple (u,v,w; rhou,rhov,rhow over rho): Q, vorticity, speed; per scalar f: |grad|(f)."""
    sizes = dict(fields) if isinstance(fields, dict) else {str(n): 1 for n in fields}
    velocities = [n for n, k in sizes.items() if k == 3]
    for triple in VELOCITY_NAMES:
        if all(n in sizes for n in triple):
            density = next((d for d in DENSITY_NAMES if d in sizes), None) if triple[0].startswith("rho") else None
            if not triple[0].startswith("rho") or density is not None:
                velocities.append(",".join(triple) + (f"/{density}" if density else ""))
    out = [f"{op}({v})" for v in velocities for op in ("Q", "vorticity", "speed")]
    return out + [f"|grad|({n})" for n, k in sizes.items() if k == 1]


def not_a_velocity(spec: DerivedSpec, name: str, components: int) -> DerivedFieldError:
    """The one-line error where a velocity's one name is not a vector of three components."""
    return DerivedFieldError(f"{spec.name}: {name!r} has {plural(components, 'component')}, not a velocity: give three "
                             f"components ({spec.operation}(u,v,w)), a vector field of three or momenta over a "
                             f"density ({spec.operation}(rhou,rhov,rhow/rho))")


def fit_modes(modes: np.ndarray) -> np.ndarray:
    """Modes per element of the derived field's fit: 2P - 1 per direction (at most MAX_MODES), P
    the components' largest: the degree of a product of two of their polynomials, so the fit
    of Q of a polynomial velocity on an affine element is exact, and an affine segment's samples
    (restriction_degree of these modes) are exact for it."""
    return np.minimum(2 * np.asarray(modes).max(axis=1) - 1, MAX_MODES).astype(np.int32)


@dataclass
class DerivedField:
    """A mesh's derived field: per element, its components' value and reference-gradient
    expansions (kernels/args.DerivedArgs' layout) and the object transform's linear part."""

    spec: DerivedSpec
    modes: np.ndarray  # (N, 3) the components' modes
    offset: np.ndarray  # (N,) where element e's blocks start in coeffs
    size: np.ndarray  # (N,) coefficients per block
    coeffs: np.ndarray  # per element and component c: value, d/dxi_0, d/dxi_1, d/dxi_2 blocks
    components: int  # 1 (a scalar), 3 (a velocity) or 4 (momenta and density, the density last)
    axes: np.ndarray  # (N, 3, 3) dx/dx_data: identity, or the object transform's linear part
    derived: np.ndarray  # (N,) bool: False where the element's field is its own (another volume)

    def blocks(self, idx, c: int, k: int) -> np.ndarray:
        """(len(idx), size) coefficient blocks: component c's value (k = 0) or d/dxi_(k-1)."""
        idx = np.asarray(idx)
        start = self.offset[idx] + (4 * c + k) * self.size[idx]
        return self.coeffs[start[:, None] + np.arange(int(self.size[idx[0]]))[None, :]]

    def transformed(self, linear) -> "DerivedField":
        """After the object transform x' = linear x + t of its geometry."""
        return dataclasses.replace(self, axes=np.einsum("ij,ejk->eik", np.asarray(linear, float), self.axes))

    def subset(self, elements) -> "DerivedField":
        e = np.asarray(elements, dtype=np.int64)
        lengths = 4 * self.components * self.size[e]
        index = np.concatenate([np.arange(o, o + n) for o, n in zip(self.offset[e], lengths)])
        return dataclasses.replace(self, modes=self.modes[e], size=self.size[e], coeffs=self.coeffs[index],
                                   offset=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64),
                                   axes=self.axes[e], derived=self.derived[e])


def gradient_expansion(shape: int, modes, C: np.ndarray) -> np.ndarray:
    """(3, K, E): d/dxi_k of the expansions C (K, E) as expansions in the same modes, fitted
    from the exact derivatives at the fit points: exact on hexahedra, prisms and tetrahedra
    (their spaces hold their polynomials' derivatives), least squares on pyramids."""
    g = ex.eval_modal_grad(shape, modes, C, ex.fit_points(shape, modes))  # (P, E, 3)
    return np.moveaxis(ex.fit_modal(shape, modes, g), -1, 0)


def _jacobian_inverse(mesh, idx, shape: int, xi) -> np.ndarray:
    """(E, P, 3, 3) dxi/dx at reference points xi of elements idx (one shape)."""
    if mesh.geom_coeffs is None:
        return np.broadcast_to(mesh.ref_from_world[idx][:, None, :, :3], (len(idx), len(xi), 3, 3))
    out = np.empty((len(idx), len(xi), 3, 3))
    gm = mesh.geom_modes[idx]
    for key in np.unique(gm, axis=0):
        sel = np.nonzero((gm == key).all(axis=1))[0]
        modes = tuple(int(v) for v in key)
        k = ex.num_coeffs(shape, modes)
        G = mesh.geom_coeffs[mesh.geom_offset[idx[sel]][:, None] + np.arange(k)[None, :]]  # (E, K, 3)
        J = ex.eval_modal_grad(shape, modes, np.moveaxis(G, 0, 1), xi)  # (P, E, 3, 3): dx_i / dxi_k
        out[sel] = np.linalg.inv(np.moveaxis(J, 0, 1))
    return out


def derived_values(mesh, field: DerivedField, idx, xi) -> np.ndarray:
    """(len(idx), len(xi)): the derived field, exactly, at reference points xi of elements idx
    (one shape, one component modes), from the components' own expansions and their exact
    derivatives (not the fitted gradients the kernels read): the host oracle."""
    idx = np.asarray(idx)
    xi = np.asarray(xi, dtype=np.float64).reshape(-1, 3)
    shape = int(mesh.shape[idx[0]])
    modes = tuple(int(v) for v in field.modes[idx[0]])
    M = _jacobian_inverse(mesh, idx, shape, xi) @ field.axes[idx][:, None]  # (E, P, 3, 3): J^-1 A
    values, grads = [], []
    for c in range(field.components):
        C = field.blocks(idx, c, 0).T  # (K, E)
        values.append(ex.eval_modal(shape, modes, C, xi).T)  # (E, P)
        g = np.moveaxis(ex.eval_modal_grad(shape, modes, C, xi), 0, 1)  # (E, P, 3): d/dxi
        grads.append(np.einsum("epki,epk->epi", M, g))  # (J^-1 A)^T grad_xi
    op = field.spec.operation
    if op == "|grad|":
        return np.linalg.norm(grads[0], axis=-1)
    u = np.stack(values[:3], axis=-1)  # (E, P, 3)
    L = np.stack(grads[:3], axis=-2)  # (E, P, 3, 3): L_ij = du_i / dx_j
    if field.components == 4:
        rho, g_rho = values[3][..., None], grads[3]
        u = u / rho
        L = (L - u[..., :, None] * g_rho[..., None, :]) / rho[..., None]
    if op == "speed":
        return np.linalg.norm(u, axis=-1)
    if op == "vorticity":
        w = np.stack([L[..., 2, 1] - L[..., 1, 2], L[..., 0, 2] - L[..., 2, 0], L[..., 1, 0] - L[..., 0, 1]], -1)
        return np.linalg.norm(w, axis=-1)
    return -0.5 * np.einsum("...ij,...ji->...", L, L)


def lattice_values(mesh, operation: str | None = None, per_axis: int = 4) -> np.ndarray:
    """The mesh's derived field (or `operation` of the same components, e.g. "speed" beside a Q),
    exactly, at a lattice of reference points inside every element (as VolumeMesh.field_samples)."""
    field = mesh.derived
    if operation is not None:
        field = dataclasses.replace(field, spec=dataclasses.replace(field.spec, operation=operation))
    g = np.linspace(-1.0, 1.0, per_axis)
    lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    keys = np.concatenate([mesh.shape[:, None], field.modes], axis=1)
    out = []
    for key in np.unique(keys[field.derived], axis=0):
        idx = np.nonzero((keys == key).all(axis=1) & field.derived)[0]
        out.append(derived_values(mesh, field, idx, lattice[ex.inside(int(key[0]), lattice, tol=1e-12)]).ravel())
    return np.concatenate(out)


def random_inside(shape: int, n: int, rng) -> np.ndarray:
    """n uniform random points of the reference element (rejection from the cube)."""
    out = np.zeros((0, 3))
    while len(out) < n:
        p = rng.uniform(-1.0, 1.0, (8 * n, 3))
        out = np.concatenate([out, p[ex.inside(shape, p, tol=0.0)]])
    return out[:n]


def _check_components(spec: DerivedSpec, components) -> None:
    base = components[0]
    for c in components[1:]:
        if c.num_elements != base.num_elements or not np.array_equal(c.shape, base.shape) \
                or not np.array_equal(c.vertices, base.vertices):
            raise DerivedFieldError(f"{spec.name}: component {c.field_name!r} lies on other elements than "
                                    f"{base.field_name!r}")
        if not np.array_equal(c.modes, base.modes):
            raise DerivedFieldError(f"{spec.name}: component {c.field_name!r} has other modes than "
                                    f"{base.field_name!r} in some elements")


def derived_mesh(spec: DerivedSpec, components, seed: int = 0):
    """The VolumeMesh of derived field `spec` from its component meshes (same geometry and
    modes; a velocity's three then the density where there is one): the fit as its field, the
    components as its DerivedField, the range hull and the fit's measured error."""
    components = list(components)
    expected = 1 if spec.operation == "|grad|" else 3 + (spec.density is not None)
    if len(components) != expected:
        raise DerivedFieldError(f"{spec.name}: {len(components)} component fields, needs {expected}")
    _check_components(spec, components)
    base = components[0]
    n = base.num_elements
    size = np.array([ex.num_coeffs(int(s), m) for s, m in zip(base.shape, base.modes)], np.int64)
    offset = np.concatenate([[0], np.cumsum(4 * len(components) * size)[:-1]]).astype(np.int64)
    coeffs = np.zeros(int(4 * len(components) * size.sum()))
    for c, comp in enumerate(components):
        keys = np.concatenate([base.shape[:, None], base.modes], axis=1)
        for key in np.unique(keys, axis=0):
            idx = np.nonzero((keys == key).all(axis=1))[0]
            shape, modes = int(key[0]), tuple(int(v) for v in key[1:])
            k = ex.num_coeffs(shape, modes)
            C = comp.coeffs[comp.coeff_offset[idx][:, None] + np.arange(k)[None, :]].T  # (K, E)
            blocks = np.concatenate([C[None], gradient_expansion(shape, modes, C)])  # (4, K, E)
            for j in range(4):
                start = offset[idx] + (4 * c + j) * k
                coeffs[start[:, None] + np.arange(k)[None, :]] = blocks[j].T
    field = DerivedField(spec, base.modes.astype(np.int32), offset, size, coeffs, len(components),
                         np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.ones(n, bool))

    Q = fit_modes(base.modes)
    fit_size = np.array([ex.num_coeffs(int(s), (q, q, q)) for s, q in zip(base.shape, Q)], np.int64)
    fit_offset = np.concatenate([[0], np.cumsum(fit_size)[:-1]]).astype(np.int64)
    fit = np.zeros(int(fit_size.sum()))
    err = np.zeros(n)
    peak, points = 0.0, 0
    rng = np.random.default_rng(seed)
    per_element = int(np.clip(MAX_SAMPLE_POINTS // max(n, 1), 8, SAMPLES_PER_ELEMENT))
    keys = np.concatenate([base.shape[:, None], base.modes, Q[:, None]], axis=1)
    for key in np.unique(keys, axis=0):
        idx = np.nonzero((keys == key).all(axis=1))[0]
        shape, q = int(key[0]), int(key[4])
        exact = derived_values(base, field, idx, ex.fit_points(shape, (q, q, q)))  # (E, P)
        F = ex.fit_modal(shape, (q, q, q), exact.T).T  # (E, K)
        fit[fit_offset[idx][:, None] + np.arange(F.shape[1])[None, :]] = F
        xi = random_inside(shape, per_element, rng)
        truth = derived_values(base, field, idx, xi)
        err[idx] = np.abs(F @ ex.basis_matrix(shape, (q, q, q), xi).T - truth).max(axis=1)
        peak, points = max(peak, float(np.abs(truth).max())), points + truth.size
    if not np.all(np.isfinite(fit)):
        raise DerivedFieldError(f"{spec.name}: not finite in some element (a density of 0?)")
    try:
        out = dataclasses.replace(base, modes=np.stack([Q] * 3, axis=1), coeff_offset=fit_offset, coeffs=fit,
                                  field_name=spec.name, field_range_hull=None, derived=field)
        lo, hi = element_field_ranges(out)
    except MeshError as exc:
        raise DerivedFieldError(f"{base.source}: {spec.name}: {exc}") from exc
    pad = ERROR_SAFETY * err + 1e-12 * peak
    out.field_range_hull = (lo - pad, hi + pad)
    worst = float(err.max())
    out.derived_error = {"max_error": worst, "max_value": peak, "points": points,
                         "relative": worst / peak if peak > 0 else 0.0}
    note = (f"{spec.name}: sampled exactly in the render; its fit ({'/'.join(str(q) for q in sorted(set(Q.tolist())))}"
            f" modes per direction, for ranges and normals) is within {worst:.3g} of it at {points} random points "
            f"({100 * out.derived_error['relative']:.3g} % of max {peak:.4g})")
    return with_reader_notes(out, components, note, out.derived_error["relative"])


# a fit's error, relative to the field's largest value, above which its report is a warning (below:
# a note): a thousandth is what one can see in a picture; Q's fit on PyFR's Taylor-Green (7.8e-13) is
# a note, a magnitude's at its kinks (2 % on hump3D's momentum) a warning
FIT_WARNING = 1e-3


def with_reader_notes(out, components, note: str, relative: float):
    """`out` (a field derived from `components`) with their readers' warnings, its fit's report
    `note` (out.fit_report; among the warnings where the fit's relative error passes FIT_WARNING,
    else among out.notes), and the reader's element ids and has_field of the first component."""
    warnings = []
    for c in components:
        warnings += [w for w in getattr(c, "warnings", []) if w not in warnings]
    out.fit_report = note
    out.warnings = warnings + ([note] if relative > FIT_WARNING else [])
    out.notes = [] if relative > FIT_WARNING else [note]
    for attr in ("element_ids", "has_field"):
        if hasattr(components[0], attr):
            setattr(out, attr, getattr(components[0], attr))
    return out
