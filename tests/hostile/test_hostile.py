"""The hostile-input suite (issue 13): every case through the `hovr` command in a fresh, memory-
capped process, judged on exit code, message, wall time (< 5 s) and peak memory (< 500 MB).
`python -m tests.hostile.table` prints the same cases as a table."""
import pytest

from .cases import CASES as READER_CASES
from .harness import run_case
from .run_cases import RUN_CASES

CASES = READER_CASES + RUN_CASES  # the readers' inputs, then issue 29's runs


SLOW = {"VTU 3 GiB zlib bomb in one block", 'field ID="0-9999999", matching zlib stream',
        "VTU 512 MiB LZMA bomb in one block", "mesh with a 1 GiB attribute"}  # seconds each (building the input included)
SLOW |= {c.name for c in RUN_CASES if c.max_seconds > 5.0}  # a Dask cluster, or Blender, starts first


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c.name in SLOW else c for c in CASES],
                         ids=[c.name for c in CASES])
def test_hostile_input(case, tmp_path):
    outcome, problems = run_case(case, tmp_path)
    assert not problems, f"{case.klass} / {case.name}: " + "; ".join(problems)
