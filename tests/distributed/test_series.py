"""A series of frames over a local Dask cluster (issue 18): 2 worker processes render a 6-frame
numbered field series along a camera path identical to serial renders; a worker killed mid-run
still leaves every frame written exactly once; a rerun writes nothing new."""
import functools
import json
import os
import signal
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from hovr_blender.engine.camera import RayCamera  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.view import View  # noqa: E402
from hovr_blender.distributed import series  # noqa: E402
from hovr_blender.io.sources import VolumeSource, load_volume  # noqa: E402

FRAMES = list(range(1, 7))
W, H = 32, 24

pytestmark = pytest.mark.slow


def _write_field_series(folder):
    """flow_0001.vtu .. flow_0006.vtu: one 3x3x3 brick of linear hexahedra, a field moving with the frame."""
    import meshio

    g = np.linspace(0.0, 1.0, 4)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pts = np.c_[X.ravel(), Y.ravel(), Z.ravel()]
    idx = np.arange(64).reshape(4, 4, 4)
    hexes = [[idx[i, j, k], idx[i + 1, j, k], idx[i + 1, j + 1, k], idx[i, j + 1, k],
              idx[i, j, k + 1], idx[i + 1, j, k + 1], idx[i + 1, j + 1, k + 1], idx[i, j + 1, k + 1]]
             for i in range(3) for j in range(3) for k in range(3)]
    for f in FRAMES:
        s = np.sin(3.0 * pts[:, 0] + 0.5 * f) + pts[:, 1] * pts[:, 2]
        meshio.write(str(folder / f"flow_{f:04d}.vtu"), meshio.Mesh(pts, [("hexahedron", np.array(hexes))],
                                                                     point_data={"s": s}), binary=False)


def _view(folder):
    view = {"data": {"path": "flow_####.vtu", "field": "s"},
            "camera": {"eye": [2.6, -1.9, 1.7], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1], "fov_y_deg": 35},
            "image": {"width": W, "height": H},
            "transfer_function": {"color": [[-1, 0.1, 0.2, 0.9], [0.5, 0.2, 0.9, 0.3], [2, 0.9, 0.2, 0.1]],
                                  "density": [[-1, 0.5], [0.5, 4.0], [2, 1.0]]},
            "background": [0.02, 0.02, 0.03]}
    path = folder / "view.json"
    path.write_text(json.dumps(view))
    return path, view


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c, \
            Client(c) as client:
        yield c, client


def _job(tmp_path):
    _write_field_series(tmp_path)
    path, view = _view(tmp_path)
    (tmp_path / "out").mkdir()
    cams = series.orbit_cameras(view["camera"], FRAMES, 120.0)
    job = series.SeriesJob(view=str(path), frames=FRAMES, output=str(tmp_path / "out" / "frame_####.npy"),
                           cameras=cams, device="cpu")
    return job, cams


def _serial(job, cams):
    view = View.load(job.view)
    out = {}
    for f in FRAMES:
        mesh = load_volume(VolumeSource.resolve(view.data["path"], field="s", frame=f, base_dir=view.base_dir))
        cam = RayCamera.from_contract(cams[f], W, H)
        out[f] = Renderer(mesh, "cpu").render(cam, view.transfer_function, view.background, view.options).rgba
    return out


def _log(job):
    with open(os.path.join(os.path.dirname(job.npy(1)), series.LOG_NAME)) as fh:
        return [json.loads(line) for line in fh]


def test_series_on_two_workers_equals_serial_and_a_rerun_writes_nothing(tmp_path, cluster):
    _, client = cluster
    job, cams = _job(tmp_path)
    records = series.render_series(job, client)
    assert sorted(r["frame"] for r in records) == FRAMES and all(r["status"] == "written" for r in records)
    assert len({r["pid"] for r in records}) == 2  # both workers rendered
    assert any(r["upload"] == "field" for r in records)  # the geometry stayed on the device, the field changed
    serial = _serial(job, cams)
    for f in FRAMES:
        assert np.array_equal(np.load(job.npy(f)), serial[f]), f
    assert sorted(r["frame"] for r in _log(job)) == FRAMES
    before = {f: os.stat(job.npy(f)).st_mtime_ns for f in FRAMES}
    assert series.render_series(job, client) == []  # nothing pending: nothing submitted
    assert series.pending_frames(job) == []
    assert {f: os.stat(job.npy(f)).st_mtime_ns for f in FRAMES} == before
    assert len(_log(job)) == len(FRAMES)
    # even a frame submitted again by hand is not written twice
    assert series.write_frame(job, 3)["status"] == "exists"


def test_a_worker_killed_mid_run_still_gives_every_frame_once(tmp_path, cluster):
    _, client = cluster
    job, cams = _job(tmp_path)
    pids = client.run(os.getpid)
    killed = []

    def kill_a_busy_worker(done, total, rec):
        if killed:
            return
        for _ in range(100):
            busy = [addr for addr, keys in client.processing().items() if keys]
            if busy:
                break
            time.sleep(0.02)
        os.kill(pids[busy[0]], signal.SIGKILL)
        killed.append(busy[0])

    slow = functools.partial(time.sleep, 0.6)  # frames slow enough that one is mid-render when killed
    records = series.render_series(job, client, progress=kill_a_busy_worker, before_render=slow)
    assert killed
    assert sorted(r["frame"] for r in records) == FRAMES
    assert series.pending_frames(job) == []
    logged = [r["frame"] for r in _log(job)]
    assert sorted(logged) == FRAMES  # each frame written exactly once
    serial = _serial(job, cams)
    for f in FRAMES:
        assert np.array_equal(np.load(job.npy(f)), serial[f]), f
    client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed worker


def test_a_series_frame_draws_the_views_isosurfaces_and_planes(tmp_path):
    """A frame of a series is `hovr render`'s image of the same view (both through
    engine/frame.render_frame), isosurfaces and cut planes included: a series once dropped them."""
    from hovr_blender import cli
    from tests.helpers import REPO

    view = json.loads((REPO / "examples" / "sphere_isosurface.json").read_text())
    view["image"] = {"width": W, "height": H}
    assert view["isosurfaces"] and view["planes"]
    path = tmp_path / "view.json"
    path.write_text(json.dumps(view))
    assert cli.main(["render", str(path), "-o", str(tmp_path / "cli.npy")]) == 0
    want = np.load(tmp_path / "cli.npy")
    job = series.SeriesJob(view=str(path), frames=[3], output=str(tmp_path / "frame_####.npy"), device="cpu")
    assert series.write_frame(job, 3)["status"] == "written"
    got = np.load(tmp_path / "frame_0003.npy")
    np.testing.assert_array_equal(got, want)
    without = dict(view, isosurfaces=[], planes=[])
    path.write_text(json.dumps(without))
    assert cli.main(["render", str(path), "-o", str(tmp_path / "plain.npy")]) == 0
    assert np.abs(np.load(tmp_path / "plain.npy") - got).max() > 0.05  # the surfaces show
