"""Opaque surfaces stop the rays (engine/opaque.py, Renderer.render(surface_t=...)): the paper's
sphere volume cut by an opaque plane, every pixel against an independent float64 reference
(the exact integral from the eye to the plane, composited over the plane's shaded colour)."""
from __future__ import annotations

import numpy as np
import pytest

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.frame import Frame, render_frame
from hovr_blender.engine.opaque import OpaqueError, OpaqueMesh, OpaqueScene, composite, shade
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io import builtin

W, H = 32, 24
# the ramp of tests/helpers.SPHERE: non-zero only for f = |x|^2 < 1 (the ball inside the box)
STOPS = [(0.0, (1.0, 0.875, 0.25, 0.5)), (0.125, (1.0, 0.5, 0.25, 1.0)), (0.25, (0.25, 1.0, 0.375, 0.25)),
         (0.375, (0.125, 0.5, 1.0, 0.75)), (0.5, (1.0, 0.25, 0.5, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
TF = TransferFunction.from_rgba_ramp([p for p, _ in STOPS], [c for _, c in STOPS], 2.0, 0.0, 2.0)
BACKGROUND = np.array([0.0625, 0.03125, 0.125])
PLANE_COLOR = (0.75, 0.5, 0.25)
# a tilted plane through the ball, a finite quad (some pixels miss it)
PLANE_POINT = np.array([0.1, -0.05, 0.2])
PLANE_NORMAL = np.array([0.25, -0.3, 1.0]) / np.linalg.norm([0.25, -0.3, 1.0])
PLANE_HALF = 1.6
CAMERAS = {
    "perspective": {"projection": "perspective", "eye": [3.0, 2.5, 3.5], "target": [0.0, 0.0, 0.0],
                    "up": [0.0, 0.0, 1.0], "fov_y_deg": 45.0},
    "orthographic": {"projection": "orthographic", "eye": [3.0, -2.5, 3.0], "target": [0.0, 0.0, 0.2],
                     "up": [0.0, 0.0, 1.0], "height": 3.6},
}


def plane_frame():
    a = np.cross(PLANE_NORMAL, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(PLANE_NORMAL, a)
    return a, b


def plane_mesh(color=PLANE_COLOR, holdout=False) -> OpaqueMesh:
    a, b = plane_frame()
    corners = [PLANE_POINT + PLANE_HALF * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return OpaqueMesh(np.array(corners), [[0, 1, 2], [0, 2, 3]], color, holdout, "plane")


def plane_t(o, d):
    """float64 ray-plane parameter, +inf where the ray misses the finite quad or runs away from it."""
    a, b = plane_frame()
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.sum((PLANE_POINT - o) * PLANE_NORMAL, axis=-1) / np.sum(d * PLANE_NORMAL, axis=-1)
    p = o + t[..., None] * d - PLANE_POINT
    inside = (np.abs(p @ a) <= PLANE_HALF) & (np.abs(p @ b) <= PLANE_HALF) & (t > 0)
    return np.where(inside, t, np.inf)


def exact_integral(o, d, t_stop, nodes=24):
    """(C, T) of contract §3 over [0, t_stop] for the ball's field f = |x|^2 through TF, by
    pieces: f(t) is quadratic in t, so the transfer function's breakpoints are roots of
    quadratics; between them kappa and tau are linear in f (polynomial in t), and Gauss-Legendre
    on each piece is exact for the optical depth and converges fast for the emission."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x4, w4 = np.polynomial.legendre.leggauss(4)
    # f(t) = |o|^2 + 2 t o.d + t^2 (|d| = 1)
    b, c = float(o @ d), float(o @ o)

    def roots(s):
        disc = b * b - (c - s)
        if disc <= 0:
            return []
        r = np.sqrt(disc)
        return [-b - r, -b + r]

    ball = roots(1.0)
    if not ball:
        return np.zeros(3), 1.0
    lo, hi = max(ball[0], 0.0), min(ball[1], t_stop)
    if hi <= lo:
        return np.zeros(3), 1.0
    cuts = {lo, hi}
    for s in np.unique(np.concatenate([TF.color_s, TF.density_s])):
        cuts.update(t for t in roots(float(s)) if lo < t < hi)
    cuts = sorted(cuts)

    def f(t):
        return c + 2 * b * t + t * t

    C, tau_sum = np.zeros(3), 0.0
    for p0, p1 in zip(cuts[:-1], cuts[1:]):
        t = p0 + 0.5 * (p1 - p0) * (x + 1)
        # the optical depth from p0 to each node (tau(f(u)) is quadratic in u on the piece)
        u = p0 + 0.5 * (t[:, None] - p0) * (x4[None] + 1)
        depth = tau_sum + 0.5 * (t - p0) * (TF.density(f(u)) @ w4)
        g = TF.color(f(t)) * (TF.density(f(t)) * np.exp(-depth))[:, None]
        C += 0.5 * (p1 - p0) * (w @ g)
        tau_sum += 0.5 * (p1 - p0) * (w4 @ TF.density(f(p0 + 0.5 * (p1 - p0) * (x4 + 1))))
    return C, np.exp(-tau_sum)


def opaque_render(renderer, scene, camera, options, mode="SHADED", rows=None):
    """The frame of TF over BACKGROUND with the opaque meshes `scene`, through the door."""
    return render_frame(renderer, Frame(TF, BACKGROUND, options, opaque=scene, opaque_mode=mode), camera, rows=rows)


def reference_image(camera: RayCamera, holdout=False):
    """The expected pixels, independent of the renderer and of engine/opaque.py."""
    o, d = camera.rays()
    t_s = plane_t(o, d)
    img = np.zeros((camera.height, camera.width, 4))
    for j in range(camera.height):
        for i in range(camera.width):
            C, T = exact_integral(o[j, i], d[j, i], t_s[j, i])
            if not np.isfinite(t_s[j, i]):
                img[j, i] = [*(C + T * BACKGROUND), 1 - T]
            elif holdout:
                img[j, i] = [*C, 1 - T]
            else:
                cos = abs(float(d[j, i] @ PLANE_NORMAL))
                img[j, i] = [*(C + T * np.array(PLANE_COLOR) * cos), 1.0]
    return img, t_s


@pytest.fixture(scope="module")
def renderer():
    from hovr_blender.engine.renderer import Renderer

    return Renderer(builtin.sphere(), device="cpu")


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_plane_cuts_sphere_exact(renderer, projection):
    camera = RayCamera.from_contract(CAMERAS[projection], W, H)
    expected, t_s = reference_image(camera)
    hit = np.isfinite(t_s)
    assert 0.3 * hit.size < hit.sum() < hit.size  # the plane covers part of the image, not all
    res = opaque_render(renderer, OpaqueScene([plane_mesh()]), camera,
                        RenderOptions(method="split", tolerance=1e-7, min_transmittance=0.0, device="cpu"))
    assert res.stats["surface_pixels"] == hit.sum()
    np.testing.assert_array_equal(res.opaque_hits.hit, hit)
    assert np.max(np.abs(res.opaque_hits.t[hit] - t_s[hit])) < 1e-5 * np.max(t_s[hit])
    err = np.abs(res.rgba.astype(np.float64) - expected)
    assert err.max() <= 1e-4, (err.max(), np.unravel_index(err.argmax(), err.shape))
    # the volume does show in front of the plane (the test is not passing on the plane alone)
    vol = expected[..., :3] - np.where(hit[..., None], 0.0, BACKGROUND)
    assert (np.abs(vol - np.where(hit[..., None], np.array(PLANE_COLOR) * np.abs(camera.rays()[1] @ PLANE_NORMAL)[..., None], 0)) > 0.05).any()


def test_plane_holdout_float64_and_depth(renderer):
    """The holdout mode (the volume in front of the surfaces, premultiplied, for compositing over
    another renderer): RGB = C, alpha = 1 - T on the plane; float64 kernels; the depth output is
    the plane's t where the volume's opacity stays under 0.5."""
    camera = RayCamera.from_contract(CAMERAS["perspective"], W, H)
    expected, t_s = reference_image(camera, holdout=True)
    res = opaque_render(renderer, OpaqueScene([plane_mesh()]), camera, RenderOptions.pixel_exact(), mode="HOLDOUT")
    assert res.rgba.dtype == np.float64
    assert np.abs(res.rgba - expected).max() <= 1e-6
    thin = np.isfinite(t_s) & (expected[..., 3] < 0.45)
    assert thin.any()
    np.testing.assert_allclose(res.depth[thin], t_s[thin], rtol=1e-5)
    # a holdout object gives the same in the SHADED mode
    res2 = opaque_render(renderer, OpaqueScene([plane_mesh(holdout=True)]), camera, RenderOptions.pixel_exact())
    np.testing.assert_array_equal(res2.rgba, res.rgba)


def test_no_surface_is_the_plain_render(renderer):
    """No triangles: the door renders as Renderer.render itself; an all-+inf limit and an
    all-missing surface leave the volume's integral as it was."""
    camera = RayCamera.from_contract(CAMERAS["perspective"], 16, 12)
    opts = RenderOptions(method="split", tolerance=1e-6, device="cpu")
    plain = renderer.render(camera, TF, BACKGROUND, opts)
    none = opaque_render(renderer, OpaqueScene([]), camera, opts)
    np.testing.assert_array_equal(none.rgba, plain.rgba)
    inf = renderer.render(camera, TF, BACKGROUND, opts, surface_t=np.full((12, 16), np.inf))
    np.testing.assert_array_equal(inf.rgba, plain.rgba)
    far = OpaqueMesh([[50, 50, 50], [51, 50, 50], [50, 51, 50]], [[0, 1, 2]])
    missed = opaque_render(renderer, OpaqueScene([far]), camera, opts)
    assert missed.stats["surface_pixels"] == 0
    np.testing.assert_allclose(missed.rgba, plain.rgba, atol=1e-6)


def test_rows_and_behind_camera(renderer):
    """A band of rows composites with its own rows' hits; a surface behind the eye or before the
    near clip plane stops nothing."""
    camera = RayCamera.from_contract(CAMERAS["perspective"], 16, 12)
    opts = RenderOptions(method="split", tolerance=1e-6, device="cpu")
    scene = OpaqueScene([plane_mesh()])
    whole = opaque_render(renderer, scene, camera, opts)
    band = opaque_render(renderer, scene, camera, opts, rows=(5, 9))
    np.testing.assert_array_equal(band.rgba, whole.rgba[5:9])
    behind = OpaqueMesh([[-9, -9, 10], [30, -9, 10], [-9, 30, 10]], [[0, 1, 2]])  # above the eye (z 3.5)
    assert OpaqueScene([behind]).cast(camera).hit.sum() == 0
    from dataclasses import replace

    near = replace(camera, t_min=10.0)  # the plane lies within 10 of the eye: clipped away
    assert OpaqueScene([plane_mesh()]).cast(near).hit.sum() == 0


def test_composite_and_shade_formulas():
    hits_t = np.array([[1.0, np.inf]])
    from hovr_blender.engine.opaque import OpaqueHits

    hits = OpaqueHits(t=hits_t, surface=np.array([[0, -1]]), normal=np.array([[[0, 0, 1.0], [0, 0, 0]]]),
                       shaded=np.array([[[0.5, 0.25, 1.0], [0, 0, 0]]]), holdout=np.array([[False, False]]))
    vol = np.array([[[0.1, 0.2, 0.3, 0.25], [0.1, 0.2, 0.3, 0.25]]])
    out = composite(vol, hits, [1.0, 1.0, 1.0])
    np.testing.assert_allclose(out[0, 0], [0.1 + 0.75 * 0.5, 0.2 + 0.75 * 0.25, 0.3 + 0.75, 1.0])
    np.testing.assert_allclose(out[0, 1], [0.85, 0.95, 1.05, 0.25])
    held = composite(vol, hits, [1.0, 1.0, 1.0], mode="HOLDOUT")
    np.testing.assert_allclose(held[0, 0], vol[0, 0])
    np.testing.assert_allclose(shade([1.0, 0.5, 0.25], [0, 0, -1.0], [0, 0.6, 0.8]), [0.8, 0.4, 0.2])
    with pytest.raises(OpaqueError):
        composite(vol, hits, [0, 0, 0], mode="GLOSSY")
    with pytest.raises(OpaqueError):
        OpaqueMesh([[0, 0, 0]], [[0, 1, 2]])
