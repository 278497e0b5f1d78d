"""The reader process (io/isolation.py): files are read in a separate process and come back equal
to a read in this one; a crash, a hang, a cancel or a broken reply there is one clear error here,
the process is gone, and the next read works; reader processes end with their parent."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from hovr_blender.engine import limits
from hovr_blender.io import isolation, nektar, reader_protocol, vtu
from hovr_blender.io.sources import SourceError, VolumeSource, load_volume, read_volume
from tests.helpers import REPO, data_file, stopped_warm_reader

from ..engine.test_derived_fields import geometry, q_mesh, velocity_components  # noqa: F401  (fixtures)


def _tet():
    return VolumeSource.resolve(str(data_file("nektar", "Tet_channel_m3.xml")), field="w")


def _gone(pid, seconds=5.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # our own child: reap it, else it lingers as a zombie
            if os.waitpid(pid, os.WNOHANG)[0]:
                return True
        except ChildProcessError:
            pass
        time.sleep(0.05)
    return False


def _started(task, args, seconds=60.0, what="m.fld"):
    request = isolation.Request(task, args, seconds, what)
    assert request.pid is not None
    return request


def test_a_read_in_the_reader_process_equals_one_here():
    source = _tet()
    here = read_volume(source)
    there = load_volume(source)
    for name in ("shape", "vertices", "ref_from_world", "modes", "coeff_offset", "coeffs", "geom_coeffs", "affine",
                 "element_ids"):
        np.testing.assert_array_equal(getattr(there, name), getattr(here, name), err_msg=name)
    assert (there.field_name, there.has_field, there.warnings) == (here.field_name, here.has_field, here.warnings)


def test_listings_and_walls_come_back_as_the_readers_give_them():
    mesh, fld = data_file("nektar", "Tet_channel_m3.xml"), data_file("nektar", "Tet_channel_m3.fld")
    assert isolation.list_fields("nektar", fld) == nektar.list_fields(fld)
    assert isolation.wall_choices("nektar", mesh) == nektar.mesh_boundaries(mesh).choices()
    got, want = isolation.wall_faces("nektar", mesh, "C[1]"), nektar.mesh_boundaries(mesh).select("C[1]")
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_reader_errors_keep_their_class_and_words(tmp_path):
    with pytest.raises(nektar.NektarError, match="no field 'zz'"):
        load_volume(VolumeSource.resolve(str(data_file("nektar", "Tet_channel_m3.xml")), field="zz"))
    (tmp_path / "m.vtu").write_text("<VTKFile/>")
    with pytest.raises(vtu.VtuError, match="m.vtu"):
        isolation.list_fields("vtu", tmp_path / "m.vtu")
    with pytest.raises(SourceError, match="not found"):
        load_volume(VolumeSource(str(tmp_path / "missing.xml")))


def test_a_crash_in_the_reader_is_one_line_naming_the_file_and_the_next_read_works():
    pid = stopped_warm_reader()
    request = _started("list_fields", {"kind": "nektar", "path": "hump3D_GLL.xml"}, what="hump3D_GLL.xml")
    os.kill(pid, signal.SIGSEGV)
    os.kill(pid, signal.SIGCONT)
    while not request.poll(1.0):
        pass
    with pytest.raises(isolation.ReaderFailure, match=r"hump3D_GLL.xml: the reader process crashed \(SIGSEGV\)") as info:
        request.value()
    assert "\n" not in str(info.value)
    assert _gone(pid)
    assert load_volume(_tet()).num_elements == 48


def test_a_hang_is_stopped_at_the_time_limit():
    request = _started("read_volume", {"path": str(data_file("nektar", "hump3D_GLL.xml")), "solution": "",
                                        "field": "", "component": ""}, seconds=1.5)
    while request.stage == "starting the reader":  # the limit runs from the reader's start
        request.poll(0.05)
    t0 = time.monotonic()
    pid = request.pid
    os.kill(pid, signal.SIGSTOP)  # as good as libhdf5's endless loop
    while not request.poll(0.5):
        pass
    assert time.monotonic() - t0 < 5.0
    with pytest.raises(isolation.ReaderFailure, match="longer than the limit of 1.5 s"):
        request.value()
    assert _gone(pid)


def test_the_time_limit_comes_from_the_resource_limits(monkeypatch):
    monkeypatch.setenv("HOVR_MAX_READ_SECONDS", "0.001")
    with pytest.raises(isolation.ReaderFailure, match="longer than the limit of 0.001 s"):
        load_volume(_tet())


def test_cancel_kills_the_reader():
    pid = stopped_warm_reader()
    request = _started("list_fields", {"kind": "nektar", "path": str(data_file("nektar", "Tet_channel_m3.fld"))})
    assert request.pid == pid and not request.poll(0.2)
    request.cancel()
    with pytest.raises(isolation.ReadCancelled):
        request.value()
    assert _gone(pid)


def test_cancel_through_call():
    stopped_warm_reader()
    with pytest.raises(isolation.ReadCancelled):
        isolation.call("list_fields", {"kind": "nektar", "path": str(data_file("nektar", "Tet_channel_m3.fld"))},
                       cancelled=lambda: True)


def test_xml_elements_count_against_the_memory_limit(tmp_path):
    (tmp_path / "m.xml").write_text("<NEKTAR>" + "<a/>" * 1_000_000 + "</NEKTAR>")
    with limits.using(limits.ResourceLimits(max_memory=64 << 20)):
        with pytest.raises(nektar.NektarError, match="memory limit"):
            load_volume(VolumeSource(str(tmp_path / "m.xml")))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS is Linux's")
def test_the_reader_address_space_grows_by_the_memory_limit_only_and_a_header_read_by_little():
    code = ("from hovr_blender.engine import limits\n"
            "limits.own_address_space()\n"
            "limits.cap_address_space(64 << 20)\n"
            "try:\n    bytearray(512 << 20)\nexcept MemoryError:\n    print('refused')\n"
            "with limits.small_allocations(16 << 20):\n"
            "    try:\n        bytearray(32 << 20)\n    except MemoryError:\n        print('refused in the block')\n"
            "bytearray(32 << 20)\nprint('the cap is back after it')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(REPO)), check=True)
    assert out.stdout.split("\n")[:3] == ["refused", "refused in the block", "the cap is back after it"]


def test_only_plain_data_leaves_the_reader():
    with pytest.raises(TypeError):
        reader_protocol.encode(np.array([object()]), [])
    with pytest.raises(TypeError):
        reader_protocol.encode({"f": len}, [])
    arrays = []
    tree = reader_protocol.encode({"a": (np.arange(3), "x", 1.5)}, arrays)
    json.dumps(tree)  # JSON only
    assert reader_protocol.decode(tree, arrays)["a"][1:] == ("x", 1.5)
    with pytest.raises(isolation.ReaderFailure):
        reader_protocol.decode({"$pickle": "..."}, [])


def test_the_switch_reads_here(monkeypatch):
    monkeypatch.setenv("HOVR_ISOLATION", "0")
    assert not isolation.enabled()
    assert load_volume(_tet()).num_elements == 48


def test_the_interpreter_is_python_not_blender(monkeypatch):
    assert os.path.basename(isolation.interpreter()).lower().startswith("python")
    monkeypatch.setattr(sys, "executable", "/opt/blender/blender")
    assert os.path.basename(isolation.interpreter()).lower().startswith("python")


_EXTENSION = textwrap.dedent("""
    import importlib, json, runpy, sys
    folder = sys.argv[1] + "/hovr_blender"
    name = "fake_bl_ext.user_repo.hovr_blender"  # as Blender names an installed extension
    runpy.run_path(folder + "/engine/bootstrap.py")["import_package"](name, folder)
    sources = importlib.import_module(name + ".io.sources")
    isolation = importlib.import_module(name + ".io.isolation")
    mesh = sources.load_volume(sources.VolumeSource.resolve(sys.argv[2], field="w"))
    reader = isolation._IDLE[0].proc.pid
    with open(f"/proc/{reader}/cmdline", "rb") as fh:
        config = json.loads(fh.read().split(b"\\0")[-2])
    print(json.dumps({"elements": mesh.num_elements, "mesh_class": type(mesh).__module__,
                      "reader_package": config["package"], "importable": "hovr_blender" in sys.modules}))
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the reader's command line from /proc")
def test_the_reader_loads_the_package_under_the_parents_name_as_the_device_processes_do():
    """An installed extension's package (bl_ext.<repo>.hovr_blender, no folder on sys.path gives
    it): the reader process loads it from its folder under that name, through the one bootstrap
    the render devices' processes use (engine/bootstrap.py)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", _EXTENSION, str(REPO), str(data_file("nektar", "Tet_channel_m3.xml"))],
                          env=env, cwd="/", capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.splitlines()[-1])
    assert out == {"elements": 48, "mesh_class": "fake_bl_ext.user_repo.hovr_blender.engine.mesh",
                   "reader_package": "fake_bl_ext.user_repo.hovr_blender", "importable": False}


_PARENT = textwrap.dedent("""
    import os, sys, time
    from hovr_blender.io import isolation
    request = isolation.Request("list_fields", {"kind": "nektar", "path": sys.argv[1]}, 600.0)
    while not request.poll(0.1):
        pass
    idle = isolation._IDLE[0].proc.pid  # the warm one, between tasks
    busy = isolation.Request("list_fields", {"kind": "nektar", "path": sys.argv[1]}, 600.0)
    os.kill(busy.pid, 19)  # SIGSTOP: a reader stuck inside a C loop
    print(idle, busy.pid, flush=True)
    time.sleep(600)
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux process checks")
def test_reader_processes_end_with_their_parent():
    parent = subprocess.Popen([sys.executable, "-c", _PARENT, str(data_file("nektar", "Tet_channel_m3.fld"))],
                              stdout=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        idle, busy = (int(v) for v in parent.stdout.readline().split())
    finally:
        parent.kill()
        parent.wait()
    assert _gone(idle), "the idle reader outlived its parent"
    assert _gone(busy), "the stuck reader outlived its parent"


_BARE_READ = "import sys; from hovr_blender.io.nektar import list_fields; list_fields(sys.argv[1])"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="signals")
@pytest.mark.parametrize("mutant,outcome", [("VLEN_TYPE_BITS", "crash"), ("HEAP_OBJECT_SIZE", "hang")])
def test_the_hostile_hdf5_mutants_crash_or_hang_libhdf5_itself(tmp_path, mutant, outcome):
    """The hostile suite's HDF5 cases are what the issue found: read without the reader process
    (list_fields here, in a bare Python), libhdf5 itself crashes or never returns. Should a
    libhdf5 release fix one, this fails: the case then no longer shows containment."""
    from tests.hostile import cases

    getattr(cases, mutant)(tmp_path / "m.fld")
    proc = subprocess.Popen([sys.executable, "-c", _BARE_READ, str(tmp_path / "m.fld")], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(REPO)))
    try:
        code = proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        code = "hang"
    assert (code == -signal.SIGSEGV) if outcome == "crash" else (code == "hang"), code
    with pytest.raises(isolation.ReaderFailure, match="m.fld"):
        with limits.using(limits.ResourceLimits(max_read_seconds=2.0)):
            isolation.list_fields("nektar", tmp_path / "m.fld")


def test_a_sample_of_the_hdf5_byte_flip_fuzzer(tmp_path):
    """tests/fuzz/hdf5_mutation.py on 30 mutants, the hostile suite's three first: each loads or
    is refused with one line naming the file; this process lives on."""
    from tests.fuzz import hdf5_mutation as fuzz

    items = fuzz.mutants(np.random.default_rng(7), fuzz.sources(tmp_path), 30, tmp_path)
    summary = fuzz.run_here(items, tmp_path, seconds=2.0)
    assert summary["mutants"] == 30 and not summary["problems"], summary
    assert summary["outcomes"].get("reader crashed", 0) >= 1, summary  # the SIGSEGV mutant, contained
    assert summary["outcomes"].get("reader stopped (time limit)", 0) >= 1, summary  # the heap loop, stopped
    assert summary["outcomes"].get("refused", 0) >= 1, summary  # the 4 GiB string: a header's allocations are capped


def test_derived_mesh_leaves_the_reader_process(q_mesh):
    """The reader process's encoding carries the components (io/reader_protocol.py encode / decode)."""
    from hovr_blender.io.reader_protocol import decode, encode

    arrays = []
    back = decode(encode(q_mesh, arrays), arrays)
    assert back.derived.spec == q_mesh.derived.spec and back.derived.components == 3
    for name in ("modes", "offset", "size", "coeffs", "axes", "derived"):
        np.testing.assert_array_equal(getattr(back.derived, name), getattr(q_mesh.derived, name))
