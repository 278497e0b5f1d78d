"""Issue 29's Esc on a long import, in a real window: Debian's Blender 3.4 under Xvfb, keys
pressed through Blender's own event queue (--enable-event-simulate; import_cancel_capture.py).
File > Import's browser confirmed with Return imports modally and makes the volume; a second
import whose reader process is stopped waits with its stage in the status bar, Esc kills the
reader, nothing is made, and the report says so in one line. Skipped where blender, xvfb-run
or warp's venv are missing."""
import json
import shutil
import subprocess

import pytest

from ..helpers import data_file
from .test_legacy_xvfb import HERE, XVFB_RUN, BLENDER, legacy_env  # noqa: F401  (the fixture)

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.mark.parametrize("keys", ["event_simulate", "xdotool"])
def test_esc_cancels_an_import_in_a_window(legacy_env, tmp_path, keys):
    """Keys through Blender's event queue (event_simulate), or as X11 input (xdotool)."""
    root, env = legacy_env
    simulate = ["--enable-event-simulate"]  # Blender then reads no X11 input
    if keys == "xdotool":
        if shutil.which("xdotool") is None:
            pytest.skip("needs xdotool (apt-get install xdotool)")
        env, simulate = dict(env, HOVR_KEYS="xdotool"), []
    xml = data_file("nektar", "Tet_channel_m3.xml")
    out = tmp_path / "cancel"
    (tmp_path / "copy").mkdir()
    out.mkdir()
    for ext in (".xml", ".fld"):  # the second import's file: another path, so not the first's cached mesh
        shutil.copy(xml.with_suffix(ext), tmp_path / "copy" / xml.with_suffix(ext).name)
    fresh = tmp_path / "factory.blend"
    subprocess.run([BLENDER, "-b", "--factory-startup", "--python-expr",
                    f"import bpy; bpy.ops.wm.save_as_mainfile(filepath={str(fresh)!r})"],
                   env=env, check=True, capture_output=True, timeout=300)
    proc = subprocess.run([XVFB_RUN, "-a", "-s", "-screen 0 900x800x24", BLENDER, str(fresh), "-p", "0", "0",
                           "900", "800", *simulate, "--python", str(HERE / "import_cancel_capture.py"),
                           "--", str(out), str(xml), str(tmp_path / "copy" / xml.name)],
                          env=env, capture_output=True, text=True, timeout=600)
    report_path = out / "report.json"
    assert report_path.exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(report_path.read_text())
    assert "error" not in report, report["error"] + "\n".join(report["log"])
    assert report["invoke_result"] == ["RUNNING_MODAL"]  # the file browser
    assert report["volumes_after_import"] == report["volumes_before"] + ["Tet_channel_m3"]
    assert report["redo_result"] == ["FINISHED"] and report["volumes_after_redo"] == report["volumes_after_import"]
    # the second import waits on its stopped reader: nothing made until Esc, nothing after
    assert report["reader_alive_before_esc"] and not report["reader_alive_after_esc"]
    assert report["volumes_while_reading"] == report["volumes_after_esc"] == report["volumes_after_import"]
    (phases,) = report["phases"]  # one modal import running, its stages shown as they came
    assert phases[0].startswith("finding the solution and field (1/4)")
    assert phases[-1] == "reading the data (2/4): starting the reader"
    assert report["phases_after_esc"] == []
    cancelled = [line for line in report["reports"] if "cancelled" in line]
    assert len(cancelled) == 1 and "import of Tet_channel_m3.xml cancelled (reading the data)" in cancelled[0], \
        report["reports"]
