"""Fixtures tests/ share (the device fixture and the markers are in the repository's conftest.py;
plain helper functions and constants in tests/helpers.py)."""
import os
import signal

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


@pytest.fixture
def stopped_reader(monkeypatch):
    """A function that starts a reader process (io/isolation.py) and stops it (SIGSTOP: as good as
    libhdf5's endless loop), and returns its pid: the next read is handed to it, whatever the pool
    holds then (an idle reader may end between a look at the pool and a read), and waits on it
    until it is killed (cancel, the time limit). Still alive at the test's end, it is killed."""
    from hovr_blender.io import isolation

    made = []

    def stop_next_reader() -> int:
        worker = isolation._Worker()
        os.kill(worker.proc.pid, signal.SIGSTOP)
        made.append(worker)
        take, pending = isolation._take, [worker]
        monkeypatch.setattr(isolation, "_take", lambda: pending.pop() if pending else take())
        return worker.proc.pid

    yield stop_next_reader
    for worker in made:
        worker.kill()
