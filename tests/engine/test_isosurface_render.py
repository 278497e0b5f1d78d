"""Isosurfaces and cut planes in whole renders (contract §7) against analytic answers: a
polynomial field on curved elements of all four shapes whose level set is a sphere (depth within
1e-6 of the exact ray-sphere intersection in float64; float32 within a stated bound; near
tangency, nothing outside the band of audit/isosurface_band.py, and the rays of the 1920x1080
frame that float32 got wrong), a thin shell that a linearised contour misses, planes coloured by
the field at the crossing, clipping, and the bad-input messages."""
import numpy as np
import pytest

from hovr_blender.audit import isosurface_band
from hovr_blender.audit.scenes import BALL_CENTRE as CENTRE
from hovr_blender.audit.scenes import BALL_RADIUS as RADIUS
from hovr_blender.audit.scenes import ball_field as _ball
from hovr_blender.audit.scenes import ball_mesh as _ball_mesh
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, SurfaceError, Surfaces
from hovr_blender.engine.render_result import RenderError
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from tests.helpers import framing


@pytest.fixture(scope="module")
def ball_mesh():
    return _ball_mesh()


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


def _clear_render(mesh, device, cam, precision, alpha=0.5):
    """The sphere level alone (opacity alpha, no volume) through camera cam."""
    iso = Surfaces((Isosurface(RADIUS ** 2, (1.0, 1.0, 1.0), alpha),))
    return Renderer(mesh, device).render(cam, _clear_tf(), np.zeros(3), RenderOptions(precision=precision, device=device),
                                         surfaces=iso)


def _silhouette_sweep(direction, normal, spacing, width):
    """An orthographic camera of one row of `width` parallel rays along `direction`, their
    origins `spacing` apart along `normal` (perpendicular to it), the middle one tangent to the
    sphere: closest approaches from -width/2 to width/2 spacings off the surface."""
    z = np.zeros(3)
    o0 = CENTRE + RADIUS * normal - 3.0 * direction
    return RayCamera(width, 1, o0, 0.5 * spacing * normal, z, direction, z, z, projection="orthographic")


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_nothing_outside_the_tangency_band(ball_mesh, device, precision):
    """Rays across the sphere's silhouette at eight places (random directions, so the tangent
    points fall in different elements and shapes), 1/16 of float32's band eta apart over +-8 eta:
    outside the band (audit/isosurface_band.py, contract §7) a ray that misses draws nothing and
    one that crosses meets the sphere twice (opacity 0.75 at 0.5 each), its depth within the
    stated tolerance; and a frame of the scene at 128x72. float64 takes the same rays, all far
    outside its own band."""
    r = Renderer(ball_mesh, device)
    map_error = isosurface_band.device_map_error(ball_mesh, isosurface_band.near_sphere(CENTRE, RADIUS))
    eps32, eps = (isosurface_band.level_rounding(r, p, RADIUS ** 2, 2.0 * RADIUS, map_error)
                  for p in ("float32", precision))
    spacing = (2.0 * eps32 / (2.0 * RADIUS)) / 16.0
    rng = np.random.default_rng(36)
    in_band = 0
    for _ in range(8):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        n = rng.normal(size=3)
        n -= (n @ d) * d
        n /= np.linalg.norm(n)
        cam = _silhouette_sweep(d, n, spacing, 256)
        res = _clear_render(ball_mesh, device, cam, precision)
        o, dd = cam.rays()
        got = isosurface_band.classify(res.rgba[0], res.depth[0], o[0], dd[0], CENTRE, RADIUS, eps, precision)
        assert got["hits_outside_band"] > 64 and got["misses_outside_band"] > 64, got
        assert got["outside_band"] == 0, got["failures"][:3]
        in_band += got["in_band"]
    if precision == "float32":
        assert in_band > 100  # the sweeps do reach into the band
    cam = framing(ball_mesh, 128, 72)
    res = _clear_render(ball_mesh, device, cam, precision)
    o, dd = cam.rays()
    got = isosurface_band.classify(res.rgba, res.depth, o, dd, CENTRE, RADIUS, eps, precision)
    assert got["hits_outside_band"] > 500 and got["outside_band"] == 0, got["failures"][:3]


# Rays of the frame framing(ball_mesh, 1920, 1080) that float32 got wrong on the CPU (ffccdbf),
# each as the 1x1 camera whose ray is the pixel's float32 ray bit for bit there (its origin and
# unnormalised direction as the CPU kernel computes them; the kernel normalises it the same way).
# On a GPU the frame's rays differ in their last bits (fused multiply-adds): there these are rays
# like the frame's, checked all the same.
EYE = [2.192173719406128, -0.8287389278411865, 1.6870216131210327]
FRAME_RAYS = {
    # passes at 0.67 R from the centre: its entry into the sphere fell in the gap of 5e-6 the
    # traversal leaves between a tetrahedron's exit (element 15) and a prism's entry (element 2),
    # so no segment's series held it; the exit, 0.443 deeper, was drawn
    "entry_between_two_segments_1099_638": [-0.6236416697502136, 0.5875585079193115, -0.5225192308425903],
    # tangency, both inside the band (eta = 1.1e-4) but decided by the field_err of the samples
    # (2.9e-5) where the series' own rounding decides now: misses by 1.0e-5 and was drawn ...
    "miss_drawn_913_340": [-0.7366781234741211, 0.5597941279411316, -0.39276933670043945],
    # ... and crosses 4.8e-5 deep and was drawn at its tangent point, 5.4e-3 behind its entry
    "pair_at_its_extremum_846_809": [-0.6702863574028015, 0.46410563588142395, -0.5969730615615845],
}


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("case", sorted(FRAME_RAYS))
def test_frame_rays_float32_got_wrong(ball_mesh, device, case, precision):
    z = np.zeros(3)
    cam = RayCamera(1, 1, np.array(EYE), z, z, np.array(FRAME_RAYS[case]), z, z)
    res = _clear_render(ball_mesh, device, cam, precision)
    o, d = cam.rays()
    delta, _, t1, _ = isosurface_band.sphere_rays(o[0, 0], d[0, 0], CENTRE, RADIUS)
    alpha = float(res.rgba[0, 0, 3])
    if delta > 0:
        assert alpha == 0.0, f"drawn at {res.depth[0, 0]:.6f}, the ray misses by {delta:.2e}"
    else:
        assert alpha == 0.75, f"alpha {alpha}: the sphere met {'once' if alpha == 0.5 else 'not twice'}"
        assert abs(res.depth[0, 0] - t1) < 2e-6, f"depth {res.depth[0, 0]:.7f}, exact {t1:.7f}"


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_crossing_on_an_element_face_is_met_where_its_depth_rounds_to_the_segments_end(ball_mesh, device, precision):
    """Rows 704 and 730 of the 1920x1080 frame (audit/scenes.framing): the sphere runs along the
    faces between the central hexahedron and its neighbours, so rays cross it where one segment
    ends and the next begins. Pixel (787, 704): float32's root in the prism's segment, 3e-7
    before its end, rounded to the end itself and was dropped there, while the hexahedron's
    segment started beyond the crossing (the sphere met once, at its far side); the H200 did the
    same at (930, 730) on the way out. Every pixel of both rows against its exact ray, outside
    the band."""
    from hovr_blender.audit import scenes

    r = Renderer(ball_mesh, device)
    map_error = isosurface_band.device_map_error(ball_mesh, isosurface_band.near_sphere(CENTRE, RADIUS))
    eps = isosurface_band.level_rounding(r, precision, RADIUS ** 2, 2.0 * RADIUS, map_error)
    cam = scenes.framing(ball_mesh, 1920, 1080)
    o, dd = cam.rays()
    iso = Surfaces((Isosurface(RADIUS ** 2, (1.0, 1.0, 1.0), 0.5),))
    for row in (704, 730):
        res = r.render(cam, _clear_tf(), np.zeros(3), RenderOptions(precision=precision, device=device), surfaces=iso,
                       rows=(row, row + 1))
        got = isosurface_band.classify(res.rgba, res.depth, o[row:row + 1], dd[row:row + 1], CENTRE, RADIUS, eps,
                                       precision)
        assert got["hits_outside_band"] > 300, got
        assert got["outside_band"] == 0, got["failures"][:3]


def _bump(x, y, z):
    return -((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2)


def test_thin_feature_a_linearised_contour_misses(device):
    """One quadratic hexahedron whose field peaks at its centre: the level -0.01 is a sphere of
    radius 0.1 inside it. Its vertex values are all -0.75, so the contour of the linearised cell
    (the vertices' trilinear interpolant, what a tessellated contour filter sees) is empty; the
    render finds the sphere at its exact depth."""
    from hovr_blender.io.synthetic import brick

    mesh = brick((0, 0, 0), (1, 1, 1), (1, 1, 1), 3, _bump)
    vertex_values = _bump(*mesh.vertices[0].T)
    assert vertex_values.max() < -0.01  # the linearised cell holds no point of the level set
    cam = framing(mesh, 24, 24, distance=1.4)
    iso = Surfaces((Isosurface(-0.01, (1.0, 1.0, 1.0), 1.0),))
    res = Renderer(mesh, device).render(cam, _clear_tf(), np.zeros(3), RenderOptions(precision="float64", device=device),
                                        surfaces=iso)
    t, disc = _sphere_depth(cam, np.array([0.5, 0.5, 0.5]), 0.1)
    hit = disc.reshape(res.depth.shape) > 1e-6
    assert hit.sum() >= 8
    assert np.abs(res.depth[hit] - t.reshape(res.depth.shape)[hit]).max() < 1e-6
    assert np.all(res.rgba[~hit & (disc.reshape(res.depth.shape) < -1e-6)][:, 3] == 0.0)


def test_plane_takes_the_fields_colour_at_the_crossing(ball_mesh, device):
    """A plane through the curved cube, the colour ramp red = f over [0, 1]: each pixel's red is
    f at the ray's crossing with the plane (float64), where the ray meets the data."""
    tf = TransferFunction(np.array([0.0, 1.0]), np.array([[0.0, 0.2, 1.0], [1.0, 0.2, 0.0]]), np.array([0.0, 1.0]),
                          np.zeros(2))
    normal = np.array([0.3, -0.2, 1.0])
    plane = CutPlane.through((0.5, 0.5, 0.5), normal, opacity=1.0)
    cam = framing(ball_mesh, 20, 16)
    res = Renderer(ball_mesh, device).render(cam, tf, np.zeros(3), RenderOptions(precision="float64", device=device),
                                             surfaces=Surfaces((), (plane,)))
    o, d = cam.rays()
    n = np.asarray(plane.normal)
    t = (plane.offset - o @ n) / (d @ n)
    x = o + t[..., None] * d
    inside = (x > 0.05).all(axis=-1) & (x < 0.95).all(axis=-1)  # well inside the bent cube
    assert inside.sum() > 30
    got = res.rgba[inside]
    assert np.all(got[:, 3] == 1.0)
    # the point located by Newton in its curved element (geometry.invert_point's stop): 3e-9 measured
    assert np.abs(got[:, 0] - _ball(*x[inside].T)).max() < 1e-8
    assert np.abs(res.depth[inside] - t[inside]).max() < 1e-9


def test_clipping_plane_removes_the_volume_on_its_front(device):
    """Constant density 2 in the unit box, a clipping plane x + y = 1 that removes the side its
    normal points to and draws nothing (opacity 0): each ray's transmittance is exp(-2 L), L its
    chord in the box's half x + y <= 1."""
    from hovr_blender.io.synthetic import brick

    mesh = brick((0, 0, 0), (1, 1, 1), (2, 2, 2), 2, lambda x, y, z: x + 0.0 * y)
    tf = TransferFunction(np.array([0.0, 1.0]), np.ones((2, 3)), np.array([0.0, 1.0]), np.full(2, 2.0))
    plane = CutPlane.through((0.5, 0.5, 0.5), (1.0, 1.0, 0.0), opacity=0.0, clip=1)
    cam = framing(mesh, 16, 12, direction=(0.3, -1.0, 0.5))
    res = Renderer(mesh, device).render(cam, tf, np.zeros(3), RenderOptions(precision="float64", device=device),
                                        surfaces=Surfaces((), (plane,)))
    o, d = cam.rays()
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (0.0 - o) / d, (1.0 - o) / d
    t0 = np.nanmax(np.minimum(ta, tb), axis=-1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=-1)
    n = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    g0, g1 = o @ n - 0.5 * np.sqrt(2), d @ n  # kept where g0 + t g1 <= 0
    tc = -g0 / g1
    t0 = np.where(g1 < 0, np.maximum(t0, tc), t0)
    t1 = np.where(g1 > 0, np.minimum(t1, tc), t1)
    chord = np.maximum(t1 - t0, 0.0)
    assert (chord > 0).sum() > 20 and (chord == 0).sum() > 5
    assert np.abs(res.rgba[..., 3] - (1.0 - np.exp(-2.0 * chord))).max() < 1e-7


def test_bad_surfaces_get_one_line_messages(ball_mesh):
    from hovr_blender.engine.isosurfaces import surfaces_from_view
    from hovr_blender.engine.view import ViewError

    r = Renderer(ball_mesh, "cpu")
    cam = framing(ball_mesh, 4, 3)
    with pytest.raises(SurfaceError, match=r"value 5 is outside the field's range"):
        r.render(cam, _clear_tf(), np.zeros(3), RenderOptions(), surfaces=Surfaces((Isosurface(5.0, (1, 1, 1)),)))
    with pytest.raises(SurfaceError, match="misses the volume's box"):
        r.render(cam, _clear_tf(), np.zeros(3), RenderOptions(),
                 surfaces=Surfaces((), (CutPlane.through((0, 0, 9), (0, 0, 1)),)))
    with pytest.raises(RenderError, match="method classified or split"):
        r.render(cam, _clear_tf(), np.zeros(3), RenderOptions(method="riemann", h=0.1),
                 surfaces=Surfaces((Isosurface(0.09, (1, 1, 1)),)))
    for bad, msg in (({"isosurfaces": [{"color": [1, 1, 1]}]}, "needs a value"),
                     ({"isosurfaces": [{"value": 1, "opacity": 2}]}, r"opacity must be in \[0, 1\]"),
                     ({"isosurfaces": [{"value": 1, "colour": [1, 0, 0]}]}, "unknown key 'colour'"),
                     ({"planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}, "non-zero vector"),
                     ({"planes": [{"point": [0, 0, 0], "normal": [0, 0, 1], "clip": "left"}]}, "clip must be one of"),
                     ({"planes": {"point": [0, 0, 0]}}, "planes must be a list")):
        with pytest.raises(ViewError, match=msg):
            surfaces_from_view(bad, ViewError)


def test_shaded_from_the_segment_cache_equals_the_render(ball_mesh):
    """Surfaces are part of the look: a cached trace shaded with them is the fresh render (bitwise
    on the CPU), and changing the levels needs no new trace."""
    from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame

    r = Renderer(ball_mesh, "cpu")
    cam = framing(ball_mesh, 12, 9)
    tf = TransferFunction(np.array([0.0, 0.5]), np.array([[0.1, 0.3, 0.9], [0.9, 0.3, 0.1]]), np.array([0.0, 0.5]),
                          np.array([0.5, 0.0]))
    opts = RenderOptions(precision="float64")
    slot, cache = SegmentSlot(), None
    for level, plane in ((0.09, None), (0.05, CutPlane.through((0.5, 0.5, 0.5), (0, 1, 0), 0.7, clip=-1))):
        surfaces = Surfaces((Isosurface(level, (1.0, 0.9, 0.2), 0.6),), () if plane is None else (plane,))
        fresh = r.render(cam, tf, np.zeros(3), opts, surfaces=surfaces)
        shaded = render_frame(r, Frame(tf, np.zeros(3), opts, surfaces=surfaces, cache=slot), cam)
        assert cache is None or slot.cache is cache  # the second look: no new trace
        cache = slot.cache
        assert np.array_equal(shaded.rgba, fresh.rgba)
        assert np.array_equal(shaded.depth, fresh.depth)


def test_levels_are_checked_against_the_fields_range_over_the_data():
    """Issue 40: PyFR's Taylor-Green pressure runs 71.05..72.01 while its coefficients bound it by
    64.7..78.4. A level of 500 is refused quoting the range over the data, and so is 75, inside
    the bounds but outside the data (it drew nothing and said nothing)."""
    from hovr_blender.engine.looks import field_samples, sampled_ranges
    from hovr_blender.io.sources import VolumeSource, load_volume
    from tests.helpers import data_file

    mesh = load_volume(VolumeSource.resolve(str(data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")), "", "Pressure"))
    (lo, hi), = sampled_ranges(mesh)
    (blo, bhi), = Renderer.volume_ranges(mesh)
    values = field_samples(mesh)
    assert (lo, hi) == (values.min(), values.max()) and 71.0 < lo < 71.1 and 72.0 < hi < 72.05
    assert blo < 65 and bhi > 78  # the certified bounds the check quoted before
    box = mesh.vertices.reshape(-1, 3)
    for level in (500.0, 75.0, 70.0):
        with pytest.raises(SurfaceError, match=rf"value {level:g} is outside the field's range over the data "
                                                rf"\[71\.0\d+, 72\.0\d+\]"):
            Surfaces((Isosurface(level, (1, 1, 1)),)).check([(lo, hi)], box.min(axis=0), box.max(axis=0))
    Surfaces((Isosurface(71.5, (1, 1, 1)),)).check([(lo, hi)], box.min(axis=0), box.max(axis=0))


def test_a_level_no_ray_meets_is_said_once(ball_mesh):
    """A level inside the range whose surface lies outside the camera's view: the render says, once,
    that the isosurface meets no ray in this frame; in view it says nothing."""
    from hovr_blender.engine.frame import Frame, render_frame

    r = Renderer(ball_mesh, "cpu")
    iso = Surfaces((Isosurface(0.09, (1, 1, 1)),))
    frame = Frame(_clear_tf(), np.zeros(3), RenderOptions(), surfaces=iso)
    seen = render_frame(r, frame, framing(ball_mesh, 8, 6))
    assert not any("meets no ray" in w for w in seen.stats["warnings"])
    away = RayCamera.from_contract({"eye": [0.5, 0.5, 3.0], "target": [0.5, 0.5, 9.0], "up": [0, 1, 0],
                                    "fov_y_deg": 30}, 8, 6)  # looking away from the cube
    missed = render_frame(r, frame, away)
    assert [w for w in missed.stats["warnings"] if "meets no ray" in w] == [
        "isosurface 0 (value 0.09) meets no ray in this frame: no element holding it is in the camera's view"]
    assert missed.rgba[..., 3].max() == 0
