"""What bench/ and scripts/ share: where the repository and the project's real data are, what a
result records of its run (the command that reruns it, git's state), numpy values as JSON, and
the suite's measuring helpers (a renderer with its kernels compiled, best-of timing, a result
row, the RGB error). The scenes the tests share too are the package's
(hovr_blender/audit/scenes.py), the audit's datasets and views hovr_blender/audit/datasets.py.

Every script runs as a module from the repository's root (`python -m bench.suite`,
`python -m scripts.audit`), so the package and this module import without touching sys.path.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from hovr_blender.audit.datasets import SHARED as DATA  # noqa: F401  (the real files: one home)
from hovr_blender.audit.scenes import BACKGROUND

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"


def command_line() -> str:
    """The command that reruns this run: `python -m bench.NAME` and its arguments."""
    spec = getattr(sys.modules["__main__"], "__spec__", None)
    program = f"-m {spec.name}" if spec is not None else os.path.relpath(sys.argv[0], REPO)
    return " ".join(["python", program, *sys.argv[1:]])


def git(*args):
    """git's answer here; on a device machine whose copy of .git can be stale, the command
    passes the commit in HOVR_COMMIT (HOVR_COMMIT=$(git rev-parse --short HEAD) where it was sent from)."""
    if args == ("rev-parse", "HEAD") and os.environ.get("HOVR_COMMIT"):
        return os.environ["HOVR_COMMIT"]
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=10).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def git_dirty(out_dir) -> bool:
    """Tracked files changed since the commit, the output folder (rewritten by this run) aside."""
    rel = os.path.relpath(os.path.abspath(out_dir), REPO)
    spec = ["--", ".", f":(exclude){rel}"] if not rel.startswith("..") else []
    return bool(git("status", "--porcelain", "--untracked-files=no", *spec))


def jsonable(o):
    """json.dumps's default=: numpy scalars and arrays as Python numbers and lists."""
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# ----------------------------------------------------------------------- measuring renders


def write_report(report: dict, out: str | None):
    """The report as indented JSON into `out`, or printed where there is no `out`."""
    text = json.dumps(report, indent=1) + "\n"
    if out:
        Path(out).write_text(text)
    else:
        print(text)


def rgb_error(img, ref):
    return float(np.abs(np.asarray(img)[..., :3].astype(np.float64) - np.asarray(ref)[..., :3]).max())


def timed(renderer, cam, tf, opts, repeats):
    """Best of `repeats` renders; a render over 2 s is not repeated (its noise is small)."""
    best = None
    for _ in range(repeats):
        res = renderer.render(cam, tf, BACKGROUND, opts)
        if best is None or res.stats["render_seconds"] < best.stats["render_seconds"]:
            best = res
        if res.stats["render_seconds"] > 2.0:
            break
    return best


def row_of(res, **extra):
    s = res.stats
    return {**extra, "seconds": s["render_seconds"], "samples_per_ray": s["samples_per_ray"],
            "field_evaluations": s["field_evaluations"], "restriction_evaluations": s["restriction_evaluations"],
            "segments": s["segments"], "segments_empty": s["segments_empty"],
            "segments_smooth": s["segments_smooth"], "segments_piecewise_smooth": s["segments_piecewise_smooth"],
            "empty_fraction": s["segments_empty"] / max(s["segments"], 1), "curved_locates": s["curved_locates"]}


def compile_all(meshes, device, precisions=("float32", "float64")) -> float:
    """Compile every kernel module renders of `meshes` use in `precisions`, side by side
    (engine/kernel_loading.load_modules: HOVR_COMPILE_WORKERS threads), before the first frame:
    seconds. On a GPU each module's first compile takes tens of seconds; one after another they add up."""
    from hovr_blender.engine import kernel_loading as kl
    from hovr_blender.engine.devices import resolve_device

    t0 = time.perf_counter()
    kernels = [k for mesh in meshes for precision in precisions
               for k in kl.render_kernels(kl.kernel_variant([mesh]), precision)]
    kl.load_modules(kernels, resolve_device(device))
    return time.perf_counter() - t0


def compiled_renderer(mesh, device):
    """(Renderer, seconds of its first render): the first render compiles the kernel (or loads
    it from Warp's cache), so timed renders after it measure the kernel alone."""
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.transfer_function import TransferFunction
    from hovr_blender.engine.view import RenderOptions

    r = Renderer(mesh, device)
    t0 = time.perf_counter()
    r.render(RayCamera.from_contract({"eye": [9, 9, 9], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": 30}, 4, 3),
             TransferFunction.from_contract({"color": [[0, 1, 1, 1]], "density": [[0, 0.0]]}), BACKGROUND,
             RenderOptions(method="split", device=device))
    return r, time.perf_counter() - t0
