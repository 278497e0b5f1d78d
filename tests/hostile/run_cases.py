"""Issue 29's hostile runs, beside the readers' cases (cases.py): what a view, a command line or a
.blend chooses that the run must refuse or confine: processes, file sizes, frame ranges, output
links, duplicate keys, transfer-function magnitudes, fixed steps, the render-series cluster and
render-blend. Built fresh in a folder like the others; `after(folder, outcome)` checks what the
run left behind (a marker a script would write, a link's target, the pixels).

The .blend files are written by make_blend.py in a child process with the bpy module (skipped
where there is none), so the runner never imports bpy.
"""
from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import unittest
from pathlib import Path

import numpy as np

from tests.helpers import tree_listing

from .cases import base_view, nektar_field, nektar_mesh, render_args
from .harness import Case, write_view

# A refusal made by a frame's task comes after the local cluster's start (TLS keys, a worker
# process importing Dask: 3-5 s on an idle 2-core machine), and render-blend's after Blender's
# start too; those cases get this limit (the table prints the time each took).
CLUSTER_SECONDS = 30.0
# Blender's own process rendering a legitimate frame (bpy 5.0 with Workbench): 400 MB here, 556 MB
# on CI's machine; the hostile part (a text block that must not run) adds nothing to it
BLENDER_RENDER_PEAK_MB = 800.0
SPHERE_TF = {"color": [[0.0, 1.0, 1.0, 1.0], [1.0, 1.0, 0.0, 0.0]], "density": [[0.0, 1.0], [1.0, 5.0]]}


def _sphere_view(folder: Path, **render) -> dict:
    v = base_view({"builtin": "sphere"}, 16, 12)
    v["camera"] = {"projection": "perspective", "eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0],
                   "fov_y_deg": 40}
    v["transfer_function"] = SPHERE_TF
    v["render"].update(render)
    return v


# ------------------------------------------------------------------------------ view files

def _devices(n):
    def build(folder):
        return render_args(folder, _sphere_view(folder, device=",".join(["cpu"] * n)))
    return build


def _sparse_view(folder):
    """A view file of 3.9 GB, all but its first bytes a hole: refused on its size (fstat), unread."""
    p = folder / "view.json"
    with open(p, "wb") as fh:
        fh.write(json.dumps(_sphere_view(folder)).encode())
        fh.truncate(3_900_000_000)
    return ["render", str(p), "-o", str(folder / "out.npy")]


def _duplicate_data(folder):
    """Two "data" keys: json.loads would keep the second and render another dataset."""
    (folder / "m.xml").write_text(nektar_mesh())
    (folder / "m.fld").write_text(nektar_field())
    text = json.dumps(_sphere_view(folder))
    text = text.replace('"data": {', '"data": {"path": "m.xml", "solution": "m.fld", "field": "p"}, "data": {', 1)
    p = folder / "view.json"
    p.write_text(text)
    return ["render", str(p), "-o", str(folder / "out.npy")]


def _tf_extreme(folder):
    v = _sphere_view(folder)
    v["transfer_function"] = {"color": [[-1e308, 1, 1, 1], [1e308, 1, 0, 0]], "density": [[-1e308, 1], [1e308, 1]]}
    return render_args(folder, v)


def _riemann_h(h):
    def build(folder):
        return render_args(folder, _sphere_view(folder), "--method", "riemann", "--h", str(h))
    return build


def _contract_holds(folder, outcome):
    """C <= kappa_max (1 - T) within the Riemann factor at one e-folding a step (1.582, contract §3)."""
    if outcome.returncode != 0:
        return []
    rgba = np.load(folder / "out.npy")
    excess = float((rgba[..., :3].max(axis=-1) - 1.582 * rgba[..., 3]).max())  # kappa_max = 1; background 0
    problems = [] if excess <= 1e-3 else [f"RGB exceeds 1.582 kappa_max (1 - T) by {excess:.3g}"]
    if "cannot resolve the data" not in outcome.stderr:
        problems.append(f"no warning that the step was shortened: {outcome.stderr[-300:]!r}")
    return problems


# ------------------------------------------------------------------------------ render-series

def _series_view(folder: Path) -> Path:
    return write_view(folder, _sphere_view(folder))


def _series(frames, *extra, out="out/f_####.npy"):
    def build(folder):
        (folder / "out").mkdir(exist_ok=True)
        return ["render-series", str(_series_view(folder)), "-o", str(folder / out), "--frames", frames,
                "--workers", "1", "--device", "cpu", *extra]
    return build


def _camera_path(place):
    def build(folder):
        place(folder / "cams.json")
        return _series("1-2", "--camera-path", str(folder / "cams.json"))(folder)
    return build


def _planted(name, target_name):
    """A link named `name` in the output folder pointing at `target_name` beside it (dangling)."""
    def build(folder):
        args = _series("1-2", "--png")(folder)
        os.symlink(folder / target_name, folder / "out" / name)
        return args
    return build


def _target_untouched(target_name):
    def after(folder, outcome):
        return [f"the link's target {target_name} was created"] if os.path.lexists(folder / target_name) else []
    return after


def _frame_refused(folder):
    """Frame 2's data is a FIFO: the worker refuses it; the run ends with that frame's one line,
    not retried (a retry would block again or print Dask's tracebacks)."""
    (folder / "m_0001.xml").write_text(nektar_mesh())
    os.mkfifo(folder / "m_0002.xml")
    v = base_view({"path": "m_####.xml"}, 16, 12)
    (folder / "out").mkdir()
    return ["render-series", str(write_view(folder, v)), "-o", str(folder / "out" / "f_####.npy"), "--frames", "2",
            "--workers", "1", "--device", "cpu"]


# ------------------------------------------------------------------------------ render-blend

def _blend(kind, *extra, marker="marker"):
    """A .blend of make_blend.py's `kind` in folder/scene/, rendered by render-blend."""
    def build(folder):
        if importlib.util.find_spec("bpy") is None:
            raise unittest.SkipTest("render-blend needs the bpy module (Blender as a Python module)")
        (folder / "scene").mkdir()
        blend = folder / "scene" / "s.blend"
        subprocess.run([sys.executable, str(Path(__file__).with_name("make_blend.py")), kind, str(blend),
                        str(folder / marker)], check=True, capture_output=True, timeout=120)
        return ["render-blend", str(blend), "--workers", "1",
                *[a.format(d=folder) for a in extra]]
    return build


def _no_marker(folder, outcome):
    return ["the .blend's registered text block ran"] if (folder / "marker").exists() else []


_TREES: dict = {}  # folder -> its tree once the hostile .blend was made


def _writing_blend(kind):
    """make_blend.py's `kind`, whose datablocks name ./elsewhere (a folder of the user's, with a
    file in it) or the .blend's own folder, rendered with -o ./out: nothing outside ./out may change."""
    def build(folder):
        args = _blend(kind, "--frames", "1-2", "-o", "{d}/out", marker="elsewhere")(folder)
        for leftover in ("elsewhere", "scene/blendcache_s"):  # what making the .blend wrote
            shutil.rmtree(folder / leftover, ignore_errors=True)
        (folder / "out").mkdir()
        (folder / "elsewhere").mkdir()
        (folder / "elsewhere" / "notes.txt").write_text("the user's")
        _TREES[str(folder)] = tree_listing(folder, [folder / "out"])
        return args
    return build


def _nothing_outside_out(folder, outcome):
    before = _TREES.pop(str(folder))
    after = tree_listing(folder, [folder / "out"])
    changed = sorted(set(before.items()) ^ set(after.items()))
    return [f"wrote outside -o: {changed[:6]}"] if changed else []


RUN_CASES = [
    # one resource budget per run
    Case('view "device": 18 x cpu', "run budget", _devices(18), expect=("18 processes", "HOVR_MAX_PROCESSES")),
    Case("sparse 3.9 GB view file", "run budget", _sparse_view, expect=("view file", "at most")),
    Case("render-series --workers 64", "run budget", _series("1", "--workers", "64"), expect=("64 processes",)),
    Case("--camera-path a FIFO", "run budget", _camera_path(os.mkfifo), expect=("FIFO",)),
    Case("--camera-path /proc/self/mem", "run budget", _camera_path(lambda p: os.symlink("/proc/self/mem", p)),
         expect=("cams.json", "cannot be read")),
    Case("--camera-path /dev/zero", "run budget", _camera_path(lambda p: os.symlink("/dev/zero", p)),
         expect=("device",)),
    Case("--camera-path with a key twice", "run budget",
         _camera_path(lambda p: p.write_text('{"first_frame": 1, "first_frame": 2, "cameras": []}')),
         expect=("twice",)),
    # messages
    Case("--frames -1", "messages", _series("-1"), expect=("--frames", "not a frame range")),
    Case("--frames 1-100000000", "messages", _series("1-100000000"), expect=("more than 1000000 frames",)),
    Case('view with "data" twice', "messages", _duplicate_data, expect=("'data' appears twice",)),
    Case("transfer function at +-1e308", "messages", _tf_extreme, expect=("1e+30",)),
    Case("render-series: a frame's data refused on the worker", "messages", _frame_refused,
         expect=("frame 2", "FIFO"), max_seconds=CLUSTER_SECONDS),
    # outputs never follow links
    Case("render-series: .hovr-series.log a dangling link", "output links",
         _planted(".hovr-series.log", "created-by-log"), expect=(".hovr-series.log", "symbolic link"),
         after=_target_untouched("created-by-log")),
    Case("render-series: frame's .png a planted link", "output links", _planted("f_0002.png", "png-target"),
         expect=("f_0002.png", "symbolic link"), after=_target_untouched("png-target")),
    # the contract holds for fixed steps
    Case("riemann h = 1e6 stepped at one e-folding", "fixed steps", _riemann_h(1e6), expect_rc=0,
         after=_contract_holds),
    # render-blend confined
    Case("render-blend: a Register text block", "render-blend", _blend("register", "--frames", "1"), expect_rc=0,
         after=_no_marker, max_seconds=CLUSTER_SECONDS, max_peak_mb=BLENDER_RENDER_PEAK_MB),
    Case("render-blend: an endless driver", "render-blend", _blend("driver", "--frames", "2", "--frame-timeout", "2"),
         expect=("per-frame limit",), max_seconds=CLUSTER_SECONDS),
    Case("render-blend: output path outside its folder", "render-blend", _blend("outside", "--frames", "1"),
         expect=("elsewhere", "outside its own folder"), max_seconds=CLUSTER_SECONDS),
    Case("render-blend: absolute output path", "render-blend",
         _blend("absolute", "--frames", "1", marker="abs/frame_####"), expect=("abs/frame_0001", "refused"),
         max_seconds=CLUSTER_SECONDS),
    Case("render-blend: -o a missing folder", "render-blend", _blend("plain", "--frames", "1", "-o", "{d}/none"),
         expect=("no such folder",)),
    # render-blend: datablocks that write (Landlock confines Blender on Linux, ui/batch.py refuses first)
    Case("render-blend: fluid cache folder elsewhere", "render-blend writes", _writing_blend("fluid"),
         expect=("fluid cache folder", "elsewhere", "refused"), after=_nothing_outside_out,
         max_seconds=CLUSTER_SECONDS),
    Case("render-blend: point cache on disk beside the .blend", "render-blend writes", _writing_blend("pointcache"),
         expect=("disk cache", "blendcache_s", "refused"), after=_nothing_outside_out, max_seconds=CLUSTER_SECONDS),
    Case("render-blend: ocean bake folder elsewhere", "render-blend writes", _writing_blend("ocean"), expect_rc=0,
         after=_nothing_outside_out, max_seconds=CLUSTER_SECONDS, max_peak_mb=BLENDER_RENDER_PEAK_MB),
    Case("render-blend: Alembic exporter to elsewhere", "render-blend writes", _writing_blend("alembic"), expect_rc=0,
         after=_nothing_outside_out, max_seconds=CLUSTER_SECONDS, max_peak_mb=BLENDER_RENDER_PEAK_MB),
]
