"""The Warp devices a render may use: Warp started once (quietly: its greeting and the driver
probe only with HOVR_DEBUG=1), device names resolved, device lists expanded ("cuda:all",
"cpu:all"). Imported by the renderer's modules, which the CLI and the add-on import only when
they render."""
from __future__ import annotations

import os
import sys
import threading

import warp as wp

from .limits import cpu_cores
from .render_result import RenderError
from .shipped_kernels import CPU_COMPILER_FLAGS

_WARP_READY = False
_WARP_LOCK = threading.Lock()  # Warp starts once, whichever thread asks first


def _init_warp():
    """Initialise Warp once, on the first device look-up (device probing deferred until a render
    needs it). Warp's greeting, module-load lines and its native "no CUDA driver" line are shown
    only with HOVR_DEBUG=1: on a machine without a GPU they are noise on every render."""
    global _WARP_READY
    with _WARP_LOCK:
        if not _WARP_READY:
            _start_warp()
            _WARP_READY = True


def _start_warp():
    # portable CPU objects: the add-on's shipped kernels (shipped_kernels.py) match on any CPU
    wp.config.cpu_compiler_flags = CPU_COMPILER_FLAGS
    debug = bool(os.environ.get("HOVR_DEBUG"))
    wp.config.log_level = wp.LOG_INFO if debug else wp.LOG_ERROR
    if debug:
        wp.init()
        return
    # the driver probe prints from C to the process's stderr: hold fd 2 on /dev/null meanwhile
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def resolve_device(device: str) -> str:
    _init_warp()
    try:
        return str(wp.get_device(device))
    except (RuntimeError, ValueError) as exc:
        avail = ", ".join(str(d) for d in wp.get_devices())
        raise RenderError(f"Warp device {device!r} is not available here (available: {avail})") from exc


def cuda_devices() -> list[str]:
    """The names of the CUDA devices here ("cuda:0", ...); empty without a GPU."""
    _init_warp()
    return [str(d) for d in wp.get_devices() if d.is_cuda]


def expand_devices(devices) -> list[str]:
    """A device list: "cpu", "cuda:1", "cuda:0,cuda:1" (or a list of names), "cuda:all" / "all"
    for every CUDA device here, or "cpu:all" for one CPU device a core (Warp runs a CPU launch
    on one thread, so the cores are used by one process each); each name resolved (RenderError
    for one that is not here)."""
    names = [d.strip() for d in (devices.split(",") if isinstance(devices, str) else devices) if d.strip()]
    if not names:
        raise RenderError("no device named")
    out = []
    for name in names:
        if name in ("all", "cuda:all"):
            cuda = cuda_devices()
            if not cuda:
                raise RenderError(f"{name!r}: there is no CUDA device here")
            out.extend(cuda)
        elif name == "cpu:all":
            out.extend(["cpu"] * cpu_cores())
        else:
            out.append(resolve_device(name))
    return out
