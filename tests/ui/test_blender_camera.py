"""blender_camera.py (engine's and ui's) without Blender: projection matrices built here from the OpenGL
frustum formulas (the form Blender's calc_matrix_camera returns) must give the contract's rays."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hovr_blender.engine.camera_matrices import is_orthographic, ray_camera_from_matrices
from hovr_blender.engine.camera import CameraError, RayCamera


def frustum(l, r, b, t, n, f):
    return np.array([
        [2 * n / (r - l), 0, (r + l) / (r - l), 0],
        [0, 2 * n / (t - b), (t + b) / (t - b), 0],
        [0, 0, -(f + n) / (f - n), -2 * f * n / (f - n)],
        [0, 0, -1, 0],
    ])


def ortho(l, r, b, t, n, f):
    return np.array([
        [2 / (r - l), 0, 0, -(r + l) / (r - l)],
        [0, 2 / (t - b), 0, -(t + b) / (t - b)],
        [0, 0, -2 / (f - n), -(f + n) / (f - n)],
        [0, 0, 0, 1],
    ])


def look_at(eye, target, up):
    """Camera-to-world matrix of a Blender camera (looks down -Z, +Y up) at eye facing target."""
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    up2 = np.cross(right, fwd)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up2, -fwd, eye
    return m


EYE, TARGET, UP = [4.0, 3.0, 2.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]


@pytest.mark.parametrize("w,h", [(64, 48), (48, 64), (7, 5)])
def test_perspective_matches_contract_camera(w, h):
    fov_y = 35.0
    t = 0.1 * np.tan(np.radians(fov_y) / 2)
    P = frustum(-t * w / h, t * w / h, -t, t, 0.1, 100.0)
    cam = ray_camera_from_matrices(P, look_at(EYE, TARGET, UP), w, h)
    ref = RayCamera.from_contract({"eye": EYE, "target": TARGET, "up": UP, "fov_y_deg": fov_y}, w, h)
    (o, d), (o_ref, d_ref) = cam.rays(), ref.rays()
    np.testing.assert_allclose(o, o_ref, atol=1e-12)
    np.testing.assert_allclose(d, d_ref, atol=1e-12)
    assert cam.projection == "perspective" and cam.t_min == 0.0  # rays start at the eye, not clip_start


@pytest.mark.parametrize("w,h", [(64, 48), (48, 64)])
def test_orthographic_matches_contract_camera(w, h):
    height = 3.5
    P = ortho(-height / 2 * w / h, height / 2 * w / h, -height / 2, height / 2, 0.1, 100.0)
    cam = ray_camera_from_matrices(P, look_at(EYE, TARGET, UP), w, h)
    ref = RayCamera.from_contract(
        {"projection": "orthographic", "eye": EYE, "target": TARGET, "up": UP, "height": height}, w, h
    )
    (o, d), (o_ref, d_ref) = cam.rays(), ref.rays()
    np.testing.assert_allclose(o, o_ref, atol=1e-12)  # origins on the plane through the eye
    np.testing.assert_allclose(d, d_ref, atol=1e-12)
    assert cam.projection == "orthographic"


def test_shifted_frustum_pixel_centres():
    """An off-centre frustum (Blender's lens shift): pixel (i, j) looks through the matching
    point of the near-plane window, row 0 at the top."""
    w, h, n = 8, 6, 0.5
    l, r, b, t = -0.2, 0.6, -0.1, 0.35
    C = look_at(EYE, TARGET, UP)
    o, d = ray_camera_from_matrices(frustum(l, r, b, t, n, 50.0), C, w, h).rays()
    i, j = np.meshgrid(np.arange(w), np.arange(h))
    local = np.stack([l + (r - l) * (i + 0.5) / w, t - (t - b) * (j + 0.5) / h, np.full(i.shape, -n)], axis=-1)
    want = local @ C[:3, :3].T
    want /= np.linalg.norm(want, axis=-1, keepdims=True)
    np.testing.assert_allclose(d, want, atol=1e-12)
    np.testing.assert_allclose(o, np.broadcast_to(EYE, o.shape), atol=1e-12)


def test_camera_object_scale_is_ignored():
    P = frustum(-0.4, 0.4, -0.3, 0.3, 0.1, 10.0)
    C = look_at(EYE, TARGET, UP)
    scaled = C @ np.diag([2.0, 0.5, 3.0, 1.0])
    a, b = ray_camera_from_matrices(P, C, 16, 12), ray_camera_from_matrices(P, scaled, 16, 12)
    for x, y in zip(a.rays(), b.rays()):
        np.testing.assert_allclose(x, y, atol=1e-12)


def test_rejects_non_pinhole_and_singular_projections():
    C = look_at(EYE, TARGET, UP)
    bent = frustum(-0.4, 0.4, -0.3, 0.3, 0.1, 10.0)
    bent[3, 0] = 0.3  # w depends on x: not a pinhole camera, rays are not affine in (u, v)
    with pytest.raises(CameraError, match="pinhole or orthographic"):
        ray_camera_from_matrices(bent, C, 16, 12)
    with pytest.raises(CameraError, match="singular"):
        ray_camera_from_matrices(np.zeros((4, 4)), C, 16, 12)
    with pytest.raises(CameraError):
        ray_camera_from_matrices(np.eye(3), C, 16, 12)
    with pytest.raises(CameraError, match="zero scale"):
        ray_camera_from_matrices(frustum(-1, 1, -1, 1, 0.1, 10), np.diag([1.0, 0.0, 1.0, 1.0]), 4, 4)


def _rotation(q):
    q = np.asarray(q, float)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


finite = st.floats(-5, 5, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    q=st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 0.1),
    pos=st.tuples(finite, finite, finite),
    window=st.tuples(st.floats(0.05, 2.0), st.floats(0.05, 2.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    size=st.tuples(st.integers(1, 40), st.integers(1, 40)),
    persp=st.booleans(),
    t=st.floats(0.5, 20.0),
)
def test_points_on_pixel_rays_project_to_pixel_centres(q, pos, window, size, persp, t):
    """Whatever the pose, window and shift: projecting any point of pixel (i, j)'s ray back
    through P @ inverse(C) lands on that pixel's centre in NDC."""
    (hw, hh, sx, sy), (w, h) = window, size
    make = frustum if persp else ortho
    P = make(sx - hw, sx + hw, sy - hh, sy + hh, 0.1, 100.0)
    C = np.eye(4)
    C[:3, :3], C[:3, 3] = _rotation(q), pos
    cam = ray_camera_from_matrices(P, C, w, h)
    assert is_orthographic(P) == (not persp)
    o, d = cam.rays()
    x = o + t * d
    clip = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=-1) @ (P @ np.linalg.inv(C)).T
    ndc = clip[..., :2] / clip[..., 3:]
    i, j = np.meshgrid(np.arange(w), np.arange(h))
    np.testing.assert_allclose(ndc[..., 0], 2 * (i + 0.5) / w - 1, atol=1e-8)
    np.testing.assert_allclose(ndc[..., 1], 1 - 2 * (j + 0.5) / h, atol=1e-8)
    if persp:
        np.testing.assert_allclose(o, np.broadcast_to(pos, o.shape), atol=1e-9)
    else:  # origins on the plane through the camera, perpendicular to its view axis
        np.testing.assert_allclose((o - np.asarray(pos)) @ -C[:3, 2], 0.0, atol=1e-9)


# --- clipping, sub-images (render border, viewport bands), depth, viewport cameras ---------

from hovr_blender.engine.camera_matrices import clip_range, clipped  # noqa: E402
from hovr_blender.ui.blender_camera import border_region, ray_camera_from_view, sub_camera, view_depth  # noqa: E402


@pytest.mark.parametrize("make", [frustum, ortho])
def test_clip_range_reads_near_and_far_from_the_projection(make):
    assert clip_range(make(-0.3, 0.5, -0.2, 0.4, 0.25, 40.0)) == pytest.approx((0.25, 40.0), rel=1e-12)


def test_clipped_orthographic_is_exact_and_moves_origins_behind_the_camera():
    C = look_at(EYE, TARGET, UP)
    cam = ray_camera_from_matrices(ortho(-2, 2, -1.5, 1.5, 0.5, 9.0), C, 8, 6)
    c = clipped(cam, 0.5, 9.0)
    assert (c.t_min, c.t_max) == (0.5, 9.0)  # t is the distance from the camera plane
    np.testing.assert_array_equal(c.o0, cam.o0)
    neg = clipped(cam, -3.0, 3.0)  # a viewport ortho view clips from behind the view origin
    fwd = -C[:3, 2]
    np.testing.assert_allclose(neg.o0, cam.o0 - 3.0 * fwd, atol=1e-12)
    assert (neg.t_min, neg.t_max) == (0.0, 6.0)
    np.testing.assert_allclose(view_depth(neg, np.full((6, 8), 4.0)), 1.0)  # z = -3 + t


def test_clipped_perspective_is_exactly_the_clip_slab():
    """Perspective clipping is per ray along the view axis: t in [near / c, far / c] keeps
    exactly the points with near <= z <= far (the kernel applies it)."""
    C = look_at(EYE, TARGET, UP)
    w, h, near, far = 16, 12, 0.3, 7.0
    cam = clipped(ray_camera_from_matrices(frustum(-0.2, 0.25, -0.1, 0.15, 0.1, 50.0), C, w, h), near, far)
    _, d = cam.rays()
    cos = d @ -C[:3, 2]
    axis = np.asarray(cam.clip_axis)
    np.testing.assert_allclose(axis, -C[:3, 2], atol=1e-12)
    np.testing.assert_allclose(d @ axis, cos)
    assert (cam.clip_near, cam.clip_far) == (near, far) and cam.t_min == 0.0
    t = np.random.default_rng(0).uniform(1, 5, (h, w))
    o, _ = cam.rays()
    z = ((o + t[..., None] * d) - C[:3, 3]) @ -C[:3, 2]  # distance along the view axis
    np.testing.assert_allclose(view_depth(cam, t), z, atol=1e-12)


@pytest.mark.parametrize("make", [frustum, ortho])
def test_sub_camera_pixels_are_the_full_images_pixels(make):
    cam = ray_camera_from_matrices(make(-0.3, 0.5, -0.2, 0.4, 0.2, 40.0), look_at(EYE, TARGET, UP), 37, 23)
    o, d = cam.rays()
    for x0, y0, w, h in [(0, 0, 37, 23), (5, 3, 10, 7), (36, 22, 1, 1), (0, 9, 37, 2)]:
        so, sd = sub_camera(cam, x0, y0, w, h).rays()
        np.testing.assert_allclose(so, o[y0:y0 + h, x0:x0 + w], atol=1e-12)
        np.testing.assert_allclose(sd, d[y0:y0 + h, x0:x0 + w], atol=1e-12)
    with pytest.raises(CameraError, match="outside"):
        sub_camera(cam, 30, 0, 8, 1)


def test_border_region_repeats_blenders_float32_truncation():
    # measured in bpy 5.0: 40x30, border x 0.26..0.71, y 0.1..0.55 -> an 18x13 result at (10, 3)
    assert border_region(40, 30, True, 0.26, 0.71, 0.1, 0.55) == (10, 3, 18, 13)
    assert border_region(40, 30, False, 0.26, 0.71, 0.1, 0.55) == (0, 0, 40, 30)
    assert border_region(40, 30, True, 0.5, 0.51, 0.2, 0.8) == (0, 0, 40, 30)  # empty -> full frame
    assert border_region(100, 50, True, 0.0, 1.0, 0.0, 1.0) == (0, 0, 100, 50)


def test_view_camera_equals_camera_from_inverse_view_matrix():
    C = look_at(EYE, TARGET, UP)
    P = frustum(-0.2, 0.25, -0.1, 0.15, 0.1, 50.0)
    v = ray_camera_from_view(P, np.linalg.inv(C), 20, 10)
    ref = ray_camera_from_matrices(P, C, 20, 10)
    for a, b in zip(v.rays(), ref.rays()):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert v.clip_near == pytest.approx(0.1) and v.clip_far == pytest.approx(50.0, rel=1e-3)
