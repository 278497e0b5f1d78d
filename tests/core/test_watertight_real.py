"""Watertightness on real Nektar++ meshes (issue 3): a constant density tau over
CubeAllElements.xml (181 straight elements of all four shapes filling the unit cube) and the
curved RotPerBcs3D_Annulus.xml (60 hexahedra with curved quad faces) gives T = exp(-tau L),
L the exact chord through the domain, computed here without engine code:

- the cube: the slab test against the unit cube;
- the annulus: every intersection of the ray with the domain's boundary faces (faces of one
  element only), each a polynomial patch x(u, v) of the element map, solved by float64
  Newton on (u, v, t) from a grid of starts; the chord is the sum of the in/out intervals.

Rays: orthographic views whose pixel centres lie on the cube's 1/6 grid (rays along grid
lines: through vertices, along edges and faces, between elements of different shapes),
diagonal views, and perspective views of both meshes; several thousand rays per mesh.
Budgets (issue 3): max relative error of T <= 1e-6 with float64 kernels, <= 1e-4 float32.
"""
import numpy as np
import pytest

from hovr_blender.core import expansions as ex
from hovr_blender.core import shapes
from hovr_blender.core.camera import RayCamera
from hovr_blender.core.renderer import Renderer
from hovr_blender.core.transfer_function import TransferFunction
from hovr_blender.core.view import RenderOptions
from hovr_blender.io.nektar import read_nektar
from hovr_blender.io.synthetic import with_field

from ..helpers import data_file

BUDGET = {"float64": 1e-6, "float32": 1e-4}


def constant(mesh):
    return with_field(mesh, lambda x, y, z: 0.0 * x + 1.0, 2)


def tf(tau):
    return TransferFunction.from_contract({"color": [[-9, 0.3, 0.6, 0.9], [9, 0.3, 0.6, 0.9]],
                                           "density": [[-9, tau], [9, tau]]})


def relative_T_error(res, L, tau):
    assert np.all(np.isfinite(res.rgba))
    T = 1.0 - res.rgba[..., 3].astype(np.float64)
    want = np.exp(-tau * L)
    rel = np.abs(T - want) / want
    return float(rel.max()), np.unravel_index(int(rel.argmax()), rel.shape)


def box_chord(o, d, lo=0.0, hi=1.0):
    """Length of each ray (o + t d, t >= 0) inside the box [lo, hi]^3, float64."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - o) / d
        tb = (hi - o) / d
    t0 = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), np.minimum(ta, tb)).max(axis=-1)
    t1 = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), np.maximum(ta, tb)).min(axis=-1)
    return np.clip(t1 - np.maximum(t0, 0.0), 0.0, None)


def cube_cameras():
    """Orthographic along each axis with pixel centres on the 1/12 grid inside the cube (every
    other one on the mesh's 1/6 grid lines: through vertices and along edges; the rest in faces
    and between; none on the cube's own surface, where inside and outside are a matter of
    rounding), along (1, 1, 0) (the centre column through the vertical edges x = y) and the
    diagonal (the centre ray through the vertices (k, k, k) / 6), and two perspective views:
    5,000+ rays."""
    g = 1.0 / 12.0
    cams = []
    for axis, up in ((0, [0, 0, 1]), (1, [0, 0, 1]), (2, [0, 1, 0])):
        eye = np.full(3, 0.5)
        eye[axis] = -1.0
        tgt = np.full(3, 0.5)
        tgt[axis] = 0.0
        cams.append(RayCamera.from_contract({"projection": "orthographic", "eye": eye.tolist(), "target": tgt.tolist(),
                                             "up": up, "height": 11 * g}, 11, 11))
    cams.append(RayCamera.from_contract({"projection": "orthographic", "eye": [-0.5, -0.5, 0.5], "target": [0.5, 0.5, 0.5],
                                         "up": [0, 0, 1], "height": 11 * g}, 27, 11))
    cams.append(RayCamera.from_contract({"projection": "orthographic", "eye": [-1.0, -1.0, -1.0], "target": [0.5, 0.5, 0.5],
                                         "up": [0, 0, 1], "height": 1.0}, 33, 33))
    cams.append(RayCamera.from_contract({"eye": [-1.0, -0.5, -0.7], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1],
                                         "fov_y_deg": 55}, 64, 48))
    cams.append(RayCamera.from_contract({"eye": [0.5, 0.5, 2.5], "target": [0.5, 0.5, 0.5], "up": [0, 1, 0],
                                         "fov_y_deg": 40}, 40, 40))
    return cams


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_cube_all_elements_is_watertight(device, precision):
    mesh = constant(read_nektar(data_file("nektar", "CubeAllElements.xml")))
    assert np.bincount(mesh.shape, minlength=4).tolist() == [10, 36, 66, 69]
    r = Renderer(mesh, device)
    tau = 1.3
    rays, worst = 0, (0.0, None)
    for i, cam in enumerate(cube_cameras()):
        o, d = cam.rays()
        L = box_chord(o, d)
        res = r.render(cam, tf(tau), [0, 0, 0], RenderOptions(method="split", tolerance=1e-7, min_transmittance=0.0,
                                                              precision=precision))
        err, at = relative_T_error(res, L, tau)
        rays += L.size
        worst = max(worst, (err, (i, at)))
    assert rays >= 5000
    assert worst[0] <= BUDGET[precision], f"max relative error of T {worst[0]:.3g} at camera/pixel {worst[1]}"


# ------------------------------------------------------------------------------- annulus

HEX_FACES = [(0, -1.0), (0, 1.0), (1, -1.0), (1, 1.0), (2, -1.0), (2, 1.0)]  # xi_axis = value


def boundary_faces(mesh):
    """(element, axis, value) of every hexahedron face that no other element shares (faces keyed
    by their four corner vertices, rounded)."""
    V = shapes.VERTICES[shapes.HEX]
    count, where = {}, {}
    for e in range(mesh.num_elements):
        for axis, val in HEX_FACES:
            corners = mesh.vertices[e, :8][np.isclose(V[:, axis], val)]
            key = tuple(sorted(map(tuple, np.round(corners, 9))))
            count[key] = count.get(key, 0) + 1
            where[key] = (e, axis, val)
    return [where[k] for k, c in count.items() if c == 1]


def face_patch(mesh, face):
    """The face's map x(u, v) as a tensor power series: (C (n, n, 3), n), x = sum C_ab u^a v^b,
    fitted exactly (n = the geometry's modes) to the oracle's element map on the face."""
    e, axis, val = face
    gm = tuple(int(v) for v in mesh.geom_modes[e])
    G = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(shapes.HEX, gm)]
    n = max(gm)
    s = np.cos(np.pi * np.arange(n) / (n - 1))
    U, Vv = np.meshgrid(s, s, indexing="ij")
    xi = np.zeros((n * n, 3))
    xi[:, axis] = val
    xi[:, [k for k in range(3) if k != axis]] = np.stack([U.ravel(), Vv.ravel()], axis=1)
    X = ex.eval_modal(shapes.HEX, gm, G, xi)
    P = np.einsum("pa,pb->pab", U.ravel()[:, None] ** np.arange(n), Vv.ravel()[:, None] ** np.arange(n)).reshape(n * n, -1)
    C = np.linalg.solve(P, X).reshape(n, n, 3)
    # the same polynomial: check at other points of the face
    rng = np.random.default_rng(1)
    uv = rng.uniform(-1, 1, (20, 2))
    xi = np.zeros((20, 3))
    xi[:, axis] = val
    xi[:, [k for k in range(3) if k != axis]] = uv
    assert np.allclose(patch_eval(C, uv[:, 0], uv[:, 1])[0], ex.eval_modal(shapes.HEX, gm, G, xi), atol=1e-13)
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


def face_hits(C, o, d, starts=3, iters=30):
    """t of every intersection of the rays with one patch (NaN where none): Newton on (u, v, t)
    in float64 from a starts x starts grid of (u, v); a root found from several starts once."""
    n = len(o)
    hits = []
    for su in np.linspace(-0.67, 0.67, starts):
        for sv in np.linspace(-0.67, 0.67, starts):
            u, v = np.full(n, su), np.full(n, sv)
            t = np.einsum("ij,ij->i", patch_eval(C, u, v)[0] - o, d)
            for _ in range(iters):
                x, xu, xv = patch_eval(C, u, v)
                F = x - o - t[:, None] * d
                M = np.stack([xu, xv, -d], axis=2)
                with np.errstate(all="ignore"):
                    step = np.linalg.solve(M, F[..., None])[..., 0]
                step = np.nan_to_num(step, nan=0.0, posinf=0.0, neginf=0.0)
                u, v, t = np.clip(u - step[:, 0], -1.5, 1.5), np.clip(v - step[:, 1], -1.5, 1.5), t - step[:, 2]
            F = patch_eval(C, u, v)[0] - o - t[:, None] * d
            ok = (np.abs(F).max(axis=1) < 1e-12) & (np.maximum(np.abs(u), np.abs(v)) <= 1.0 + 1e-12) & (t >= 0)
            hits.append(np.where(ok, t, np.nan))
    H = np.sort(np.stack(hits, axis=1), axis=1)
    dup = np.zeros_like(H, dtype=bool)
    dup[:, 1:] = np.abs(np.diff(H, axis=1)) < 1e-9
    return np.where(dup, np.nan, H)


def patch_box(C, pad=1e-6):
    s = np.linspace(-1, 1, 9)
    U, V = np.meshgrid(s, s, indexing="ij")
    X = patch_eval(C, U.ravel(), V.ravel())[0]
    ext = X.max(axis=0) - X.min(axis=0)
    return X.min(axis=0) - 0.1 * ext - pad, X.max(axis=0) + 0.1 * ext + pad  # curved between samples: margin


def annulus_chord(mesh, o, d):
    """Chord through the union of the elements: boundary hits sorted per ray, alternately
    entering and leaving (hits on two faces at one edge count once)."""
    o = o.reshape(-1, 3)
    d = d.reshape(-1, 3)
    cols = []
    for f in boundary_faces(mesh):
        C = face_patch(mesh, f)
        lo, hi = patch_box(C)
        near = box_chord(o, d, lo, hi) > 0  # only rays that meet the patch's box
        col = np.full((len(o), 9), np.nan)
        if near.any():
            col[near] = face_hits(C, o[near], d[near])
        cols.append(col)
    H = np.concatenate(cols, axis=1)
    H = np.sort(H, axis=1)
    dup = np.zeros_like(H, dtype=bool)
    dup[:, 1:] = np.abs(np.diff(H, axis=1)) < 1e-9
    H = np.where(dup, np.nan, H)
    H = np.sort(H, axis=1)  # NaN last
    count = np.isfinite(H).sum(axis=1)
    assert np.all(count % 2 == 0), f"odd number of boundary crossings on {np.sum(count % 2)} rays"
    L = np.zeros(len(o))
    for k in range(0, H.shape[1] - 1, 2):
        seg = H[:, k + 1] - H[:, k]
        L += np.where(np.isfinite(seg), seg, 0.0)
    return L


def annulus_cameras():
    """Perspective views from outside (through the hole and the side faces), from above (rays
    along the axis through the hole and down through every layer), and an orthographic view
    along y through the curved walls at grazing incidence near r = 0.3 and r = 1."""
    return [
        RayCamera.from_contract({"eye": [1.8, 1.5, 1.6], "target": [0.45, 0.45, 0.5], "up": [0, 0, 1], "fov_y_deg": 45},
                                48, 40),
        RayCamera.from_contract({"eye": [0.35, 0.35, 2.5], "target": [0.4, 0.4, 0.0], "up": [0, 1, 0], "fov_y_deg": 50},
                                40, 40),
        RayCamera.from_contract({"projection": "orthographic", "eye": [0.5, -1.0, 0.5], "target": [0.5, 0.0, 0.5],
                                 "up": [0, 0, 1], "height": 1.2}, 48, 36),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_curved_annulus_is_watertight(device, precision):
    mesh = constant(read_nektar(data_file("nektar", "RotPerBcs3D_Annulus.xml")))
    assert mesh.num_elements == 60 and not mesh.affine.any()
    r = Renderer(mesh, device)
    tau = 1.1
    rays, hit, worst = 0, 0, (0.0, None)
    for i, cam in enumerate(annulus_cameras()):
        o, d = cam.rays()
        L = annulus_chord(mesh, o, d).reshape(cam.height, cam.width)
        res = r.render(cam, tf(tau), [0, 0, 0], RenderOptions(method="split", tolerance=1e-7, min_transmittance=0.0,
                                                              precision=precision))
        err, at = relative_T_error(res, L, tau)
        rays += L.size
        hit += int((L > 0).sum())
        worst = max(worst, (err, (i, at)))
    assert rays >= 4000 and hit >= 2000
    assert worst[0] <= BUDGET[precision], f"max relative error of T {worst[0]:.3g} at camera/pixel {worst[1]}"
