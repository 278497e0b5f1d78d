"""The `hovr` command line and view-file validation (render contract §1, §5)."""
import json

import numpy as np
import pytest

from hovr_blender import cli
from hovr_blender.engine.camera import CameraError, RayCamera
from hovr_blender.engine.transfer_function import TransferFunction, TransferFunctionError
from hovr_blender.engine.view import View, ViewError

VIEW = {
    "data": {"builtin": "sphere"},
    "camera": {"projection": "perspective", "eye": [7.0, 5.5, 8.0], "target": [0, 0, 1], "up": [0, 0, 1], "fov_y_deg": 40},
    "image": {"width": 40, "height": 30},
    "transfer_function": {"color": [[1, 1, 0.5, 0], [9, 0, 0.5, 1]],
                          "density": [[1.5, 0], [2, 3], [2.5, 0], [8.5, 0], [9, 2], [9.5, 0]]},
    "background": [0.1, 0.2, 0.3],
}


def write_view(tmp_path, view=VIEW, name="view.json"):
    p = tmp_path / name
    p.write_text(json.dumps(view))
    return p


def test_render_writes_npy_png_stats(tmp_path):
    p = write_view(tmp_path)
    out, png, st = tmp_path / "o.npy", tmp_path / "o.png", tmp_path / "s.json"
    assert cli.main(["render", str(p), "-o", str(out), "--png", str(png), "--stats", str(st), "--method", "split"]) == 0
    img = np.load(out)
    assert img.shape == (30, 40, 4) and img.dtype == np.float32
    # background where rays miss: RGB = background, alpha 0 (top-left corner misses the box)
    np.testing.assert_allclose(img[0, 0], [0.1, 0.2, 0.3, 0.0], atol=1e-7)
    assert img[..., 3].max() > 0.2
    stats = json.loads(st.read_text())
    for key in ("device", "render_seconds", "field_evaluations", "method", "parameters"):
        assert key in stats
    assert stats["method"] == "split" and stats["field_evaluations"] > 0
    from PIL import Image

    assert Image.open(png).size == (40, 30)


def test_cli_options_override_view(tmp_path):
    v = dict(VIEW, render={"method": "riemann", "h": 0.5})
    p = write_view(tmp_path, v)
    st = tmp_path / "s.json"
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy"), "--stats", str(st), "--h", "0.05",
                     "--method", "trapezoid"]) == 0
    stats = json.loads(st.read_text())
    assert stats["method"] == "trapezoid" and stats["parameters"]["h"] == 0.05


@pytest.mark.parametrize("mutate, message", [
    (lambda v: v.pop("camera"), "camera"),
    (lambda v: v["camera"].update(projection="fisheye"), "projection"),
    (lambda v: v["camera"].pop("fov_y_deg"), "fov_y_deg"),
    (lambda v: v["camera"].update(up=[7, 5.5, 7]), "parallel"),
    (lambda v: v["transfer_function"].update(density=[[2, 0], [1, 1]]), "increasing"),
    (lambda v: v["transfer_function"].update(density=[[1, 0], [2, -1]]), ">= 0"),
    (lambda v: v["image"].update(width=0), "image size"),
    (lambda v: v.update(data={"builtin": "teapot"}), "teapot"),
    (lambda v: v.update(data={"path": "missing.xml"}), "missing.xml"),
    (lambda v: v.update(render={"method": "magic"}), "magic"),
    (lambda v: v.update(render={"h": -1}), "h must be"),
])
def test_bad_views_give_clear_errors(tmp_path, capsys, mutate, message):
    v = json.loads(json.dumps(VIEW))
    mutate(v)
    p = write_view(tmp_path, v)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    err = capsys.readouterr().err
    assert "hovr: error:" in err and message in err
    assert not (tmp_path / "o.npy").exists()


def test_malformed_json(tmp_path, capsys):
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    assert "not valid JSON" in capsys.readouterr().err


def test_contract_rays():
    cam = RayCamera.from_contract({"eye": [0, 0, 0], "target": [0, 0, -1], "up": [0, 1, 0], "fov_y_deg": 90}, 4, 2)
    o, d = cam.rays()
    # pixel (i=3, j=0): u = (2*3.5/4 - 1)*2 = 1.5, v = 1 - 0.5 = 0.5; right = +x, up' = +y
    np.testing.assert_allclose(d[0, 3], np.array([1.5, 0.5, -1.0]) / np.linalg.norm([1.5, 0.5, -1.0]))
    np.testing.assert_allclose(o, 0.0)
    ortho = RayCamera.from_contract({"projection": "orthographic", "eye": [0, 0, 5], "target": [0, 0, 0],
                                     "up": [0, 1, 0], "height": 2.0}, 4, 2)
    o, d = ortho.rays()
    np.testing.assert_allclose(o[1, 0], [-1.5, -0.5, 5.0])
    np.testing.assert_allclose(d[1, 0], [0, 0, -1])
    with pytest.raises(CameraError):
        RayCamera.from_contract({"eye": [0, 0, 0], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 30}, 4, 2)


def test_ramp_to_transfer_function():
    tf = TransferFunction.from_rgba_ramp([0.0, 0.5, 0.5, 1.0], [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0.5], [1, 1, 1, 0]],
                                         density_scale=4.0, value_min=10.0, value_max=20.0)
    assert np.all(np.diff(tf.density_s) > 0)  # the step stays a (near-vertical) ramp
    np.testing.assert_allclose(tf.density(15.0 - 1e-6), 4.0, atol=1e-3)
    np.testing.assert_allclose(tf.color(12.5), [0.5, 0.5, 0.0])
    with pytest.raises(TransferFunctionError):
        TransferFunction.from_contract({"color": [[0, 1, 1, float("nan")]], "density": [[0, 1]]})
