"""Fixtures tests/ share (the device fixture and the markers are in the repository's conftest.py;
plain helper functions and constants in tests/helpers.py)."""
import pytest


@pytest.fixture(scope="session")
def vm():
    """tests/fuzz/vtu_mutation.py: its vtk-written sources and its .vtu block editor."""
    pytest.importorskip("vtk", reason="the vtk package (writer of the .vtu sources) is not installed")
    from tests.fuzz import vtu_mutation

    return vtu_mutation
