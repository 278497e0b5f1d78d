"""The GPU audit's reference pool: its workers start with one BLAS thread each."""
import os

from hovr_blender.io.isolation import BLAS_THREADS
from scripts import audit


def test_the_reference_workers_start_with_one_blas_thread(monkeypatch, tmp_path):
    """Two BLAS threads made the reference's Newton 1.85x slower a pixel on Hex_Mushroom (a
    cell's 3,375 shape functions times its nodes, 35x slower handed between threads); on the
    GPU host 15 workers of 16 threads each left the audit at ~144 random pixels a dataset."""
    for k in BLAS_THREADS:
        monkeypatch.setenv(k, "4")
    checker = audit._Checker(1, str(tmp_path))
    try:
        seen = [checker.pool.apply(os.getenv, (k,)) for k in BLAS_THREADS]
    finally:
        checker.stop()
    assert seen == ["1"] * len(BLAS_THREADS)
    assert [os.environ[k] for k in BLAS_THREADS] == ["4"] * len(BLAS_THREADS)  # this process's, restored
