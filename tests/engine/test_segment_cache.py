"""Transfer-function edits from cached segments (Renderer.trace / shade, a Frame's SegmentSlot): the image
shaded from a trace equals a fresh render through the new transfer function, for split and
classified, float32 and float64, on a curved and an affine mesh, with transfer functions that
empty segments and stop rays early; the cache is refused where it does not hold the view (camera,
rows, field, precision, method family, surfaces, another field frame) and re-traced by
the door (engine/frame.render_frame); the memory limit refuses it and the frame then renders plainly.

Equality is bitwise on the CPU: the shade kernel hands integrate_segment the same element, t0,
t1, degree, flags, tail and series values (copied, not recomputed) in the same order as the
integrate kernel, and the per-ray state carries the same precision between rounds as inside
one kernel, so every floating-point operation is the same. On a GPU the two kernels are compiled
apart, and NVRTC may contract multiply-adds differently in each, so there the images may differ
by rounding: GPU_ATOL.
"""
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hovr_blender.engine import limits
from hovr_blender.engine import segment_cache
from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame
from hovr_blender.engine.render_result import SegmentCacheError
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import cube_field, curved_cube, mixed_cube

from ..helpers import COLORS, framing, tents

GPU_ATOL = 1e-6
COUNTERS = ("field_evaluations", "restriction_evaluations", "segments", "segments_empty", "segments_smooth",
            "segments_piecewise_smooth")
BACKGROUND = np.array([0.1, 0.2, 0.3])
W, H = 24, 18

_RENDERERS = {}


def scene(kind: str, device: str):
    """(renderer, camera, transfer function) of the curved or the affine mixed-shape cube (all four
    shapes, pyramids included), tents over the field's 2..98 % range (transparent between them:
    empty segments), framed from a corner."""
    if (kind, device) not in _RENDERERS:
        mesh = curved_cube(2) if kind == "curved" else mixed_cube(2, 4, cube_field)
        lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
        _RENDERERS[kind, device] = (Renderer(mesh, device), framing(mesh, W, H), tents(lo, hi, COLORS, 12.0))
    return _RENDERERS[kind, device]


def edits(tf: TransferFunction) -> dict:
    """Edits that keep the transfer function's breakpoint band (so its field frame): colours,
    density scaled up until rays stop early (min_transmittance), one tent's density zeroed (its
    segments empty), every density zero, moved inner breakpoints."""
    s = tf.density_s.copy()
    s[1:-1] = s[1:-1] + 0.3 * np.diff(s)[:-1]  # each inner breakpoint a third of the way to the next
    one_tent = tf.density_tau.copy()
    one_tent[3:] = 0.0
    return {"colours": replace(tf, color_rgb=tf.color_rgb[::-1] * 0.5 + 0.25),
            "opaque": replace(tf, density_tau=tf.density_tau * 60.0),
            "one tent": replace(tf, density_tau=one_tent),
            "transparent": replace(tf, density_tau=0.0 * tf.density_tau),
            "moved": TransferFunction(s, tf.color_rgb, s, tf.density_tau)}


def assert_same_image(a, b, device):
    atol = 0.0 if device == "cpu" else GPU_ATOL
    for x, y in ((a.rgba, b.rgba), (a.depth, b.depth), (a.error, b.error)):
        assert x.shape == y.shape and x.dtype == y.dtype
        if atol == 0.0:
            np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_allclose(x, y, rtol=0, atol=atol)


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("method", ["split", "classified"])
@pytest.mark.parametrize("kind", ["curved", "affine"])
def test_shaded_edits_equal_fresh_renders(kind, method, precision, device):
    r, cam, tf = scene(kind, device)
    opts = RenderOptions(method=method, tolerance=1e-5, precision=precision, h=0.01)
    cache = r.trace(cam, tf, opts)
    assert cache.complete and r.cache_fits(cache, cam, tf, opts)
    stops = {}
    for name, edit in {"original": tf, **edits(tf)}.items():
        assert r.cache_fits(cache, cam, edit, opts), name
        fresh = r.render(cam, edit, BACKGROUND, opts)
        shaded = r.shade(cache, edit, BACKGROUND, opts)
        assert_same_image(fresh, shaded, device)
        assert shaded.stats["segment_cache"]["segments"] == cache.counts[0]
        stops[name] = shaded.stats["segments"]
    # the edits did what they are for: rays stopped early, empty segments skipped
    assert stops["opaque"] < cache.counts[0] and stops["transparent"] == cache.counts[0]
    assert np.all(r.shade(cache, edits(tf)["transparent"], BACKGROUND, opts).rgba[..., 3] == 0.0)


@pytest.mark.parametrize("method", ["trapezoid", "riemann"])
def test_fixed_step_methods_shade_too(method, device):
    """The baselines evaluate affine elements as they march (SEG_EVALUATE: no series cached)."""
    r, cam, tf = scene("affine", device)
    opts = RenderOptions(method=method, h=0.02)
    cache = r.trace(cam, tf, opts)
    assert cache.counts[2] == 0  # affine segments of the baselines keep no coefficients
    for edit in (tf, edits(tf)["opaque"]):
        assert_same_image(r.render(cam, edit, BACKGROUND, opts), r.shade(cache, edit, BACKGROUND, opts), device)


def test_shade_only_options_reuse_the_cache(device):
    """Tolerance, h, inner rule, min_transmittance, background and the method within its family
    (split/classified sample the same segments) are the shade's: the cache fits and the image is
    the fresh render with those options."""
    r, cam, tf = scene("curved", device)
    opts = RenderOptions(method="split", tolerance=1e-5)
    cache = r.trace(cam, tf, opts)
    for changed in (opts.with_(tolerance=1e-3), opts.with_(min_transmittance=0.0), opts.with_(min_transmittance=0.5),
                    opts.with_(method="classified", h=0.05, inner="trapezoid")):
        assert r.cache_fits(cache, cam, tf, changed)
        assert_same_image(r.render(cam, tf, [0.5, 0.0, 1.0], changed), r.shade(cache, tf, [0.5, 0.0, 1.0], changed),
                          device)


def test_cache_does_not_fit_another_view():
    r, cam, tf = scene("curved", "cpu")
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tf, opts)
    moved = replace(cam, o0=cam.o0 + 1e-3)
    assert r.cache_fits(cache, cam, tf, opts)
    assert not r.cache_fits(cache, moved, tf, opts)
    assert not r.cache_fits(cache, replace(cam, t_max=3.0), tf, opts)
    assert not r.cache_fits(cache, cam, tf, opts, rows=(0, 5))
    assert not r.cache_fits(cache, cam, tf, opts.with_(precision="float64"))
    assert not r.cache_fits(cache, cam, tf, opts.with_(method="trapezoid", h=0.05))
    assert not r.cache_fits(cache, cam, tf, opts, surface_key="a plane")
    assert not r.cache_fits(None, cam, tf, opts)
    with pytest.raises(SegmentCacheError, match="precision or method"):
        r.shade(cache, tf, BACKGROUND, opts.with_(method="riemann", h=0.05))
    other = Renderer(r.mesh, "cpu")  # the same mesh, another upload: its own caches
    assert not other.cache_fits(cache, cam, tf, opts)
    with pytest.raises(SegmentCacheError):
        other.shade(cache, tf, BACKGROUND, opts)


def test_a_new_field_invalidates_the_cache():
    mesh = mixed_cube(2, 3, cube_field)
    r = Renderer(mesh, "cpu")
    cam = framing(mesh, 12, 9)
    tf = tents(0.0, 1.5, COLORS, 10.0)
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tf, opts)
    assert r.cache_fits(cache, cam, tf, opts)
    r.replace_field(replace(mesh, coeffs=mesh.coeffs * 1.25))
    assert not r.cache_fits(cache, cam, tf, opts)
    with pytest.raises(SegmentCacheError):
        r.shade(cache, tf, BACKGROUND, opts)


def cached(r, cam, tf, opts, cache=None, opaque=None, mode="SHADED", rows=None, **how):
    """(result, the cache its SegmentSlot holds afterwards): the door with a slot holding `cache`."""
    slot = SegmentSlot(cache)
    res = render_frame(r, Frame(tf, BACKGROUND, opts, opaque=opaque, opaque_mode=mode, cache=slot), cam, rows=rows,
                       **how)
    return res, slot.cache

def test_another_frame_traces_again():
    """A transfer function whose breakpoint band moves far maps the field into another frame
    (engine/field_frame.py): the cached series are in the old one, so shade refuses and
    the door traces again; its image is still the fresh render's."""
    r, cam, tf = scene("curved", "cpu")
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tf, opts)
    wide = TransferFunction(tf.color_s * 4.0 - 1.0, tf.color_rgb, tf.density_s * 4.0 - 1.0, tf.density_tau)
    assert r.frame_key(wide) != cache.frame_key and not r.cache_fits(cache, cam, wide, opts)
    with pytest.raises(SegmentCacheError, match="frame"):
        r.shade(cache, wide, BACKGROUND, opts)
    res, new = cached(r, cam, wide, opts, cache=cache)
    assert new is not cache and new.frame_key == r.frame_key(wide)
    assert_same_image(r.render(cam, wide, BACKGROUND, opts), res, "cpu")
    # and back: the first frame's field is uploaded again for the old cache
    res, again = cached(r, cam, tf, opts, cache=cache)
    assert again is cache
    assert_same_image(r.render(cam, tf, BACKGROUND, opts), res, "cpu")


def test_rows_tiles_growth_and_surfaces(monkeypatch):
    """A trace of some rows, in several launch tiles, with a per-pixel far limit (an opaque
    surface's t), and with the cache's arrays starting tiny so they grow (and are copied) many
    times, is still the render of the same rows and limit."""
    monkeypatch.setattr(segment_cache, "CACHE_MIN_SEGMENTS", 8)
    r, cam, tf = scene("curved", "cpu")
    opts = RenderOptions(method="split")
    o, d = cam.rays()
    t_far = np.linalg.norm(o - np.array([0.5, 0.45, 0.5]), axis=-1)  # as far as the cube's centre
    surface_t = np.where(np.arange(W)[None, :] % 3 == 0, np.inf, t_far)
    rows = (4, 13)
    fractions = []
    cache = r.trace(cam, tf, opts, rows=rows, surface_t=surface_t, progress=lambda f: fractions.append(f) or True,
                    tile_pixels=50)
    assert len(fractions) > 3 and fractions[-1] == 1.0 and cache.rays == 9 * W
    assert r.cache_fits(cache, cam, tf, opts, rows=rows, surface_key=segment_cache.surface_digest(surface_t))
    assert not r.cache_fits(cache, cam, tf, opts, rows=rows, surface_key=segment_cache.surface_digest(surface_t + 1))
    for edit in (tf, edits(tf)["opaque"]):
        fresh = r.render(cam, edit, BACKGROUND, opts, rows=rows, surface_t=surface_t)
        shaded = r.shade(cache, edit, BACKGROUND, opts, progress=lambda f: True, tile_pixels=37)
        assert shaded.rgba.shape == (9, W, 4) and shaded.stats["rows"] == [4, 13]
        assert_same_image(fresh, shaded, "cpu")


def test_cancelled_trace_is_not_used():
    r, cam, tf = scene("affine", "cpu")
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tf, opts, progress=lambda f: False, tile_pixels=100)
    assert not cache.complete and not r.cache_fits(cache, cam, tf, opts)
    with pytest.raises(SegmentCacheError, match="cancelled"):
        r.shade(cache, tf, BACKGROUND, opts)
    res, kept = cached(r, cam, tf, opts, progress=lambda f: False, tile_pixels=100)
    assert res.cancelled and kept is None


def test_memory_limit_refuses_the_cache_and_the_frame_renders_plainly():
    r, cam, tf = scene("curved", "cpu")
    opts = RenderOptions(method="split")
    full = r.trace(cam, tf, opts)
    image_bytes = r.check_limits(W, H, opts, W * H)
    # room for the render but not for its cache beside it
    with limits.using(limits.ResourceLimits(max_memory=image_bytes + full.nbytes // 2)):
        with pytest.raises(limits.ResourceLimitError, match="segment cache of a 24x18 image"):
            r.trace(cam, tf, opts)
        res, cache = cached(r, cam, tf, opts)
        assert cache is None and "memory limit" in res.stats["segment_cache"]["refused"]
        assert_same_image(r.render(cam, tf, BACKGROUND, opts), res, "cpu")
        # what a viewport holds in its other caches counts too
        with pytest.raises(limits.ResourceLimitError):
            r.trace(cam, tf, opts, held_bytes=10 * full.nbytes)


def test_cache_size_is_reported(monkeypatch):
    r, cam, tf = scene("curved", "cpu")
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tf, opts)
    info = cache.describe()
    segments, chunks, coefficients = cache.counts
    assert info["segments"] == segments > 0 and chunks >= segments / segment_cache.SEGMENTS_PER_ROUND
    assert info["bytes"] == cache.nbytes and info["bytes_per_ray"] == pytest.approx(cache.nbytes / (W * H))
    # shrunk to fit: each segment its 28-byte record, its series (degree + 3 floats) and a chunk's share
    series = 4 * coefficients / segments
    assert 28 + series <= info["bytes_per_segment"] <= 28 + series + 12 + 4 * 3 / segments + 1e-9
    res = r.shade(cache, tf, BACKGROUND, opts)
    assert res.stats["segment_cache"] == info
    # the counters summed on the device, many rows a thread, as one row a thread
    monkeypatch.setattr(segment_cache, "SUM_THREADS", 7)
    few = r.shade(cache, tf, BACKGROUND, opts).stats
    assert {k: few[k] for k in COUNTERS} == {k: res.stats[k] for k in COUNTERS}
    assert res.stats["segments"] == segments and res.stats["restriction_evaluations"] > 0
    # the door reports the trace and the shade as one render
    res, _ = cached(r, cam, tf, opts)
    assert res.stats["render_seconds"] >= res.stats["segment_cache"]["trace_seconds"]


_PROPERTY = {}


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_random_transfer_functions_shade_as_they_render(data):
    """Random transfer functions within the trace's breakpoint band (so its frame): random inner
    breakpoints, colours and densities (zeros among them), through split or classified."""
    if not _PROPERTY:
        mesh = mixed_cube(2, 3, cube_field)
        r = Renderer(mesh, "cpu")
        cam = framing(mesh, 10, 8)
        lo, hi = np.percentile(mesh.field_samples(3), [5, 95])
        base = TransferFunction(np.array([lo, hi]), np.ones((2, 3)), np.array([lo, hi]), np.ones(2))
        _PROPERTY.update(r=r, cam=cam, lo=lo, hi=hi,
                         caches={m: r.trace(cam, base, RenderOptions(method=m)) for m in ("split", "classified")})
    r, cam, lo, hi = _PROPERTY["r"], _PROPERTY["cam"], _PROPERTY["lo"], _PROPERTY["hi"]
    method = data.draw(st.sampled_from(["split", "classified"]))
    k = data.draw(st.integers(0, 5))
    inner = np.sort(np.array(data.draw(st.lists(st.floats(0.01, 0.99), min_size=k, max_size=k, unique=True))))
    s = np.concatenate([[lo], lo + inner * (hi - lo), [hi]])
    s = s[np.concatenate([[True], np.diff(s) > 1e-9 * (hi - lo)])]
    tau = np.array(data.draw(st.lists(st.sampled_from([0.0, 0.5, 3.0, 20.0, 150.0]), min_size=len(s), max_size=len(s))))
    rgb = np.array(data.draw(st.lists(st.tuples(*[st.floats(0, 1)] * 3), min_size=len(s), max_size=len(s))))
    tf = TransferFunction(s, rgb, s, tau)
    opts = RenderOptions(method=method, tolerance=1e-4)
    cache = _PROPERTY["caches"][method]
    assert r.cache_fits(cache, cam, tf, opts)
    assert_same_image(r.render(cam, tf, BACKGROUND, opts), r.shade(cache, tf, BACKGROUND, opts), "cpu")


def test_surfaces_keep_their_hits_with_the_cache(monkeypatch):
    """A frame's opaque meshes with a segment cache: their hits are cast once and kept with the
    cache; a look change composites the shaded volume over them exactly as a fresh render does, in
    both modes and for a band of rows."""
    from hovr_blender.engine.opaque import OpaqueMesh, OpaqueScene

    r, cam, tf = scene("curved", "cpu")
    plane = OpaqueMesh(np.array([[-1.0, -1.0, 0.45], [2.0, -1.0, 0.55], [2.0, 2.0, 0.6], [-1.0, 2.0, 0.5]]),
                        [[0, 1, 2], [0, 2, 3]], (0.75, 0.5, 0.25))
    surfaces = OpaqueScene([plane])
    opts = RenderOptions(method="split")
    res, cache = cached(r, cam, tf, opts, opaque=surfaces)
    assert cache is not None and cache.opaque_hits is not None and 0 < res.stats["surface_pixels"] < W * H
    cast, casts = OpaqueScene.cast, []
    monkeypatch.setattr(OpaqueScene, "cast", lambda self, camera: casts.append(camera) or cast(self, camera))
    for mode in ("SHADED", "HOLDOUT"):
        for edit in (edits(tf)["colours"], edits(tf)["opaque"]):
            shaded, again = cached(r, cam, edit, opts, opaque=surfaces, mode=mode, cache=cache)
            assert again is cache
            fresh = render_frame(r, Frame(edit, BACKGROUND, opts, opaque=surfaces, opaque_mode=mode), cam)
            np.testing.assert_array_equal(shaded.rgba, fresh.rgba)
            np.testing.assert_array_equal(shaded.depth, fresh.depth)
    assert len(casts) == 4  # the fresh renders' casts only
    # other surfaces (another scene object): traced again
    other = OpaqueScene([plane])
    _, new = cached(r, cam, tf, opts, opaque=other, cache=cache)
    assert new is not cache
    # a band of rows
    band, band_cache = cached(r, cam, tf, opts, opaque=surfaces, rows=(3, 11))
    fresh = render_frame(r, Frame(tf, BACKGROUND, opts, opaque=surfaces), cam, rows=(3, 11))
    np.testing.assert_array_equal(band.rgba, fresh.rgba)
    assert band_cache.rows == (3, 11)


def test_two_volumes_each_with_its_own_look():
    """Two volumes in one mesh, one transfer function each (their frames side by side on one
    axis): editing either look shades from the cache as a fresh render would draw it."""
    from hovr_blender.engine.mesh import concatenate

    a = mixed_cube(2, 3, cube_field)
    b = mixed_cube(1, 3, lambda x, y, z: 1000.0 + 50.0 * cube_field(x, y, z), lower=(0.2, 1.3, 0.1), size=0.8)
    mesh = concatenate([a, b])
    r = Renderer(mesh, "cpu")
    cam = framing(mesh, 20, 14)
    tfs = [tents(0.0, 1.5, COLORS, 10.0), tents(1000.0, 1075.0, COLORS[::-1], 8.0)]
    opts = RenderOptions(method="split")
    cache = r.trace(cam, tfs, opts)
    for edited in ([edits(tfs[0])["opaque"], tfs[1]], [tfs[0], edits(tfs[1])["colours"]],
                   [edits(tfs[0])["one tent"], edits(tfs[1])["moved"]]):
        assert r.cache_fits(cache, cam, edited, opts)
        assert_same_image(r.render(cam, edited, BACKGROUND, opts), r.shade(cache, edited, BACKGROUND, opts), "cpu")


def test_a_trace_over_threads_keeps_each_band_and_shades_the_one_image():
    """On the CPU a trace runs in bands of rows over cpu_threads threads (BandedCache: each band a
    cache of its own, their counters in one array): it fits the view as the one-thread cache does,
    and shading it, before and after a look-only edit, and through render_frame's slot, gives the
    one-thread image and counts bit for bit. A progress that says stop leaves it incomplete (not
    shaded: trace again), and the memory limit counts each band's share."""
    mesh = curved_cube(1)
    cam = framing(mesh, 128, 96)
    v = mesh.field_samples(3)
    tf = tents(float(v.min()), float(v.max()), COLORS, 3.0)
    edited = tents(float(v.min()), float(v.max()), COLORS[::-1], 5.0)
    opts = RenderOptions()
    r = Renderer(mesh, "cpu")
    r.cpu_threads = 1
    one = r.trace(cam, tf, opts)
    r.cpu_threads = 3
    banded = r.trace(cam, tf, opts)
    assert isinstance(banded, segment_cache.BandedCache) and isinstance(one, segment_cache.SegmentCache)
    assert len(banded.parts) == 12 and [p.rows for p in banded.parts] == segment_cache.row_bands(0, 96, 12)
    assert banded.complete and r.cache_fits(banded, cam, tf, opts) and banded.key == one.key
    assert banded.counts == one.counts and banded.describe()["bands"] == 12
    for key in ("field_evaluations", "segments", "newton_iterations"):
        assert banded.stats[key] == one.stats[key], key
    for look in (tf, edited):
        want, got = r.shade(one, look, np.zeros(3), opts), r.shade(banded, look, np.zeros(3), opts)
        np.testing.assert_array_equal(got.rgba, want.rgba)
        np.testing.assert_array_equal(got.depth, want.depth)
        assert got.stats["restriction_evaluations"] == want.stats["restriction_evaluations"]
        assert got.stats["segment_cache"]["bands"] == 12
    slot = SegmentSlot()
    framed = render_frame(r, Frame(tf, np.zeros(3), opts, cache=slot), cam)
    assert isinstance(slot.cache, segment_cache.BandedCache)
    np.testing.assert_array_equal(framed.rgba, r.render(cam, tf, np.zeros(3), opts).rgba)
    stopped = r.trace(cam, tf, opts, progress=lambda f: False)
    assert not stopped.complete and not r.cache_fits(stopped, cam, tf, opts)
    with pytest.raises(SegmentCacheError, match="cancelled"):
        r.shade(stopped, tf, np.zeros(3), opts)
    with limits.using(limits.ResourceLimits(max_memory=banded.nbytes)):  # the bands' shares are too small
        with pytest.raises(limits.ResourceLimitError):
            r.trace(cam, tf, opts)
