"""The audit's reference pools (the gpu stage's and the check stage's): their workers start with one
BLAS thread each."""
import ctypes
import os

import numpy as np  # noqa: F401  (its OpenBLAS loaded, as in the workers)
import pytest

from hovr_blender.io.isolation import BLAS_THREADS
from scripts import audit


def openblas_threads():
    """The threads numpy's OpenBLAS runs in this process, as loaded (None: no OpenBLAS found)."""
    with open("/proc/self/maps") as f:
        libs = sorted({line.split()[-1] for line in f if "openblas" in line.lower()})
    for path in libs:
        lib = ctypes.CDLL(path)
        for name in ("openblas_get_num_threads64_", "openblas_get_num_threads", "scipy_openblas_get_num_threads64_"):
            if hasattr(lib, name):
                return int(getattr(lib, name)())
    return None


def test_the_reference_workers_start_with_one_blas_thread(monkeypatch, tmp_path):
    """The reference's products are a cell's shape functions times its nodes, one thread's work; on
    the GPU host 15 workers of 16 OpenBLAS threads each oversubscribe its 16 cores."""
    for k in BLAS_THREADS:
        monkeypatch.setenv(k, "4")
    checker = audit._Checker(1, str(tmp_path))
    try:
        seen = [checker.pool.apply(os.getenv, (k,)) for k in BLAS_THREADS]
        threads = checker.pool.apply(openblas_threads)
    finally:
        checker.stop()
    assert seen == ["1"] * len(BLAS_THREADS)
    assert threads in (1, None)  # as loaded (None: no OpenBLAS found)
    assert [os.environ[k] for k in BLAS_THREADS] == ["4"] * len(BLAS_THREADS)  # this process's, restored


def test_the_check_stage_workers_start_with_one_blas_thread(monkeypatch):
    """A forked worker keeps the parent's BLAS as it was loaded: the check stage's are spawned."""
    for k in BLAS_THREADS:
        monkeypatch.setenv(k, "4")
    if not os.path.exists("/proc/self/maps") or openblas_threads() is None:
        pytest.skip("numpy's OpenBLAS is not found through /proc/self/maps")
    with audit.spawned_executor(1) as pool:
        seen = [pool.submit(os.getenv, k).result() for k in BLAS_THREADS]
        threads = pool.submit(openblas_threads).result()
    assert seen == ["1"] * len(BLAS_THREADS)
    assert threads == 1  # as loaded: a forked worker reports this process's count
    assert [os.environ[k] for k in BLAS_THREADS] == ["4"] * len(BLAS_THREADS)


def test_a_worker_decides_random_pixels_from_the_prepared_state(tmp_path, monkeypatch):
    """The gpu stage's pool job end to end, in this process: _prepare writes a dataset's state once
    (the dense boundary for undecided rays among it), and _decide draws random pixels through the
    domain and decides each by the reference, whose inside length is the exact chord. A ray the
    default chords leave undecided goes to the prepared dense boundary (the default search is made
    to leave every ray undecided here)."""
    pytest.importorskip("vtkmodules.vtkIOXML", reason="the vtk package (the independent reference's engine) is not installed")
    from hovr_blender.audit import chords

    audit._prepare("curved_mixed_cube", str(tmp_path), (32, 18))
    audit._STATE.pop("curved_mixed_cube", None)
    st = audit._state("curved_mixed_cube", str(tmp_path))
    assert "dense" in st
    default = chords.intervals
    monkeypatch.setattr(chords, "intervals", lambda b, o, d, *rest: default(b, o, d, *rest) if rest else [None] * len(o))
    try:
        rows = audit._decide("curved_mixed_cube", str(tmp_path), "sample", [None] * 2, [0, 0, 0])
    finally:
        audit._STATE.pop("curved_mixed_cube", None)
    assert len(rows) == 2 and all(r["checkable"] for r in rows)
    for r in rows:
        assert r["exact_chord"] is not None and r["exact_chord"] > 0
        assert abs(r["reference_inside"] - r["exact_chord"]) <= 1e-6 * max(1.0, r["exact_chord"]), r
        assert 0.0 <= r["reference"][3] <= 1.0


def test_a_pixel_the_reference_fails_is_listed_never_checked(tmp_path):
    """A pixel whose reference failed (PixelResult.failed: NaN, error inf) compared as NaN, which no
    threshold exceeds: it counted as checked and right. It is listed as not decided instead."""
    pytest.importorskip("vtkmodules.vtkIOXML", reason="the vtk package (the independent reference's engine) is not installed")
    from hovr_blender.audit.vtk_reference import PixelResult

    audit._prepare("curved_mixed_cube", str(tmp_path), (32, 18))
    audit._STATE.pop("curved_mixed_cube", None)
    st = audit._state("curved_mixed_cube", str(tmp_path))
    st["reference"].pixel = lambda *a, **k: PixelResult(np.full(4, np.nan), np.inf, failed="cell 3 does not locate")
    try:
        rows = audit._decide("curved_mixed_cube", str(tmp_path), "sample", [None] * 2, [0, 0, 0])

        class Checker:
            lock = __import__("threading").Lock()
            results, errors, prepared = {"curved_mixed_cube": rows}, {}, {}

            def pending_pixels(self, name):
                return 0

        image = np.zeros((18, 32, 4))
        report = audit._dataset_report("curved_mixed_cube", {"images": {k: image for k in audit.ALL_IMAGES}}, Checker())
    finally:
        audit._STATE.pop("curved_mixed_cube", None)
    assert [r["reference_failed"] for r in rows] == ["cell 3 does not locate"] * 2
    assert report["checked"] == 0 and report["unchecked_curved_pyramids"] == 0
    assert len(report["reference_failed"]) == 2 and report["pixels_over"] == []
    assert all(v["max_error"] is None for v in report["vs_reference"].values())
