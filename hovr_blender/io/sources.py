"""The loader: the one entry point from a data description to a VolumeMesh, used by the `hovr`
command, the render engine and the import operators alike. A source (io/volume_source.py:
VolumeSource, its files and frame numbers) is read in a reader process (io/isolation.py) and
kept in a small cache by its key.
"""
from __future__ import annotations

from ..engine.lru_cache import LRUCache
from ..engine.mesh import VolumeMesh
from . import isolation
# the loader's callers name the source and its errors through this module too
from .volume_source import SourceError, VolumeSource, file_format, frame_path, parse_component, read_volume  # noqa: F401


def load_volume(source: VolumeSource, **progress) -> VolumeMesh:
    """The mesh (object space) of a resolved source, read by its format (io/formats.py) in a
    reader process (io/isolation.py; `progress`: its on_stage and cancelled). Nektar++ field
    "|u,v,w|" and a VTU vector (the default for vector arrays) are magnitudes derived from the
    exact components (io/magnitude.py); `component` picks one component of a vector instead."""
    return isolation.wait(volume_request(source), **progress)


def volume_request(source: VolumeSource):
    """load_volume started, not waited for: an isolation.Request to poll (a built-in dataset is
    made here, isolation.Finished). A missing file or an unknown format is raised now."""
    if source.path.startswith("builtin:"):
        return isolation.Finished(lambda: read_volume(source))
    file_format(source)
    return isolation.read_volume_request(source)


class _Unlisted(Exception):
    """Format.choose needs the fields of a file not listed yet (choose_steps lists it, then asks again)."""

    def __init__(self, path):
        super().__init__(path)
        self.path = path


def choose_steps(data_format, path: str, solution: str = "", field: str = "", component: str = "",
                 settings: tuple[str, str] = ("set Field", "set Solution")):
    """data_format.choose's defaults (the solution given or the likeliest beside the data, the field
    given or the file's first), each file's fields listed in a reader process: a generator that
    yields each listing's isolation.Request, is sent its value, and returns the format's Choice
    (Blender's import polls the requests; choose_data waits for them)."""
    listed = {}

    def list_fields(p):
        if p not in listed:
            raise _Unlisted(p)
        return listed[p]

    while True:
        try:
            return data_format.choose(path, solution, field, component, list_fields=list_fields, settings=settings)
        except _Unlisted as missing:
            listed[missing.path] = yield isolation.list_fields_request(data_format.name, missing.path)


def choose_data(path: str, solution: str = "", field: str = "", component: str = "",
                settings: tuple[str, str] = ("set Field", "set Solution")):
    """(format, Choice): what an import of `path` with these settings reads (choose_steps), waited for."""
    data_format = file_format(VolumeSource(path))
    steps = choose_steps(data_format, path, solution, field, component, settings)
    try:
        request = next(steps)
        while True:
            request = steps.send(isolation.wait(request))
    except StopIteration as done:
        return data_format, done.value


def load_view_data(view) -> VolumeMesh:
    """The mesh a view file (engine.view.View) names in its `data` object."""
    return load_volume(VolumeSource.from_view_data(view.data, view.base_dir))


# Loaded meshes (object space) by VolumeSource.key: moving the object, another device or the
# viewport and F12 share one read; a changed file (size or mtime) has another key.
_MESHES = LRUCache(6)  # several volumes in one scene, each with its previous frame


def cached_volume(source: VolumeSource) -> VolumeMesh:
    """load_volume(source), read again only when source.key changes."""
    return _MESHES.get(source.key, lambda: load_volume(source))


def cached_volume_steps(source: VolumeSource):
    """cached_volume for a caller that must not wait (Blender's modal import): a generator that
    yields the reader's request (volume_request) only when the mesh is not cached, is sent its
    value, and returns the mesh, now cached."""
    mesh = _MESHES.get(source.key)
    if mesh is None:
        mesh = yield volume_request(source)
        _MESHES.put(source.key, mesh)
    return mesh


def clear_cache():
    _MESHES.clear()
