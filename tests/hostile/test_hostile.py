"""The hostile-input suite (issue 13): every case through the `hovr` command in a fresh, memory-
capped process, judged on exit code, message, wall time (< 5 s) and peak memory (< 500 MB).
`python -m tests.hostile.table` prints the same cases as a table."""
import pytest

from .cases import CASES
from .harness import run_case


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_input(case, tmp_path):
    outcome, problems = run_case(case, tmp_path)
    assert not problems, f"{case.klass} / {case.name}: " + "; ".join(problems)
