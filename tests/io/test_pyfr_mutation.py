"""A sample of the PyFR fuzzer (tests/fuzz/pyfr_mutation.py; its full run is in docs/limits.md):
byte flips and truncations of the shell case's .pyfrm and .pyfrs each load or are refused with
one line naming a file, through the reader process, and this process lives on."""
from __future__ import annotations

import numpy as np


def test_a_sample_of_the_pyfr_fuzzer(tmp_path):
    from tests.fuzz import pyfr_mutation as fuzz

    items = fuzz.mutants(np.random.default_rng(3), fuzz.sources(), 40)
    summary = fuzz.CAMPAIGN.run_here(items, tmp_path, seconds=5.0)
    assert summary["mutants"] == 40 and not summary["problems"], summary
    assert summary["outcomes"].get("refused", 0) >= 3, summary
