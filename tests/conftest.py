import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_file(*parts) -> Path:
    """A file from ../shared/data, or skip the test with the reason."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"shared data not present: {p}")
    return p


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
