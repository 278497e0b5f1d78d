"""Private scratch (issue 41): another user of the machine plants links, in the shared temporary
folder, at the names Dask, Blender and our own processes would write (Dask's
dask-scratch-space/global.lock, purge.lock and *.dirlock, which it opens with "wb"; Blender's crash
log and quit file), pointing at files of the victim's. Dask at its defaults empties them; a
render-series run, a read in the reader process and a render-blend run change none of them, and
leave the shared folder as they found it (engine/scratch.py: every temporary file of a run lives in
a private 0700 folder made for it, removed at its end). The shared folder is a sticky 1777 folder
standing in for /tmp (TMPDIR); the links are planted by a child that became uid 65534."""
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from tests.helpers import data_file, tree_listing

pytest.importorskip("distributed")
REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow
if not hasattr(os, "geteuid") or os.geteuid() != 0:
    pytest.skip("planting links as another user needs root (setuid to uid 65534)", allow_module_level=True)

NOBODY = 65534
# where Dask (its workspace lock files), Blender (its crash log and quit file, named by the .blend)
# and a careless program would write in the temporary folder
PLANTED = ("dask-scratch-space/global.lock", "dask-scratch-space/purge.lock", "dask-scratch-space/worker-x.dirlock",
           "s.crash.txt", "blender.crash.txt", "quit.blend")


def _plant(shared: Path, victims: list[Path]):
    """As uid 65534: dask-scratch-space (mode 0777) in `shared`, and a link at each PLANTED name to a victim."""
    pid = os.fork()
    if pid == 0:  # the other user
        try:
            os.setgroups([])
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            (shared / "dask-scratch-space").mkdir()
            os.chmod(shared / "dask-scratch-space", 0o777)
            for name, victim in zip(PLANTED, victims):
                os.symlink(victim, shared / name)
            os._exit(0)
        except BaseException:  # noqa: BLE001
            os._exit(1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, "planting the links failed"


@pytest.fixture
def attacked(tmp_path):
    """(shared temporary folder with the links planted, the victim's files, their contents)."""
    home = tmp_path / "home"
    home.mkdir()
    victims = [home / f"file{k}.txt" for k in range(len(PLANTED))]
    for k, v in enumerate(victims):
        v.write_text(f"the victim's file {k}\n")
    shared = Path(tempfile.mkdtemp(prefix="shared-tmp-", dir="/tmp"))  # /tmp's own sticky bit applies above it
    os.chmod(shared, 0o1777)
    try:
        _plant(shared, victims)
        yield shared, victims
    finally:
        shutil.rmtree(shared, ignore_errors=True)


def _contents(victims):
    return [v.read_bytes() for v in victims]


DASK_DEFAULTS = textwrap.dedent("""
    from distributed import Client, LocalCluster
    if __name__ == "__main__":
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as c:
            with Client(c) as client:
                print(client.submit(sum, [1, 2]).result())
""")


def test_dask_at_its_defaults_writes_through_the_links(attacked, tmp_path):
    """The attack is real: a LocalCluster with its default scratch empties the victim's files."""
    shared, victims = attacked
    before = _contents(victims)
    script = tmp_path / "dask_defaults.py"
    script.write_text(DASK_DEFAULTS)
    subprocess.run([sys.executable, str(script)], env=dict(os.environ, TMPDIR=str(shared)), capture_output=True,
                   timeout=180, check=True)
    assert _contents(victims) != before


def _hovr(args, shared, cwd):
    env = dict(os.environ, TMPDIR=str(shared), PYTHONPATH=str(REPO))
    env.pop("TEMP", None)
    env.pop("TMP", None)
    return subprocess.run([sys.executable, "-m", "hovr_blender.cli", *args], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def test_our_runs_write_nothing_through_the_links_nor_leave_anything(attacked, tmp_path):
    shared, victims = attacked
    before, listing = _contents(victims), tree_listing(shared)
    work = tmp_path / "work"
    (work / "out").mkdir(parents=True)
    sphere = {"data": {"builtin": "sphere"}, "image": {"width": 16, "height": 12},
              "camera": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0], "fov_y_deg": 40},
              "transfer_function": {"color": [[0, 1, 1, 1], [1, 1, 0, 0]], "density": [[0, 1], [1, 5]]},
              "background": [0, 0, 0]}
    (work / "sphere.json").write_text(json.dumps(sphere))
    runs = [["render-series", str(work / "sphere.json"), "-o", str(work / "out" / "f_####.npy"), "--frames", "1-3",
             "--workers", "2", "--device", "cpu"]]
    mesh, fld = data_file("nektar", "Tet_channel_m3.xml"), data_file("nektar", "Tet_channel_m3.fld")
    (work / "tet.json").write_text(json.dumps({**sphere, "data": {"path": str(mesh), "solution": str(fld),
                                                                  "field": "w"}}))
    runs.append(["render", str(work / "tet.json"), "-o", str(work / "tet.npy")])  # the reader process
    if importlib.util.find_spec("bpy") is not None:
        (work / "scene").mkdir()
        subprocess.run([sys.executable, str(REPO / "tests" / "hostile" / "make_blend.py"), "plain",
                        str(work / "scene" / "s.blend")], check=True, capture_output=True, timeout=300)
        runs.append(["render-blend", str(work / "scene" / "s.blend"), "--frames", "1", "--workers", "1"])
    for args in runs:
        proc = _hovr(args, shared, work)
        assert proc.returncode == 0, (args[0], proc.stderr[-2000:])
    assert _contents(victims) == before
    assert tree_listing(shared) == listing  # nothing of ours written there, nothing left behind
    assert len(list((work / "out").glob("f_*.npy"))) == 3 and (work / "tet.npy").exists()
