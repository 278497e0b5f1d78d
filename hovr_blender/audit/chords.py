"""Exact chords through a curved hexahedral mesh, for watertightness audits: with a constant
density tau the contract's transmittance is exp(-tau L), L the length of the ray inside the
union of the elements. L comes from the mesh's boundary alone: every hexahedron face that no
other element shares is a polynomial patch x(u, v) of its element's map, each ray's crossings
of every patch are found by float64 Newton on (u, v, t) from a grid of starts, and the chord
is the sum of the in/out intervals of the sorted crossings.

Nothing here is shared with the renderer (no traversal, no element location, no BVH): the
patches are power series fitted to the element maps of engine/expansions (the mesh's definition),
and the Warp kernel below is a brute-force loop over the patches' boxes, in float64, so that
10 M rays take seconds on a GPU. `chords_numpy` is the same computation in numpy, the
kernel's own check at small sizes.
"""

import numpy as np

from ..engine import expansions as ex
from ..engine import shapes

HEX_FACES = [(0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0), (2, -1.0), (2, 1.0)]  # xi_axis = value
STARTS = 3  # Newton starts per direction on a patch
ITERATIONS = 30
MAX_HITS = 32  # crossings kept per ray
ROOT_TOL = 1e-12  # |x(u, v) - o - t d| at a root, world units (the meshes are of unit size)
DUPLICATE = 1e-9  # two crossings closer than this in t are one (a ray through an edge)


def boundary_faces(mesh):
    """(element, axis, value) of every hexahedron face that no other element shares (faces keyed
    by their four corner vertices, rounded)."""
    if not np.all(mesh.shape == shapes.HEX):
        raise ValueError("chords: hexahedral meshes only")
    V = shapes.VERTICES[shapes.HEX]
    count, where = {}, {}
    for e in range(mesh.num_elements):
        for axis, val in HEX_FACES:
            corners = mesh.vertices[e, :8][np.isclose(V[:, axis], val)]
            key = tuple(sorted(map(tuple, np.round(corners, 9))))
            count[key] = count.get(key, 0) + 1
            where[key] = (e, axis, val)
    return [where[k] for k, c in count.items() if c == 1]


def face_patch(mesh, face, n: int | None = None):
    """The face's map x(u, v) as a tensor power series C (n, n, 3), x = sum C_ab u^a v^b, fitted
    exactly (n at least the geometry's modes) to the element map on the face, and checked."""
    e, axis, val = face
    gm = tuple(int(v) for v in mesh.geom_modes[e])
    G = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(shapes.HEX, gm)]
    n = max(gm) if n is None else max(n, max(gm))
    s = np.cos(np.pi * np.arange(n) / (n - 1))
    U, Vv = np.meshgrid(s, s, indexing="ij")

    def on_face(uv):
        xi = np.zeros((len(uv), 3))
        xi[:, axis] = val
        xi[:, [k for k in range(3) if k != axis]] = uv
        return ex.eval_modal(shapes.HEX, gm, G, xi)

    X = on_face(np.stack([U.ravel(), Vv.ravel()], axis=1))
    P = np.einsum("pa,pb->pab", U.ravel()[:, None] ** np.arange(n), Vv.ravel()[:, None] ** np.arange(n)).reshape(n * n, -1)
    C = np.linalg.solve(P, X).reshape(n, n, 3)
    uv = np.random.default_rng(1).uniform(-1, 1, (20, 2))
    if not np.allclose(patch_eval(C, uv[:, 0], uv[:, 1])[0], on_face(uv), atol=1e-12):
        raise ValueError(f"element {e}: face patch does not reproduce the element map")
    return C


def patch_eval(C, u, v):
    """x, dx/du, dx/dv of the patch at (u, v)."""
    n = C.shape[0]
    k = np.arange(n)
    pu, pv = u[:, None] ** k, v[:, None] ** k
    du = np.zeros_like(pu)
    dv = np.zeros_like(pv)
    du[:, 1:] = k[1:] * u[:, None] ** k[:-1]
    dv[:, 1:] = k[1:] * v[:, None] ** k[:-1]
    return (np.einsum("pa,pb,abc->pc", pu, pv, C), np.einsum("pa,pb,abc->pc", du, pv, C),
            np.einsum("pa,pb,abc->pc", pu, dv, C))


def patch_box(C, pad=1e-6):
    """A box around the patch: its samples' hull with a margin for the curvature between them."""
    s = np.linspace(-1, 1, 9)
    U, V = np.meshgrid(s, s, indexing="ij")
    X = patch_eval(C, U.ravel(), V.ravel())[0]
    ext = X.max(axis=0) - X.min(axis=0)
    return X.min(axis=0) - 0.1 * ext - pad, X.max(axis=0) + 0.1 * ext + pad


def box_chord(o, d, lo, hi):
    """Length of each ray (o + t d, t >= 0) inside the box [lo, hi], float64."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - o) / d
        tb = (hi - o) / d
    t0 = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), np.minimum(ta, tb)).max(axis=-1)
    t1 = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), np.maximum(ta, tb)).min(axis=-1)
    return np.clip(t1 - np.maximum(t0, 0.0), 0.0, None)


class Boundary:
    """A mesh's boundary patches, padded to one degree: C (F, n, n, 3) and boxes (F, 3) x 2."""

    def __init__(self, mesh):
        faces = boundary_faces(mesh)
        n = int(mesh.geom_modes.max())
        self.faces = faces
        self.patches = np.stack([face_patch(mesh, f, n) for f in faces])
        boxes = [patch_box(C) for C in self.patches]
        self.lo = np.array([b[0] for b in boxes])
        self.hi = np.array([b[1] for b in boxes])


def _face_hits(C, o, d):
    """t of every crossing of the rays with one patch (NaN where none), STARTS^2 starts."""
    n = len(o)
    hits = []
    for su in np.linspace(-0.67, 0.67, STARTS):
        for sv in np.linspace(-0.67, 0.67, STARTS):
            u, v = np.full(n, su), np.full(n, sv)
            t = np.einsum("ij,ij->i", patch_eval(C, u, v)[0] - o, d) / np.einsum("ij,ij->i", d, d)
            for _ in range(ITERATIONS):
                x, xu, xv = patch_eval(C, u, v)
                F = x - o - t[:, None] * d
                M = np.stack([xu, xv, -d], axis=2)
                with np.errstate(all="ignore"):
                    step = np.linalg.solve(M, F[..., None])[..., 0]
                step = np.nan_to_num(step, nan=0.0, posinf=0.0, neginf=0.0)
                u, v, t = np.clip(u - step[:, 0], -1.5, 1.5), np.clip(v - step[:, 1], -1.5, 1.5), t - step[:, 2]
            F = patch_eval(C, u, v)[0] - o - t[:, None] * d
            ok = (np.abs(F).max(axis=1) < ROOT_TOL) & (np.maximum(np.abs(u), np.abs(v)) <= 1.0 + 1e-12) & (t >= 0)
            hits.append(np.where(ok, t, np.nan))
    return np.stack(hits, axis=1)


def _pair_up(H):
    """Chord lengths from each row's crossings (NaN for none): sorted, duplicates dropped,
    alternately entering and leaving. Rows with an odd count get NaN."""
    H = np.sort(H, axis=1)
    dup = np.zeros_like(H, dtype=bool)
    dup[:, 1:] = np.abs(np.diff(H, axis=1)) < DUPLICATE
    H = np.sort(np.where(dup, np.nan, H), axis=1)
    count = np.isfinite(H).sum(axis=1)
    L = np.zeros(len(H))
    for k in range(0, H.shape[1] - 1, 2):
        seg = H[:, k + 1] - H[:, k]
        L += np.where(np.isfinite(seg), seg, 0.0)
    return np.where(count % 2 == 0, L, np.nan)


def chords_numpy(boundary: Boundary, o, d):
    """Chord of each ray (o, d: (..., 3)) through the mesh; NaN where the crossings are odd."""
    shape = o.shape[:-1]
    o = o.reshape(-1, 3).astype(np.float64)
    d = d.reshape(-1, 3).astype(np.float64)
    cols = []
    for C, lo, hi in zip(boundary.patches, boundary.lo, boundary.hi):
        near = box_chord(o, d, lo, hi) > 0
        col = np.full((len(o), STARTS * STARTS), np.nan)
        if near.any():
            col[near] = _face_hits(C, o[near], d[near])
        cols.append(col)
    return _pair_up(np.concatenate(cols, axis=1)).reshape(shape)


# ----------------------------------------------------------------------------- the Warp kernel

_KERNEL = None


def _kernel():
    """Built on first use: Warp is imported only by callers that have it."""
    global _KERNEL
    if _KERNEL is not None:
        return _KERNEL
    import warp as wp

    f64, v3 = wp.float64, wp.vec3d

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

    @wp.kernel
    def chord(C: wp.array(dtype=v3, ndim=3), lo: wp.array(dtype=v3), hi: wp.array(dtype=v3), n: int,
              origins: wp.array(dtype=v3), dirs: wp.array(dtype=v3), out: wp.array(dtype=f64),
              hits: wp.array(dtype=f64, ndim=2)):
        i = wp.tid()
        o = origins[i]
        d = dirs[i]
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
            for s in range(STARTS * STARTS):
                u = f64(-0.67) + f64(0.67) * f64(s // STARTS)
                v = f64(-0.67) + f64(0.67) * f64(s % STARTS)
                x, xu, xv = patch_at(C, f, n, u, v)
                t = wp.dot(x - o, d) / wp.dot(d, d)
                for it in range(ITERATIONS):
                    x, xu, xv = patch_at(C, f, n, u, v)
                    F = x - o - t * d
                    M = wp.mat33d(xu[0], xv[0], -d[0], xu[1], xv[1], -d[1], xu[2], xv[2], -d[2])
                    det = wp.determinant(M)
                    if det != f64(0.0):
                        step = wp.inverse(M) * F
                        u = wp.clamp(u - step[0], f64(-1.5), f64(1.5))
                        v = wp.clamp(v - step[1], f64(-1.5), f64(1.5))
                        t = t - step[2]
                x, xu, xv = patch_at(C, f, n, u, v)
                F = x - o - t * d
                err = wp.max(wp.max(wp.abs(F[0]), wp.abs(F[1])), wp.abs(F[2]))
                if err < f64(ROOT_TOL) and wp.max(wp.abs(u), wp.abs(v)) <= f64(1.0 + 1e-12) and t >= f64(0.0):
                    # the same root from another start (or a neighbouring patch at an edge): once
                    known = int(0)
                    for k in range(wp.min(count, MAX_HITS)):
                        if wp.abs(hits[i, k] - t) < f64(DUPLICATE):
                            known = 1
                    if known == 0:
                        if count < MAX_HITS:
                            hits[i, count] = t
                        count += 1
        if count > MAX_HITS:
            out[i] = f64(-1.0)  # too many crossings to keep: the caller refuses the ray
        else:
            out[i] = f64(count)

    _KERNEL = chord
    return chord


def chords_warp(boundary: Boundary, o, d, device: str = "cpu", chunk: int = 1 << 20):
    """chords_numpy, with the crossings found by a float64 Warp kernel on `device` (pairing on
    the host). Rays in chunks of `chunk`."""
    import warp as wp

    kernel = _kernel()
    shape = o.shape[:-1]
    o = o.reshape(-1, 3).astype(np.float64)
    d = d.reshape(-1, 3).astype(np.float64)
    L = np.empty(len(o))
    with wp.ScopedDevice(device):
        C = wp.array(boundary.patches, dtype=wp.vec3d)
        lo = wp.array(boundary.lo, dtype=wp.vec3d)
        hi = wp.array(boundary.hi, dtype=wp.vec3d)
        for s in range(0, len(o), chunk):
            m = min(chunk, len(o) - s)
            out = wp.zeros(m, dtype=wp.float64)
            hits = wp.full((m, MAX_HITS), np.nan, dtype=wp.float64)
            wp.launch(kernel, m, [C, lo, hi, int(boundary.patches.shape[1]), wp.array(o[s:s + m], dtype=wp.vec3d),
                                  wp.array(d[s:s + m], dtype=wp.vec3d), out, hits])
            count = out.numpy()
            chunk_L = _pair_up(hits.numpy())
            L[s:s + m] = np.where(count < 0, np.nan, chunk_L)
    return L.reshape(shape)
