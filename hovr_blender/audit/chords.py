"""Exact chords through a curved mesh of any shapes, for watertightness audits: with a constant
density tau the contract's transmittance is exp(-tau L), L the length of the ray inside the
union of the elements. L comes from the mesh's boundary alone: every face that no other element
shares (quadrilaterals and triangles, curved, of hexahedra, prisms, tetrahedra and pyramids) is
a polynomial patch x(u, v) of its element's map; each ray's crossings of every patch are found
by float64 Newton on (u, v, t), and the chord is the sum of the in/out intervals of the sorted
crossings (an odd count: NaN, the ray undecided).

Faces: a face is parameterised onto its element's reference face as engine/walls.py's
face_reference_points does (pure geometry: a quadrilateral by (u, v) in [-1, 1]^2, bilinear in
its corners; a triangle by u, v >= -1, u + v <= 0, affine). The element map restricted to a face
is a polynomial in (u, v) (for the pyramid too: its rational terms reduce to polynomials on every
face), fitted here as a power series at interior Chebyshev points (a quadrilateral: tensor degree
n - 1; a triangle: total degree n - 1) and checked against the element map at random points of
the face (FIT_TOL).

Crossings: a face is split into sub-patches (quarters; a triangle's four) until each one's
Bernstein net lies within FLAT of its extent from a plane, so that Newton from five starts (the
centre, the quarters' middles) meets every crossing of a sub-patch. A ray that grazes a sub-patch
may cross it twice, close together: each start's Newton is deflated by the roots the earlier
starts found (Farrell, Birkisson and Funke 2015), so the second one is found too. A sub-patch's
box is the hull of its Bernstein coefficients (a triangle: of its collapsed square), so no
crossing lies outside it. Crossings closer than DUPLICATE are one (a ray through an edge).

Boundary faces: faces keyed by their corner vertices that occur once, less those that pave one
quadrilateral from both its sides: the quadrilateral against two triangles on a diagonal (a
hexahedron against tetrahedra), or two triangles on one diagonal against two on the other
(tetrahedra split differently on each side, as in io/synthetic's mixed cube). Those lie inside
the domain. Corners are one vertex when they agree to KEY_TOL of the mesh's size (_corner_ids).

Nothing here is shared with the renderer (no traversal, no element location, no BVH, no
adjacency): the patches come from the element maps of engine/expansions (the mesh's definition),
and the Warp kernel below is a brute-force loop over the sub-patches' boxes, in float64, that
sorts and pairs each ray's crossings itself, so that 10 M rays take seconds on a GPU.
`chords_numpy` is the same computation in numpy, the kernel's own check at small sizes.
Coordinates are taken relative to the mesh's centre and tolerances scale with its size
(`Boundary.scale`).
"""

import numpy as np

from ..engine import expansions as ex
from ..engine import shapes
from ..engine.walls import face_corners, face_reference_points

FLAT = 0.05  # a sub-patch's Bernstein net lies within this fraction of its extent from a plane
MAX_DEPTH = 4  # halvings of a face (at most 4^4 sub-patches)
ITERATIONS = 40  # at most; a start stops once its step is below STEP_TOL
MAX_HITS = 32  # crossings kept per ray
ROOT_TOL = 1e-12  # |x(u, v) - o - t d| at a root, in units of the mesh's size
STEP_TOL = 1e-15  # a Newton step below this (parameters; t in units of the mesh's size) has converged
DUPLICATE = 1e-9  # two crossings closer than this (in units of the mesh's size) are one (a ray through an edge)
EDGE_TOL = 1e-12  # a root this far outside its face's parameter domain still counts (an edge's rounding)
FIT_TOL = 1e-11  # a patch's largest departure from the element map, in units of the mesh's size
KEY_TOL = 1e-9  # corner vertices closer than this (of the mesh's size) are one
DENSE_FLAT, DENSE_DEPTH, DENSE_STARTS = 0.01, 6, 5  # dense_boundary / dense_starts: the thorough search


def _corner_ids(mesh):
    """(E, 8) int: each element's corner vertices numbered so that coincident ones share a number;
    -1 past a shape's corners. Coincident: equal when rounded to KEY_TOL of the mesh's size on
    one of the 8 grids shifted by half a cell per axis (two points closer than half a cell in
    every axis share a cell on one of them; one grid alone splits pairs that straddle its cells'
    walls), joined transitively."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    ncorner = np.array([len(shapes.VERTICES[s]) for s in range(4)])[mesh.shape]
    real = np.arange(V.shape[1])[None, :] < ncorner[:, None]
    pts = V[real]
    lo = pts.min(axis=0)
    size = float(np.ptp(pts, axis=0).max()) or 1.0
    scaled = (pts - lo) / (KEY_TOL * size)
    label = np.arange(len(pts))
    cells = [np.unique(np.floor(scaled + 0.5 * np.array([i & 1, (i >> 1) & 1, (i >> 2) & 1])).astype(np.int64), axis=0,
                       return_inverse=True)[1].ravel() for i in range(8)]
    while True:
        before = label
        for inv in cells:
            low = np.full(inv.max() + 1, len(pts))
            np.minimum.at(low, inv, label)
            label = low[inv]
        if np.array_equal(label, before):
            break
    ids = np.full(real.shape, -1, np.int64)
    ids[real] = label
    return ids


def boundary_faces(mesh):
    """[(element, face)] of every face (shapes.FACE_PLANES' numbering) on the domain's boundary:
    faces that no other element shares, less those covered from the other side (module docstring)."""
    ids = _corner_ids(mesh)
    seen = {}
    for e in range(mesh.num_elements):
        sh = int(mesh.shape[e])
        for f, corners in enumerate(shapes.plane_vertices(sh)):
            key = tuple(sorted(ids[e, corners].tolist()))
            seen.setdefault(key, []).append((e, f))
    single = {k: v[0] for k, v in seen.items() if len(v) == 1}
    inner = _covered_from_both_sides(single)
    return [v for k, v in single.items() if k not in inner]


def _covered_from_both_sides(single):
    """Keys of unmatched faces that pave one quadrilateral twice, from its two sides: two
    triangles on one diagonal against the quadrilateral itself or against the two triangles on
    the other diagonal (a hexahedron against tetrahedra; tetrahedra split the other way)."""
    by_edge = {}
    for key in single:
        if len(key) == 3:
            for k in range(3):
                edge = key[:k] + key[k + 1:]
                by_edge.setdefault(edge, []).append(key[k])
    inner = set()
    for (p, q), thirds in by_edge.items():
        for a in range(len(thirds)):
            for b in range(a + 1, len(thirds)):
                r, s = thirds[a], thirds[b]
                mine = (tuple(sorted((p, q, r))), tuple(sorted((p, q, s))))
                quad = tuple(sorted((p, q, r, s)))
                other = (tuple(sorted((p, r, s))), tuple(sorted((q, r, s))))
                if quad in single:
                    inner.update(mine + (quad,))
                elif all(k in single for k in other):
                    inner.update(mine + other)
    return inner


# ----------------------------------------------------------------------------- the patches

def _chebyshev(m):
    """m interior Chebyshev points of [-1, 1] (none at the ends: no pyramid apex)."""
    return np.cos(np.pi * (np.arange(m) + 0.5) / m)


def collapse(a, b):
    """The triangle's (u, v) of a point (a, b) of the square [-1, 1]^2 (b = 1: the third corner)."""
    return 0.5 * (1.0 + a) * (1.0 - b) - 1.0, b


def _monomials(u, v, n, tri):
    """(p, n * n) u^a v^b, the columns of (a, b) with a + b >= n zero for a triangle."""
    k = np.arange(n)
    M = (u[:, None] ** k)[:, :, None] * (v[:, None] ** k)[:, None, :]
    if tri:
        M = M * (k[:, None] + k[None, :] < n)
    return M.reshape(len(u), n * n)


class _Fitter:
    """Power series of degree n - 1 (a triangle: total degree; tensor otherwise) through values at
    `uv`, interior Chebyshev points of the face (a triangle: of its collapsed square), by least
    squares; `fit(X)` takes X (m, p, 3) and gives C (m, n, n, 3)."""

    def __init__(self, n, tri):
        g = _chebyshev(n + (2 if tri else 0))
        A, B = np.meshgrid(g, g, indexing="ij")
        self.n, self.tri = n, tri
        self.ab = np.stack([A.ravel(), B.ravel()], axis=1)
        self.uv = np.stack(collapse(*self.ab.T), axis=1) if tri else self.ab
        M = _monomials(self.uv[:, 0], self.uv[:, 1], n, tri)
        keep = np.abs(M).sum(axis=0) > 0
        self.solve = np.zeros((n * n, len(self.uv)))
        self.solve[keep] = np.linalg.pinv(M[:, keep])

    def fit(self, X):
        return np.einsum("kp,mpc->mkc", self.solve, X).reshape(len(X), self.n, self.n, 3)


def _bernstein(C):
    """Bernstein control points (m, n, n, 3) of tensor power series C (m, n, n, 3) over [-1, 1]^2:
    their hull holds the whole patch."""
    from math import comb

    n = C.shape[1]
    N = n - 1
    # u = 2 s - 1: power coefficients in s, then Bernstein: b_k = sum_j C(k, j) / C(N, j) c_j
    S = np.array([[comb(a, j) * 2.0 ** j * (-1.0) ** (a - j) if j <= a else 0.0 for a in range(n)] for j in range(n)])
    B = np.array([[comb(k, j) / comb(N, j) if j <= k else 0.0 for j in range(n)] for k in range(n)])
    T = B @ S
    return np.einsum("ka,lb,mabc->mklc", T, T, C)


def face_geometry(mesh, elems, face, uv):
    """World points (len(elems), p, 3) of face `face` of the elements `elems` (one shape and one
    geometry degree) at the face parameters uv (p, 2)."""
    sh = int(mesh.shape[elems[0]])
    gm = tuple(int(v) for v in mesh.geom_modes[elems[0]])
    xi = face_reference_points(face_corners(sh, face), uv)
    K = ex.num_coeffs(sh, gm)
    G = mesh.geom_coeffs[mesh.geom_offset[elems][:, None] + np.arange(K)[None, :]]  # (m, K, 3)
    return np.einsum("pk,mkc->mpc", ex.basis_matrix(sh, gm, xi), G)


# children of a face in its parent's (u, v): quadrilateral quarters (centre, half-size) and the
# triangle's four (corners q0, q1, q2; the child's (u', v') map affinely onto them as a face's do)
_QUARTERS = [((-0.5, -0.5), 0.5), ((0.5, -0.5), 0.5), ((-0.5, 0.5), 0.5), ((0.5, 0.5), 0.5)]
_P, _M = np.array([[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0]]), np.array([[0.0, -1.0], [0.0, 0.0], [-1.0, 0.0]])
_TRIANGLES = [(_P[0], _M[0], _M[2]), (_M[0], _P[1], _M[1]), (_M[2], _M[1], _P[2]), (_M[1], _M[2], _M[0])]


def _child_points(uv, tri, k):
    """The parent's (u, v) of child k's points uv (p, 2)."""
    if tri:
        q0, q1, q2 = _TRIANGLES[k]
        return q0 + 0.5 * (1.0 + uv[:, :1]) * (q1 - q0) + 0.5 * (1.0 + uv[:, 1:]) * (q2 - q0)
    (cu, cv), h = _QUARTERS[k]
    return np.stack([cu + h * uv[:, 0], cv + h * uv[:, 1]], axis=1)


class Boundary:
    """A mesh's boundary patches: every boundary face (`faces`, (element, face)) split into
    sub-patches until each is nearly flat (its Bernstein net within `flat` of its extent from a
    plane; at most `max_depth` halvings), so that Newton from a few starts finds every crossing
    of a sub-patch. Per sub-patch: C (P, n, n, 3) power series in its own (u, v), tri (P,) (1: a
    triangle), boxes lo, hi (P, 3), `face` (P,) the boundary face it is part of; coordinates
    relative to `centre`; `scale`, the diagonal of the mesh's box."""

    def __init__(self, mesh, flat: float = FLAT, max_depth: int = MAX_DEPTH):
        from ..engine.mesh import with_geometry_expansion

        mesh = with_geometry_expansion(mesh)
        ncorner = np.array([len(shapes.VERTICES[s]) for s in range(4)])[mesh.shape]
        pts = np.asarray(mesh.vertices, dtype=np.float64)[np.arange(mesh.vertices.shape[1])[None, :] < ncorner[:, None]]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        self.centre = 0.5 * (lo + hi)
        self.scale = float(np.linalg.norm(hi - lo)) or 1.0
        self.faces = boundary_faces(mesh)
        groups = {}
        for k, (e, f) in enumerate(self.faces):
            groups.setdefault((int(mesh.shape[e]), f, tuple(int(v) for v in mesh.geom_modes[e])), []).append(k)
        fitted = {}  # (n, tri) -> [face indices], [C]
        for (sh, f, gm), ks in groups.items():
            tri = len(shapes.plane_vertices(sh)[f]) == 3
            n, C = self._fit_faces(mesh, np.array([self.faces[k][0] for k in ks]), f, tri, max(max(gm), 2))
            fitted.setdefault((n, tri), ([], []))
            fitted[n, tri][0].extend(ks)
            fitted[n, tri][1].append(C)
        parts = [self._subdivide(np.array(ks), np.concatenate(Cs), n, tri, flat, max_depth)
                 for (n, tri), (ks, Cs) in fitted.items()]
        n = max((p[1].shape[1] for p in parts), default=1)
        self.face = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
        self.patches = np.zeros((len(self.face), n, n, 3))
        k = 0
        for _, C, _, _, _ in parts:
            self.patches[k:k + len(C), :C.shape[1], :C.shape[2]] = C
            k += len(C)
        self.tri = np.concatenate([np.full(len(p[0]), int(p[2]), np.int32) for p in parts]) if parts else np.zeros(0, np.int32)
        pad = 1e-9 * self.scale
        self.lo = (np.concatenate([p[3] for p in parts]) if parts else np.zeros((0, 3))) - pad
        self.hi = (np.concatenate([p[4] for p in parts]) if parts else np.zeros((0, 3))) + pad

    def _check(self, got, want, what):
        err = np.abs(got - want).max(axis=(1, 2))
        if err.max(initial=0.0) > FIT_TOL * self.scale:
            raise ValueError(f"{what(int(np.argmax(err)))}: the polynomial patch departs from the element map "
                             f"by {err.max():.2g}")

    def _fit_faces(self, mesh, elems, f, tri, degree):
        """(n, C (m, n, n, 3)): face f of `elems` as power series, the first n from the geometry's
        modes up whose fit reproduces the element map to FIT_TOL (a pyramid's faces may need more)."""
        test = np.random.default_rng(1).uniform(-1, 1, (24, 2))
        if tri:
            test = np.stack(collapse(test[:, 0], test[:, 1]), axis=1)
        want = face_geometry(mesh, elems, f, test) - self.centre
        for n in range(degree, degree + 4):
            fit = _Fitter(n, tri)
            C = fit.fit(face_geometry(mesh, elems, f, fit.uv) - self.centre)
            got = np.stack([patch_eval(c, test[:, 0], test[:, 1])[0] for c in C])
            if np.abs(got - want).max() <= FIT_TOL * self.scale:
                return n, C
        self._check(got, want, lambda j: f"element {elems[j]} face {f}")

    def _boxes(self, C, tri):
        """(Bernstein nets (m, n * n, 3) over the patch, lo, hi): a triangle's over its collapsed square."""
        if tri:
            fit = _Fitter(C.shape[1], False)
            X = np.stack([patch_eval(c, *collapse(*fit.uv.T))[0] for c in C])
            Cab = fit.fit(X)
            test = np.random.default_rng(2).uniform(-1, 1, (12, 2))
            self._check(np.stack([patch_eval(c, *test.T)[0] for c in Cab]),
                        np.stack([patch_eval(c, *collapse(*test.T))[0] for c in C]), lambda j: "a triangle's square")
            C = Cab
        b = _bernstein(C).reshape(len(C), -1, 3)
        return b, b.min(axis=1), b.max(axis=1)

    def _subdivide(self, faces, C, n, tri, flat, max_depth):
        """(face (P,), C (P, n, n, 3), tri, lo (P, 3), hi (P, 3)): each patch, or its children
        where its Bernstein net is not within `flat` of its extent from a plane."""
        fit = _Fitter(n, tri)
        test = np.random.default_rng(3).uniform(-1, 1, (12, 2))
        if tri:
            test = np.stack(collapse(*test.T), axis=1)
        out_f, out_C, out_lo, out_hi = [], [], [], []
        for depth in range(max_depth + 1):
            b, lo, hi = self._boxes(C, tri)
            centred = b - b.mean(axis=1, keepdims=True)
            normal = np.linalg.svd(centred, full_matrices=False)[2][:, -1]  # (m, 3): least-spread direction
            thick = np.abs(np.einsum("mpc,mc->mp", centred, normal)).max(axis=1)
            done = (thick <= flat * np.linalg.norm(hi - lo, axis=1)) | (depth == max_depth)
            out_f.append(faces[done]), out_C.append(C[done]), out_lo.append(lo[done]), out_hi.append(hi[done])
            if done.all():
                break
            faces, C = faces[~done], C[~done]
            kids = []
            for k in range(4):
                X = np.stack([patch_eval(c, *_child_points(fit.uv, tri, k).T)[0] for c in C])
                kid = fit.fit(X)
                self._check(np.stack([patch_eval(c, *test.T)[0] for c in kid]),
                            np.stack([patch_eval(c, *_child_points(test, tri, k).T)[0] for c in C]),
                            lambda j: f"face {faces[j]}'s child")
                kids.append(kid)
            faces, C = np.repeat(faces, 4), np.stack(kids, axis=1).reshape(-1, n, n, 3)
        return (np.concatenate(out_f), np.concatenate(out_C), tri, np.concatenate(out_lo), np.concatenate(out_hi))


def patch_eval(C, u, v):
    """x, dx/du, dx/dv of the patch at (u, v)."""
    n = C.shape[0]
    k = np.arange(n)
    u, v = np.asarray(u, float), np.asarray(v, float)
    pu, pv = u[:, None] ** k, v[:, None] ** k
    du = np.zeros_like(pu)
    dv = np.zeros_like(pv)
    du[:, 1:] = k[1:] * u[:, None] ** k[:-1]
    dv[:, 1:] = k[1:] * v[:, None] ** k[:-1]
    return (np.einsum("pa,pb,abc->pc", pu, pv, C), np.einsum("pa,pb,abc->pc", du, pv, C),
            np.einsum("pa,pb,abc->pc", pu, dv, C))


def box_chord(o, d, lo, hi):
    """Length of each ray (o + t d, t >= 0) inside the box [lo, hi], float64."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - o) / d
        tb = (hi - o) / d
    t0 = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), np.minimum(ta, tb)).max(axis=-1)
    t1 = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), np.maximum(ta, tb)).min(axis=-1)
    return np.clip(t1 - np.maximum(t0, 0.0), 0.0, None)


# the Newton starts on a sub-patch, in its square (a triangle: through collapse): the centre and
# the middles of its quarters
STARTS = np.array([[0.0, 0.0], [-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]])


def _starts(tri):
    a, b = STARTS.T
    return collapse(a, b) if tri else (a, b)


def in_face(u, v, tri):
    e = EDGE_TOL
    if tri:
        return (u >= -1 - e) & (v >= -1 - e) & (u + v <= e)
    return np.maximum(np.abs(u), np.abs(v)) <= 1 + e


def _newton(C, tri, o, d, scale, su, sv, found):
    """(ok, u, v, t) of Newton on x(u, v) = o + t d from (su, sv), deflated by the roots `found`
    (rows of (u, v, t / scale), NaN for none; Farrell, Birkisson and Funke 2015: the step scaled by
    1 / (1 - grad(m)/m . step), m = prod (1 / |z - r|^2 + 1), z = (u, v, t / scale))."""
    n = len(o)
    u, v = np.full(n, su), np.full(n, sv)
    t = np.einsum("ij,ij->i", patch_eval(C, u, v)[0] - o, d) / np.einsum("ij,ij->i", d, d)
    for _ in range(ITERATIONS):
        x, xu, xv = patch_eval(C, u, v)
        F = x - o - t[:, None] * d
        M = np.stack([xu, xv, -d], axis=2)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(M, F[..., None])[..., 0]
            z = np.stack([u, v, t / scale], axis=1)
            dz = -step * np.array([1.0, 1.0, 1.0 / scale])
            g = np.zeros(n)
            for r in found:
                diff = z - r
                nn = np.maximum(np.einsum("ij,ij->i", diff, diff), 1e-300)
                g += np.nan_to_num(-2.0 * np.einsum("ij,ij->i", diff, dz) / (nn * (1.0 + nn)))
            step = step / (1.0 - g)[:, None]
        step = np.nan_to_num(step, nan=0.0, posinf=0.0, neginf=0.0)
        u, v, t = np.clip(u - step[:, 0], -1.5, 1.5), np.clip(v - step[:, 1], -1.5, 1.5), t - step[:, 2]
    F = patch_eval(C, u, v)[0] - o - t[:, None] * d
    ok = (np.abs(F).max(axis=1) < ROOT_TOL * scale) & in_face(u, v, tri) & (t >= 0)
    return ok, u, v, t


def _face_hits(C, tri, o, d, scale, starts=None):
    """t of every crossing of the rays with one patch (NaN where none), up to one per start. A
    start whose plain Newton fails, or finds a root found before, runs again deflated by the
    roots found so far (_newton), so that a ray crossing the patch twice close together, grazing
    it, finds both; deflation only ever adds to what plain Newton finds."""
    hits, found = [], []
    su_all, sv_all = _starts(tri) if starts is None else starts
    for su, sv in zip(su_all, sv_all):
        ok, u, v, t = _newton(C, tri, o, d, scale, su, sv, [])
        known = np.zeros(len(o), bool)
        for h in hits:
            known |= np.abs(h - t) < DUPLICATE * scale
        again = np.nonzero((~ok | known) & np.any([np.isfinite(r[:, 0]) for r in found], axis=0))[0] \
            if found else np.zeros(0, np.int64)
        ok &= ~known
        if len(again):
            ok2, u2, v2, t2 = _newton(C, tri, o[again], d[again], scale, su, sv, [r[again] for r in found])
            new = np.ones(len(again), bool)
            for h in hits:
                new &= ~(np.abs(h[again] - t2) < DUPLICATE * scale)
            take = again[ok2 & new]
            ok[take], u[take], v[take], t[take] = True, u2[ok2 & new], v2[ok2 & new], t2[ok2 & new]
        hits.append(np.where(ok, t, np.nan))
        found.append(np.where(ok[:, None], np.stack([u, v, t / scale], axis=1), np.nan))
    return np.stack(hits, axis=1)


def _pair_up(H, scale):
    """Chord lengths from each row's crossings (NaN for none): sorted, duplicates dropped,
    alternately entering and leaving. Rows with an odd count get NaN."""
    H = np.sort(H, axis=1)
    dup = np.zeros_like(H, dtype=bool)
    dup[:, 1:] = np.abs(np.diff(H, axis=1)) < DUPLICATE * scale
    H = np.sort(np.where(dup, np.nan, H), axis=1)
    count = np.isfinite(H).sum(axis=1)
    L = np.zeros(len(H))
    for k in range(0, H.shape[1] - 1, 2):
        seg = H[:, k + 1] - H[:, k]
        L += np.where(np.isfinite(seg), seg, 0.0)
    return np.where(count % 2 == 0, L, np.nan)


def _rays(boundary, o, d):
    o = o.reshape(-1, 3).astype(np.float64) - boundary.centre
    d = d.reshape(-1, 3).astype(np.float64)
    return o, d


def _all_hits(boundary, o, d, starts=None):
    """(rays, crossings) t of every crossing found (NaN padded), rays (n, 3) about the centre;
    starts: Newton's starts (a, b) in a sub-patch's square (default STARTS)."""
    a, b = STARTS.T if starts is None else starts
    cols = [np.full((len(o), 0), np.nan)]
    for C, tri, lo, hi in zip(boundary.patches, boundary.tri, boundary.lo, boundary.hi):
        near = box_chord(o, d, lo, hi) > 0
        col = np.full((len(o), len(a)), np.nan)
        if near.any():
            col[near] = _face_hits(C, bool(tri), o[near], d[near], boundary.scale,
                                   starts=collapse(a, b) if tri else (a, b))
        cols.append(col)
    return np.concatenate(cols, axis=1)


def dense_boundary(mesh) -> Boundary:
    """The thorough search's patches (DENSE_FLAT, DENSE_DEPTH): for the rays the default one
    leaves undecided, mostly rays that graze a fold of the boundary."""
    return Boundary(mesh, flat=DENSE_FLAT, max_depth=DENSE_DEPTH)


def dense_starts():
    """The thorough search's Newton starts: a DENSE_STARTS x DENSE_STARTS grid on each sub-patch."""
    g = np.linspace(-0.8, 0.8, DENSE_STARTS)
    return tuple(x.ravel() for x in np.meshgrid(g, g, indexing="ij"))


def chords_numpy(boundary: Boundary, o, d, starts=None):
    """Chord of each ray (o, d: (..., 3)) through the mesh; NaN where the crossings are odd.
    starts: Newton's starts (a, b) on each sub-patch's square, default STARTS (a denser grid: a
    slower, more thorough search)."""
    shape = o.shape[:-1]
    o, d = _rays(boundary, o, d)
    return _pair_up(_all_hits(boundary, o, d, starts), boundary.scale).reshape(shape)


def intervals(boundary: Boundary, o, d, starts=None):
    """Per ray (o, d: (n, 3)), [(t_in, t_out)] where it is inside the mesh, or None where its
    crossings are odd (chords_numpy's crossings, duplicates dropped)."""
    H = np.sort(_all_hits(boundary, *_rays(boundary, o, d), starts), axis=1)
    out = []
    for h in H:
        h = h[np.isfinite(h)]
        if len(h):
            h = h[np.concatenate([[True], np.diff(h) >= DUPLICATE * boundary.scale])]
        out.append(None if len(h) % 2 else [(float(a), float(b)) for a, b in zip(h[0::2], h[1::2])])
    return out


# ----------------------------------------------------------------------------- the Warp kernel

_KERNEL = None


def _kernel():
    """Built on first use: Warp is imported only by callers that have it."""
    global _KERNEL
    if _KERNEL is not None:
        return _KERNEL
    import warp as wp

    f64, v3 = wp.float64, wp.vec3d
    NSTARTS = len(STARTS)

    @wp.func
    def patch_at(C: wp.array(dtype=v3, ndim=3), f: int, n: int, u: f64, v: f64):
        """x, dx/du, dx/dv of patch f at (u, v) (Horner in v inside Horner in u)."""
        x = v3()
        xu = v3()
        xv = v3()
        for ai in range(n):
            a = n - 1 - ai
            row = v3()
            drow = v3()
            for bi in range(n):
                b = n - 1 - bi
                drow = drow * v + row
                row = row * v + C[f, a, b]
            xu = xu * u + x
            x = x * u + row
            xv = xv * u + drow
        return x, xu, xv

    @wp.func
    def deflation(z: v3, dz: v3, r: v3, active: bool):
        """grad(m_r)/m_r . dz of the deflation m_r = 1 / |z - r|^2 + 1 (_face_hits), 0 when not active."""
        if not active:
            return f64(0.0)
        diff = z - r
        nn = wp.max(wp.dot(diff, diff), f64(1.0e-300))
        return f64(-2.0) * wp.dot(diff, dz) / (nn * (f64(1.0) + nn))

    @wp.func
    def newton(C: wp.array(dtype=v3, ndim=3), f: int, n: int, o: v3, d: v3, u: f64, v: f64, scale: f64,
               r0: v3, r1: v3, r2: v3, r3: v3, nr: int):
        """(u, v, t) after Newton from (u, v), deflated by the first nr of r0..r3 (_newton)."""
        x, xu, xv = patch_at(C, f, n, u, v)
        t = wp.dot(x - o, d) / wp.dot(d, d)
        for it in range(ITERATIONS):
            x, xu, xv = patch_at(C, f, n, u, v)
            F = x - o - t * d
            M = wp.mat33d(xu[0], xv[0], -d[0], xu[1], xv[1], -d[1], xu[2], xv[2], -d[2])
            if wp.determinant(M) == f64(0.0):
                break
            step = wp.inverse(M) * F
            if nr > 0:
                z = v3(u, v, t / scale)
                dz = v3(-step[0], -step[1], -step[2] / scale)
                g = deflation(z, dz, r0, nr > 0) + deflation(z, dz, r1, nr > 1)
                g = g + deflation(z, dz, r2, nr > 2) + deflation(z, dz, r3, nr > 3)
                step = step / (f64(1.0) - g)
            u = wp.clamp(u - step[0], f64(-1.5), f64(1.5))
            v = wp.clamp(v - step[1], f64(-1.5), f64(1.5))
            t = t - step[2]
            if wp.max(wp.max(wp.abs(step[0]), wp.abs(step[1])), wp.abs(step[2]) / scale) < f64(STEP_TOL):
                break
        return v3(u, v, t)

    @wp.func
    def is_root(C: wp.array(dtype=v3, ndim=3), f: int, n: int, o: v3, d: v3, z: v3, is_tri: bool, scale: f64):
        """Whether (u, v, t) = z is a crossing: on the ray to ROOT_TOL, in the face, ahead."""
        x, xu, xv = patch_at(C, f, n, z[0], z[1])
        F = x - o - z[2] * d
        err = wp.max(wp.max(wp.abs(F[0]), wp.abs(F[1])), wp.abs(F[2]))
        e = f64(EDGE_TOL)
        inside = wp.max(wp.abs(z[0]), wp.abs(z[1])) <= f64(1.0) + e
        if is_tri:
            inside = z[0] >= f64(-1.0) - e and z[1] >= f64(-1.0) - e and z[0] + z[1] <= e
        return err < f64(ROOT_TOL) * scale and inside and z[2] >= f64(0.0)

    @wp.func
    def seen(hits: wp.array(dtype=f64, ndim=2), i: int, count: int, t: f64, dup: f64):
        """Whether t is a crossing the ray has (from another start, or a neighbouring patch at an edge)."""
        known = int(0)
        for k in range(wp.min(count, MAX_HITS)):
            if wp.abs(hits[i, k] - t) < dup:
                known = 1
        return known == 1

    @wp.kernel
    def chord(C: wp.array(dtype=v3, ndim=3), tri: wp.array(dtype=wp.int32), lo: wp.array(dtype=v3),
              hi: wp.array(dtype=v3), n: int, scale: f64, origins: wp.array(dtype=v3), dirs: wp.array(dtype=v3),
              hits: wp.array(dtype=f64, ndim=2), length: wp.array(dtype=f64), crossings: wp.array(dtype=wp.int32)):
        i = wp.tid()
        o = origins[i]
        d = dirs[i]
        dup = f64(DUPLICATE) * scale
        count = int(0)
        for f in range(C.shape[0]):
            # slab test against the patch's box
            t0 = f64(-1.0e300)
            t1 = f64(1.0e300)
            for k in range(3):
                if d[k] == f64(0.0):
                    if o[k] < lo[f][k] or o[k] > hi[f][k]:
                        t1 = f64(-1.0)
                else:
                    ta = (lo[f][k] - o[k]) / d[k]
                    tb = (hi[f][k] - o[k]) / d[k]
                    t0 = wp.max(t0, wp.min(ta, tb))
                    t1 = wp.min(t1, wp.max(ta, tb))
            if t1 < wp.max(t0, f64(0.0)):
                continue
            is_tri = tri[f] == 1
            nr = int(0)  # roots found on this patch: they deflate the reruns (_face_hits)
            r0 = v3()
            r1 = v3()
            r2 = v3()
            r3 = v3()
            for s in range(NSTARTS):
                a = f64(0.0)
                b = f64(0.0)
                if s > 0:  # STARTS' quarter middles
                    a = f64(0.5) * f64(2 * ((s - 1) % 2) - 1)
                    b = f64(0.5) * f64(2 * ((s - 1) // 2) - 1)
                u = a
                v = b
                if is_tri:  # collapse(a, b)
                    u = f64(0.5) * (f64(1.0) + a) * (f64(1.0) - b) - f64(1.0)
                z = newton(C, f, n, o, d, u, v, scale, r0, r1, r2, r3, 0)
                ok = is_root(C, f, n, o, d, z, is_tri, scale)
                known = ok and seen(hits, i, count, z[2], dup)
                if (not ok or known) and nr > 0:
                    z = newton(C, f, n, o, d, u, v, scale, r0, r1, r2, r3, nr)
                    ok = is_root(C, f, n, o, d, z, is_tri, scale)
                    known = ok and seen(hits, i, count, z[2], dup)
                if ok and not known:
                    zs = v3(z[0], z[1], z[2] / scale)
                    if nr == 0:
                        r0 = zs
                    elif nr == 1:
                        r1 = zs
                    elif nr == 2:
                        r2 = zs
                    elif nr == 3:
                        r3 = zs
                    nr += 1
                    if count < MAX_HITS:
                        hits[i, count] = z[2]
                    count += 1
        if count > MAX_HITS:
            crossings[i] = -1  # too many crossings to keep: the caller refuses the ray
            length[i] = f64(0.0)
            return
        # insertion sort, then pairs (in, out)
        for k in range(1, count):
            key = hits[i, k]
            j = k - 1
            while j >= 0 and hits[i, j] > key:
                hits[i, j + 1] = hits[i, j]
                j -= 1
            hits[i, j + 1] = key
        L = f64(0.0)
        for k in range(count // 2):
            L += hits[i, 2 * k + 1] - hits[i, 2 * k]
        crossings[i] = count
        length[i] = L

    _KERNEL = chord
    return chord


class WarpChords:
    """chords_numpy on `device` through the Warp kernel (float64): the patches uploaded once, rays
    in chunks of `chunk`. Calling it gives (chords, NaN where the crossings are odd or too many)."""

    def __init__(self, boundary: Boundary, device: str = "cpu", chunk: int = 1 << 21):
        import warp as wp

        self.boundary, self.device, self.chunk = boundary, device, chunk
        self.kernel = _kernel()
        with wp.ScopedDevice(device):
            self.C = wp.array(boundary.patches, dtype=wp.vec3d)
            self.tri = wp.array(boundary.tri, dtype=wp.int32)
            self.lo = wp.array(boundary.lo, dtype=wp.vec3d)
            self.hi = wp.array(boundary.hi, dtype=wp.vec3d)

    def __call__(self, o, d):
        import warp as wp

        shape = o.shape[:-1]
        o, d = _rays(self.boundary, o, d)
        L = np.empty(len(o))
        with wp.ScopedDevice(self.device):
            for s in range(0, len(o), self.chunk):
                m = min(self.chunk, len(o) - s)
                length = wp.empty(m, dtype=wp.float64)
                count = wp.empty(m, dtype=wp.int32)
                hits = wp.empty((m, MAX_HITS), dtype=wp.float64)
                wp.launch(self.kernel, m, [self.C, self.tri, self.lo, self.hi, int(self.boundary.patches.shape[1]),
                                           float(self.boundary.scale), wp.array(o[s:s + m], dtype=wp.vec3d),
                                           wp.array(d[s:s + m], dtype=wp.vec3d), hits, length, count])
                c = count.numpy()
                L[s:s + m] = np.where((c < 0) | (c % 2 == 1), np.nan, length.numpy())
        return L.reshape(shape)


def chords_warp(boundary: Boundary, o, d, device: str = "cpu", chunk: int = 1 << 21):
    """chords_numpy, with the crossings found, sorted and paired by a float64 Warp kernel on `device`."""
    return WarpChords(boundary, device, chunk)(o, d)
