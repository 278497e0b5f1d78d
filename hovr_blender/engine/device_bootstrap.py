"""The first code a device's process runs (engine/multi_device.py starts it with runpy, so nothing
of the package has to be importable before it): the package made importable under the name the
parent imported it by, then the device's serving loop.

Installed as a Blender extension the package is `bl_ext.<repo>.hovr_blender`, and `bl_ext` is a
module Blender makes at run time, not a folder on sys.path: the package is loaded from its folder
under the parent's name (its enclosing names as bare modules), so its modules and everything
pickled with its classes (meshes, options, cameras) resolve as in the parent, from the same copy.
Any failure is answered on the pipe, so the parent reports it instead of waiting.
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


def start(conn, package: str, folder: str, payload: bytes):
    try:
        import_package(package, folder)
        serve = importlib.import_module(package + ".engine.multi_device").serve_spawned
    except BaseException as exc:  # noqa: BLE001  (answered, then this process ends)
        conn.send(("error", f"cannot import {package} in a device process: {type(exc).__name__}: {exc}"))
        return
    serve(conn, payload)


if __name__ == "__hovr_device_process__":  # runpy.run_path(this file, START, that name)
    start(**START)  # noqa: F821  (runpy's init_globals)
