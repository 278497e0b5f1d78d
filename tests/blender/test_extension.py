"""The built extension zip installs into a throw-away Blender user directory, enables, and
renders the same image as the core."""
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

import test_render as tr  # noqa: E402

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]


def build_zip(out_dir: Path) -> Path:
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "build_extension.py"), "--output-dir", str(out_dir)],
                         check=True, capture_output=True, text=True)
    zips = list(out_dir.glob("hovr_blender-*.zip"))
    assert len(zips) == 1 and str(zips[0]) in out.stdout
    return zips[0]


def test_zip_layout(tmp_path):
    names = zipfile.ZipFile(build_zip(tmp_path)).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names  # side by side at the root
    assert "engine/render_engine.py" in names and "ui/panels.py" in names and "io/builtin.py" in names
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or n.startswith("tests/")]


def test_install_enable_and_render(tmp_path):
    zip_path = build_zip(tmp_path / "dist")
    user = tmp_path / "blender-user"
    env = dict(os.environ)
    env.update({  # honoured by Blender 5.0 when set before bpy is imported
        "BLENDER_USER_RESOURCES": str(user / "resources"),
        "BLENDER_USER_CONFIG": str(user / "config"),
        "BLENDER_USER_SCRIPTS": str(user / "scripts"),
        "BLENDER_USER_EXTENSIONS": str(user / "extensions"),
    })
    env.pop("PYTHONPATH", None)
    spec = {
        "zip": str(zip_path), "out": str(tmp_path / "rgba.npy"), "exr": str(tmp_path / "ext.exr"),
        "report": str(tmp_path / "report.json"), "contract": tr.PERSPECTIVE, "width": tr.W, "height": tr.H,
        "stops": tr.STOPS, "value_range": tr.VALUE_RANGE, "density_scale": tr.DENSITY_SCALE,
        "background": tr.BACKGROUND, "location": tr.OBJECT_LOCATION, "angle_z": tr.OBJECT_ANGLE_Z,
        "method": "classified",
    }
    proc = subprocess.run([sys.executable, str(HERE / "install_and_render.py"), json.dumps(spec)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads(Path(spec["report"]).read_text())
    assert report["engine_module"].startswith("bl_ext.user_default.hovr_blender")
    assert report["renderer_loaded"] and report["foreign_modules"] == []
    assert Path(report["user_extensions"]).resolve() == (user / "extensions").resolve()
    assert (user / "extensions" / "user_default" / "hovr_blender" / "blender_manifest.toml").is_file()

    got = np.load(spec["out"])
    want = tr.core_render(tr.PERSPECTIVE, "classified", False)
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
