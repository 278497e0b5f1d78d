"""pytest set-up for tests/ and for the two checks of bench code that live in bench/
(test_resample_baseline.py, test_peers_calibration.py): the `device` fixture and the markers' behaviour. Fixtures only tests/ use are in
tests/conftest.py; shared plain functions in tests/helpers.py.

Markers (registered in pyproject.toml): `slow` (seconds each; `-m "not slow"` for a quick pass;
the default run keeps them) and `gpu` (needs a CUDA device: skipped where there is none). Every
test taking `device` runs on cpu and on cuda:0, the latter marked gpu; HOVR_TEST_DEVICES=cuda:0
narrows the list (the GPU machine's packed Warp carries no CPU compiler).
"""
import functools
import os

import pytest


def _device_params():
    names = os.environ.get("HOVR_TEST_DEVICES", "cpu,cuda:0").split(",")
    return [pytest.param(n, marks=pytest.mark.gpu) if n.startswith("cuda") else n for n in names]


@functools.cache
def cuda_available() -> bool:
    import warp as wp

    wp.config.quiet = True
    wp.init()
    return wp.is_cuda_available()


@pytest.fixture(params=_device_params())
def device(request):
    return request.param


def pytest_runtest_setup(item):
    if item.get_closest_marker("gpu") and not cuda_available():
        pytest.skip("gpu: no CUDA device")
