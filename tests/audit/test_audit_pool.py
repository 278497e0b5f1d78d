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
            results, errors, prepared, redrawn = {"curved_mixed_cube": rows}, {}, {}, {}

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


def test_random_pixels_the_reference_leaves_undecided_are_drawn_again():
    """Hex_Mushroom's reference fails on the rays through the cell whose map folds (15 of 201 on
    the GPU): as many random pixels are drawn again, from seeds of their own, so that the random
    pixels decided still reach --sample, up to REDRAWS_MAX a dataset."""
    import heapq
    import itertools
    import threading

    checker = audit._Checker.__new__(audit._Checker)  # the queue alone: no pool (jobs 0 submits nothing)
    checker.heapq, checker.order, checker.lock, checker.jobs = heapq, itertools.count(), threading.Lock(), 0
    checker.heap, checker.inflight, checker.waiting = [], {}, {}
    checker.prepared, checker.results, checker.errors, checker.redrawn = {"d": {}}, {}, {}, {}
    rows = [{"checkable": True}, {"checkable": False, "reference_failed": "x"}, {"checkable": False}, {"checkable": True}]
    for k in range(40):
        checker._done(k, (("sample", "d", "cache", [None] * 4, [7, 0, k]), rows))
    again = [job for _, _, job in sorted(checker.heap)]
    assert [len(job[3]) for job in again] == [2] * (audit.REDRAWS_MAX // 2)
    assert checker.redrawn == {"d": audit.REDRAWS_MAX}
    assert len({tuple(job[4]) for job in again}) == len(again)  # each from a seed of its own
    assert len(checker.results["d"]) == 4 * 40
    checker._done(99, (("sample", "d", "cache", [None] * 4, [7, 0, 99]), rows))  # the budget is spent
    assert len(checker.heap) == len(again)


def test_the_reference_state_matches_the_render_to_rounding():
    """The reference's tents come from a worker's one-thread BLAS and may differ from the render's in
    their last bits (paper_scale: 6e-16): that is no difference; anything larger is named."""
    tf = {"color": [[0.4645148742249266, 0.1, 0.2, 1.0]]}
    assert audit._first_difference(tf, {"color": [[0.4645148742249263, 0.1, 0.2, 1.0]]}) is None
    got = audit._first_difference(tf, {"color": [[0.4645148742, 0.1, 0.2, 1.0]]})
    assert got.startswith("/color/0/0: 0.4645148742249266 against 0.4645148742")
    assert audit._first_difference({"a": [1, 2]}, {"a": [1, 2, 3]}) == "/a: 2 items against 3"
