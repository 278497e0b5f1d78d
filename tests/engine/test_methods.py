"""The method categories (engine/methods.py) are asked by name, one home for each: the host's
predicates say what each method is, and the kernels' twin of samples_segments
(kernels/quadrature.py) agrees with the host's for every method id."""
import numpy as np
import warp as wp

from hovr_blender.engine import methods
from hovr_blender.engine.kernels.quadrature import samples_segments


def test_each_method_is_in_its_categories():
    assert methods.METHODS == ("riemann", "trapezoid", "classified", "split")  # saved ids never move
    assert [methods.samples_segments(m) for m in methods.METHODS] == [False, False, True, True]
    assert [methods.needs_step(m) for m in methods.METHODS] == [True, True, False, False]
    assert [methods.takes_step(m) for m in methods.METHODS] == [True, True, True, False]
    assert [methods.chooses_own_step(m, None) for m in methods.METHODS] == [False, False, True, False]
    assert not methods.chooses_own_step("classified", 0.01)
    named = methods.SAMPLING_METHODS + methods.FIXED_STEP_METHODS + methods.STEPLESS_METHODS + methods.OWN_STEP_METHODS
    assert set(named) <= set(methods.METHODS)


@wp.kernel
def _device_samples_segments(ids: wp.array(dtype=int), out: wp.array(dtype=int)):
    i = wp.tid()
    out[i] = samples_segments(ids[i])


def test_the_kernels_ask_the_same_question():
    from hovr_blender.engine.devices import resolve_device

    device = resolve_device("cpu")
    ids = wp.array(np.array([methods.METHOD_IDS[m] for m in methods.METHODS], np.int32), dtype=int, device=device)
    out = wp.zeros(len(methods.METHODS), dtype=int, device=device)
    wp.launch(_device_samples_segments, dim=len(methods.METHODS), inputs=[ids, out], device=device)
    assert out.numpy().tolist() == [int(methods.samples_segments(m)) for m in methods.METHODS]
