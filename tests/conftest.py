"""Fixtures tests/ share (the device fixture is in the repository's conftest.py; plain helper
functions and constants in tests/helpers.py)."""
import importlib.util
import sys

import pytest

from .helpers import REPO


@pytest.fixture(scope="session")
def vm():
    """bench/vtu_mutation.py as a module: its vtk-written sources and its .vtu block editor."""
    pytest.importorskip("vtk", reason="the vtk package (writer of the .vtu sources) is not installed")
    spec = importlib.util.spec_from_file_location("vtu_mutation", REPO / "bench" / "vtu_mutation.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["vtu_mutation"] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod
