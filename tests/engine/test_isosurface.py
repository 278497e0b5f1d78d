"""Isosurface crossings along a segment (kernels/isosurface.py) against numpy: the roots of a
segment's series less a level, every degree a segment can have, grazing double roots included,
and pyramid weights."""
import numpy as np
import numpy.polynomial.chebyshev as C
import pytest
import warp as wp

from hovr_blender.engine.kernels import isosurface
from hovr_blender.engine.kernels.args import MAX_SAMPLES
from hovr_blender.engine.kernels.isosurface import MAX_EVENTS


@wp.kernel
def _roots(c: wp.array(dtype=wp.float32), deg: wp.array(dtype=wp.int32), level: wp.array(dtype=wp.float32),
           err: wp.array(dtype=wp.float32), start: wp.array(dtype=wp.float32), out: wp.array2d(dtype=wp.float32),
           count: wp.array(dtype=wp.int32)):
    i = wp.tid()
    roots, k, evals = isosurface.level_roots(c, i * MAX_SAMPLES, deg[i], level[i], err[i], start[i])
    for j in range(k):
        out[i, j] = roots[j]
    count[i] = k


def _run(series, levels, weights=None, device="cpu", err=0.0, start=isosurface.NO_START):
    """level_roots of each series less its level (err: the samples' rounding; start: the sign at
    s = -1 the previous segment's end gives, NO_START for none), as float64 arrays."""
    n = len(series)
    coeffs = np.zeros((n, MAX_SAMPLES), np.float32)
    degs = np.zeros(n, np.int32)
    for i, c in enumerate(series):
        d = len(c) - 1
        coeffs[i, : d + 1] = c
        coeffs[i, d + 1: d + 3] = (1.0, 1.0) if weights is None else weights[i]
        degs[i] = d

    def per_series(v):
        return wp.array(np.broadcast_to(np.asarray(v, np.float32), (n,)).copy(), dtype=wp.float32, device=device)

    out = wp.zeros((n, MAX_EVENTS), dtype=wp.float32, device=device)
    count = wp.zeros(n, dtype=wp.int32, device=device)
    wp.launch(_roots, dim=n, device=device,
              inputs=[wp.array(coeffs.ravel(), dtype=wp.float32, device=device), wp.array(degs, dtype=wp.int32, device=device),
                      per_series(levels), per_series(err), per_series(start), out, count])
    k = count.numpy()
    return [out.numpy()[i, : k[i]].astype(np.float64) for i in range(n)]


def _numpy_roots(c, level, weights=(1.0, 1.0)):
    """Real roots in [-1, 1) of g - level w^2 (float64)."""
    p = np.array(c, np.float64)
    wa, wb = weights
    alpha, beta = 0.5 * (wa + wb), 0.5 * (wb - wa)
    w2 = np.array([alpha * alpha + 0.5 * beta * beta, 2 * alpha * beta, 0.5 * beta * beta])
    p = C.chebsub(p, level * w2)
    r = C.chebroots(C.chebtrim(p, 0)) if np.any(p[1:]) else np.array([])
    r = r[np.abs(r.imag) < 1e-7].real
    return np.sort(r[(r >= -1) & (r < 1)])


def test_simple_roots_of_random_series_match_numpy(device):
    rng = np.random.default_rng(11)
    series, levels, want = [], [], []
    for d in list(range(0, 19)) * 6 + [30, 40, 45]:
        # well separated simple roots: a product of known roots, level 0, plus a shifted copy
        k = min(d, 4)
        r = np.sort(rng.uniform(-0.95, 0.95, k))
        while k > 1 and np.min(np.diff(r)) < 0.3:
            r = np.sort(rng.uniform(-0.95, 0.95, k))
        p = C.chebfromroots(r) if k else np.array([1.0])
        if d > k:
            p = C.chebmul(p, np.r_[1.5, rng.uniform(-0.2, 0.2, d - k) / (1 + np.arange(d - k))])
        p = p / np.abs(p).sum()
        series.append(p[: MAX_SAMPLES - 2].astype(np.float32))
        levels.append(0.0)
        want.append(r)
    got = _run(series, levels, device=device)
    for g, w, c in zip(got, want, series):
        w = _numpy_roots(c.astype(np.float64), 0.0)
        assert len(g) == len(w), (len(c) - 1, g, w)
        assert np.allclose(g, w, atol=2e-5), (g, w)


def test_grazing_pair_is_found_where_samples_see_no_crossing(device):
    """p(s) = (s - r)^2 + delta, level 0: for delta slightly below zero two roots 2 sqrt(-delta)
    apart; at 0 a double root; above, none. Sign tests at the segment's Lobatto points miss the
    pair (same sign at every sample)."""
    cases = []
    for r in (-0.61, 0.07, 0.33):
        for delta in (-1e-4, 0.0, 1e-4):
            cases.append((r, delta))
    series, levels = [], []
    for r, delta in cases:
        p = C.chebmul(C.chebfromroots([r, r]), [1.0, 0.1])  # (s - r)^2 (1 + 0.1 s): convex near r
        p = C.chebadd(p, [delta])
        series.append(p.astype(np.float32))
        levels.append(0.0)
        samples = C.chebval(np.cos(np.pi * np.arange(4) / 3), p)
        assert np.all(samples > 0)  # no sign change at the points a degree-3 segment samples
    got = _run(series, levels, device=device)
    _assert_touch_or_pair(cases, got, lambda r, delta: np.sqrt(-delta / (1 + 0.1 * r)), 2e-4)


def _assert_touch_or_pair(cases, got, half, atol):
    """Each case (r, delta) of p = (s - r)^2 q + delta: no root for delta > 0, one at r for delta
    = 0, two at r -+ half(r, delta) within atol for delta < 0."""
    for (r, delta), g in zip(cases, got):
        if delta > 0:
            assert len(g) == 0, (r, delta, g)
        elif delta == 0:
            assert len(g) == 1 and abs(g[0] - r) < 1e-3, (r, g)
        else:
            h = half(r, delta)
            assert len(g) == 2 and np.allclose(g, [r - h, r + h], atol=atol), (r, delta, g)


def test_levels_and_pyramid_weights_match_numpy(device):
    rng = np.random.default_rng(5)
    series, levels, weights = [], [], []
    for d in range(1, 12):
        for _ in range(8):
            c = rng.uniform(-1, 1, d + 1) / (1 + np.arange(d + 1))
            series.append(c.astype(np.float32))
            levels.append(float(rng.uniform(-0.5, 0.5)))
            weights.append((float(rng.uniform(0.2, 1.0)), float(rng.uniform(0.2, 1.0))))
    got = _run(series, levels, weights, device=device)
    for g, c, lv, w in zip(got, series, levels, weights):
        want = _numpy_roots(c.astype(np.float64), np.float32(lv), np.float32(w))
        # roots closer than the float32 resolution of the level merge into one (a graze)
        near_double = len(want) > 1 and np.min(np.diff(want)) < 1e-2
        if near_double:
            continue
        assert len(g) == len(want), (g, want)
        assert np.allclose(g, want, atol=5e-4), (g, want)


def test_near_tangency_the_pair_is_met_at_its_own_roots(device):
    """p(s) = (s - r)^2 + delta with a large sample rounding err (1e-3, as an element's field_err
    can be): an extremum within err of c is no touch unless it is within the series' own rounding. A pair
    (delta < 0) is two meetings at r -+ sqrt(-delta), the first at its own place, not at the
    extremum r (the ball's silhouette at 1920x1080 was drawn up to 5.4e-3 deep there); delta > 0
    is no meeting (it was drawn, 4.3e-5 outside the sphere); an extremum on c is one meeting."""
    cases = [(r, delta) for r in (-0.4, 0.2) for delta in (-1e-4, -1e-5, 0.0, 1e-5, 1e-4)]
    series = [C.chebadd(C.chebfromroots([r, r]), [delta]).astype(np.float32) for r, delta in cases]
    got = _run(series, [0.0] * len(cases), device=device, err=1e-3)
    _assert_touch_or_pair(cases, got, lambda r, delta: np.sqrt(-delta), 1e-5)


def test_a_crossing_between_two_segments_is_met_once_at_the_start(device):
    """The sign the previous segment's end gives at s = -1 (start): where p itself starts on
    the other side of c than that end (a gap between the segments, or their ends' roundings on
    either side of c), the crossing is met at s = -1; where p crosses back to the end's side
    near its start (the previous segment met the crossing at its end), it is not met again.
    The ball's pixel (1099, 638) at 1920x1080 lost its entry so, into a gap of 5e-6 between a
    tetrahedron's exit and a prism's entry, and was drawn at the exit 0.44 deeper."""
    up = [0.5, 0.5]  # p = (s + 1) / 2: 0 at s = -1, rising
    series = [C.chebadd(up, [1e-6]), C.chebadd(up, [-1e-6]), C.chebadd(up, [1e-6]), [1.0, 0.5, 0.0], [1.0, 0.5, 0.0],
              [1.0, 0.5, 0.0], [-0.5, 0.25, 0.1]]
    starts = [-1.0, 1.0, 1.0, -1.0, 0.0, 1.0, 1.0]
    want = [[-1.0], [], [], [-1.0], [-1.0], [], [-1.0]]
    got = _run([np.asarray(c, np.float32) for c in series], [0.0] * len(series), device=device, start=starts)
    for c, st, w, g in zip(series, starts, want, got):
        assert len(g) == len(w) and np.allclose(g, w, atol=1e-6), (c, st, g)
    # no start: p's own sign (the first two: none and the root at -1 + 4e-6)
    own = _run([np.asarray(c, np.float32) for c in series[:2]], [0.0, 0.0], device=device)
    assert len(own[0]) == 0 and len(own[1]) == 1 and abs(own[1][0] + 1.0 - 2e-6) < 1e-6, own
