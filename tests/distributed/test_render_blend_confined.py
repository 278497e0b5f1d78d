"""render-blend's Blender confined by the operating system (issue 41): under the Landlock ruleset
render-blend gives it (engine/landlock.py), a process writes only in its folders; a Blender made
to write everything a hostile .blend names (tests/hostile/make_blend.py: a fluid cache, a point
cache on disk, an ocean bake, an Alembic export; blend_writer.py runs the bakes and exports on
purpose, which render-blend never does) changes nothing outside them, where the same Blender
unconfined writes into the folder around it. The trees around are listed before and after.
tests/hostile/run_cases.py runs the same .blends through `hovr render-blend`."""
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hovr_blender.engine import landlock
from tests.helpers import tree_listing

REPO = Path(__file__).resolve().parents[2]
MAKE_BLEND = REPO / "tests" / "hostile" / "make_blend.py"
WRITER = Path(__file__).with_name("blend_writer.py")
KINDS = ("fluid", "pointcache", "ocean", "alembic")

if landlock.abi() < 1:
    pytest.skip("Landlock is not available here", allow_module_level=True)


def test_a_confined_child_writes_only_in_its_folders(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "keep.txt").write_text("keep")
    code = ("import os, sys\n"
            "def attempt(name, run):\n"
            "    try:\n        run(); print(name, 'ok')\n"
            "    except OSError as exc:\n        print(name, 'refused', exc.errno)\n"
            "mine, theirs = sys.argv[1:3]\n"
            "attempt('write mine', lambda: open(os.path.join(mine, 'new'), 'w').write('x'))\n"
            "attempt('write theirs', lambda: open(os.path.join(theirs, 'new'), 'w').write('x'))\n"
            "attempt('truncate theirs', lambda: open(os.path.join(theirs, 'keep.txt'), 'r+').truncate(0))\n"
            "attempt('mkdir theirs', lambda: os.mkdir(os.path.join(theirs, 'd')))\n"
            "attempt('link theirs', lambda: os.symlink('/etc/passwd', os.path.join(theirs, 'l')))\n"
            "attempt('move out', lambda: os.rename(os.path.join(mine, 'new'), os.path.join(theirs, 'moved')))\n"
            "attempt('remove theirs', lambda: os.unlink(os.path.join(theirs, 'keep.txt')))\n"
            "attempt('read theirs', lambda: open(os.path.join(theirs, 'keep.txt')).read())\n"
            "attempt('/dev/null', lambda: open('/dev/null', 'w').write('x'))\n")
    before = tree_listing(tmp_path / "theirs")
    ruleset = landlock.write_ruleset([str(tmp_path / "mine")])
    try:
        proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "mine"), str(tmp_path / "theirs")],
                              capture_output=True, text=True, preexec_fn=lambda: landlock.restrict_self(ruleset))
    finally:
        os.close(ruleset)
    results = dict(line.rsplit(" ", 1) if "refused" not in line else (line.split(" refused")[0], "refused")
                   for line in proc.stdout.splitlines())
    assert results == {"write mine": "ok", "write theirs": "refused", "truncate theirs": "refused",
                       "mkdir theirs": "refused", "link theirs": "refused", "move out": "refused",
                       "remove theirs": "refused", "read theirs": "ok", "/dev/null": "ok"}, proc.stdout + proc.stderr
    assert tree_listing(tmp_path / "theirs") == before


def _layout(folder: Path, kind: str) -> Path:
    """folder/scene/s.blend of `kind`, naming folder/elsewhere (which holds a file of the user's);
    folder/out and folder/tmp: the folders Blender may write in."""
    for name in ("scene", "elsewhere", "out", "tmp"):
        (folder / name).mkdir()
    (folder / "elsewhere" / "notes.txt").write_text("the user's")
    blend = folder / "scene" / "s.blend"
    subprocess.run([sys.executable, str(MAKE_BLEND), kind, str(blend), str(folder / "elsewhere")], check=True,
                   capture_output=True, timeout=300)
    for leftover in ("elsewhere/config", "scene/blendcache_s"):  # what making the file wrote
        subprocess.run(["rm", "-rf", str(folder / leftover)], check=True)
    return blend


def _write_everything(folder: Path, blend: Path, confined: bool):
    ruleset = landlock.write_ruleset([str(folder / "out"), str(folder / "tmp")]) if confined else None
    env = dict(os.environ, TMPDIR=str(folder / "tmp"), PYTHONPATH=str(REPO))
    try:
        return subprocess.run([sys.executable, str(WRITER), str(blend), str(folder / "out")], capture_output=True,
                              text=True, timeout=600, env=env,
                              preexec_fn=(lambda: landlock.restrict_self(ruleset)) if confined else None)
    finally:
        if ruleset is not None:
            os.close(ruleset)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs the bpy module (Blender as a Python module)")
@pytest.mark.parametrize("kind", KINDS)
def test_blender_writes_nothing_outside_its_folders_when_confined(tmp_path, kind):
    free, fenced = tmp_path / "free", tmp_path / "fenced"
    free.mkdir()
    fenced.mkdir()
    for folder in (free, fenced):
        _layout(folder, kind)
    before = tree_listing(free, {free / "out", free / "tmp"})
    _write_everything(free, free / "scene" / "s.blend", confined=False)
    assert tree_listing(free, {free / "out", free / "tmp"}) != before, "the unconfined Blender wrote nothing: no test"
    before = tree_listing(fenced, {fenced / "out", fenced / "tmp"})
    proc = _write_everything(fenced, fenced / "scene" / "s.blend", confined=True)
    assert tree_listing(fenced, {fenced / "out", fenced / "tmp"}) == before, proc.stdout[-3000:]
    assert "render {'FINISHED'}" in proc.stdout or kind == "fluid", proc.stdout[-3000:] + proc.stderr[-3000:]
