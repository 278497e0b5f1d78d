"""A sample of the MFEM fuzzer (tests/fuzz/mfem_mutation.py; its full run is in docs/limits.md):
text mutations of the vendored meshes and GridFunctions (absurd counts and orders, numbers that
are not numbers, lines lost, files cut short) each load or are refused with one line naming a
file, through the reader process, and this process lives on."""
from __future__ import annotations

import numpy as np


def test_a_sample_of_the_mfem_fuzzer(tmp_path):
    from tests.fuzz import mfem_mutation as fuzz

    items = fuzz.mutants(np.random.default_rng(3), fuzz.sources(), 60)
    summary = fuzz.CAMPAIGN.run_here(items, tmp_path, seconds=5.0)
    assert summary["mutants"] == 60 and not summary["problems"], summary
    assert summary["outcomes"].get("refused", 0) >= 30 and summary["outcomes"].get("loaded", 0) >= 1, summary
