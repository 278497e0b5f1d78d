"""The add-on as a *legacy* add-on (bl_info) in Debian's Blender 3.4 with a real window under
Xvfb: Rendered shading in camera view converges, and a screenshot of the viewport matches the
F12 image of the same view. Skipped (with the reason) where blender, xvfb-run or warp's venv
are missing. Needs: apt-get install blender xvfb python3-numpy."""
import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.blender

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
BLENDER = shutil.which("blender")
XVFB_RUN = shutil.which("xvfb-run")


def _blender_version():
    out = subprocess.run([BLENDER, "--version"], capture_output=True, text=True, timeout=60).stdout
    return tuple(int(x) for x in out.split()[1].split(".")[:2]) if out.startswith("Blender") else None


@pytest.fixture(scope="module")
def legacy_env(tmp_path_factory):
    if BLENDER is None or XVFB_RUN is None:
        pytest.skip("needs Debian's blender and xvfb-run (apt-get install blender xvfb python3-numpy)")
    version = _blender_version()
    if version is None or version >= (4, 2):
        pytest.skip(f"blender on PATH is {version}, not a pre-extension (3.4-4.1) Blender")
    site = sysconfig.get_paths()["purelib"]
    if not (Path(site) / "warp").is_dir():
        pytest.skip("warp-lang is not installed in this venv, so Blender's Python cannot import it")
    root = tmp_path_factory.mktemp("legacy")
    addons = root / "scripts" / "addons"
    addons.mkdir(parents=True)
    (addons / "hovr_blender").symlink_to(REPO / "hovr_blender")  # the repository's add-on, as is
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(root / "scripts"), BLENDER_USER_CONFIG=str(root / "config"),
               HOVR_EXTRA_SITE=site)
    env.pop("PYTHONPATH", None)
    # Debian's Blender takes the first python3.11 on PATH as sys.executable, which All CPU Cores'
    # processes run: the system's, whose standard library is the one Blender loaded, not a shim's
    env["PATH"] = os.pathsep.join(["/usr/bin", env.get("PATH", "")])
    return root, env


def test_viewport_screenshot_matches_f12(legacy_env):
    from PIL import Image

    root, env = legacy_env
    blend = root / "scene.blend"
    subprocess.run([BLENDER, "-b", "--factory-startup", "--python", str(HERE / "legacy_make_scene.py"), "--",
                    str(blend)], env=env, check=True, capture_output=True, timeout=300)
    # A file on the command line: no splash screen over the viewport.
    proc = subprocess.run([XVFB_RUN, "-a", "-s", "-screen 0 800x600x24", BLENDER, str(blend), "-p", "0", "0", "800",
                           "600", "--python", str(HERE / "legacy_viewport_capture.py"), "--", str(root)],
                          env=env, capture_output=True, text=True, timeout=400)
    report_path = root / "report.json"
    assert report_path.exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(report_path.read_text())
    assert "error" not in report, report["error"]
    assert report["viewport_converged"], report["log"]
    kinds = [k for k, *_ in report["viewport_log"]]
    # the progressive path ran in the window: a preview first (over its time budget on a busy
    # machine: that is the scheduler's to adapt, not this test's to judge), then bands
    assert kinds[0] in ("preview", "preview-overrun") and any(k.startswith("band") for k in kinds)
    shot = Image.open(report["screenshot"]).convert("RGB")
    f12 = np.asarray(Image.open(report["f12"]).convert("RGB")).astype(float)
    # The camera frame inside the region, from Blender's own projection of the frame corners
    # (view_center_camera leaves a small margin); resample it to the F12 size and compare.
    rx, ry, _rw, _rh = report["region"]
    H = shot.size[1]
    px = np.array(report["camera_frame_px"])
    box = (px[:, 0].min() + rx, H - (px[:, 1].max() + ry), px[:, 0].max() + rx, H - (px[:, 1].min() + ry))
    fh, fw = f12.shape[:2]
    view = np.asarray(shot.resize((fw, fh), Image.BILINEAR, box=box)).astype(float)
    d = np.abs(view - f12)[8:-8, 8:-8]  # resampling blurs the outermost pixels
    print(f"viewport vs F12 ({fw}x{fh}, 8-bit display values): mean {d.mean():.3f}, p99 {np.percentile(d, 99)}, "
          f"max {d.max()}")
    assert f12.std() > 5  # the volume is in the picture
    assert d.mean() < 0.5 and np.percentile(d, 99) <= 3 and d.max() < 40
    # "All CPU Cores" from the Blender program: its processes neither re-run this script nor hang
    every_core = np.asarray(Image.open(report["f12_all_cores"]).convert("RGB")).astype(float)
    np.testing.assert_array_equal(every_core, f12)
    # the colour legend over the Rendered viewport (ui/legend_overlay.py): its bar is drawn where
    # the layout puts it, and nothing changes left of its labels
    off = np.asarray(Image.open(report["legend_off"]).convert("RGB")).astype(int)
    on = np.asarray(Image.open(report["legend_on"]).convert("RGB")).astype(int)
    x0, y0, x1, y1 = report["legend_bar"]
    top = H - (ry + _rh)  # the region's top row in the screenshot
    bar = np.abs(on - off).max(axis=2)[top + y0: top + y1, rx + x0: rx + x1]
    assert (bar > 0).mean() > 0.3, "the legend's bar is not drawn"
    assert Path(report["panels"]).is_file()  # the render panels drew (screenshot for the guide)
