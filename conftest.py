"""pytest set-up for tests/ and for bench/test_resample_baseline.py (the one check that lives in
bench/): the `device` fixture. Fixtures only tests/ use are in tests/conftest.py; shared plain
functions in tests/helpers.py."""
import os

import pytest


def warp_devices():
    """cpu always; cuda:0 too where a CUDA device exists. HOVR_TEST_DEVICES=cuda:0 narrows the
    list (the GPU machine's packed Warp carries no CPU compiler)."""
    import warp as wp

    if os.environ.get("HOVR_TEST_DEVICES"):
        return os.environ["HOVR_TEST_DEVICES"].split(",")
    wp.config.quiet = True
    wp.init()
    devs = ["cpu"]
    if wp.is_cuda_available():
        devs.append("cuda:0")
    return devs


@pytest.fixture(params=warp_devices())
def device(request):
    return request.param
