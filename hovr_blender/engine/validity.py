"""Element validity: the sign of every element's Jacobian determinant, certified over the whole
element (not at sample points), with one tolerance. Every reader calls `check_elements`.

The polynomial. Each shape is the image of the cube u in [-1, 1]^3 of its collapsed coordinates
(`expansions.uncollapse`; a hexahedron's u is xi). In u every modal function is a product of
polynomials, so the geometry map x(u) is a polynomial of degree a_d in u_d (`map_degrees`) and
det dx/du one of degree 3 a_d - 1. det dx/du = det J(xi(u)) det dxi/du, where det dxi/du is w
(prism), (1 - u1)/2 w^2 (tetrahedron) or w^2 (pyramid), w = (1 - u2)/2, and it divides det dx/du
exactly: every mode that varies with u0 carries these factors, every mode that varies with u1
carries w. So q(u) = det J(xi(u)) is a polynomial in u for all four shapes
(`determinant_degrees`), the pyramid included, whose map is rational in xi (x w^2 is the
polynomial there): its determinant is bounded and discontinuous only at the apex, where u is
many-valued, and the cube of u covers the element exactly.

The bound. q is sampled at the tensor Chebyshev points (first kind, inside the cube: no
collapsed point is evaluated) of one more than its degree per direction and turned into its
tensor Chebyshev series exactly (one transform per axis). As |T_k| <= 1, min q >= c_000 -
sum |c_k| over the other coefficients; the bound is exact for the linear part. Where it is
inconclusive the box is halved along the axis carrying most of the non-linear coefficients and
each half re-expanded exactly (a fixed N x N matrix per half: T_k stays within [-1, 1] on a half,
so the map is well conditioned, unlike Bernstein conversion at these degrees), breadth first,
up to MAX_BOXES boxes per element. A box on which q is monotone along an axis (its pure linear
coefficient outweighs the other terms' derivative, |T_k'| <= k^2) is replaced by the face where
q is least, so a minimum on an edge or a corner -- where near-degenerate elements have it -- is
bounded in the lower dimension. Every box also has its Jacobian determinant evaluated at its
corners, edge and face midpoints and centre, so a sign change is found where it is.

Float64 rounding is bounded to first order and subtracted from every bound: the sampled Jacobian
entries (sums of K products, after the element is moved to its centre), the determinant, the
Chebyshev transform (its Lebesgue constant and its sums) and each re-expansion's sums.

The rule, with TOLERANCE relative to the element's scale (the largest product of its Jacobian's
column lengths that was evaluated, the Hadamard bound of det J: invariant under size and aspect
ratio, small only for flat or folded elements):
- refused as inverted where a point with det J < -TOLERANCE scale is found, as degenerate where
  one with det J <= TOLERANCE scale is found;
- accepted where the certified lower bound is >= -TOLERANCE scale and no such point was found
  (any part of the element where det J could be <= 0 is then within TOLERANCE of zero);
- refused as not certified where neither holds after MAX_BOXES boxes.
A first pass bounds curved elements through their vertex (straight) map, the curved modes'
change of the Jacobian bounded from their coefficients (Hadamard), and certifies most mildly
curved elements without the full-degree series. docs/limits.md states the rule for users.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.polynomial import chebyshev

from . import expansions as ex
from . import limits
from .mesh_base import TOLERANCE, MeshError
from .shapes import CENTROIDS, HEX, NAMES, PRISM, PYR, TET

MAX_BOXES = 512  # sub-boxes examined per element before it is refused as not certified
VALID, INVERTED, DEGENERATE, UNCERTIFIED, OVERFLOW = range(5)

_EPS = np.finfo(np.float64).eps
_CHUNK = 1 << 20  # Jacobian entries per sampling chunk (bounds memory)
_STRAIGHT = (2, 2, 2)  # modes of the vertex map
_LOCAL = np.array([-1.0, 0.0, 1.0])  # each box's determinant is evaluated on this grid


def _gamma(n):
    """First-order rounding bound of an n-term sum of products."""
    return n * _EPS / (1.0 - n * _EPS)


def map_degrees(shape, modes) -> tuple[int, int, int]:
    """(a0, a1, a2): the geometry map's degree in each collapsed coordinate u_d."""
    p0, p1, p2 = (int(m) for m in modes)
    a2 = max(p2 - 1, min(p0, p1) + p2 - 4) if shape == PYR else p2 - 1
    return p0 - 1, p1 - 1, a2


def determinant_degrees(shape, modes) -> tuple[int, int, int]:
    """Degree of q(u) = det J(xi(u)) in each u_d (module docstring)."""
    a = map_degrees(shape, modes)
    collapse = {HEX: (0, 0, 0), PRISM: (0, 0, 1), TET: (0, 1, 2), PYR: (0, 0, 2)}[shape]
    return tuple(max(3 * a[d] - 1 - collapse[d], 0) for d in range(3))


@dataclass(frozen=True)
class _Axis:
    """Chebyshev series of degree n - 1 on one axis."""

    points: np.ndarray  # (n,) first-kind points, inside (-1, 1)
    transform: np.ndarray  # (n, n) coefficients = transform @ values at the points
    halves: tuple  # (n, n) x 2: re-expansion on [-1, 0] and on [0, 1]
    split_growth: float  # max column sum of |half|: a re-expansion's rounding per unit 1-norm
    lebesgue: float  # the points' Lebesgue constant (bound)
    local: np.ndarray  # (3, n) T_k at _LOCAL


@lru_cache(maxsize=None)
def _axis(n: int) -> _Axis:
    t = np.cos((2 * np.arange(n) + 1) * np.pi / (2 * n))
    V = chebyshev.chebvander(t, n - 1)  # V[j, k] = T_k(t_j)
    transform = V.T * (np.where(np.arange(n) == 0, 1.0, 2.0) / n)[:, None]  # discrete orthogonality
    halves = tuple(transform @ chebyshev.chebvander(0.5 * (t + s), n - 1) for s in (-1.0, 1.0))
    growth = max(np.abs(h).sum(axis=0).max() for h in halves)
    for a in (t, transform, *halves):
        a.setflags(write=False)
    return _Axis(t, transform, halves, float(growth), 2.0 / np.pi * np.log(n + 1.0) + 1.0,
                 chebyshev.chebvander(_LOCAL, n - 1))


def _along(c, M, axis):
    """M applied along axis `axis` (0, 1, 2) of the boxes' coefficients c (B, N0, N1, N2)."""
    if axis == 2:
        return c @ M.T
    if axis == 1:
        return np.matmul(M, c)
    b, n0, n1, n2 = c.shape
    return np.matmul(M, c.reshape(b, n0, n1 * n2)).reshape(b, M.shape[0], n1, n2)


def _transform(values, axes):
    for d in range(3):
        values = _along(values, axes[d].transform, d)
    return values


def _local_values(c, axes):
    """(B, 3, 3, 3): each box's series at its corners, edge and face midpoints and centre."""
    for d in range(3):
        c = _along(c, axes[d].local, d)
    return c


# ---------------------------------------------------------------------------------------------
# the Jacobian at the sample points


class _Sampler:
    """The Jacobian's columns dx/dxi_j at the tensor Chebyshev grid of `sizes` points per
    direction in u, for elements of one shape and geometry modes: hexahedra by sum
    factorisation, other shapes through the modes' gradients at the grid."""

    def __init__(self, shape, modes, sizes):
        self.shape, self.modes, self.sizes = shape, tuple(modes), tuple(sizes)
        self.axes = tuple(_axis(n) for n in sizes)
        u = np.stack(np.meshgrid(*(a.points for a in self.axes), indexing="ij"), axis=-1).reshape(-1, 3)
        self.xi = ex.uncollapse(shape, u)
        self.K = ex.num_coeffs(shape, modes)
        if shape == HEX:
            pts = [a.points for a in self.axes]
            self.A = [ex.modified_a(m, t) for m, t in zip(self.modes, pts)]
            self.dA = [ex.modified_a_derivative(m, t) for m, t in zip(self.modes, pts)]
            amax = [np.abs(a).max(axis=0) for a in self.A]
            dmax = [np.abs(a).max(axis=0) for a in self.dA]
            # mode k = i + P0 (j + P1 l): its largest |d phi / d xi_d| at the points
            i, j, l = np.meshgrid(*(np.arange(m) for m in self.modes), indexing="ij")
            i, j, l = (v.transpose(2, 1, 0).ravel() for v in (i, j, l))
            self.dmax = np.stack([dmax[0][i] * amax[1][j] * amax[2][l], amax[0][i] * dmax[1][j] * amax[2][l],
                                  amax[0][i] * amax[1][j] * dmax[2][l]], axis=1)
        else:
            B = np.asarray(ex.eval_modal_grad(shape, modes, np.eye(self.K), self.xi))  # (S, K, 3)
            self.dmax = np.abs(B).max(axis=0)
            self.B = [np.ascontiguousarray(B[:, :, j].T) for j in range(3)]  # (K, S) per direction

    def columns(self, G):
        """[dx/dxi_j, j = 0, 1, 2], each (3 coordinates, n, S), of geometries G (n, K, 3)."""
        n = G.shape[0]
        if self.shape == HEX:  # one axis at a time, direction 2 first: the grid comes out in u0, u1, u2 order
            P0, P1, P2 = self.modes
            (A0, A1, A2), (D0, D1, D2) = self.A, self.dA
            c = np.ascontiguousarray(G.reshape(n, P2, P1, P0, 3).transpose(4, 0, 3, 2, 1))  # (3, n, P0, P1, P2)
            z, dz = c @ A2.T, c @ D2.T  # (3, n, P0, P1, N2)
            zz, zd, dzz = np.matmul(A1, z), np.matmul(D1, z), np.matmul(A1, dz)  # (3, n, P0, N1, N2)

            def last(M, y):
                return np.matmul(M, y.reshape(3, n, P0, -1)).reshape(3, n, -1)

            return [last(D0, zz), last(A0, zd), last(A0, dzz)]
        Gt = G.transpose(2, 0, 1).reshape(3 * n, self.K)
        return [(Gt @ B).reshape(3, n, -1) for B in self.B]

    def entry_rounding(self, G, centre):
        """(n, 3, 3) bound of the rounding in the sampled dx_i/dxi_j of the centred geometry G,
        the centring's own rounding included."""
        vertices = ex.vertex_mode_indices(self.shape, self.modes)
        sums = _weighted(np.abs(G), self.dmax)
        moved = _weighted(np.abs(G[:, vertices]) + np.abs(centre)[:, None, :], self.dmax[vertices])
        return _gamma(self.K + 4) * sums + 2 * _EPS * moved


@lru_cache(maxsize=16)
def _sampler(shape, modes, sizes):
    return _Sampler(shape, modes, sizes)


def _weighted(absG, bounds):
    """(n, 3, 3) sum_k |G_ki| bounds_kj: bounds of the Jacobian entries dx_i/dxi_j that modes
    with gradient bounds (K, 3) and coefficients |G| (n, K, 3) make."""
    return absG.transpose(0, 2, 1) @ bounds


def _triple(a, b, c):
    """det [a b c] of columns a, b, c (3, ...)."""
    return a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2]) + a[2] * (b[0] * c[1] - b[1] * c[0])


@lru_cache(maxsize=16)
def _mode_gradient_bounds(shape, modes) -> np.ndarray:
    """(K, 3) certified bounds of max |d phi_k / d xi_j| over the element: each is a polynomial
    in u of degree <= a_d per direction, so the 1-norm of its Chebyshev series bounds it."""
    sizes = tuple(a + 1 for a in map_degrees(shape, modes))
    s = _sampler(shape, modes, sizes)
    K = s.K
    eye = np.broadcast_to(np.eye(K)[:, :, None], (K, K, 3))
    grads = np.stack([col[0] for col in s.columns(np.ascontiguousarray(eye))], axis=1)  # (K, 3, S)
    coeffs = _transform(grads.reshape(K * 3, *sizes), s.axes)
    return np.abs(coeffs).reshape(K, 3, -1).sum(axis=2) * (1.0 + 1e-12)


def _mode_subset(shape, modes, sub) -> np.ndarray:
    """Storage indices in `modes` of the modes of the smaller expansion `sub` (a mode's function
    depends on its (p, q, r) alone)."""
    look = {t: i for i, t in enumerate(map(tuple, ex.mode_triples(shape, modes).tolist()))}
    return np.array([look[t] for t in map(tuple, ex.mode_triples(shape, sub).tolist())], dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# the bound


@dataclass
class Validity:
    """Per element: status (VALID, INVERTED, DEGENERATE, UNCERTIFIED, OVERFLOW), the certified
    lower bound of det J, the smallest det J evaluated (an upper bound of the minimum; inf where
    a truncated pass certified the element without evaluating it) and the reference point where
    it was, the scale (largest product of the Jacobian's column lengths evaluated, or a bound of
    it) and the sub-boxes examined."""

    status: np.ndarray
    lower: np.ndarray
    lowest: np.ndarray
    where: np.ndarray
    scale: np.ndarray
    boxes: np.ndarray


@dataclass
class _Roots:
    """Each element's series on the whole cube and what its samples showed."""

    coeffs: np.ndarray  # (n, N0, N1, N2)
    allowance: np.ndarray  # (n,) rounding bound of the series against the true q
    scale: np.ndarray  # (n,) largest column-length product at the samples
    lowest: np.ndarray  # (n,)
    where: np.ndarray  # (n, 3)
    finite: np.ndarray  # (n,) bool
    column_bound: np.ndarray | None  # (n, 3) certified max column 1-norm (when asked for)


def _centred(shape, modes, G):
    """(G with the element's vertex centre subtracted, the centres): the same Jacobian from
    smaller sums."""
    vertices = ex.vertex_mode_indices(shape, modes)
    centre = G[:, vertices].mean(axis=1)
    Gc = G.copy()
    Gc[:, vertices] -= centre[:, None, :]
    return Gc, centre


def _roots(shape, modes, G, centre, sizes, column_bound=False) -> _Roots:
    s = _sampler(shape, modes, sizes)
    n = G.shape[0]
    S = int(np.prod(sizes))
    out = _Roots(np.empty((n, *sizes)), np.empty(n), np.empty(n), np.empty(n), np.empty((n, 3)),
                 np.empty(n, bool), np.empty((n, 3)) if column_bound else None)
    limits.progress()
    e = s.entry_rounding(G, centre).sum(axis=1)  # (n, 3) column 1-norm bounds of the rounding
    lebesgue = np.prod([a.lebesgue for a in s.axes])
    step = max(1, _CHUNK // (9 * S))
    for i0 in range(0, n, step):
        limits.progress()
        sl = slice(i0, min(n, i0 + step))
        cols = s.columns(G[sl])
        m = cols[0].shape[1]
        v = _triple(*cols)  # (m, S)
        lengths = [np.sqrt((c * c).sum(axis=0)) for c in cols]
        a = np.sqrt(3.0) * np.stack([ln.max(axis=1) for ln in lengths], axis=1)  # column 1-norms at the samples
        sample_error = np.prod(a + e[sl], axis=1) - np.prod(a, axis=1) + 8 * _EPS * np.prod(a, axis=1)
        c = _transform(v.reshape(m, *sizes), s.axes)
        out.coeffs[sl] = c
        out.allowance[sl] = lebesgue * sample_error + 24 * _gamma(max(sizes)) * np.abs(v).sum(axis=1)
        out.scale[sl] = (lengths[0] * lengths[1] * lengths[2]).max(axis=1)
        k = v.argmin(axis=1)
        out.lowest[sl] = v[np.arange(m), k]
        out.where[sl] = s.xi[k]
        out.finite[sl] = (np.isfinite(v).all(axis=1) & np.isfinite(out.scale[sl])
                          & np.isfinite(c).reshape(m, -1).all(axis=1))
        if column_bound:
            entries = np.stack(cols, axis=0).transpose(2, 0, 1, 3).reshape(m * 9, *sizes)  # (m, j, i, S)
            norms = np.abs(_transform(entries, s.axes)).reshape(m, 3, 3, -1).sum(axis=(2, 3))
            out.column_bound[sl] = norms * (1.0 + 1e-12) + e[sl]
    return out


def _rows(c):
    """c (B, ...) as (B, rest), B = 0 included."""
    return c.reshape(c.shape[0], int(np.prod(c.shape[1:])))


def determinant_series(shape, modes, G) -> np.ndarray:
    """(n, N0, N1, N2): the tensor Chebyshev series in u of q(u) = det J(xi(u)) of elements with
    geometry G (n, K, 3), N_d = determinant_degrees + 1 (exact up to rounding)."""
    shape, modes = int(shape), tuple(int(m) for m in modes)
    G = np.asarray(G, dtype=np.float64).reshape(-1, ex.num_coeffs(shape, modes), 3)
    Gc, centre = _centred(shape, modes, G)
    return _roots(shape, modes, Gc, centre, tuple(d + 1 for d in determinant_degrees(shape, modes))).coeffs


def _series_bound(c):
    """(B,) c_000 - sum of |c| over the other coefficients: a lower bound of the series."""
    flat = _rows(c)
    return flat[:, 0] + np.abs(flat[:, 0]) - np.abs(flat).sum(axis=1)


def _truncated_pass(shape, modes, G, centre, sub, gradient_bounds, tolerance):
    """(certified lower bounds, scale bounds, accepted, the vertex map's column bounds) of
    elements through their expansion truncated to `sub` modes, the other modes' change of each
    Jacobian column bounded from their coefficients and det's change by Hadamard's inequality."""
    keep = _mode_subset(shape, modes, sub)
    rest = np.ones(G.shape[1], bool)
    rest[keep] = False
    change = _weighted(np.abs(G[:, rest]), gradient_bounds[rest]).sum(axis=1)
    sizes = tuple(max(d, a) + 1 for d, a in zip(determinant_degrees(shape, sub), map_degrees(shape, sub)))
    r = _roots(shape, sub, np.ascontiguousarray(G[:, keep]), centre, sizes, column_bound=True)
    a = r.column_bound
    scale = np.prod(a + change, axis=1)
    lower = _series_bound(r.coeffs) - r.allowance - (scale - np.prod(a, axis=1))
    accepted = r.finite & np.isfinite(lower) & (lower >= tolerance * scale)
    return lower, scale, accepted, a


def _truncation_order(shape, modes, G, gradient_bounds, columns):
    """(n,) the fewest modes m (3 <= m < min(modes)) per direction whose truncation changes no
    Jacobian column by more than 5 % of the vertex map's; 0 where none does."""
    out = np.zeros(G.shape[0], np.int64)
    for m in range(min(modes) - 1, 2, -1):
        rest = np.ones(G.shape[1], bool)
        rest[_mode_subset(shape, modes, (m, m, m))] = False
        change = _weighted(np.abs(G[:, rest]), gradient_bounds[rest]).sum(axis=1)
        out[(change <= 0.05 * columns).all(axis=1)] = m
    return out


def jacobian_validity(shape, modes, G, tolerance: float = TOLERANCE, max_boxes: int = MAX_BOXES) -> Validity:
    """The validity of elements of one shape and geometry modes, geometry G (n, K, 3) (module
    docstring). Passes: the vertex map and, where the curved modes are small, a truncated
    expansion, each with the rest bounded (cheap, certifies most mildly curved elements); then
    the full series, subdivided where inconclusive."""
    shape = int(shape)
    modes = tuple(int(m) for m in modes)
    G = np.asarray(G, dtype=np.float64).reshape(-1, ex.num_coeffs(shape, modes), 3)
    n = G.shape[0]
    out = Validity(np.full(n, VALID, np.int8), np.full(n, np.inf), np.full(n, np.inf),
                   np.tile(CENTROIDS[shape], (n, 1)), np.zeros(n), np.zeros(n, np.int64))
    if n == 0:
        return out
    with np.errstate(all="ignore"):
        Gc, centre = _centred(shape, modes, G)
        limits.progress()
        todo = np.arange(n)
        if modes != _STRAIGHT and min(modes) >= 2:
            bounds = _mode_gradient_bounds(shape, modes)
            lower, scale, accepted, columns = _truncated_pass(shape, modes, Gc, centre, _STRAIGHT, bounds, tolerance)
            out.lower[accepted], out.scale[accepted] = lower[accepted], scale[accepted]
            todo = np.flatnonzero(~accepted)
            order = _truncation_order(shape, modes, Gc[todo], bounds, columns[todo])
            done = []
            for m in np.unique(order[order > 0]):
                idx = todo[order == m]
                lower, scale, accepted, _ = _truncated_pass(shape, modes, Gc[idx], centre[idx], (m, m, m), bounds,
                                                            tolerance)
                out.lower[idx[accepted]], out.scale[idx[accepted]] = lower[accepted], scale[accepted]
                done.append(idx[accepted])
            todo = np.setdiff1d(todo, np.concatenate(done)) if done else todo
        if todo.size:
            _full_pass(shape, modes, Gc[todo], centre[todo], tolerance, max_boxes, out, todo)
    return out


def _full_pass(shape, modes, G, centre, tolerance, max_boxes, out, index):
    """The full-degree series of each element, subdivided where inconclusive (breadth first,
    faces where det J is monotone): results into out[index]."""
    sizes = tuple(d + 1 for d in determinant_degrees(shape, modes))
    axes = tuple(_axis(n) for n in sizes)
    r = _roots(shape, modes, G, centre, sizes)
    n = G.shape[0]
    status = np.full(n, -1, np.int8)  # -1: undecided
    status[~r.finite] = OVERFLOW
    scale, lowest, where = r.scale, r.lowest.copy(), r.where.copy()
    lower_root = _series_bound(r.coeffs) - r.allowance
    lower_leaves = np.full(n, np.inf)
    examined = np.ones(n, np.int64)
    coeffs, allowance, element = r.coeffs, r.allowance.copy(), np.arange(n)  # the open boxes
    lo, hi = np.full((n, 3), -1.0), np.full((n, 3), 1.0)
    while coeffs.shape[0]:
        limits.progress()
        _lowest_of_boxes(shape, coeffs, lo, hi, element, axes, lowest, where)
        bad = (status < 0) & (lowest <= tolerance * scale)
        status[bad] = np.where(lowest[bad] < -tolerance * scale[bad], INVERTED, DEGENERATE)
        live = np.flatnonzero(status[element] < 0)
        coeffs, allowance, element, lo, hi = coeffs[live], allowance[live], element[live], lo[live], hi[live]
        sums = _sums(coeffs)
        bound = _bound(coeffs, sums) - allowance
        loose = np.flatnonzero(bound < -tolerance * scale[element])
        if loose.size:
            c, al, l2, h2, su = _restrict_monotone(coeffs[loose], allowance[loose], lo[loose], hi[loose], sums[loose],
                                                   axes)
            coeffs[loose], allowance[loose], lo[loose], hi[loose], sums[loose] = c, al, l2, h2, su
            bound[loose] = _bound(c, su) - al
        closed = bound >= -tolerance * scale[element]
        np.minimum.at(lower_leaves, element[closed], bound[closed])
        open_ = ~closed
        counts = np.bincount(element[open_], minlength=n)
        over = (examined + 2 * counts > max_boxes) & (counts > 0)
        if over.any():
            stuck = open_ & over[element]
            np.minimum.at(lower_leaves, element[stuck], bound[stuck])
            status[over] = UNCERTIFIED
            open_ &= ~stuck
            counts[over] = 0
        examined += 2 * counts
        keep = np.flatnonzero(open_)
        coeffs, allowance, element, lo, hi = _split(coeffs[keep], allowance[keep], element[keep], lo[keep],
                                                    hi[keep], sums[keep], axes)
    lower = np.where((status < 0) | (status == UNCERTIFIED), lower_leaves, lower_root)
    status[status < 0] = VALID  # no open box left
    lower[status == OVERFLOW] = np.nan
    out.status[index], out.lower[index], out.lowest[index] = status, lower, lowest
    out.where[index], out.scale[index], out.boxes[index] = where, scale, examined


@lru_cache(maxsize=None)
def _weights(sizes) -> np.ndarray:
    """(S, 7): sum |c| times these columns gives: the 1-norm; per axis d the coefficients that
    vary with u_d less the pure linear one (what halving along d shrinks); per axis d a bound
    of the derivative along u_d of every term but the pure linear one (|T_k'| <= k^2)."""
    k = np.meshgrid(*(np.arange(n) for n in sizes), indexing="ij")
    nonlinear, slope = [], []
    for d in range(3):
        pure = np.zeros(sizes, bool)
        if sizes[d] > 1:
            linear = [0, 0, 0]
            linear[d] = 1
            pure[tuple(linear)] = True
        nonlinear.append((k[d] >= 1) & ~pure)
        slope.append(np.where(pure, 0.0, k[d].astype(np.float64) ** 2))
    W = np.stack([np.ones(sizes)] + nonlinear + slope, axis=-1).reshape(-1, 7).astype(np.float64)
    W.setflags(write=False)
    return W


def _sums(c):
    """(B, 7): the boxes' weighted coefficient sums (_weights)."""
    return _rows(np.abs(c)) @ _weights(c.shape[1:])


def _bound(c, sums):
    """(B,) c_000 - sum of |c| over the other coefficients."""
    c0 = c[:, 0, 0, 0]
    return c0 + np.abs(c0) - sums[:, 0]


def _restrict_monotone(c, allowance, lo, hi, sums, axes):
    """Boxes on which det J is monotone along an axis replaced by the face where it is least:
    the pure linear coefficient outweighs the bound of the other terms' derivative, less the
    rounding's (Markov's inequality)."""
    c, allowance, lo, hi, sums = c.copy(), allowance.copy(), lo.copy(), hi.copy(), sums.copy()
    for d, ax in enumerate(axes):
        n = ax.points.size
        if n == 1:
            continue
        index = [slice(None), 0, 0, 0]
        index[d + 1] = 1
        linear = c[tuple(index)]
        slack = (n - 1) ** 2 * allowance + sums[:, 4 + d]
        wide = lo[:, d] < hi[:, d]
        for sel, row in ((np.flatnonzero(wide & (linear >= slack)), 0), (np.flatnonzero(wide & (-linear >= slack)), 2)):
            if not sel.size:
                continue
            face = np.zeros_like(c[sel])
            index = [slice(None)] * 4
            index[d + 1] = slice(0, 1)
            face[tuple(index)] = _along(c[sel], ax.local[row:row + 1], d)
            allowance[sel] += _gamma(n) * sums[sel, 0]
            c[sel] = face
            sums[sel] = _sums(face)
            end = lo[sel, d] if row == 0 else hi[sel, d]
            lo[sel, d] = hi[sel, d] = end
    return c, allowance, lo, hi, sums


def _split(c, allowance, element, lo, hi, sums, axes):
    """Each box halved along its loosest axis: the halves' series, allowances, elements and
    corners."""
    if not c.shape[0]:
        return c, allowance, element, lo, hi
    score = sums[:, 1:4].copy()
    score[lo >= hi] = -1.0  # a face: nothing to halve
    axis = score.argmax(axis=1)
    parts = []
    for d in range(3):
        sel = np.flatnonzero(axis == d)
        if not sel.size:
            continue
        mid = 0.5 * (lo[sel, d] + hi[sel, d])
        rounding = _gamma(axes[d].points.size) * axes[d].split_growth * sums[sel, 0]
        for half, M in enumerate(axes[d].halves):
            l2, h2 = lo[sel].copy(), hi[sel].copy()
            (h2 if half == 0 else l2)[:, d] = mid
            parts.append((_along(c[sel], M, d), allowance[sel] + rounding, element[sel], l2, h2))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(5))


def _lowest_of_boxes(shape, c, lo, hi, element, axes, lowest, where):
    """Each box's series on its 3 x 3 x 3 grid (corners, edge and face midpoints, centre): the
    elements' lowest value and where it is, updated."""
    vals = _rows(_local_values(c, axes))
    k = vals.argmin(axis=1)
    v = vals[np.arange(c.shape[0]), k]
    improve = np.flatnonzero(v < lowest[element])
    if not improve.size:
        return
    order = improve[np.lexsort((v[improve], element[improve]))]  # by element, then value
    first = order[np.r_[True, element[order][1:] != element[order][:-1]]]  # each element's smallest
    t = (_LOCAL[np.stack(np.unravel_index(k[first], (3, 3, 3)), axis=1)] + 1.0) * 0.5
    lowest[element[first]] = v[first]
    where[element[first]] = ex.uncollapse(shape, lo[first] + t * (hi[first] - lo[first]))


# ---------------------------------------------------------------------------------------------
# what readers call


@lru_cache(maxsize=16)
def _volume_rule(shape, modes):
    """(K, 3) gradients at and (P,) weights of a 3-point Gauss rule per direction of the cube
    of collapsed coordinates, the collapse's Jacobian in the weights."""
    t, w = np.polynomial.legendre.leggauss(3)
    u = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    weight = np.einsum("i,j,k->ijk", w, w, w).ravel()
    lean = 0.5 * (1.0 - u[:, 2])
    weight = weight * {HEX: 1.0, PRISM: lean, TET: 0.5 * (1.0 - u[:, 1]) * lean**2, PYR: lean**2}[shape]
    B = np.asarray(ex.eval_modal_grad(shape, modes, np.eye(ex.num_coeffs(shape, modes)), ex.uncollapse(shape, u)))
    return [np.ascontiguousarray(B[:, :, j].T) for j in range(3)], weight


def orientation(shape, modes, G) -> np.ndarray:
    """(n,) each element's signed volume in reference units (Gauss, 3 points per direction of
    its collapsed cube): its sign says which way round a writer stored it; exact in sign for an
    element whose Jacobian keeps one sign."""
    shape = int(shape)
    modes = tuple(int(m) for m in modes)
    G = np.asarray(G, dtype=np.float64)
    gradients, weight = _volume_rule(shape, modes)
    with np.errstate(all="ignore"):
        Gc, _ = _centred(shape, modes, G)
        Gt = Gc.transpose(2, 0, 1).reshape(3 * G.shape[0], -1)
        cols = [(Gt @ B).reshape(3, G.shape[0], -1) for B in gradients]
        return _triple(*cols) @ weight


def _point(xi):
    return "(" + ", ".join(f"{x:.3g}" for x in xi) + ")"


def describe(v: Validity, i: int, shape, element, G=None) -> str:
    """One line on element i of a Validity, named `element`."""
    name = NAMES[int(shape)]
    status, lower, lowest, scale = int(v.status[i]), v.lower[i], v.lowest[i], v.scale[i]
    if status == OVERFLOW:
        size = "" if G is None else f" (coordinates up to {np.abs(np.asarray(G)[i]).max():.3g})"
        return f"element {element}: {name} geometry too large for double precision{size}: its Jacobian overflows"
    at = f"Jacobian determinant {lowest:.3g} at xi = {_point(v.where[i])}"
    if status == INVERTED:
        return f"element {element}: inverted or tangled {name} ({at}; certified minimum >= {lower:.3g}, scale {scale:.3g})"
    if status == DEGENERATE:
        return (f"element {element}: degenerate {name} ({at}, not above {TOLERANCE:g} of its scale {scale:.3g}; "
                f"the Jacobian vanishes)")
    if status == UNCERTIFIED:
        return (f"element {element}: {name} not certified valid: its Jacobian determinant is certified >= "
                f"{lower:.3g} only, after {int(v.boxes[i])} sub-boxes ({at}, scale {scale:.3g}): it may fold")
    return f"element {element}: valid {name} (Jacobian determinant >= {lower:.3g}, scale {scale:.3g})"


def check_elements(shape, modes, G, ids=None) -> Validity:
    """MeshError naming the first element (by ids, else its position) that is not certified
    valid; the Validity otherwise."""
    v = jacobian_validity(shape, modes, G)
    bad = np.flatnonzero(v.status != VALID)
    if bad.size:
        i = int(bad[0])
        raise MeshError(describe(v, i, shape, i if ids is None else ids[i], np.asarray(G).reshape(len(v.status), -1, 3)))
    return v
