"""The value frame the kernels see (engine/field_frame.py): the transfer function and the field
move together, so the function of the data is unchanged, one volume or several."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hovr_blender.engine.field_frame import frame, resolution_warnings
from hovr_blender.engine.transfer_function import TransferFunction


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
    fr, mapped = frame([tf], [(offset - span, offset + 2 * span)])
    f = rng.uniform(offset - span, offset + 2 * span, 200)
    g = fr.apply(f)
    band = np.concatenate([mapped.color_s, mapped.density_s])
    width = band.max() - band.min()
    assert 0.5 < width <= 1.0 + 1e-9  # about unit width,
    assert max(abs(band.max()), abs(band.min())) <= 1.5 + 1e-9  # and near 0 (centred, or never shifted away from it)
    assert np.log2(fr.scale[0]) == round(np.log2(fr.scale[0]))  # a power of two: scaling is exact
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
    fr, combined = frame(tfs, ranges)
    for k, (tf, (dlo, dhi)) in enumerate(zip(tfs, ranges)):
        f = np.concatenate([rng.uniform(dlo, dhi, 300), [dlo, dhi]])
        g = fr.apply(f, k)
        # float64 rounding of the map: ~1e-16 x |data| / span, far below an image's 1e-3
        np.testing.assert_allclose(combined.density(g), tf.density(f), atol=1e-6 * tf.density_tau.max())
        np.testing.assert_allclose(combined.color(g), tf.color(f), atol=1e-6)


def test_a_small_edit_keeps_the_frame():
    """The renderer re-uploads the field only when the frame changes: nudging a breakpoint by a
    percent of the band must not."""
    s = np.array([100.0, 100.4, 100.8])
    tf = TransferFunction(s, np.ones((3, 3)), s.copy(), np.array([0.0, 1.0, 0.0]))
    nudged = TransferFunction(s + [0.0, 0.01, 0.01], np.ones((3, 3)), s.copy(), np.array([0.0, 2.0, 0.0]))
    assert frame([tf], [(0, 200)])[0].key == frame([nudged], [(0, 200)])[0].key


def _warnings(tf, lo, hi, scale, precision="float32"):
    fr, _ = frame([tf], [(lo.min(), hi.max())])
    eps = np.finfo(precision).eps
    return resolution_warnings([tf], fr, np.zeros(lo.size, int), fr.apply(lo), fr.apply(hi), eps * fr.scale[0] * scale,
                               precision)


def test_a_feature_float32_cannot_resolve_is_named():
    # pressure in pascals, +-5 around 101,325: after the shift, float32 resolves it
    s = np.array([101320.0, 101325.0, 101330.0])
    tf = TransferFunction(s, np.ones((3, 3)), s.copy(), np.array([0.0, 1.0, 0.0]))
    lo, hi = np.array([101318.0]), np.array([101331.0])
    assert _warnings(tf, lo, hi, scale=np.array([6.0])) == []  # an element's terms of the fluctuation's size
    # an element whose terms are 1e6 x the band (a steep field through it) cannot be resolved
    msg = _warnings(tf, lo, hi, scale=np.array([1e7]))
    assert len(msg) == 1 and "float64" in msg[0]
    assert _warnings(tf, lo, hi, scale=np.array([1e7]), precision="float64") == []
    # elements away from the band see a constant transfer function: no warning
    assert _warnings(tf, np.array([2e5]), np.array([3e5]), scale=np.array([1e7])) == []
