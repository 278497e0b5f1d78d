"""Isosurfaces and cut planes in whole renders (contract §7) against analytic answers: a
polynomial field on curved elements of all four shapes whose level set is a sphere (depth within
1e-6 of the exact ray-sphere intersection in float64; float32 within a stated bound), a thin
shell that a linearised contour misses, planes coloured by the field at the crossing, clipping,
and the bad-input messages."""
import numpy as np
import pytest

from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, SurfaceError, Surfaces
from hovr_blender.engine.renderer import RenderError, Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import curved_cube, with_field
from tests.helpers import framing

CENTRE = np.array([0.5, 0.5, 0.45])
RADIUS = 0.3


def _ball(x, y, z):
    return (x - CENTRE[0]) ** 2 + (y - CENTRE[1]) ** 2 + (z - CENTRE[2]) ** 2


@pytest.fixture(scope="module")
def ball_mesh():
    # f(x(xi)) has degree 4 in xi on curved_cube's quadratic elements: 5 modes hold it exactly
    return with_field(curved_cube(2), _ball, 5)


def _clear_tf():
    """No volume: colour black, density 0 everywhere (only the surfaces are seen)."""
    return TransferFunction(np.array([0.0, 1.0]), np.zeros((2, 3)), np.array([0.0, 1.0]), np.zeros(2))


def _sphere_depth(camera, centre, radius):
    """Exact first t of every pixel's ray on the sphere (nan where it misses), and the
    discriminant (how far from grazing)."""
    o, d = camera.rays()
    oc = o - centre
    b = np.einsum("...k,...k", d, oc)
    disc = b * b - (np.einsum("...k,...k", oc, oc) - radius * radius)
    t = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    return t, disc


def test_sphere_depth_on_curved_elements_float64(ball_mesh, device):
    cam = framing(ball_mesh, 24, 18)
    iso = Surfaces((Isosurface(RADIUS ** 2, (1.0, 0.8, 0.2), 1.0),))
    res = Renderer(ball_mesh, device).render(cam, _clear_tf(), np.zeros(3), RenderOptions(precision="float64", device=device),
                                             surfaces=iso)
    t, disc = _sphere_depth(cam, CENTRE, RADIUS)
    t = t.reshape(res.depth.shape)
    disc = disc.reshape(res.depth.shape)
    hit = disc > 1e-4  # clear hits (grazing rays are the next test's)
    assert hit.sum() > 40
    err = np.abs(res.depth[hit] - t[hit])
    assert err.max() < 1e-6, err.max()
    assert np.all(res.rgba[hit][:, 3] == 1.0)  # opaque surface
    miss = disc < -1e-4
    assert np.all(res.rgba[miss][:, 3] == 0.0)
    # headlight shading: at the sphere the normal is (x - C) / R, so the colour is exact too
    o, d = cam.rays()
    x = o.reshape(-1, 3)[hit.ravel()] + t[hit][:, None] * d.reshape(-1, 3)[hit.ravel()]
    cosine = np.abs(np.einsum("ij,ij->i", (x - CENTRE) / RADIUS, d.reshape(-1, 3)[hit.ravel()]))
    want = np.array([1.0, 0.8, 0.2])[None, :] * (0.25 + 0.75 * cosine)[:, None]
    assert np.abs(res.rgba[hit][:, :3] - want).max() < 1e-6


def test_sphere_depth_float32_bound(ball_mesh, device):
    """float32: the depth within 2e-4 of the exact one (the camera distance ~4, so about 50 ulps
    of t; the roots are polished on the series to a few ulps of s and the curved interpolant's
    tail is 1e-6 of the field)."""
    cam = framing(ball_mesh, 24, 18)
    iso = Surfaces((Isosurface(RADIUS ** 2, (1.0, 1.0, 1.0), 1.0),))
    res = Renderer(ball_mesh, device).render(cam, _clear_tf(), np.zeros(3), RenderOptions(device=device), surfaces=iso)
    t, disc = _sphere_depth(cam, CENTRE, RADIUS)
    hit = disc.reshape(res.depth.shape) > 1e-3
    err = np.abs(res.depth[hit] - t.reshape(res.depth.shape)[hit])
    assert err.max() < 2e-4, err.max()
