"""bench/split_frame.py (issue 42's command for hosts with several GPUs), on two CPU devices at a
small size: its cost-model balances, and a run whose report holds what the lead checks."""
import json

import numpy as np
import pytest

from bench.split_frame import band_balance, main, tiles_balance


def test_balances_of_bands_and_dealt_tiles():
    cost = np.array([4.0, 4.0, 1.0, 1.0, 1.0, 1.0])
    assert band_balance(cost, [(0, 3), (3, 6)]) == pytest.approx(6.0 / 9.0)
    assert band_balance(cost, [(0, 1), (1, 6)]) == pytest.approx(6.0 / 8.0)
    assert band_balance(cost[1:], [(0, 1), (1, 5)]) == pytest.approx(1.0)
    assert tiles_balance(cost, 2, 1) == pytest.approx(6.0 / 6.0)  # rows 0, 2, 4 against 1, 3, 5
    assert tiles_balance(cost, 2, 2) == pytest.approx(6.0 / 10.0)  # rows 0-1, 4-5 against 2-3


def test_a_run_on_two_cpu_devices_reports_identity_speed_and_spread(tmp_path):
    out = tmp_path / "split_frame.json"
    main(["--devices", "cpu,cpu", "--size", "32x24", "--datasets", "curved_mixed_cube", "--repeats", "1",
          "--out", str(out)])
    run = json.loads(out.read_text())
    assert run["devices"] == ["cpu", "cpu"] and run["command"].startswith("python")
    (row,) = run["rows"]
    assert row["dataset"] == "curved_mixed_cube" and row["size"] == [32, 24]
    assert [d["device"] for d in row["setup"]["devices"]] == ["cpu", "cpu"]
    for key, split_by in (("first_frame", "pre-pass"), ("steady_frame", "previous frame"),
                          ("first_frame_equal_rows", "equal rows")):
        frame = row[key]
        assert frame["split_by"] == split_by and frame["identical"] and frame["max_abs_difference"] == 0.0
        assert frame["speedup"] == pytest.approx(row["one_wall_seconds"] / frame["seconds"])
        assert frame["target_speedup"] == pytest.approx(1.8)
        per = [d["render_seconds"] for d in frame["per_device"]]
        assert frame["device_spread"] == pytest.approx((max(per) - min(per)) / min(per))
    assert row["first_frame"]["prepass_seconds"] > 0.0
    assert row["strategies"]["tile_calls"]["calls"] == 16 and row["strategies"]["tile_calls"]["wall_seconds"] > 0.0
    st = row["strategies"]
    assert set(st["prepass"]) == {"1/4", "1/8", "1/16"} and st["prepass"]["1/8"]["size"] == [4, 3]
    for n in ("2", "4", "8"):
        for balance in (st["equal_rows"][n], st["previous_frame"][n], st["prepass"]["1/8"][n],
                        st["tiles"]["8 rows"][n]):
            assert 0.0 < balance <= 1.0 + 1e-12
