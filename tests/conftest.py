"""Fixtures tests/ share (the device fixture and the markers are in the repository's conftest.py;
plain helper functions and constants in tests/helpers.py)."""
import os

import pytest


@pytest.fixture(scope="session")
def vm():
    """tests/fuzz/vtu_mutation.py: its vtk-written sources and its .vtu block editor."""
    pytest.importorskip("vtk", reason="the vtk package (writer of the .vtu sources) is not installed")
    from tests.fuzz import vtu_mutation

    return vtu_mutation


@pytest.fixture(autouse=True, scope="module")
def environment_as_it_was():
    """Each test module leaves the process's environment as it found it: a Dask LocalCluster
    started in this process (tests/distributed, tests/blender's animation) sets its workers'
    pre-spawn variables (OMP_NUM_THREADS=1 ...) here for good, and the device processes of the
    tests after it would run BLAS unlike this process (hovr's own local_cluster restores them:
    tests/distributed/test_cluster_security.py)."""
    saved = dict(os.environ)
    yield
    os.environ.clear()
    os.environ.update(saved)
