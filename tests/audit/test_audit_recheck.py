"""scripts/audit.py recheck: a pixel a GPU audit blamed on the renderer, decided again with the
dense chords as the reference's cover (Hex_Mushroom, pixel (575, 301), H200 2026-12-02: the
default chords left the ray undecided, the VTK reference saw no chord and gave 0, every image
gave alpha 0.057)."""
import argparse
import json

import pytest

from ..helpers import data_file

pytest.importorskip("vtkmodules")

F64 = [0.009274787571288015, 0.03986944207468175, 0.03234158607191392, 0.057214764159370546]
F32 = [0.009268337860703468, 0.03984171897172928, 0.032319098711013794, 0.0571749210357666]
IMAGES = ("float32-split", "float32-classified", "float64-split", "float64-classified", "float64-split-1e-7")


def test_recheck_clears_a_pixel_the_reference_missed_and_says_so(tmp_path, monkeypatch):
    path = data_file("nektar", "Hex_Mushroom.xml")
    data_file("nektar", "Hex_Mushroom.fld")
    from hovr_blender.audit import datasets
    from scripts import audit

    monkeypatch.setattr(datasets, "SHARED", path.parent.parent)

    values = {k: (F32 if k.startswith("float32") else F64) for k in IMAGES}
    row = {"i": 575, "j": 301, "why": "gap", "exact_chord": None, "reference_inside": 0.0, "reference_missed_chord": False,
           "reference": [0.0] * 4, "values": values, "errors": {k: v[3] for k, v in values.items()}}
    doc = {"size": [1920, 1080], "datasets": {"Hex_Mushroom": {
        "pixels_over": [row], "pixels": [{k: v for k, v in row.items() if k != "values"}], "reference_missed_chord": 0,
        "vs_reference": {k: {"over": 1, "over_where_reference_inside_is_the_chord": 1, "max_error": v[3], "at": [575, 301]}
                         for k, v in values.items()}}}}
    src, out = tmp_path / "audit.json", tmp_path / "rechecked.json"
    src.write_text(json.dumps(doc))
    audit.recheck_stage(argparse.Namespace(audit=str(src), out=str(out)))
    d = json.loads(out.read_text())["datasets"]["Hex_Mushroom"]
    assert d["pixels_over"] == []
    [p] = d["pixels"]
    assert abs(p["exact_chord"] - 0.0190075) < 1e-6 and not p["reference_missed_chord"]
    assert max(p["errors"].values()) < 1e-3
    assert all(v["over"] == 0 and v["over_where_reference_inside_is_the_chord"] == 0 for v in d["vs_reference"].values())
