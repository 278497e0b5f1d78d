"""The first code a process of the package runs, before the package is importable there: a
render device's process (engine/multi_device.py starts this file with runpy, under the name
__hovr_device_process__) and the reader process (io/isolation.py's BOOT runs this file with runpy
and calls import_package). Nothing of the parent's `__main__` is re-run (a bpy script, guarded
or not), and nothing of the package has to be on sys.path.

Installed as a Blender extension the package is `bl_ext.<repo>.hovr_blender`, and `bl_ext` is a
module Blender makes at run time, not a folder on sys.path: the package is loaded from its folder
under the parent's name (its enclosing names as bare modules), so its modules and everything
pickled with its classes (meshes, options, cameras) resolve as in the parent, from the same copy.
Only the standard library is imported here. A device's start-up failure is answered on its
pipe, so the parent reports it instead of waiting.
"""
import importlib
import importlib.util
import os
import sys
import types


def import_package(package: str, folder: str):
    """The package `package` (dotted) loaded from `folder`, unless this process has it already."""
    if package in sys.modules:
        return sys.modules[package]
    parts = package.split(".")
    for k in range(1, len(parts)):
        name = ".".join(parts[:k])
        if name not in sys.modules:
            outer = types.ModuleType(name)
            outer.__path__ = []
            sys.modules[name] = outer
    spec = importlib.util.spec_from_file_location(package, os.path.join(folder, "__init__.py"),
                                                  submodule_search_locations=[folder])
    module = importlib.util.module_from_spec(spec)
    sys.modules[package] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[package]
        raise
    if len(parts) > 1:
        setattr(sys.modules[".".join(parts[:-1])], parts[-1], module)
    return module


def start_device(conn, package: str, folder: str, payload: bytes):
    """A device's process: the package imported, then multi_device.serve_spawned."""
    try:
        import_package(package, folder)
        serve = importlib.import_module(package + ".engine.multi_device").serve_spawned
    except BaseException as exc:  # noqa: BLE001  (answered, then this process ends)
        conn.send(("error", f"cannot import {package} in a device process: {type(exc).__name__}: {exc}"))
        return
    serve(conn, payload)


if __name__ == "__hovr_device_process__":  # runpy.run_path(this file, START, that name)
    start_device(**START)  # noqa: F821  (runpy's init_globals)
