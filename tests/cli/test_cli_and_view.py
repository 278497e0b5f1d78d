"""The `hovr` command line and view-file validation (render contract §1, §5)."""
import json
from pathlib import Path

import numpy as np
import pytest

from hovr_blender import cli
from hovr_blender.engine.camera import CameraError, RayCamera
from hovr_blender.engine.transfer_function import TransferFunction, TransferFunctionError
from hovr_blender.engine.view import View, ViewError

REPO_DATA = Path(__file__).resolve().parents[1] / "data"

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
    (lambda v: v.pop("data"), "data"),
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


@pytest.mark.parametrize("mutate, message", [
    (lambda v: v.update(camera=[1, 2, 3]), "camera must be a JSON object"),
    (lambda v: v.update(data=5), "data must be a JSON object"),
    (lambda v: v.update(data={"path": 5}), "data.path must be a string"),
    (lambda v: v.update(data={"builtin": [1]}), "data.builtin must be a string"),
    (lambda v: v["image"].update(width=float("inf")), "width must be a whole number"),
    (lambda v: v["image"].update(width=True), "width must be a whole number"),
    (lambda v: v["image"].update(width=1.9), "width must be a whole number"),
    (lambda v: v["image"].update(height="32"), "height must be a whole number"),
    (lambda v: v["camera"].update(eye=[0, "1", 2]), "camera.eye"),
    (lambda v: v["camera"].update(fov_y_deg=True), "fov_y_deg must be a finite number"),
    (lambda v: v["transfer_function"].update(color=[[1, 1, 0.5, "0"]]), "transfer_function.color"),
    (lambda v: v["transfer_function"].update(density=[[1, True]]), "transfer_function.density"),
    (lambda v: v.update(background=[0, 0]), "background"),
    (lambda v: v.update(render={"h": "0.1"}), "h must be a number"),
    (lambda v: v.update(render={"method": 3}), "method must be a string"),
    (lambda v: v.update(render=[1]), "render must be a JSON object"),
])
def test_view_values_are_read_strictly(tmp_path, capsys, mutate, message):
    """JSON types the contract does not mean are refused, never coerced (true, 1.9, "32", 1e400)."""
    v = json.loads(json.dumps(VIEW))
    mutate(v)
    p = tmp_path / "view.json"
    p.write_text(json.dumps(v, allow_nan=True).replace("Infinity", "1e400"))
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hovr: error:") and message in err and "Traceback" not in err


def test_ramp_value_range_must_increase():
    with pytest.raises(TransferFunctionError, match="Value Max > Value Min"):
        TransferFunction.from_rgba_ramp([0.0, 1.0], [[1, 1, 1, 0], [1, 1, 1, 1]], 1.0, 2.0, 1.0)


@pytest.mark.parametrize("args, message", [
    (["-o", "{d}"], "must end with .npy"),
    (["-o", "{d}/name"], "must end with .npy"),
    (["-o", "{d}/missing/o.npy"], "does not exist"),
    (["-o", "{d}/o.npy", "--png", "{d}/o.jpg"], "must end with .png"),
    (["-o", "{d}/o.npy", "--stats", "{d}/missing/s.json"], "does not exist"),
])
def test_output_paths_are_checked_before_rendering(tmp_path, capsys, args, message):
    p = write_view(tmp_path)
    argv = ["render", str(p)] + [a.format(d=tmp_path) for a in args]
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.glob("*.npy")) and not list(tmp_path.glob(".*tmp"))


def test_fifo_output_is_refused(tmp_path, capsys):
    import os

    fifo = tmp_path / "o.npy"
    os.mkfifo(fifo)
    assert cli.main(["render", str(write_view(tmp_path)), "-o", str(fifo)]) == 2
    assert "not a regular file" in capsys.readouterr().err


def test_outputs_written_together_or_not_at_all(tmp_path, capsys, monkeypatch):
    """A failing PNG leaves neither the .npy nor a temporary file behind."""
    from hovr_blender.engine import image_io

    def broken(fh, rgba, alpha=True):
        raise OSError("disk full")

    monkeypatch.setattr(image_io, "write_png", broken)
    out = tmp_path / "o.npy"
    assert cli.main(["render", str(write_view(tmp_path)), "-o", str(out), "--png", str(tmp_path / "o.png")]) == 2
    assert "disk full" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["view.json"]


def test_output_name_is_exactly_the_one_given(tmp_path):
    out = tmp_path / "frame.NPY"
    assert cli.main(["render", str(write_view(tmp_path)), "-o", str(out)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.NPY", "view.json"]
    assert np.load(out).shape == (30, 40, 4)


@pytest.mark.parametrize("method", ["riemann", "trapezoid", "classified"])
def test_tiny_step_is_refused_with_the_limit_named(tmp_path, capsys, method):
    """h far below the data's scale: refused before any work (the sphere's box diagonal is ~6.6);
    the kernel's step count cannot overflow into a wrong image."""
    p = write_view(tmp_path)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy"), "--method", method, "--h", "1e-12"]) == 2
    err = capsys.readouterr().err
    assert "h = 1e-12" in err and "diagonal is 6.6" in err and "100000 samples per ray" in err


_WITHOUT_WARP = """
import sys
class NoWarp:  # Warp takes seconds to load: what the policy refuses without it must not load it
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "warp":
            raise ImportError("Warp was loaded for a refusal")
sys.meta_path.insert(0, NoWarp())
from hovr_blender.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("args, image, words", [(["--method", "riemann", "--h", "1e-6"], None, "samples per ray"),
                                                ([], {"width": 32768, "height": 32768}, "memory limit")])
def test_refusals_that_need_no_renderer_do_not_load_warp(tmp_path, args, image, words):
    """A step too small for the data and an image too large for the memory limit are refused
    before the renderer (and Warp) is imported: the hostile table's cases in a second, not five."""
    import os
    import subprocess
    import sys

    from ..helpers import REPO

    view = json.loads(write_view(tmp_path).read_text())
    view["image"] = image or view["image"]
    path = write_view(tmp_path, view)
    proc = subprocess.run([sys.executable, "-c", _WITHOUT_WARP, "render", str(path), "-o", str(tmp_path / "o.npy"),
                           *args], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert proc.returncode == 2 and words in proc.stderr and "Warp was loaded" not in proc.stderr, proc.stderr


def test_sample_limit_can_be_raised_and_is_honoured(tmp_path):
    p = write_view(tmp_path)
    out = tmp_path / "o.npy"
    # diagonal 6.63 / h 1e-3 = 6633 samples: refused at 5000, rendered at 10000
    assert cli.main(["render", str(p), "-o", str(out), "--method", "riemann", "--h", "1e-3",
                     "--max-samples-per-ray", "5000"]) == 2
    assert cli.main(["render", str(p), "-o", str(out), "--method", "riemann", "--h", "1e-3",
                     "--max-samples-per-ray", "10000"]) == 0


def test_memory_limit_refuses_a_huge_image_before_allocating(tmp_path, capsys):
    v = json.loads(json.dumps(VIEW))
    v["image"] = {"width": 32768, "height": 32768}
    p = write_view(tmp_path, v)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    err = capsys.readouterr().err
    assert "32768x32768 image" in err and "memory limit of 4 GiB" in err


def test_unexpected_exception_is_one_line_and_debug_shows_traceback(tmp_path, capsys, monkeypatch):
    from hovr_blender.io import sources

    def bug(source):
        raise KeyError("boom")

    monkeypatch.setattr(sources, "load_volume", bug)
    p = write_view(tmp_path)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hovr: error: unexpected KeyError") and "Traceback" not in err
    assert cli.main(["--debug", "render", str(p), "-o", str(tmp_path / "o.npy")]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_a_transfer_function_float32_cannot_resolve_is_warned_about(tmp_path, capsys):
    """Breakpoints a millionth apart where the sphere's field is ~10: float32 rounds the field by
    more than that, even in the transfer function's frame (engine/field_frame.py): the render
    still runs, and says to use float64; in float64 it says nothing."""
    view = json.loads(json.dumps(VIEW))
    view["transfer_function"] = {"color": [[5, 1, 1, 1], [5.000002, 1, 0, 0]],
                                 "density": [[5, 0], [5.000001, 3], [5.000002, 0]]}
    p = write_view(tmp_path, view)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "a.npy")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("hovr: warning: ") and "precision float64" in err
    assert cli.main(["render", str(p), "-o", str(tmp_path / "b.npy"), "--precision", "float64"]) == 0
    assert capsys.readouterr().err == ""
    view["transfer_function"]["density"] = [[5, 0], [5.000002, 0]]  # issue 40: every alpha zero, nothing to resolve
    p = write_view(tmp_path, view)
    assert cli.main(["render", str(p), "-o", str(tmp_path / "c.npy")]) == 0
    assert "precision float64" not in capsys.readouterr().err


def test_png_is_flattened_on_the_view_background_unless_asked_otherwise(tmp_path):
    """Issue 30: the PNG shows what the .npy's RGB shows (no alpha a viewer would composite over
    white); --png-background transparent keeps the volume alone with straight alpha, R,G,B
    flattens on another colour."""
    from PIL import Image

    from hovr_blender.engine.image_io import to_png_bytes_rgba

    p = write_view(tmp_path)
    out = tmp_path / "o.npy"
    pngs = {k: tmp_path / f"{k}.png" for k in ("default", "transparent", "white")}
    for name, extra in (("default", []), ("transparent", ["--png-background", "transparent"]),
                        ("white", ["--png-background", "1,1,1"])):
        assert cli.main(["render", str(p), "-o", str(out), "--png", str(pngs[name]), *extra]) == 0
    img = np.load(out).astype(np.float64)
    default = Image.open(pngs["default"])
    assert default.mode == "RGB"
    np.testing.assert_array_equal(np.asarray(default), to_png_bytes_rgba(img)[..., :3])
    transparent = np.asarray(Image.open(pngs["transparent"]))
    assert transparent.shape[2] == 4 and transparent[0, 0, 3] == 0  # a missed ray: see-through
    assert (transparent[..., 3] == 255).sum() < transparent[..., 3].size
    white = np.asarray(Image.open(pngs["white"]), dtype=float)
    assert white[0, 0].tolist() == [255, 255, 255]
    with pytest.raises(SystemExit) as refused:  # argparse's one-line usage error
        cli.main(["render", str(p), "-o", str(out), "--png", str(pngs["white"]), "--png-background", "2,0"])
    assert refused.value.code == 2


def test_png_pixels_recompose_the_contract_image():
    """Flattened on the view's own background, the transparent PNG's straight alpha gives the
    contract's RGB back; flattened on a colour, it is C + T colour."""
    from hovr_blender.engine.image_io import png_pixels

    rng = np.random.default_rng(1)
    background = np.array([0.1, 0.2, 0.3])
    alpha = rng.uniform(0, 1, (5, 6, 1))
    alpha[0, 0] = 0.0
    emitted = alpha * rng.uniform(0, 1, (5, 6, 3))  # C <= 1 - T for colours within 0..1
    rgba = np.concatenate([emitted + (1 - alpha) * background, alpha], axis=2)
    view = png_pixels(rgba, background)
    np.testing.assert_array_equal(view[..., :3], rgba[..., :3])
    assert (view[..., 3] == 1).all()
    straight = png_pixels(rgba, background, "transparent")
    np.testing.assert_allclose(straight[..., :3] * straight[..., 3:] + (1 - straight[..., 3:]) * background,
                               rgba[..., :3], atol=1e-12)
    np.testing.assert_allclose(png_pixels(rgba, background, (1.0, 1.0, 1.0))[..., :3], emitted + (1 - alpha), atol=1e-12)
    with pytest.raises(ValueError, match="PNG background"):
        png_pixels(rgba, background, "checkerboard")


def test_png_legend_shows_the_ramp_and_its_values(tmp_path):
    """Issue 30, 40: --legend draws the transfer function's bar, its density, round values and the
    field's name and units at the PNG's right edge (engine/legend.py, the layout Blender's viewport
    overlay and F12 draw too), and nothing else."""
    from PIL import Image

    from hovr_blender.engine.image_io import srgb_encode
    from hovr_blender.engine.legend import legend_layout, tf_value_range
    from hovr_blender.engine.legend_text import text_width

    p = write_view(tmp_path, dict(VIEW, image={"width": 160, "height": 120}))
    plain, legend = tmp_path / "plain.png", tmp_path / "legend.png"
    out = str(tmp_path / "o.npy")
    assert cli.main(["render", str(p), "-o", out, "--png", str(plain)]) == 0
    assert cli.main(["render", str(p), "-o", out, "--png", str(legend), "--legend", "--units", "m^2"]) == 0
    a = np.asarray(Image.open(plain), dtype=int)
    b = np.asarray(Image.open(legend), dtype=int)
    view = View.load(p)
    layout = legend_layout(view.transfer_function, *tf_value_range(view.transfer_function), "f", 160, 120,
                           view.background, units="m^2")
    x0, y0, x1, y1 = layout.bar
    left = min(t.x - (text_width(t.text, layout.font_px) if t.anchor == "right" else 0) for t in layout.texts)
    changed = np.abs(a - b).max(axis=2) > 0
    assert changed[:, : int(left) - 2].sum() == 0  # the picture itself is untouched
    assert changed[y0, x0:x1].all() and changed[y0:y1, int(left):layout.curve[0]].any()  # the bar, its labels
    assert changed[: y0 - 1].any() and "f [m^2]" in [t.text for t in layout.texts]  # the title
    want = np.round(srgb_encode(layout.bar_rgb[0]) * 255)  # the largest value's colour, at full strength
    np.testing.assert_allclose(b[y0, (x0 + x1) // 2], want, atol=1)
    assert cli.main(["render", str(p), "-o", out, "--legend"]) == 2  # it needs --png
    assert cli.main(["render", str(p), "-o", out, "--png", str(legend), "--units", "Pa"]) == 2  # and --legend


def test_cli_renders_the_example_view_and_refuses_bad_surfaces(tmp_path, capsys):
    """hovr render takes isosurfaces and planes from the view file (examples/sphere_isosurface.json);
    a level outside the field's range is one line and exit code 2."""
    import json

    from hovr_blender import cli
    from tests.helpers import REPO

    view = json.loads((REPO / "examples" / "sphere_isosurface.json").read_text())
    view["image"] = {"width": 24, "height": 18}
    p = tmp_path / "v.json"
    p.write_text(json.dumps(view))
    out = tmp_path / "o.npy"
    assert cli.main(["render", str(p), "-o", str(out)]) == 0
    img = np.load(out)
    assert (img[..., 3] == 1.0).any()  # the opaque level and the plane cover pixels
    view["isosurfaces"][0]["value"] = 99.0  # f = x^2 + y^2 + z^2 <= 18 in the sphere's box
    p.write_text(json.dumps(view))
    capsys.readouterr()
    assert cli.main(["render", str(p), "-o", str(tmp_path / "bad.npy")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "isosurface 0: value 99 is outside the field's range" in err[0], err


def test_cli_field_option(tmp_path, capsys):
    """hovr render --field takes a derived field instead of the view's; Nektar++'s channel's
    vorticity |1 - 2y| is at most 1; Q(p) (one scalar) is one line and exit code 2."""
    import json

    from hovr_blender import cli
    from tests.helpers import data_file

    mesh = data_file("nektar", "Tet_channel_m3.xml")
    view = {"data": {"path": str(mesh), "solution": str(data_file("nektar", "Tet_channel_m3.fld")), "field": "w"},
            "camera": {"projection": "perspective", "eye": [3.0, 2.5, 2.0], "target": [0.5, 0.5, 1.0],
                       "up": [0, 0, 1], "fov_y_deg": 40},
            "image": {"width": 12, "height": 9},
            "transfer_function": {"color": [[0.0, 0.0, 0.0, 1.0], [1.0, 1.0, 0.0, 0.0]],
                                  "density": [[0.0, 0.0], [1.0, 2.0]]},
            "background": [0, 0, 0]}
    p = tmp_path / "v.json"
    p.write_text(json.dumps(view))
    out = tmp_path / "o.npy"
    assert cli.main(["render", str(p), "-o", str(out), "--field", "vorticity(u,v,w)"]) == 0
    assert np.load(out)[..., 3].max() > 0.0
    capsys.readouterr()
    assert cli.main(["render", str(p), "-o", str(tmp_path / "bad.npy"), "--field", "Q(p)"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a velocity" in err[0], err


def test_a_derived_field_of_a_scalar_is_a_users_error_in_one_line(tmp_path, capsys):
    """Issue 40: Q(Pressure) on PyFR's output came back from the reader process as 'unexpected
    DerivedFieldError ... (a bug: please report it)'; it is the user's error, said in one line."""
    path = REPO_DATA / "pyfr" / "shell_lagrange_p2.vtu"
    assert cli.main(["render", str(path), "--field", "Q(Pressure)", "--png", str(tmp_path / "q.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("hovr: error: Q(Pressure): 'Pressure' has 1 component, not a "
                                               "velocity") and "bug" not in err[0] and "unexpected" not in err[0]
    assert not (tmp_path / "q.png").exists()


def test_a_derived_fields_exact_fit_is_a_note_not_a_warning(capsys):
    """Issue 40: Q's fit (for ranges and normals; the render samples Q exactly) within 1e-3 of its
    largest value is reported as a note; the CLI prints it without 'warning'."""
    from hovr_blender.engine.derived_fields import FIT_WARNING
    from hovr_blender.io.sources import VolumeSource, load_volume

    path = REPO_DATA / "pyfr" / "shell_lagrange_p2.vtu"
    mesh = load_volume(VolumeSource.resolve(str(path), "", "Q(Velocity)"))
    assert mesh.derived_error["relative"] <= FIT_WARNING
    assert mesh.notes == [mesh.fit_report] and mesh.fit_report not in mesh.warnings
    assert "sampled exactly in the render" in mesh.fit_report


def test_a_data_file_needs_no_view_file(tmp_path, capsys):
    """Issue 40: `hovr render FILE` renders a data file's first view (engine/first_view.py, Blender's
    import's); `hovr view FILE` writes that view, which renders within float32's rounding of the
    camera of it; a view file with only its data (and image) is the same first view; bad sizes and
    missing outputs are one line."""
    direct, partial, edited = (tmp_path / f"{k}.npy" for k in ("direct", "partial", "edited"))
    assert cli.main(["render", "builtin:sphere", "--size", "40x30", "-o", str(direct)]) == 0
    capsys.readouterr()
    assert cli.main(["view", "builtin:sphere", "--size", "40x30"]) == 0
    view = json.loads(capsys.readouterr().out)
    assert set(view) == {"data", "image", "camera", "transfer_function", "background", "render"}
    assert view["image"] == {"width": 40, "height": 30} and view["render"]["method"] == "classified"
    p = write_view(tmp_path, view)
    assert cli.main(["render", str(p), "-o", str(edited)]) == 0
    a, b = np.load(direct), np.load(edited)
    assert a[..., 3].max() > 0.1 and np.abs(a - b).max() < 1e-4
    q = tmp_path / "partial.json"
    q.write_text(json.dumps({"data": {"builtin": "sphere"}, "image": {"width": 40, "height": 30}}))
    assert cli.main(["render", str(q), "-o", str(partial)]) == 0
    np.testing.assert_array_equal(np.load(partial), a)  # the first view's own camera: the same rays
    capsys.readouterr()
    with pytest.raises(SystemExit) as usage:  # argparse's usage error
        cli.main(["render", "builtin:sphere", "--size", "40"])
    assert usage.value.code == 2 and "WxH" in capsys.readouterr().err
    assert cli.main(["render", "builtin:sphere"]) == 2
    assert capsys.readouterr().err.strip() == "hovr: error: give -o out.npy, --png out.png or both"
