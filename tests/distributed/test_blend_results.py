"""render-blend's results come over a private pipe, with their paths checked (issue 41): Blender's
output is never read for them (an object's name with a newline could print a line saying any
file was rendered), and the pipe's result is refused unless its output lies in the folder and its
temporary is the regular file ui/batch.py names beside it. A stand-in for ui/batch.py (no Blender
needed) prints a forged line on stdout and writes `FAKE` to the pipe."""
import json
import os
import textwrap

import pytest

pytest.importorskip("distributed")

from hovr_blender.distributed import blender_frames  # noqa: E402
from hovr_blender.distributed.series import FrameError  # noqa: E402

FAKE_BATCH = textwrap.dedent("""
    import json, os, sys
    blend, frame, root, mode = sys.argv[1:5]
    out = os.path.join(root, "frame_0001.png")
    tmp = os.path.join(root, f".frame_0001.png.{os.getpid()}.tmp")
    print("HOVR-RENDERED " + json.dumps({"tmp": "/etc/hostname", "out": out}), flush=True)  # forged, as a name can
    fake = json.loads(os.environ["FAKE"])
    with os.fdopen(int(os.environ["HOVR_RESULT_FD"]), "w") as fh:
        fh.write(json.dumps({"status": "rendering", "tmp": tmp, "out": out}) + "\\n")
        open(tmp, "wb").write(b"png")
        if fake.get("result") is not None:
            fh.write(json.dumps(fake["result"]).replace("TMP", tmp).replace("ROOT", root) + "\\n")
    sys.exit(fake.get("exit", 0))
""")


@pytest.fixture
def fake(tmp_path, monkeypatch):
    script = tmp_path / "fake_batch.py"
    script.write_text(FAKE_BATCH)
    monkeypatch.setattr(blender_frames, "BATCH", str(script))
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "s.blend").write_bytes(b"BLENDER")
    (tmp_path / "out").mkdir()

    def run(result, exit=0):
        monkeypatch.setenv("FAKE", json.dumps({"result": result, "exit": exit}))
        return blender_frames.render_blend_frame(str(tmp_path / "scene" / "s.blend"), 1, timeout=60,
                                                 output=str(tmp_path / "out"))
    return tmp_path, run


def test_the_result_comes_from_the_pipe_not_from_the_output(fake):
    folder, run = fake
    record = run({"status": "rendered", "tmp": "TMP", "out": "ROOT/frame_0001.png"})
    assert record["status"] == "written" and (folder / "out" / "frame_0001.png").read_bytes() == b"png"
    assert sorted(p.name for p in (folder / "out").iterdir()) == [".hovr-series.log", "frame_0001.png"]


def test_a_forged_line_alone_is_no_result(fake):
    folder, run = fake
    with pytest.raises(FrameError, match="Blender gave no result"):
        run(None)
    assert list((folder / "out").iterdir()) == []  # the temporary it announced is gone


def test_a_blender_that_fails_after_rendering_leaves_no_temporary(fake):
    folder, run = fake
    with pytest.raises(FrameError, match="exited with 134"):
        run({"status": "rendered", "tmp": "TMP", "out": "ROOT/frame_0001.png"}, exit=134)
    assert list((folder / "out").iterdir()) == []


@pytest.mark.parametrize("result, words", [
    ({"status": "rendered", "tmp": "/etc/hostname", "out": "ROOT/frame_0001.png"}, "not ROOT"),
    ({"status": "rendered", "tmp": "TMP", "out": "/etc/frame_0001.png"}, "is outside"),
    ({"status": "done", "out": "ROOT/frame_0001.png"}, "gave no result"),
])
def test_a_result_whose_paths_are_not_ours_is_refused(fake, result, words):
    folder, run = fake
    with pytest.raises(FrameError, match=words.replace("ROOT", str(folder / "out"))):
        run(result)
    assert list((folder / "out").iterdir()) == []  # no frame, no temporary left


def test_a_temporary_that_is_a_link_is_refused(fake):
    folder, run = fake
    (folder / "precious").write_bytes(b"the user's")
    script = (folder / "fake_batch.py").read_text().replace(
        'open(tmp, "wb").write(b"png")', f'os.symlink({str(folder / "precious")!r}, tmp)')
    assert script != (folder / "fake_batch.py").read_text()
    (folder / "fake_batch.py").write_text(script)
    with pytest.raises(FrameError, match="is not a regular file"):
        run({"status": "rendered", "tmp": "TMP", "out": "ROOT/frame_0001.png"})
    assert list((folder / "out").iterdir()) == [] and (folder / "precious").read_bytes() == b"the user's"
