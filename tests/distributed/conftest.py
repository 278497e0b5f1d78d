import os

import pytest


@pytest.fixture(autouse=True, scope="module")
def environment_as_it_was():
    """Each test module leaves the process's environment as it found it: a Dask LocalCluster started here
    sets its workers' pre-spawn variables (OMP_NUM_THREADS=1 ...) in this process for good, and
    the tests after it would start their device processes under them (hovr's own local_cluster
    restores them: tests/distributed/test_cluster_security.py)."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)
