"""The value frame the kernels see (core/field_frame.py): the transfer function and the field
move together, so the function of the data is unchanged, one volume or several."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hovr_blender.core.field_frame import frame
from hovr_blender.core.transfer_function import TransferFunction


def random_tf(rng, lo, hi, n=5):
    s = np.sort(rng.uniform(lo, hi, n))
    s = s + np.arange(n) * 1e-9 * (hi - lo)  # strictly increasing
    return TransferFunction(s, rng.uniform(0, 1, (n, 3)), s.copy(), rng.uniform(0, 5, n))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 10_000), st.floats(-1e6, 1e6), st.floats(1e-6, 1e6))
def test_one_volume_the_function_of_the_data_is_unchanged(seed, ratio, span):
    """Offsets up to 1e6 times the span (the issue's range of b)."""
    rng = np.random.default_rng(seed)
    offset = ratio * span
    tf = random_tf(rng, offset, offset + span)
    fr, mapped, warnings = frame([tf], [(offset - span, offset + 2 * span)])
    f = rng.uniform(offset - span, offset + 2 * span, 200)
    g = fr.apply(f)
    band = np.concatenate([mapped.color_s, mapped.density_s])
    np.testing.assert_allclose([band.min(), band.max()], [-0.5, 0.5], atol=1e-6)  # the band at unit width around 0
    # float64 rounding of the map: ~1e-16 x |data| / span, far below an image's 1e-3
    np.testing.assert_allclose(mapped.density(g), tf.density(f), atol=1e-6 * tf.density_tau.max())
    np.testing.assert_allclose(mapped.color(g), tf.color(f), atol=1e-6)


@pytest.mark.parametrize("seed", range(8))
def test_several_volumes_read_only_their_own_transfer_function(seed):
    rng = np.random.default_rng(seed)
    tfs, ranges = [], []
    for k in range(3):
        lo = rng.uniform(-1e5, 1e5)
        span = 10 ** rng.uniform(-3, 4)
        tfs.append(random_tf(rng, lo, lo + span))
        ranges.append((lo - rng.uniform(0, 3) * span, lo + span * (1 + rng.uniform(0, 3))))
    fr, combined, _ = frame(tfs, ranges)
    for k, (tf, (dlo, dhi)) in enumerate(zip(tfs, ranges)):
        f = np.concatenate([rng.uniform(dlo, dhi, 300), [dlo, dhi]])
        g = fr.apply(f, k)
        # float64 rounding of the map: ~1e-16 x |data| / span, far below an image's 1e-3
        np.testing.assert_allclose(combined.density(g), tf.density(f), atol=1e-6 * tf.density_tau.max())
        np.testing.assert_allclose(combined.color(g), tf.color(f), atol=1e-6)


def test_a_feature_float32_cannot_resolve_is_named():
    s = np.array([0.0, 1e-9, 2e-9, 1.0])
    tf = TransferFunction(s, np.ones((4, 3)), s.copy(), np.array([0.0, 1.0, 0.0, 0.0]))
    assert any("float64" in w for w in frame([tf], [(0.0, 1.0)])[2])
    ok = TransferFunction(np.array([0.0, 0.5, 1.0]), np.ones((3, 3)), np.array([0.0, 0.5, 1.0]),
                          np.array([0.0, 1.0, 0.0]))
    assert frame([ok], [(1e5, 1e5 + 1.0)])[2] == []
