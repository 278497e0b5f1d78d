"""Private scratch: the temporary folders of a run, made for it and removed at its end.

The shared temporary folder (/tmp, or $TMPDIR) is writable by every user of the machine: a
fixed name there (Dask's `dask-scratch-space/global.lock`, Blender's `<file>.crash.txt`) can be
a link another user planted, and a program that opens it for writing writes where the link
points (Dask's lock files, opened with "wb", emptied a file of the victim's). So nothing a run
starts writes there:

- `run_folder()`: this process's folder for the run, made by mkdtemp (a fresh random name,
  created only if it did not exist, mode 0700: nobody else can enter it or plant anything in it)
  and removed when the process exits (shutil.rmtree, which does not follow links);
- `private_folder(prefix)`: a fresh 0700 folder inside it, for one child (a Blender, a frame);
- `child_env(folder)`: an environment whose TMPDIR, TEMP and TMP name the folder, so the
  temporary files of every program a child runs (Python's tempfile, Blender's session folder
  and crash log, libraries) go there;
- `adopted()`: the run folder as this whole process's temporary folder (the `hovr` command).

A process killed with SIGKILL leaves its folder behind (private, and empty of anything that
could redirect a write); the next run makes a new one.
"""
from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import tempfile
import threading

PREFIX = "hovr-run-"
_TEMP_VARIABLES = ("TMPDIR", "TEMP", "TMP")  # where programs look for their temporary folder
_LOCK = threading.Lock()
_RUN: dict = {}  # pid -> this process's run folder (a forked child makes its own)


def run_folder() -> str:
    """This process's private scratch folder (mode 0700), made on first use, removed at exit."""
    pid = os.getpid()
    with _LOCK:
        folder = _RUN.get(pid)
        if folder is None or not os.path.isdir(folder):
            folder = _RUN[pid] = tempfile.mkdtemp(prefix=PREFIX)
            atexit.register(remove, folder, pid)
    return folder


def private_folder(prefix: str = "tmp-") -> str:
    """A fresh folder (mode 0700) inside run_folder(), for one child; remove() it when done."""
    return tempfile.mkdtemp(prefix=prefix, dir=run_folder())


def remove(folder: str, owner: int | None = None):
    """Remove a scratch folder and what is in it (never following a link); only in the process
    that made it (`owner`), so a forked child's exit does not remove its parent's."""
    if owner is not None and owner != os.getpid():
        return
    shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def adopted():
    """Within the block, run_folder() is this whole process's temporary folder: Python's
    tempfile, and the TMPDIR its children inherit (Dask's nannies, multiprocessing's helpers).
    For a process that is one run (the `hovr` command), never for Blender's."""
    folder = run_folder()
    saved = tempfile.tempdir, {k: os.environ.get(k) for k in _TEMP_VARIABLES}
    tempfile.tempdir = folder
    os.environ.update(dict.fromkeys(_TEMP_VARIABLES, folder))
    try:
        yield folder
    finally:
        tempfile.tempdir = saved[0]
        for key, value in saved[1].items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def child_env(folder: str, env: dict | None = None) -> dict:
    """`env` (default: this process's environment) with the temporary folder set to `folder`."""
    out = dict(os.environ if env is None else env)
    out.update(dict.fromkeys(_TEMP_VARIABLES, folder))
    return out
