"""The data formats' registry (io/formats.py): a toy format, one module (tests/toy_format.py) and
one registry line, is read by the loader and rendered by the `hovr` command like a built-in one;
the registry finds a file's format by extension, by its head where the extension is unknown, and
fills in an import's defaults the same way for every format. Blender's side of the toy format is
tests/blender/test_formats.py."""
import json

import numpy as np
import pytest

from hovr_blender import cli
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.view import View
from hovr_blender.io import formats
from hovr_blender.io.sources import SourceError, VolumeSource, load_volume
from tests import toy_format

from ..helpers import data_file


@pytest.fixture
def toy():
    formats.register(toy_format.FORMAT)  # the one registry line a new format needs
    try:
        yield toy_format.FORMAT
    finally:
        formats.unregister("toy")


def toy_view(folder, data_path, field="r2", size=(24, 16)) -> dict:
    return {"data": {"path": str(data_path), "field": field},
            "camera": {"eye": [3.0, -2.2, 2.4], "target": [0.0, 0.0, 0.0], "up": [0, 0, 1], "fov_y_deg": 40.0},
            "image": {"width": size[0], "height": size[1]},
            "transfer_function": {"color": [[0.0, 1.0, 0.6, 0.2], [3.0, 0.2, 0.4, 1.0]],
                                  "density": [[0.0, 0.0], [1.0, 2.0], [3.0, 0.0]]},
            "background": [0.02, 0.02, 0.03], "render": {"method": "split", "tolerance": 1e-5}}


def test_a_toy_format_renders_from_the_command_line(toy, tmp_path):
    path = toy_format.write(tmp_path / "brick.toy")
    view_path = tmp_path / "view.json"
    view_path.write_text(json.dumps(toy_view(tmp_path, path.name)))  # relative to the view file, as users write
    out = tmp_path / "image.npy"
    assert cli.main(["render", str(view_path), "-o", str(out)]) == 0
    image = np.load(out)
    view = View.load(str(view_path))
    want = Renderer(toy_format.read(path, field="r2"), "cpu").render(view.camera, view.transfer_function,
                                                                     view.background, view.options).rgba
    np.testing.assert_array_equal(image, want)
    assert image[..., 3].max() > 0.3  # the brick is in view and not empty


def test_the_loader_reads_a_registered_format_by_extension_or_by_its_head(toy, tmp_path):
    path = toy_format.write(tmp_path / "brick.toy", cells=(1, 2, 3))
    mesh = load_volume(VolumeSource.resolve(str(path), field="x"))
    assert mesh.num_elements == 6 and mesh.field_name == "x"
    renamed = toy_format.write(tmp_path / "brick.dat")  # no format has .dat: the head says toy
    assert formats.format_of(renamed) is toy and formats.format_of(renamed, sniff=False) is None
    assert load_volume(VolumeSource.resolve(str(renamed))).field_name == "r2"
    assert "Toy (.toy)" in formats.described()
    with pytest.raises(toy_format.ToyError, match="no field 'q'"):
        load_volume(VolumeSource.resolve(str(path), field="q"))


def test_an_unregistered_format_is_refused_in_one_line(tmp_path):
    path = toy_format.write(tmp_path / "brick.toy")
    assert formats.format_of(path) is None
    with pytest.raises(SourceError, match=r"unsupported data format '\.toy' \(use builtin:NAME or a file of "
                                          r"Nektar\+\+ \(\.xml\), VTU \(\.vtu\), PyFR \(\.pyfrm\), MFEM \(\.mesh\)\)"):
        load_volume(VolumeSource.resolve(str(path)))


def test_register_checks_the_name_and_extensions(toy):
    import dataclasses

    with pytest.raises(ValueError, match="identifier"):
        formats.register(dataclasses.replace(toy, name="toy-2"))
    with pytest.raises(ValueError, match="lower-case"):
        formats.register(dataclasses.replace(toy, extensions=(".TOY",)))
    formats.register(dataclasses.replace(toy, label="Toy 2"))  # the same name replaces the format
    assert [f.label for f in formats.FORMATS if f.name == "toy"] == ["Toy 2"]


def test_choose_fills_in_the_first_field_and_says_so(toy, tmp_path):
    path = toy_format.write(tmp_path / "brick.toy")
    choice = toy.choose(str(path))
    assert (choice.solution, choice.field, choice.component) == ("", "r2", "")
    assert choice.notes == ["showing 'r2' of r2, x (set Field to choose)"] and choice.warnings == []
    assert toy.choose(str(path), field="x").notes == []


def test_choose_finds_a_nektar_solution_beside_the_mesh():
    nektar = formats.named("nektar")
    xml = data_file("nektar", "Hex_CurvedFace.xml")
    choice = nektar.choose(str(xml))
    assert choice.solution.endswith("Hex_CurvedFace.fld") and choice.field == "u"
    assert choice.notes[0].startswith("solution Hex_CurvedFace.fld (")
    assert nektar.takes_solution and nektar.boundaries is not None and not nektar.components


def test_the_built_in_formats_by_extension_and_by_head(tmp_path):
    assert formats.format_of("a/b/MESH.XML", sniff=False).name == "nektar"
    assert formats.format_of("flow.vtu", sniff=False).name == "vtu"
    xml = data_file("nektar", "Hex_CurvedFace.xml")
    copy = tmp_path / "mesh.txt"
    copy.write_bytes(xml.read_bytes())
    assert formats.format_of(copy).name == "nektar"
    assert formats.format_of(tmp_path / "missing.txt") is None
    with pytest.raises(ValueError, match="no data format 'cgns'"):
        formats.named("cgns")
