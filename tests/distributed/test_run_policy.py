"""Issue 29's run policy without a cluster or a render: frame ranges, duplicate JSON keys,
transfer-function bounds, fixed steps shortened to what resolves the data, outputs that never
follow links, sizes checked before reading, the process budget and camera paths."""
import json
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hovr_blender.distributed import series
from hovr_blender.engine import limits, strict_json
from hovr_blender.engine.transfer_function import TransferFunction, TransferFunctionError
from hovr_blender.engine.view import MAX_STEP_OPTICAL_DEPTH, RenderOptions, resolving_step


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 500), st.integers(0, 50), st.integers(1, 7)), min_size=1, max_size=5))
def test_frames_parse_as_ranges_each_once(parts):
    text = ",".join(f"{lo}-{lo + n}:{step}" for lo, n, step in parts)
    want = list(dict.fromkeys(f for lo, n, step in parts for f in range(lo, lo + n + 1, step)))
    assert series.parse_frames(text) == want


@pytest.mark.parametrize("text", ["-1", "1--3", "a", "3-1", "1-3:0", "1.5", "", ",", "1-2:-1", "9" * 30])
def test_frames_refused_with_our_message(text):
    with pytest.raises(ValueError, match="--frames"):
        series.parse_frames(text)


def test_frames_counted_before_any_list():
    with pytest.raises(ValueError, match="more than 1000000 frames"):
        series.parse_frames("0-999999999999")  # a list of these would not fit in memory
    with pytest.raises(ValueError, match="more than 1000000 frames"):
        series.parse_frames("1-600000,1-600000")
    assert len(series.parse_frames(f"1-{series.MAX_FRAMES}")) == series.MAX_FRAMES


def test_a_key_twice_is_an_error_at_any_depth():
    assert strict_json.loads(b'{"a": {"b": 1}, "c": [{"b": 2}]}', "x") == {"a": {"b": 1}, "c": [{"b": 2}]}
    for doc in (b'{"data": 1, "data": 2}', b'{"a": {"b": 1, "b": 1}}', b'[{"k": 0, "k": 0}]'):
        with pytest.raises(ValueError, match="appears twice"):
            strict_json.loads(doc, "view.json")


@pytest.mark.parametrize("color, density", [
    ([[0, 1, 1, 1], [1e31, 1, 1, 1]], [[0, 1], [1, 1]]),
    ([[0, 1, 1, 1], [1, 2e30, 1, 1]], [[0, 1], [1, 1]]),
    ([[0, 1, 1, 1], [1, 1, 1, 1]], [[-1e308, 1], [1e308, 1]]),  # was "unexpected OverflowError"
    ([[0, 1, 1, 1], [1, 1, 1, 1]], [[0, 1], [1, 1e300]]),
])
def test_transfer_function_values_are_bounded(color, density):
    with pytest.raises(TransferFunctionError, match=r"within \+-1e\+30"):
        TransferFunction.from_contract({"color": color, "density": density})
    TransferFunction.from_contract({"color": [[-1e30, 1, 1, 1], [1e30, 1, 1, 1]], "density": [[-1e30, 1e30]]})


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 50.0), min_size=2, max_size=6), st.floats(-1.0, 2.0), st.floats(0.0, 3.0))
def test_max_density_is_the_largest_over_the_range(taus, lo, width):
    s = np.linspace(0.0, 1.0, len(taus))
    tf = TransferFunction(s, np.ones((len(s), 3)), s, np.array(taus))
    hi = lo + width
    dense = tf.density(np.linspace(lo, hi, 20001)).max()
    assert tf.max_density(lo, hi) == pytest.approx(dense, rel=1e-3, abs=1e-9)
    assert tf.max_density(lo, hi) >= dense - 1e-12


@pytest.mark.parametrize("method", ["riemann", "trapezoid", "classified"])
def test_a_step_that_cannot_resolve_the_data_is_shortened(method):
    tf = TransferFunction.from_contract({"color": [[0, 1, 1, 1], [1, 1, 1, 1]], "density": [[0, 0], [0.5, 8], [1, 2]]})
    ranges = [(0.0, 0.4)]  # the field never reaches the peak at 0.5: tau_max = 6.4
    fine = RenderOptions(method=method, h=0.1)
    assert resolving_step(fine, tf, ranges) == (fine, [])
    shortened, warnings = resolving_step(RenderOptions(method=method, h=1e6), tf, ranges)
    assert shortened.h == pytest.approx(MAX_STEP_OPTICAL_DEPTH / 6.4) and len(warnings) == 1
    assert "cannot resolve the data" in warnings[0] and "1e+06" in warnings[0]
    assert resolving_step(RenderOptions(method="split", h=1e6), tf, ranges)[1] == []
    if method == "classified":
        assert resolving_step(RenderOptions(method=method), tf, ranges)[1] == []  # its own steps


def test_outputs_never_follow_links(tmp_path):
    target = tmp_path / "target"
    for name, points_to in (("dangling.npy", tmp_path / "created"), ("existing.npy", target)):
        target.write_bytes(b"keep")
        os.symlink(points_to, tmp_path / name)
        with pytest.raises(limits.UnsafeFileError, match="symbolic link"):
            limits.open_output(tmp_path / name, "output")
        with pytest.raises(limits.UnsafeFileError, match="symbolic link"):
            limits.open_output(tmp_path / name, "series log", append=True)
        with pytest.raises(limits.UnsafeFileError, match="symbolic link"):
            series.check_output(str(tmp_path / name))
    assert not (tmp_path / "created").exists() and target.read_bytes() == b"keep"
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(limits.UnsafeFileError, match="FIFO"):
        limits.open_output(tmp_path / "fifo", "output")  # refused without blocking on a reader
    with limits.open_output(tmp_path / "plain.json", "output") as fh:
        fh.write(b"{}")
    series.append_log(str(tmp_path), {"frame": 1})
    series.append_log(str(tmp_path), {"frame": 2})
    lines = (tmp_path / series.LOG_NAME).read_text().splitlines()
    assert [json.loads(ln)["frame"] for ln in lines] == [1, 2]


def test_sizes_are_checked_before_reading(tmp_path):
    big = tmp_path / "view.json"
    with open(big, "wb") as fh:
        fh.truncate(3_900_000_000)  # sparse: reading it would take 3.9 GB
    with pytest.raises(limits.ResourceLimitError, match="at most 1 MiB"):
        limits.read_regular(big, "view file", max_bytes=1 << 20)


def test_process_budget(monkeypatch):
    monkeypatch.setenv("HOVR_MAX_PROCESSES", "3")
    assert limits.check_processes(3, "x") == 3
    with pytest.raises(limits.ResourceLimitError, match="4 processes.*limit of 3"):
        limits.check_processes(4, "x")
    with pytest.raises(limits.ResourceLimitError, match="18 processes"):
        RenderOptions(device=",".join(["cpu"] * 18))
    monkeypatch.delenv("HOVR_MAX_PROCESSES")
    assert limits.check_processes(2, "two devices on any machine") == 2


def test_camera_paths_are_checked_before_any_worker(tmp_path):
    cam = {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40}
    path = tmp_path / "cams.json"
    path.write_text(json.dumps({"first_frame": 3, "cameras": [cam, cam]}))
    assert sorted(series.read_camera_path(str(path), [3, 4])) == [3, 4]
    for text, words in ((json.dumps({"first_frame": 1, "cameras": [{**cam, "eye": "x"}]}), "frame 1"),
                        (json.dumps({"cameras": {"a": 1}}), "must be a list"),
                        (json.dumps({"first_frame": -2, "cameras": [cam]}), "first_frame"),
                        ('{"cameras": [], "cameras": []}', "twice"),
                        (json.dumps([cam]), "no camera for frame 2")):
        path.write_text(text)
        with pytest.raises(ValueError, match=words):
            series.read_camera_path(str(path), [1, 2])
