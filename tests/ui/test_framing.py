"""The bpy-free numbers of a first picture (hovr_blender/ui/framing.py, engine/first_view.py) and the Nektar++
importer's solution discovery (io/nektar/reader.py): density and step relative to the volume's
size, a camera that sees every point, clip planes around them, and the words for an empty, faint or
clipped render."""
import numpy as np
import pytest

from hovr_blender.engine import first_view
from hovr_blender.ui import framing
from hovr_blender.io import formats, nektar


def test_relative_density_is_optical_depth_along_the_diagonal():
    lo, hi = (0.0, 0.0, 0.0), (0.02, 0.01, 0.005)
    diag = first_view.volume_diagonal(lo, hi)
    assert diag == pytest.approx(np.sqrt(0.02**2 + 0.01**2 + 0.005**2))
    assert first_view.density_per_world_unit(4.0, "RELATIVE", diag) * diag == pytest.approx(4.0)
    assert first_view.density_per_world_unit(4.0, "WORLD", diag) == 4.0
    # the object's matrix: rotation keeps the diagonal, scale scales it
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0, 5], [s, c, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    assert first_view.volume_diagonal(lo, hi, rot) == pytest.approx(diag)
    assert first_view.volume_diagonal(lo, hi, np.diag([3.0, 3.0, 3.0, 1.0])) == pytest.approx(3 * diag)
    with pytest.raises(ValueError, match="no extent"):
        first_view.density_per_world_unit(1.0, "RELATIVE", 0.0)
    with pytest.raises(ValueError):
        first_view.density_per_world_unit(1.0, "PER_PARSEC", 1.0)


def test_relative_step_is_the_smallest_diagonal_over_steps_across():
    assert framing.step_world_length(0.01, 1000, "RELATIVE", [0.0226]) == pytest.approx(2.26e-5)
    # several volumes: each sampled at least Steps Across times along its diagonal
    assert framing.step_world_length(0.01, 500, "RELATIVE", [10.0, 2.0, 4.0]) == pytest.approx(2.0 / 500)
    assert framing.step_world_length(0.03, 1000, "WORLD", []) == 0.03  # World Units: h itself, no data needed
    with pytest.raises(ValueError, match="no extent"):
        framing.step_world_length(0.01, 1000, "RELATIVE", [1.0, 0.0])
    with pytest.raises(ValueError, match="at least 1"):
        framing.step_world_length(0.01, 0, "RELATIVE", [1.0])
    with pytest.raises(ValueError, match="no volume"):
        framing.step_world_length(0.01, 10, "RELATIVE", [])
    with pytest.raises(ValueError, match="unknown step units"):
        framing.step_world_length(0.01, 10, "PER_PARSEC", [1.0])


@pytest.mark.parametrize("scale", [0.02, 1.0, 300.0])
@pytest.mark.parametrize("forward", [(-7.36, 6.93, -4.96), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0)])
def test_fit_view_sees_every_corner_and_clip_planes_hold_them(scale, forward):
    corners = framing.box_corners(np.array([-1.0, -0.3, 0.1]) * scale, np.array([2.0, 0.4, 0.3]) * scale)
    W, H, fov = 96, 54, 40.0
    ty = np.tan(np.radians(fov) / 2)
    tx = ty * W / H
    eye, _, near, far = first_view.fit_view(corners, forward, (0, 0, 1), tx, ty, margin=1.1)
    f, r, u = first_view._axes(forward, (0, 0, 1))
    rel = corners - eye
    z = rel @ f
    assert np.all(z > 0)
    px, py = np.abs(rel @ r) / z / tx, np.abs(rel @ u) / z / ty
    assert max(px.max(), py.max()) <= 1 / 1.1 + 1e-9  # inside the frame, with the margin
    assert max(px.max(), py.max()) == pytest.approx(1 / 1.1, rel=1e-6)  # and as large as that allows
    assert (near, far) == pytest.approx((z.min(), z.max()))
    start, end = first_view.clip_planes(near, far)
    assert 0 < start < near and end > far
    assert framing.clip_warning(corners, eye, f, start, end) is None


def test_fit_view_orthographic_height():
    corners = framing.box_corners((-1, -1, -1), (1, 1, 1))
    eye, height, near, far = first_view.fit_view(corners, (0, 1, 0), (0, 0, 1), 1.0, 0.5, orthographic=True, margin=1.0)
    assert height == pytest.approx(2.0 * max(1.0, 1.0 * 0.5 / 1.0))  # z extent 1 vs x extent 1 at aspect 2
    assert near > 0 and far - near == pytest.approx(2.0)


def test_clip_warnings_name_the_cause():
    corners = framing.box_corners((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))  # a 2 cm box
    eye, fwd = np.array([0.0, -0.06, 0.0]), (0.0, 1.0, 0.0)
    hidden = framing.clip_warning(corners, eye, fwd, 0.1, 100.0)  # Blender's default clip start
    assert "entirely before" in hidden and "Clip Start (0.1 m" in hidden and "Frame Volume" in hidden
    assert "cuts into" in framing.clip_warning(corners, eye, fwd, 0.06, 100.0)
    assert "beyond" in framing.clip_warning(corners, eye, fwd, 0.001, 0.04)
    assert "cuts off" in framing.clip_warning(corners, eye, fwd, 0.001, 0.06)
    assert "behind" in framing.clip_warning(corners, eye, (0.0, -1.0, 0.0), 0.001, 100.0)
    assert framing.clip_warning(corners, eye, fwd, 0.01, 1.0) is None
    assert "0.1 m" in hidden and "0.20000000298" not in hidden  # numbers without float noise


def test_image_warnings():
    assert "empty" in framing.image_warning(np.zeros((4, 4)))
    faint = framing.image_warning(np.full((4, 4), 0.005))
    assert "nearly transparent" in faint and "0.5%" in faint
    assert framing.image_warning(np.full((4, 4), 0.3)) is None


@pytest.fixture
def folder(tmp_path):
    def make(*names):
        for n in names:
            if n.endswith("/"):
                (tmp_path / n).mkdir()
                (tmp_path / n / "Info.xml").write_text("<x/>")
            else:
                (tmp_path / n).write_text("")
        return tmp_path
    return make


def test_solution_named_like_the_mesh_first(folder):
    d = folder("flow.xml", "flow.fld", "flow_3.chk", "other.fld")
    picked, why, others = nektar.pick_solution(d / "flow.xml")
    assert picked.name == "flow.fld" and why == "named like the mesh" and len(others) == 3


def test_solution_of_a_decorated_mesh_name(folder):
    d = folder("hump3D_GLL.xml", "hump3D.rst", "Tet_channel_m3.fld", "Hex_Mushroom.fld")
    picked, why, _ = nektar.pick_solution(d / "hump3D_GLL.xml")
    assert picked.name == "hump3D.rst" and "hump3D" in why


def test_solution_latest_of_a_numbered_series(folder):
    d = folder("session.xml", "session_9.chk", "session_12.chk", "session_123.chk", "unrelated.fld")
    picked, why, others = nektar.pick_solution(d / "session.xml")
    assert picked.name == "session_123.chk" and "latest of 3" in why
    assert [p.name for p in others][:3] == ["session_123.chk", "session_12.chk", "session_9.chk"]


def test_solution_folder_and_lone_file(folder):
    d = folder("mesh.xml", "run.fld/")
    picked, why, _ = nektar.pick_solution(d / "mesh.xml")
    assert picked.name == "run.fld" and "only field file" in why


def test_no_guess_among_unrelated_files(folder):
    d = folder("mesh.xml", "a.fld", "b.chk")
    picked, why, others = nektar.pick_solution(d / "mesh.xml")
    assert picked is None and "none named like the mesh" in why and len(others) == 2
    for p in others:
        p.unlink()
    picked, why, others = nektar.pick_solution(d / "mesh.xml")
    assert picked is None and others == [] and "no .fld" in why


def test_missing_dependencies_are_named_with_what_to_do():
    from hovr_blender.ui import dependencies

    assert dependencies.missing(lambda name: object()) == []
    assert dependencies.report_lines([]) == []
    absent = dependencies.missing(lambda name: None if name in ("warp", "h5py") else object())
    assert [m for m, *_ in absent] == ["warp", "h5py"]
    lines = dependencies.report_lines(absent, python="/blender/python")
    assert "warp-lang is missing" in lines[0] and "will not work" in lines[0]
    assert "h5py is missing" in lines[1] and "HDF5" in lines[1] and "is unavailable" in lines[1]
    # issue 40: Warp pinned at the version the add-on needs (an unpinned install takes the newest)
    assert '"/blender/python" -m pip install warp-lang==1.19.0 h5py' in lines[-1] and "extension zip" in lines[-1]


def test_the_readme_and_the_guide_name_the_zips_the_build_writes():
    """Issue 40: the README named the zip ...-linux-x64.zip; the build writes ...-linux_x64.zip."""
    import re

    from scripts import build_extension

    _, manifest = build_extension._load_manifest()
    written = {build_extension.zip_name(manifest)} | {build_extension.zip_name(manifest, p)
                                                      for p in build_extension.DEFAULT_PLATFORMS}
    tails = {name[len(f"{manifest['id']}-{manifest['version']}"):] for name in written}  # "-linux_x64.zip", ...
    for doc in ("README.md", "docs/user-guide.md"):
        text = (build_extension.REPO / doc).read_text(encoding="utf-8")
        named = re.findall(r"hovr_blender-[0-9.]+[-\w]*\.zip", text)
        assert named and set(named) <= written, (doc, named)
        assert set(re.findall(r"`(-[a-z]+[-_][a-z0-9]+\.zip)`", text)) <= tails, doc


def test_the_guide_names_the_packages_each_reader_needs():
    """Issue 40: the user guide said the VTU reader needs no package; every package the add-on
    checks is named there, Warp with its one version."""
    from hovr_blender.ui import dependencies

    text = (formats.__file__.rsplit("/hovr_blender/", 1)[0] + "/docs/user-guide.md")
    with open(text, encoding="utf-8") as fh:
        guide = fh.read()
    requirements = guide[guide.index("- **Python packages**"):guide.index("- Warp's console messages")]
    assert f"warp-lang {dependencies.WARP_VERSION}" in requirements and "no package" not in requirements
    for _, package, *_ in dependencies.dependencies():
        assert package in requirements
    assert "VTU" in requirements[requirements.index("defusedxml"):]


def test_the_dependency_check_and_the_extension_wheels_name_the_same_packages():
    """What the add-on checks at enable time (Warp and the formats' packages, io/formats.py) is
    what the platform zips bundle (scripts/build_extension.py), and nothing the product does not import."""
    from hovr_blender.ui import dependencies
    from scripts import build_extension

    checked = {package for _, package, *_ in dependencies.dependencies()}
    bundled = {requirement.split("==")[0] for requirement in build_extension.RUNTIME_REQUIREMENTS}
    assert checked == bundled == {"warp-lang", "h5py", "defusedxml"}
    # one pin of Warp: the add-on's, the zips' and the package's own
    pyproject = (build_extension.REPO / "pyproject.toml").read_text()
    assert f'"warp-lang=={dependencies.WARP_VERSION}"' in pyproject
    assert f"warp-lang=={dependencies.WARP_VERSION}" in build_extension.RUNTIME_REQUIREMENTS
    # issue 40: the VTU reader needs defusedxml (the user guide said it needed nothing)
    assert ("defusedxml", "defusedxml") in {(m, p) for m, p, *_ in dependencies.dependencies()}
    assert any(p == "defusedxml" for _, p, _ in formats.named("vtu").packages)
