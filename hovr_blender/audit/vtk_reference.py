"""An independent float64 reference for chosen pixels: slow (about a second a pixel), sharing no
code with the Warp kernels or engine/expansions.py.

For each pixel ray (render contract §4, computed here from the view):
1. Where the ray lies in which cell: every cell whose (padded) box the ray meets is sampled
   along the ray with VTK's own point location (vtkCell.EvaluatePosition, whose Newton stops
   at ~1e-3 in parametric coordinates for higher-order cells, then polished by Newton on
   VTK's own shape functions and their derivatives to 1e-12), and each run of inside samples
   is bounded by bisection to 1e-13 of the ray's extent. A gap left between two runs (a cell the
   ray only clips, its chord shorter than the samples' spacing) is sampled again at its own scale
   against the cells whose boxes span it. Runs of different cells that overlap by more than that are reported.
2. Where the field crosses a transfer-function breakpoint: sign changes of f - level between
   64 samples per stretch, located by bisection; between crossings the integrand is smooth.
3. Emission-absorption (contract §3) on each smooth piece by adaptive Gauss-Kronrod (G7/K15),
   left to right so each panel starts from the exact transmittance before it; the optical
   depth to each node by 12-point Gauss-Legendre from the panel's start. A panel is accepted
   when its K15/G7 difference (colour and depth) is below the tolerance.
The field comes from VTK's interpolation of the cell's nodal values (vtk_volume.py). The error
estimate is the sum of the accepted panels' differences, plus any overlap or unresolved stretch,
plus each stretch end's slack: a cell counts points within INSIDE_TOL (parametric) outside it as
inside, so an end may lie INSIDE_TOL over the ray's crossing rate beyond the face.
"""
from __future__ import annotations

import array
from dataclasses import dataclass, field

import numpy as np

from .vtk_volume import FIELD, import_vtk

# Gauss-Kronrod 7/15 on [-1, 1] (Kronrod's nodes and weights; G7 weights on the odd nodes)
_XK = np.array([0.991455371120813, 0.949107912342759, 0.864864423359769, 0.741531185599394,
                0.586087235467691, 0.405845151377397, 0.207784955007898, 0.0])
_WK = np.array([0.022935322010529, 0.063092092629979, 0.104790010322250, 0.140653259715525,
                0.169004726639267, 0.190350578064785, 0.204432940075298, 0.209482141084728])
_WG = np.array([0.129484966168870, 0.279705391489277, 0.381830050505119, 0.417959183673469])
GK_X = np.concatenate([-_XK[:-1], _XK[::-1]])
GK_WK = np.concatenate([_WK[:-1], _WK[::-1]])
GK_WG = np.zeros(15)
GK_WG[1::2] = np.concatenate([_WG[:-1], _WG[::-1]])
GL_X, GL_W = np.polynomial.legendre.leggauss(12)

SAMPLES_PER_BOX = 48
INSIDE_TOL = 1e-12  # in VTK's parametric coordinates
NEWTON_STEPS = 16
FAR = 0.05  # of a cell's size: a point VTK finds this far outside the cell is not polished by Newton
NEWTON_TOL = 1e-12  # parametric; the rounding floor of a degree-14 cell's map is ~1e-13
NEAR_NEWTON_STEPS = 6  # from the last point located in the cell; then VTK's own search
SIMPLEX_TRIANGLE = (13, 73)  # VTK_WEDGE, VTK_LAGRANGE_WEDGE
SIMPLEX_TET = (10, 71)  # VTK_TETRA, VTK_LAGRANGE_TETRAHEDRON
CROSSING_SAMPLES = 64
MAX_PANELS = 20000


def face_margins(kind: int, pc) -> list:
    """(margin, its gradient in pc) of each face of a cell of VTK type `kind` at parametric pc:
    the margin is >= 0 inside (a wedge: a triangle in (r, s), a line in t; a tetrahedron; else a
    hexahedron's unit cube)."""
    r, s, t = pc
    if kind in SIMPLEX_TRIANGLE:
        return [(r, (1, 0, 0)), (s, (0, 1, 0)), (1 - r - s, (-1, -1, 0)), (t, (0, 0, 1)), (1 - t, (0, 0, -1))]
    if kind in SIMPLEX_TET:
        return [(r, (1, 0, 0)), (s, (0, 1, 0)), (t, (0, 0, 1)), (1 - r - s - t, (-1, -1, -1))]
    return [(r, (1, 0, 0)), (1 - r, (-1, 0, 0)), (s, (0, 1, 0)), (1 - s, (0, -1, 0)), (t, (0, 0, 1)),
            (1 - t, (0, 0, -1))]


@dataclass
class PixelResult:
    rgba: np.ndarray  # (4,) RGB = C + T background, A = 1 - T
    error: float  # self-reported: quadrature differences + unresolved geometry
    panels: int = 0
    evaluations: int = 0
    stretches: list = field(default_factory=list)  # (t0, t1, cell)
    notes: list = field(default_factory=list)
    failed: str | None = None  # why the reference has no value here (rgba NaN, error inf)


class _NotLocated(Exception):
    """A point of a stretch its cell does not locate: the integrand has no value there."""


def _inside(kind, pc) -> bool:
    """Parametric coordinates pc inside a cell of VTK type `kind`, to INSIDE_TOL."""
    return min(m for m, _ in face_margins(kind, pc)) >= -INSIDE_TOL


def _located(f, ts, c):
    """Raise _NotLocated where cell c gave no field value at one of the ray parameters ts."""
    bad = ~np.isfinite(f)
    if bad.any():
        raise _NotLocated(f"cell {c} does not locate the ray's point at t = {ts[np.argmax(bad)]:.12g} inside its stretch")


class IndependentReference:
    """The reference for one volume (a vtkUnstructuredGrid with point array FIELD) and one
    transfer function (arrays of breakpoints)."""

    def __init__(self, grid, color_s, color_rgb, density_s, density_tau, tol: float = 1e-10, pyramids=None):
        """grid may be None (no VTK cells); pyramids (pyramids.AffinePyramids): cells after the
        grid's, decided by their exact affine inverse (pyramids.py)."""
        vtk = import_vtk()
        from vtkmodules.util.numpy_support import vtk_to_numpy

        self.grid = grid
        self.pyramids = pyramids
        if grid is not None and grid.GetNumberOfCells():
            self.values = vtk_to_numpy(grid.GetPointData().GetArray(FIELD)).astype(np.float64)
            points = vtk_to_numpy(grid.GetPoints().GetData()).astype(np.float64)
        self.n_cells = grid.GetNumberOfCells() if grid is not None else 0
        self.cells = []
        boxes = np.zeros((self.n_cells, 6))
        for c in range(self.n_cells):
            cell = vtk.vtkGenericCell()
            grid.GetCell(c, cell)
            ids = np.array([cell.GetPointId(i) for i in range(cell.GetNumberOfPoints())], dtype=np.int64)
            # VTK writes the shape functions into buffers numpy reads in place (a list is copied each time)
            self.cells.append((cell, ids, array.array("d", bytes(8 * len(ids))), array.array("d", bytes(24 * len(ids))),
                               points[ids]))
            boxes[c] = grid.GetCell(c).GetBounds()
        # a curved Lagrange cell may bulge beyond its nodes' box: pad by a tenth of its size
        size = np.maximum(boxes[:, 1::2] - boxes[:, 0::2], 0.0).max(axis=1, keepdims=True)
        self.far2 = (FAR * size[:, 0]) ** 2
        self.lo = boxes[:, 0::2] - 0.1 * size
        self.hi = boxes[:, 1::2] + 0.1 * size
        if pyramids is not None and len(pyramids):  # affine: their vertices' box holds them
            pad = 1e-9 * np.ptp(pyramids.hi - pyramids.lo, axis=1, keepdims=True)
            self.lo = np.concatenate([self.lo, pyramids.lo - pad])
            self.hi = np.concatenate([self.hi, pyramids.hi + pad])
        self.color_s, self.color_rgb = np.asarray(color_s, float), np.asarray(color_rgb, float)
        self.density_s, self.density_tau = np.asarray(density_s, float), np.asarray(density_tau, float)
        self.levels = np.unique(np.concatenate([self.color_s, self.density_s]))
        self.tol = float(tol)
        self._closest = [0.0, 0.0, 0.0]
        self._near = {}  # cell -> parametric coordinates of the last point located inside it
        self._sub = vtk.reference(0)
        self._pc = [0.0, 0.0, 0.0]
        self._d2 = vtk.reference(0.0)
        self._center = [0.0, 0.0, 0.0]
        self._by_node = {}  # cell type -> layout of InterpolateDerivs (see _jacobian)
        self.evaluations = 0

    # ------------------------------------------------------------------ the field
    def _at(self, c: int, x) -> tuple[bool, float]:
        """(inside cell c, field of cell c's interpolant) at world point x. Inside is decided on
        the polished parametric coordinates with a tolerance of 1e-12 (VTK's own status
        allows 1e-3)."""
        self.evaluations += 1
        if c >= self.n_cells:
            return self.pyramids.at(c - self.n_cells, x)
        cell, ids, w, dw, nodes = self.cells[c]
        pc = self._locate(c, np.asarray(x, dtype=np.float64))
        if pc is None:
            return False, np.nan
        cell.InterpolateFunctions(list(pc), w)
        inside = _inside(cell.GetCellType(), pc)
        return inside, float(np.frombuffer(w) @ self.values[ids])

    def _locate(self, c: int, x: np.ndarray):
        """Cell c's parametric coordinates of world point x, polished by Newton from VTK's own guess
        or the cell's centre, or the last point located inside c; None where all fail (VTK's
        guesses are not tried where it puts x FAR from the cell). A cell whose map folds by a face
        gives a point there two preimages, one outside the cell, where VTK's guess may lead: the
        one inside is taken where any start finds it. First, Newton from the last point located
        inside c, in a few steps: a preimage inside c is the one these find (VTK's search costs
        more than the polish)."""
        cell, ids, w, dw, nodes = self.cells[c]
        near = self._near.get(c)
        kind = cell.GetCellType()
        if near is not None:  # the last point located in c: the ray's points come near each other
            pc = self._newton(cell, w, dw, nodes, x, near, NEAR_NEWTON_STEPS)
            if pc is not None and _inside(kind, pc):
                self._near[c] = pc
                return pc
        starts = []
        status = cell.EvaluatePosition(list(map(float, x)), self._closest, self._sub, self._pc, self._d2, w)
        # VTK's distance to its linear sub-cells: the cell is FAR away, less their linearisation
        # error, orders of magnitude below FAR of the cell's size (by a rim that bulges past the
        # sub-cells, not always: the last point's start, with all its steps, may still find it)
        if not (status == 0 and self._d2.get() > self.far2[c]):
            cell.GetParametricCenter(self._center)
            starts = [list(self._pc), list(self._center)]
        if near is not None:
            starts.append(list(near))
        found = None
        for start in starts:
            pc = self._newton(cell, w, dw, nodes, x, np.array(start, dtype=np.float64))
            if pc is None:
                continue
            if _inside(kind, pc):
                self._near[c] = pc
                return pc
            found = pc if found is None else found
        return found

    def _jacobian(self, cell, pc, w, dw, nodes):
        """J[k] = dx / d(pcoord k) from VTK's shape-function derivatives. VTK's cells lay these out
        by derivative (dN_i/dr for all i, then d/ds, d/dt) or by node (dN_i/dr, dN_i/ds, dN_i/dt
        per i): which one is found once per cell type against finite differences."""
        cell.InterpolateDerivs(list(pc), dw)
        kind = cell.GetCellType()
        if kind not in self._by_node:
            n = len(w)
            h = 1e-6
            fd = []
            for k in range(3):
                plus, minus = np.array(pc, float), np.array(pc, float)
                plus[k] += h
                minus[k] -= h
                cell.InterpolateFunctions(list(plus), w)
                xp = np.frombuffer(w) @ nodes
                cell.InterpolateFunctions(list(minus), w)
                fd.append((xp - np.frombuffer(w) @ nodes) / (2 * h))
            cell.InterpolateFunctions(list(pc), w)
            by_node = np.frombuffer(dw).reshape(n, 3).T @ nodes
            self._by_node[kind] = np.abs(by_node - np.array(fd)).max() < np.abs(
                np.frombuffer(dw).reshape(3, n) @ nodes - np.array(fd)).max()
        n = len(w)
        d = np.frombuffer(dw).reshape(n, 3).T if self._by_node[kind] else np.frombuffer(dw).reshape(3, n)
        return d @ nodes

    def _newton(self, cell, w, dw, nodes, x, pc, steps=NEWTON_STEPS):
        """Parametric coordinates of x by Newton on VTK's shape functions from pc, or None."""
        for _ in range(steps):
            cell.InterpolateFunctions(list(pc), w)
            J = self._jacobian(cell, pc, w, dw, nodes)  # leaves w at pc
            try:
                step = np.linalg.solve(J.T, np.frombuffer(w) @ nodes - x)
            except np.linalg.LinAlgError:
                return None
            pc = pc - step
            if not np.all(np.isfinite(pc)) or np.abs(pc).max() > 10.0:
                return None
            if np.abs(step).max() < NEWTON_TOL:
                return pc
        return None

    def _end_slack(self, c: int, o, d, t: float) -> float:
        """How far along the ray the face cell c's stretch ends on at t may be from t: INSIDE_TOL over
        the rate the ray's parametric coordinates cross the face nearest there (0 where the point
        does not locate; a ray running along the face has the slack of a rate of INSIDE_TOL: a whole
        parametric unit, as good as undecided)."""
        pc = self._locate(c, o + t * d)
        if pc is None:
            return 0.0
        cell, ids, w, dw, nodes = self.cells[c]
        J = self._jacobian(cell, pc, w, dw, nodes)
        try:
            rate = np.linalg.solve(J.T, d)  # d(pc)/dt
        except np.linalg.LinAlgError:
            return 0.0
        _, grad = min(face_margins(cell.GetCellType(), pc), key=lambda f: f[0])
        speed = abs(float(np.dot(grad, rate)))
        return INSIDE_TOL / max(speed, INSIDE_TOL)

    def tau(self, s):
        return np.interp(s, self.density_s, self.density_tau)

    def kappa(self, s):
        s = np.asarray(s, float)
        return np.stack([np.interp(s, self.color_s, self.color_rgb[:, k]) for k in range(3)], axis=-1)

    # ------------------------------------------------------------------ 1. the stretches
    def stretches(self, o, d, t0, t1, cover=None):
        """Sorted (a, b, cell) where the ray o + t d, t in [t0, t1], lies in a cell. cover: the
        intervals [(a, b)] where the ray is known to be inside the domain (the exact chords'
        crossings, audit/chords.py, along the same o and d): a part of them that no stretch
        covers, such as a cell clipped before the first stretch or after the last (no gap
        brackets those), is sampled again at its own scale."""
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            ta = (self.lo - o) * inv
            tb = (self.hi - o) * inv
        tmin = np.nanmax(np.where(np.isfinite(ta), np.minimum(ta, tb), -np.inf), axis=1)
        tmax = np.nanmin(np.where(np.isfinite(tb), np.maximum(ta, tb), np.inf), axis=1)
        parallel = (d == 0)
        outside = np.any(parallel & ((o < self.lo) | (o > self.hi)), axis=1)
        tmin, tmax = np.maximum(tmin, t0), np.minimum(tmax, t1)
        hits = np.nonzero((tmax > tmin) & ~outside)[0]
        scale = max(abs(t1 - t0) if np.isfinite(t1) else 0.0, float(np.max(tmax[hits], initial=0.0)), 1e-300)
        eps = 1e-13 * scale
        out = []
        for c in hits:
            out += self._runs(c, o, d, tmin[c], tmax[c], eps)
        out.sort()
        # a cell the ray only clips (a corner or edge, a chord shorter than its box / SAMPLES_PER_BOX)
        # can fall between the samples and leave a gap between the stretches of its neighbours:
        # every gap is sampled again at its own scale against the cells whose boxes span it
        gaps = [(b, a) for (_, b, _), (a, _, _) in zip(out, out[1:]) if a - b > 2.0 * eps]
        for g0, g1 in gaps:
            for c in hits[(tmin[hits] < g1) & (tmax[hits] > g0)]:
                # (not the neighbours' own ends again: runs at the gap's ends that round to inside)
                out += [r for r in self._runs(c, o, d, max(g0, tmin[c]), min(g1, tmax[c]), eps) if r[1] - r[0] > 2.0 * eps]
        out.sort()
        for g0, g1 in uncovered(cover or [], out, 2.0 * eps):
            for c in hits[(tmin[hits] < g1) & (tmax[hits] > g0)]:
                out += [r for r in self._runs(c, o, d, max(g0, tmin[c]), min(g1, tmax[c]), eps) if r[1] - r[0] > 2.0 * eps]
        out.sort()
        return out

    def _runs(self, c, o, d, t0, t1, eps):
        """(a, b, c): the runs of [t0, t1] inside cell c, found by SAMPLES_PER_BOX + 1 samples and
        bounded by bisection (a run that touches t0 or t1 ends there)."""
        ts = np.linspace(t0, t1, SAMPLES_PER_BOX + 1)
        inside = np.array([self._at(c, o + t * d)[0] for t in ts])
        out = []
        k = 0
        while k < len(ts):
            if not inside[k]:
                k += 1
                continue
            j = k
            while j + 1 < len(ts) and inside[j + 1]:
                j += 1
            a = ts[k] if k == 0 else self._boundary(c, o, d, ts[k - 1], ts[k], eps)
            b = ts[j] if j == len(ts) - 1 else self._boundary(c, o, d, ts[j + 1], ts[j], eps)
            if b > a:
                out.append((a, b, int(c)))
            k = j + 1
        return out

    def _boundary(self, c, o, d, t_out, t_in, eps):
        """Bisection between an outside and an inside sample of cell c."""
        while abs(t_in - t_out) > eps:
            m = 0.5 * (t_in + t_out)
            if self._at(c, o + m * d)[0]:
                t_in = m
            else:
                t_out = m
        return 0.5 * (t_in + t_out)

    # ------------------------------------------------------------------ 2. the crossings
    def _pieces(self, c, o, d, a, b):
        """[a, ..., b]: the stretch cut where the field crosses a breakpoint level."""
        ts = np.linspace(a, b, CROSSING_SAMPLES + 1)
        f = np.array([self._at(c, o + t * d)[1] for t in ts])
        cuts = [a, b]
        eps = 1e-14 * max(abs(a), abs(b), b - a)
        for lvl in self.levels:
            g = f - lvl
            for i in np.nonzero(g[:-1] * g[1:] < 0)[0]:
                cuts.append(self._bisect_level(c, o, d, ts[i], ts[i + 1], g[i], lvl, eps))
        return sorted(set(cuts))

    # ------------------------------------------------------------------ 3. the integrals
    def _integrate_piece(self, c, o, d, a, b, state):
        """Adaptive G7/K15 on the smooth piece [a, b]; state = [C (3,), depth, error, panels]."""
        stack = [(a, b)]
        while stack:
            lo, hi = stack.pop()
            half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
            x = mid + half * GK_X
            f = np.array([self._at(c, o + t * d)[1] for t in x])
            _located(f, x, c)
            tau = self.tau(f)
            # depth from the panel's start to each node: 12-point Gauss-Legendre of tau
            depth = np.empty(15)
            for j, xj in enumerate(x):
                h = 0.5 * (xj - lo)
                u = lo + h * (GL_X + 1.0)
                fu = np.array([self._at(c, o + t * d)[1] for t in u])
                _located(fu, u, c)
                depth[j] = h * np.dot(GL_W, self.tau(fu))
            g = (tau * np.exp(-(state[1] + depth)))[:, None] * self.kappa(f)
            ck, cg = half * (GK_WK @ g), half * (GK_WG @ g)
            dk, dg = half * (GK_WK @ tau), half * (GK_WG @ tau)
            err = float(np.max(np.abs(ck - cg)) + np.exp(-state[1]) * abs(dk - dg))
            state[3] += 1
            if err <= self.tol or hi - lo <= 1e-14 * max(abs(hi), 1.0) or state[3] > MAX_PANELS:
                state[0] = state[0] + ck
                state[1] += dk
                state[2] += err
            else:
                stack.append((mid, hi))  # right half after the left one: front to back
                stack.append((lo, mid))

    def pixel(self, o, d, background, t0=0.0, t1=np.inf, cover=None) -> PixelResult:
        """The pixel of the ray o + t d (d is normalised; cover, for a unit d: see stretches)."""
        o, d = np.asarray(o, float), np.asarray(d, float)
        d = d / np.linalg.norm(d)
        self.evaluations = 0
        stretches = self.stretches(o, d, t0, t1, cover)
        state = [np.zeros(3), 0.0, 0.0, 0]
        # each stretch's ends are where its cell's inside test, with its INSIDE_TOL of slack, flips:
        # up to INSIDE_TOL over the rate the ray crosses that face from the face itself, light
        # gained or (at a shared face) counted twice, which the estimate carries
        slack = sum(self._end_slack(c, o, d, t) for a, b, c in stretches if c < self.n_cells for t in (a, b))
        state[2] += slack * float(np.max(self.density_tau)) * max(1.0, float(np.abs(self.color_rgb).max()),
                                                                  float(np.abs(np.asarray(background, float)).max()))
        notes = []
        end = -np.inf
        for a, b, c in stretches:
            if a < end - 1e-9 * max(abs(a), 1.0):  # cells overlapping along the ray
                notes.append(f"cell {c} overlaps the previous stretch by {end - a:.3g}")
                state[2] += abs(end - a) * float(np.max(self.density_tau))
                a = end
                if b <= a:
                    continue
            try:
                cuts = self._pieces(c, o, d, a, b)
                for lo, hi in zip(cuts[:-1], cuts[1:]):
                    self._integrate_piece(c, o, d, lo, hi, state)
            except _NotLocated as exc:
                # a NaN integrand never meets the tolerance: the quadrature would halve its panel
                # MAX_PANELS times (an hour) and still give NaN
                return PixelResult(np.full(4, np.nan), np.inf, state[3], self.evaluations, stretches, notes,
                                   failed=str(exc))
            end = max(end, b)
        T = float(np.exp(-state[1]))
        bg = np.asarray(background, float)
        rgba = np.concatenate([state[0] + T * bg, [1.0 - T]])
        return PixelResult(rgba, float(state[2]), state[3], self.evaluations, stretches, notes)

    # ------------------------------------------------------------------ 4. surfaces (contract §7)
    def first_crossing(self, o, d, level: float, t0=0.0, t1=np.inf) -> float:
        """t where the ray first meets f = level (nan: nowhere), from VTK's interpolation: each
        stretch sampled at CROSSING_SAMPLES + 1 points, the first sign change (or zero) bisected
        to 1e-14 of its extent. A ray that only touches the level between two samples is not
        seen here (the renderer's isolation finds it: tests/engine/test_isosurface.py)."""
        o, d = np.asarray(o, float), np.asarray(d, float)
        d = d / np.linalg.norm(d)
        for a, b, c in self.stretches(o, d, t0, t1):
            ts = np.linspace(a, b, CROSSING_SAMPLES + 1)
            g = np.array([self._at(c, o + t * d)[1] for t in ts]) - level
            hits = np.nonzero((g[:-1] == 0) | (g[:-1] * g[1:] < 0))[0]
            if len(hits) == 0:
                continue
            i = hits[0]
            lo, hi, glo = ts[i], ts[i + 1], g[i]
            if glo == 0:
                return float(lo)
            return float(self._bisect_level(c, o, d, lo, hi, glo, level, 1e-14 * max(abs(a), abs(b), b - a)))
        return float("nan")

    def _bisect_level(self, c, o, d, lo, hi, glo, level, eps) -> float:
        """The t in [lo, hi] where cell c's field along o + t d crosses `level` (glo: the field
        less the level at lo, of the other sign than at hi), bisected to eps."""
        while hi - lo > eps:
            m = 0.5 * (lo + hi)
            gm = self._at(c, o + m * d)[1] - level
            if (gm < 0) == (glo < 0):
                lo, glo = m, gm
            else:
                hi = m
        return 0.5 * (lo + hi)

    def value_at(self, x) -> float:
        """The field at world point x, in the first cell whose padded box holds x and that holds
        it (nan where none does)."""
        x = np.asarray(x, float)
        for c in np.nonzero(np.all((self.lo <= x) & (x <= self.hi), axis=1))[0]:
            inside, value = self._at(c, x)
            if inside:
                return value
        return float("nan")


def uncovered(cover, stretches, tol):
    """The parts of the intervals `cover` [(a, b)] that no stretch (a, b, cell) covers, longer than tol."""
    out = []
    for a, b in cover:
        for s0, s1, _ in sorted(stretches):
            if s1 <= a or s0 >= b:
                continue
            if s0 - a > tol:
                out.append((a, s0))
            a = max(a, s1)
        if b - a > tol:
            out.append((a, b))
    return out


def contract_ray(camera: dict, width: int, height: int, i: int, j: int):
    """(origin, unit direction) of pixel (i, j) (row 0 at the top), render contract §4,
    written out here so the reference depends on no project code for its rays."""
    eye, target, up = (np.asarray(camera[k], float) for k in ("eye", "target", "up"))
    u = (2.0 * (i + 0.5) / width - 1.0) * (width / height)
    v = 1.0 - 2.0 * (j + 0.5) / height
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    up2 = np.cross(right, fwd)
    if camera.get("projection", "perspective") == "orthographic":
        h = float(camera["height"])
        return eye + 0.5 * h * (u * right + v * up2), fwd
    t = np.tan(np.radians(float(camera["fov_y_deg"])) / 2.0)
    dvec = fwd + t * (u * right + v * up2)
    return eye, dvec / np.linalg.norm(dvec)
