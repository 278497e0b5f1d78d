"""Long waits in Blender without background threads (Blender supports Python threads only when
they end before the script that started them; ui/jobs.py says why): an import read in
stages with its progress, the same volume as before, a failed read making nothing, and F12
compiling the render kernels in place, saying so, once a session."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import engine as render_engine  # noqa: E402
from hovr_blender.ui import import_operators, jobs  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import copy_tet, render_to_exr  # noqa: E402


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
