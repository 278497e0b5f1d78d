"""Long waits in Blender (issue 16): an import read in a background thread, cancelled (the
scene exactly as before) or finished (the same volume as the synchronous import), and the
render kernels compiled in the background, F12 and the viewport waiting for them rather than
compiling a second time. Background mode runs no modal operator, so these drive the functions
the import operator and the engine call (import_operators.import_job / finish_import,
kernel_warmup, render.kernels_pending); the modal operator itself runs in the windowed test."""
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.blender import engine as render_engine  # noqa: E402
from hovr_blender.blender import import_operators, jobs, kernel_warmup, render  # noqa: E402
from hovr_blender.io import sources  # noqa: E402

from ..helpers import SPHERE, data_file  # noqa: E402
from .blender_helpers import copy_tet, datablock_counts, render_to_exr  # noqa: E402


class _Reports:
    """Stands in for the operator's report()."""

    def __init__(self):
        self.lines = []

    def report(self, kind, message):
        self.lines.append((set(kind), message))


def _fingerprint(scene):
    objects = sorted((o.name, o.type, tuple(o.location), o.hovr.is_volume, o.hovr.value_min, o.hovr.value_max,
                      o.hovr.transfer_function.name if o.hovr.transfer_function else None) for o in scene.objects)
    cam = scene.camera
    return (objects, datablock_counts(), len(bpy.data.cameras), cam and (cam.name, tuple(cam.matrix_world.col[3])),
            bpy.context.view_layer.objects.active and bpy.context.view_layer.objects.active.name)


def _request(path, kind="vtu", field=""):
    return import_operators.ImportRequest(kind, str(path), "", field, "", fit_range=True, walls=False,
                                          frame=bpy.context.scene.frame_current)


def test_a_cancelled_import_leaves_the_scene_unchanged(scene):
    """PyFR's velocity magnitude (seconds of reading): cancelled while it reads, the thread stops
    (nothing lands in the data cache) and finishing the import changes nothing."""
    path = data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")
    bpy.ops.hovr.add_sphere_volume()  # the user's volume and look
    bpy.context.active_object.hovr.value_min = -3.0
    sources.clear_cache()
    before = _fingerprint(scene)
    request = _request(path, field="Velocity")
    job = import_operators.import_job(request).start()
    deadline = time.perf_counter() + 30
    while job.stage != "reading the data" and not job.done and time.perf_counter() < deadline:
        time.sleep(0.005)
    assert job.stage == "reading the data" and not job.done
    job.cancel()
    assert job.wait(30)
    assert job.cancelled and job.result is None, (job.error, job._interrupted)
    src = sources.VolumeSource.resolve(request.path, "", "Velocity", request.frame)
    assert src.key not in sources._MESHES  # interrupted before the read ended
    reports = _Reports()
    assert import_operators.finish_import(reports, bpy.context, request, job) == {'CANCELLED'}
    assert reports.lines == [({'WARNING'}, "HOVR: importing pyfr_tgv_hexprism_p4_t4.vtu cancelled; "
                                           "the scene is unchanged")]
    assert _fingerprint(scene) == before


def test_an_import_read_in_the_background_makes_the_same_volume(scene, tmp_path):
    xml = copy_tet(tmp_path)
    request = import_operators.ImportRequest("nektar", str(xml), "", "|u,v,w|", "", frame=1)
    job = import_operators.import_job(request).start()
    assert job.wait(60) and job.error is None
    reports = _Reports()
    assert import_operators.finish_import(reports, bpy.context, request, job) == {'FINISHED'}
    threaded = bpy.context.active_object
    assert reports.lines[0][1].startswith(f"HOVR: {threaded.name}: 48 elements, field |u,v,w|")
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="|u,v,w|") == {'FINISHED'}
    direct = bpy.context.active_object
    for prop in ("source", "solution", "field", "value_min", "value_max", "density", "density_units"):
        assert getattr(threaded.hovr, prop) == getattr(direct.hovr, prop), prop
    assert len(threaded.data.edges) == len(direct.data.edges) and scene.camera is not None
    failed = import_operators.import_job(_request(tmp_path / "missing.vtu")).start()
    assert failed.wait(30) and failed.error is not None
    reports = _Reports()
    assert import_operators.finish_import(reports, bpy.context, _request(tmp_path / "missing.vtu"), failed) \
        == {'CANCELLED'}
    assert reports.lines[0][0] == {'ERROR'} and "HOVR: cannot import missing.vtu" in reports.lines[0][1]


@pytest.fixture
def fresh_warmup(monkeypatch):
    """jobs.WARMUP as in a new session (nothing compiled yet), each compile counted and slowed
    down so that a render certainly meets it running."""
    compiled = []

    def compile_key(key):
        time.sleep(1.0)
        jobs.compile_render_kernels(key)
        compiled.append(key)

    monkeypatch.setattr(jobs.WARMUP, "compile_key", compile_key)
    monkeypatch.setattr(jobs.WARMUP, "_ready", set())
    yield compiled
    jobs.WARMUP.wait_idle()


class _Stats:
    """Wraps the engine: records the stats lines."""

    def __init__(self, engine, lines):
        self._engine, self._lines = engine, lines

    def __getattr__(self, name):
        return getattr(self._engine, name)

    def update_stats(self, a, b):
        self._lines.append(b)
        self._engine.update_stats(a, b)


def test_f12_waits_for_the_background_compile(scene, tmp_path, monkeypatch, fresh_warmup):
    """The warm-up an import starts (kernel_warmup.scene_kernel_keys: the scene's volumes read in
    the thread) is running when F12 starts: F12 says it is waiting, then renders with those
    kernels, compiled once; a second F12 compiles nothing."""
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    lines = []
    monkeypatch.setattr(render_engine, "_engine_api", lambda engine: _Stats(engine, lines))
    kernel_warmup.request(kernel_warmup.scene_kernel_keys(scene))
    assert jobs.WARMUP.busy
    got = render_to_exr(scene, tmp_path / "f12.exr")
    assert any(s.startswith("HOVR | waiting: ") for s in lines), lines
    assert len(fresh_warmup) == 1 and not any(jobs.WARMUP.COMPILING in s for s in lines if "waiting" not in s)
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
    render_to_exr(scene, tmp_path / "again.exr")
    assert len(fresh_warmup) == 1


def test_f12_compiles_in_place_without_a_warmup(scene, tmp_path, monkeypatch, fresh_warmup):
    """Background mode starts no warm-up: F12 compiles what it needs itself, saying so, once."""
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    lines = []
    monkeypatch.setattr(render_engine, "_engine_api", lambda engine: _Stats(engine, lines))
    render_to_exr(scene, tmp_path / "f12.exr")
    assert any(jobs.WARMUP.COMPILING in s for s in lines) and len(fresh_warmup) == 1
    assert not jobs.WARMUP.busy


def test_the_viewport_waits_for_kernels_compiled_in_the_background(scene, fresh_warmup):
    """The Rendered viewport never compiles on Blender's main thread: kernels not compiled yet
    start the warm-up and the viewport shows its words until they are ready."""
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    key = jobs.kernel_key("cpu", "float32", (False, 3), False)
    t0 = time.perf_counter()
    status = render.kernels_pending(key)
    assert time.perf_counter() - t0 < 0.5  # returned at once: the compile runs in the thread
    assert status.startswith(("Reading volume data", "Compiling render kernels (first use)"))
    assert jobs.WARMUP.busy and render.kernels_pending(key) is not None
    assert jobs.WARMUP.wait_idle()
    assert render.kernels_pending(key) is None and fresh_warmup == [key]
