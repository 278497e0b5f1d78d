"""Processes a run starts end with it: the render devices' processes (engine/multi_device.py),
Dask's local workers and the headless Blenders of `hovr render-blend` (hovr_blender/distributed).

Two mechanisms, because Linux's parent-death signal (prctl PR_SET_PDEATHSIG) fires when the
*thread* that started the child ends, not its process: Blender renders in a thread that ends
after each render, and Dask starts workers from its event-loop thread.

- `watch_parent(pid)`, called in the child: a daemon thread that ends the child as soon as its
  parent process is gone (the child is re-parented, so getppid() changes). The render kernels
  run through ctypes, which releases the GIL, so the thread runs while a frame renders.
- `die_with_parent` as a subprocess preexec_fn: the death signal, for a child that cannot run
  Python of ours first (Blender) and is started from a thread that outlives it (a Dask task's
  thread waits on it).

`sigint_blocked()` starts children with SIGINT blocked (a blocked signal stays blocked across
exec), so Ctrl-C in a terminal reaches only the parent, which ends its children itself: one
line, not one traceback per child.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time

PR_SET_PDEATHSIG = 1  # linux/prctl.h
PARENT_POLL_SECONDS = 0.5
EXIT_PARENT_GONE = 75  # the child's exit status when its parent died


def watch_parent(parent_pid: int | None = None, interval: float = PARENT_POLL_SECONDS) -> threading.Thread:
    """End this process (os._exit) within `interval` seconds of its parent process ending."""
    pid = os.getppid() if parent_pid is None else int(parent_pid)

    def watch():
        while os.getppid() == pid:
            time.sleep(interval)
        os._exit(EXIT_PARENT_GONE)

    if os.getppid() != pid:  # gone before we could look
        os._exit(EXIT_PARENT_GONE)
    t = threading.Thread(target=watch, name="hovr-watch-parent", daemon=True)
    t.start()
    return t


def die_with_parent():
    """A subprocess preexec_fn (Linux; a no-op elsewhere): SIGKILL this child when the thread that
    started it ends, i.e. when its parent process dies while waiting for it."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() == 1:  # the parent died before prctl
        os._exit(EXIT_PARENT_GONE)


@contextlib.contextmanager
def sigint_blocked():
    """Start children inside this block: they are born with SIGINT blocked (this thread's mask,
    restored after), so Ctrl-C interrupts only the parent."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
