"""The peers' report (bench/peers.py --table): the equal-time row, the grid estimates and the
figure's columns are computed from the rows as stated, on runs made up here."""
import json

import numpy as np

from bench import peers


def _row(method, frame=None, prep=1.0, max_err=0.1, mean_err=0.01, skipped=None, dims=None):
    fam = "ours" if method.startswith("ours") else "vtk"
    r = {"method": method, "family": fam}
    if fam == "vtk":
        r["preparation"] = method.split("-")[1]
    if skipped:
        r["skipped"] = skipped
        return r
    r.update(frame_seconds=frame, prepare_seconds=prep, host_peak_bytes=0, gpu_bytes=0, max_error=max_err,
             mean_error=mean_err, data_bytes=1024)
    if dims:
        r["grid_dimensions"] = dims
    return r


def _entry():
    return {"rows": [
        _row("ours-split", 0.100, max_err=2e-4, mean_err=1e-6),
        _row("vtk-lattice-projected", 0.020, max_err=0.2, mean_err=0.02),
        _row("vtk-tess2-projected", 0.300, max_err=0.05, mean_err=0.004),  # slower than ours: not within
        _row("vtk-resample32-smart", 0.050, prep=2.0, max_err=0.5, mean_err=0.1, dims=[32, 16, 8]),
        _row("vtk-resample64-smart", 0.060, prep=16.0, max_err=0.3, mean_err=0.05, dims=[64, 32, 16]),
        _row("vtk-resample128-smart", skipped="preparation estimated at 128 s > --budget 60 s"),
    ]}


def test_equal_time_is_the_largest_grid_within_our_frame_and_says_what_stopped_the_next():
    q = peers.equal_time(_entry())
    assert q["ours"]["method"] == "ours-split"
    assert q["largest_grid"]["method"] == "vtk-resample64-smart"
    assert q["next_grid"] == "vtk-resample128-smart: preparation estimated at 128 s > --budget 60 s"
    # the tessellation has the least error but its frame is slower than ours: not within
    assert q["best_within"]["method"] == "vtk-lattice-projected"


def test_equal_time_with_every_grid_slower_than_ours():
    e = _entry()
    e["rows"][0]["frame_seconds"] = 0.040
    q = peers.equal_time(e)
    assert q["largest_grid"] is None
    assert q["next_grid"].startswith("vtk-resample32-smart: its frame takes 50.0 ms")
    assert q["best_within"]["method"] == "vtk-lattice-projected"


def test_grid_points_about_recovers_the_box_and_the_rate_extrapolates_linearly():
    assert peers.grid_points_about([64, 32, 16], 64, 128) == 128 * 64 * 32
    assert peers.grid_points_about([64, 32, 16], 64, 64) == 64 * 32 * 16
    q = peers.resampling_rates(_entry())
    assert q["n"] == 64 and q["points"] == 64 * 32 * 16
    assert np.isclose(q["rate"], 64 * 32 * 16 / 16.0)
    pts, sec = q["estimates"][256]
    assert np.isclose(sec, pts / q["rate"])


def test_figure_columns_add_vtks_best_when_the_four_do_not_show_it():
    e = _entry()
    done = {r["method"] for r in e["rows"] if "skipped" not in r}
    cols = peers.figure_columns(e, done)
    assert cols[:2] == ["ours-split", "vtk-lattice-projected"]
    assert "vtk-tess2-projected" in cols  # the finest tessellation, and VTK's least mean error
    assert len(cols) == 4
    e["rows"].append(_row("vtk-tess1-projected", 0.03, max_err=0.04, mean_err=0.001))
    e["rows"][2]["mean_error"] = 0.01
    done.add("vtk-tess1-projected")
    cols = peers.figure_columns(e, done)
    assert cols[-1] == "vtk-tess1-projected" and len(cols) == 5


def test_report_keeps_each_datasets_sizes_together(tmp_path):
    paths = []
    for size, name in (("1920x1080", "a"), ("512x512", "b")):
        run = {"size": size, "device": "cuda:0", "device_name": "GPU", "date": "2026-11-27T10:00:00",
               "git_commit": "abc1234", "git_dirty": False, "warp": "1.19.0", "vtk": "9.7.2",
               "vtk_opengl": "vtkEGLRenderWindow | OpenGL renderer string:  Card", "settings":
               {"resample": "32,64,128", "budget": 60.0, "max_points": 2.2e6},
               "datasets": {"X": _entry(), **({"Y": _entry()} if name == "a" else {})}}
        p = tmp_path / f"{name}.json"
        p.write_text(json.dumps(run))
        paths.append(str(p))
    md = peers.report(paths)
    rows = [line for line in md.splitlines() if line.startswith("| X | ") or line.startswith("| Y | ")]
    sizes = [line.split(" | ")[1] for line in rows if "| ours-split |" in line]
    assert sizes == ["1920x1080", "512x512", "1920x1080"]  # X at both sizes, then Y
    assert "OpenGL renderer Card" in md
    assert "| X | 512x512 | 100.0 ms, 2.0e-04 | vtk-resample64-smart (64x32x16)" in md


class _Independent:
    """A stand-in for audit's IndependentReference: an empty pixel, with the given stretches."""

    def __init__(self, stretches):
        self._stretches = stretches

    def pixel(self, o, d, background):
        class R:
            rgba = np.zeros(4)
            error = 0.0

        return R()

    def stretches(self, o, d, t0, t1):
        return self._stretches


def _decide(stretches, exact):
    cam = {"eye": [3.0, 0.0, 0.0], "target": [0.0, 0.0, 0.0], "up": [0, 0, 1], "fov_y_deg": 30.0}
    ref = np.zeros((1, 2, 4))
    ref[0, 1] = [0.0, 0.004, 0.0, 0.005]  # our float64: a faint pixel
    other = ref.copy()
    other[0, 1, 1] = 0.006  # our float32, 2e-3 off it: the pixel goes to the independent reference
    info = peers.decide(None, cam, 2, 1, None, ref, other, 10, lambda *a: None,
                        chord=lambda o, d: exact, independent=_Independent(stretches))
    return info, ref


def test_decide_keeps_float64_where_the_independent_reference_misses_the_exact_chord():
    info, ref = _decide([], 1.6e-3)  # it found no stretch; the ray clips the mesh over 1.6e-3
    assert info["independent_missed"] == 1 and info["float64_wrong"] == 0
    assert ref[0, 1, 1] == 0.004  # not replaced
    assert info["pixels"][0][4] == [0, 1.6e-3]


def test_decide_replaces_where_the_independent_reference_covers_the_chord():
    info, ref = _decide([(2.0, 2.0016, 0)], 1.6e-3)
    assert info["independent_missed"] == 0 and info["float64_wrong"] == 1
    assert ref[0, 1, 1] == 0.0  # the independent value
