"""The hostile-input suite (issue 13): every case through the `hovr` command in a fresh, memory-
capped process, judged on exit code, message, wall time (< 5 s) and peak memory (< 500 MB).
`python -m tests.hostile.table` prints the same cases as a table."""
import pytest

from .cases import CASES
from .harness import run_case


SLOW = {"VTU 3 GiB zlib bomb in one block", 'field ID="0-9999999", matching zlib stream',
        "VTU 512 MiB LZMA bomb in one block"}  # seconds each (building the input included)


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c.name in SLOW else c for c in CASES],
                         ids=[c.name for c in CASES])
def test_hostile_input(case, tmp_path):
    outcome, problems = run_case(case, tmp_path)
    assert not problems, f"{case.klass} / {case.name}: " + "; ".join(problems)
