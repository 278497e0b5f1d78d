"""Long waits in Blender without background threads (Blender supports Python threads only when
they end before the script that started them; ui/jobs.py says why): an import read in
stages with its progress, the same volume as before, a failed read making nothing; the file
browser's import modal (a timer polls the reader process, the status bar shows the stages, Esc
or right-click cancels and the scene is unchanged), driven here by synthetic events, as a
window-less Blender cannot hold a modal handler (the Xvfb window test presses Esc for real);
and F12 compiling the render kernels in place, saying so, once a session."""
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import engine as render_engine  # noqa: E402
from hovr_blender.ui import import_operators, jobs  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import copy_tet, datablock_counts, render_to_exr  # noqa: E402


class _Reports:
    """Stands in for the operator's report()."""

    def __init__(self):
        self.lines = []

    def report(self, kind, message):
        self.lines.append((set(kind), message))


def test_an_import_runs_in_stages_with_its_progress(scene, tmp_path):
    xml = copy_tet(tmp_path)
    request = import_operators.ImportRequest("nektar", str(xml), "", "|u,v,w|", "", frame=1)
    seen = []
    job = import_operators.import_job(request, on_step=lambda j: seen.append((j.step_index, j.stage))).run()
    assert job.done and job.error is None
    assert [i for i, _ in seen] == list(range(1, request.steps + 1))
    assert seen[1][1] == "reading the data" and job.status().startswith("sampling the field")
    reports = _Reports()
    assert import_operators.finish_import(reports, bpy.context, request, job) == {'FINISHED'}
    via_operator = bpy.ops.import_scene.hovr_nektar(filepath=str(xml), field="|u,v,w|")
    assert via_operator == {'FINISHED'}
    a, b = [o for o in scene.objects if o.hovr.is_volume][-2:]
    assert (a.hovr.value_min, a.hovr.value_max) == (b.hovr.value_min, b.hovr.value_max)


def test_a_failed_read_makes_nothing(scene, tmp_path):
    request = import_operators.ImportRequest("vtu", str(tmp_path / "missing.vtu"), "", "", "", frame=1)
    before = len(bpy.data.objects)
    job = import_operators.import_job(request).run()
    assert job.done and job.error is not None
    reports = _Reports()
    assert import_operators.finish_import(reports, bpy.context, request, job) == {'CANCELLED'}
    assert reports.lines[0][0] == {'ERROR'} and "HOVR: cannot import missing.vtu" in reports.lines[0][1]
    assert len(bpy.data.objects) == before


class _WindowManager:
    """What a modal operator asks of Blender's window manager, recorded: a window-less Blender
    (background mode) cannot hold a modal handler or a timer."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args, **kwargs: self.calls.append((name, args)) or name


class _Context:
    """bpy.context with the recorded window manager and a window."""

    def __init__(self, wm):
        self.window_manager, self.window = wm, SimpleNamespace()

    def __getattr__(self, name):
        return getattr(bpy.context, name)


TIMER = SimpleNamespace(type='TIMER', value='NOTHING')


def _modal_import(tmp_path, field="|u,v,w|"):
    request = import_operators.ImportRequest("nektar", str(copy_tet(tmp_path)), "", field, "", frame=1)
    reports, wm = _Reports(), _WindowManager()
    modal = import_operators.ModalImport(reports, None, request)
    return modal, reports, wm, _Context(wm)


def test_a_modal_import_polls_the_reader_shows_its_stages_and_makes_the_volume(scene, tmp_path):
    modal, reports, wm, context = _modal_import(tmp_path, field="")  # the field listing is a read too
    before = len([o for o in scene.objects if o.hovr.is_volume])
    assert modal.begin(context) == {'RUNNING_MODAL'}
    names = [name for name, _ in wm.calls]
    assert names[:1] == ["progress_begin"] and "event_timer_add" in names and "modal_handler_add" in names
    assert modal.job.waiting is not None and not modal.job.done  # begin() returned while the reader reads
    result, ticks = {'PASS_THROUGH'}, 0
    while result == {'PASS_THROUGH'}:
        assert modal.on_event(context, SimpleNamespace(type='MOUSEMOVE', value='NOTHING')) == {'PASS_THROUGH'}
        result = modal.on_event(context, TIMER)
        ticks += 1
        assert ticks < 2000, modal.phases
        time.sleep(0.01)
    assert result == {'FINISHED'}, reports.lines
    stages = [p.split(" (")[0] for p in modal.phases]
    assert stages[:1] == ["finding the solution and field"] and "reading the data" in stages
    assert stages[-1] == "sampling the field"
    assert any(": starting the reader" in p or ": reading" in p for p in modal.phases), modal.phases
    names = [name for name, _ in wm.calls]
    assert "event_timer_remove" in names and names[-1] == "progress_end"
    assert ("progress_update", (2,)) in wm.calls
    assert len([o for o in scene.objects if o.hovr.is_volume]) == before + 1
    assert reports.lines[0][0] == {'INFO'} and "48 elements" in reports.lines[0][1]


@pytest.mark.parametrize("key", ['ESC', 'RIGHTMOUSE'])
def test_esc_cancels_a_modal_import_kills_the_reader_and_leaves_the_scene_unchanged(scene, tmp_path, key, stopped_reader):
    pid = stopped_reader()  # a read that never ends (libhdf5's endless loop)
    modal, reports, wm, context = _modal_import(tmp_path)
    before = datablock_counts()
    assert modal.begin(context) == {'RUNNING_MODAL'}
    for _ in range(5):
        assert modal.on_event(context, TIMER) == {'PASS_THROUGH'}
    assert modal.job.waiting.pid == pid and modal.phases[-1] == "reading the data (2/4): starting the reader"
    assert modal.on_event(context, SimpleNamespace(type=key, value='PRESS')) == {'CANCELLED'}
    assert modal.job.cancelled and isinstance(modal.job.error, import_operators.isolation.ReadCancelled)
    assert datablock_counts() == before
    assert len(reports.lines) == 1 and reports.lines[0][0] == {'WARNING'}
    assert "import of Tet_channel_m3.xml cancelled (reading the data); nothing was made" in reports.lines[0][1]
    names = [name for name, _ in wm.calls]
    assert "event_timer_remove" in names and names[-1] == "progress_end"
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:  # killed, and reaped by the cancel
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        pytest.fail(f"the reader process {pid} outlived the cancel")
    # the next import reads in a fresh reader process
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(copy_tet(tmp_path / "again")), field="|u,v,w|") == {'FINISHED'}


def test_blender_ending_a_modal_import_stops_the_reader(scene, tmp_path, stopped_reader):
    """Blender cancels a running modal operator when a file is loaded or its window closes: the
    operator's cancel() stops the reader, and nothing is made or reported."""
    pid = stopped_reader()
    modal, reports, wm, context = _modal_import(tmp_path)
    before = datablock_counts()
    modal.begin(context)
    modal.stop(context)
    assert modal.job.done and modal.job.cancelled and datablock_counts() == before and not reports.lines
    with pytest.raises(ProcessLookupError):
        for _ in range(100):
            os.kill(pid, 0)
            time.sleep(0.05)


def test_a_modal_import_that_fails_before_reading_ends_at_once(scene, tmp_path):
    request = import_operators.ImportRequest("vtu", str(tmp_path / "missing.vtu"), "", "f", "sideways", frame=1)
    reports, wm = _Reports(), _WindowManager()
    modal = import_operators.ModalImport(reports, None, request)
    before = datablock_counts()
    assert modal.begin(_Context(wm)) == {'CANCELLED'}
    assert "modal_handler_add" not in [name for name, _ in wm.calls]
    assert reports.lines[0][0] == {'ERROR'} and "component 'sideways'" in reports.lines[0][1]
    assert datablock_counts() == before


class _Layout:
    """Stands in for a UILayout: records the labels drawn."""

    def __init__(self):
        self.labels = []

    def box(self):
        return self

    def label(self, text="", icon='NONE'):
        self.labels.append(text)


def test_the_import_dialog_never_waits_for_the_reader(scene, tmp_path, stopped_reader):
    """Browsing to a file the reader hangs on (libhdf5's loops) draws at once, saying the fields
    are being read; a timer redraws once the reader has answered."""
    import signal

    xml = copy_tet(tmp_path)
    nektar = import_operators.formats.named("nektar")
    pid = stopped_reader()
    layout, t0 = _Layout(), time.monotonic()
    import_operators.draw_solution_choice(layout, str(xml), nektar)
    import_operators.draw_wall_choices(layout, str(xml), nektar)
    assert time.monotonic() - t0 < 5.0  # (a wait would be the listing's limit: 30 s)
    assert "Fields: reading..." in layout.labels and "Reading the file's composites..." in layout.labels
    assert bpy.app.timers.is_registered(import_operators._poll_listings)
    os.kill(pid, signal.SIGCONT)
    deadline = time.monotonic() + 60
    while import_operators._poll_listings() is not None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    layout = _Layout()
    import_operators.draw_solution_choice(layout, str(xml), nektar)
    import_operators.draw_wall_choices(layout, str(xml), nektar)
    assert "Fields: u, v, w, p" in layout.labels and "Walls From (empty: all boundary faces):" in layout.labels
    bpy.app.timers.unregister(import_operators._poll_listings)


class _Stats:
    """Wraps the engine: records the stats lines."""

    def __init__(self, engine, lines):
        self._engine, self._lines = engine, lines

    def __getattr__(self, name):
        return getattr(self._engine, name)

    def update_stats(self, a, b):
        self._lines.append(b)
        self._engine.update_stats(a, b)


def test_f12_compiles_in_place_once_saying_so(scene, tmp_path, monkeypatch):
    """A session's first F12 compiles what it needs (or loads it from Warp's disk cache) and says
    so in the status line; the next F12 compiles nothing."""
    compiled = []

    def compile_key(key):
        jobs.compile_render_kernels(key)
        compiled.append(key)

    monkeypatch.setattr(jobs.KERNELS, "compile_key", compile_key)
    monkeypatch.setattr(jobs.KERNELS, "_ready", set())
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    lines = []
    monkeypatch.setattr(render_engine, "_engine_api", lambda engine: _Stats(engine, lines))
    got = render_to_exr(scene, tmp_path / "f12.exr")
    stages = (jobs.KERNELS.COMPILING, jobs.KERNELS.LOADING)  # loading where the add-on ships them compiled
    assert any(stage in s for s in lines for stage in stages) and len(compiled) == 1
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)
    lines.clear()
    render_to_exr(scene, tmp_path / "again.exr")
    assert len(compiled) == 1 and not any(stage in s for s in lines for stage in stages)
