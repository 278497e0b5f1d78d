"""What to read, and reading it here: a data description resolved to a VolumeSource (its files,
frame numbers substituted, a key that changes exactly when the bytes may) and read by its
registered format in this process (read_volume: the reader process's task, io/reader_process.py).
io/sources.py is the loader every caller uses (load_volume: the same read in a reader process).

A source is "builtin:NAME" or a file of a registered format (io/formats.py: a Nektar++ mesh
.xml with its solution, .fld/.chk/.rst, XML or HDF5, or a multi-part .fld/ folder; a VTK .vtu). A
run of '#' in a path is the frame number (Blender's convention, `flow_####.fld`). Data given
without a solution, of a format that keeps its fields in solution files, gets the one beside
it, if there is one (the format's find_solution), in the CLI and in Blender alike.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

from ..engine.mesh import VolumeMesh
from . import builtin, formats


class SourceError(ValueError):
    """A data description that cannot be read (unknown kind, missing file, bad setting)."""


def frame_path(path: str, frame: int) -> str:
    """Blender's numbered-file convention: the last run of '#' becomes the frame number,
    zero-padded to the run's length ("flow_####.fld", 12 -> "flow_0012.fld")."""
    if not path:
        return path
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    last = runs[-1]
    number = f"{abs(int(frame)):0{len(last.group())}d}"
    return path[: last.start()] + ("-" if frame < 0 else "") + number + path[last.end():]


def parse_component(text) -> int | str | None:
    """A VTU vector's component setting -> read_vtu's component: "" -> None (the magnitude),
    "magnitude" -> "magnitude", "0", "1", ... -> the index (ints pass through)."""
    if isinstance(text, int) and not isinstance(text, bool):
        return text
    text = str(text or "").strip()
    if not text:
        return None
    if text.lower() == "magnitude":
        return "magnitude"
    if text.isdigit():
        return int(text)
    raise SourceError(f"component {text!r}: use an index (0, 1, 2, ...), 'magnitude' or nothing")


def _stamps(*paths) -> tuple:
    out = []
    for p in paths:
        if p:
            try:
                status = os.stat(p)
                out.append((status.st_mtime_ns, status.st_size))
            except OSError:
                out.append(None)  # missing: load_volume reports it
    return tuple(out)


@dataclass(frozen=True)
class VolumeSource:
    """One frame's data, resolved: what to read, and a key that changes exactly when the bytes
    may. `path` is "builtin:NAME" or an absolute path (frame numbers already substituted)."""

    path: str
    solution: str = ""
    field: str = ""
    stamps: tuple = ()  # (mtime_ns, size) of each file when the source was resolved
    component: str = ""  # VTU vectors: "" or "magnitude", or an index ("0", "1", ...)

    @property
    def key(self) -> tuple:
        base = (self.path, self.solution, self.field, self.stamps)
        return base + (self.component,) if self.component else base

    @classmethod
    def resolve(cls, path: str, solution: str = "", field: str = "", frame: int = 1, base_dir: str = "",
                abspath=None, component="") -> "VolumeSource":
        """A data description at a frame. Relative paths are taken from base_dir (the CLI: the
        view file's folder) after `abspath` (Blender: '//' is the .blend's folder)."""
        path, solution, field = path.strip(), (solution or "").strip(), (field or "").strip()
        component = str(component if component is not None else "").strip()
        if path.startswith("builtin:"):
            return cls(path)
        if not path:
            raise SourceError(f"no data: give a file ({formats.described()}) or builtin:NAME")

        def absolute(p):
            p = (abspath or (lambda q: q))(frame_path(p, frame))
            return os.path.abspath(os.path.join(base_dir, p) if base_dir else p)

        full = absolute(path)
        sol = absolute(solution) if solution else ""
        data_format = formats.format_of(full, sniff=False)
        if not sol and data_format is not None and data_format.takes_solution:
            sol = str(data_format.find_solution(full) or "")
        return cls(full, sol, field, _stamps(full, sol), component)

    @classmethod
    def from_view_data(cls, data: dict, base_dir: str = ".") -> "VolumeSource":
        """The view file's `data` object (engine.view.data_spec has checked its types)."""
        if "builtin" in data:
            return cls("builtin:" + data["builtin"])
        if not data.get("path"):
            raise SourceError("data needs 'path' (or 'builtin')")
        comp = data.get("component")
        return cls.resolve(data["path"], data.get("solution") or "", data.get("field") or "", base_dir=base_dir,
                           component="" if comp is None else comp)


def file_format(source: VolumeSource):
    """The registered format that reads the source's file, its files checked to exist."""
    data_format = formats.format_of(source.path)
    if data_format is None:
        ext = os.path.splitext(source.path)[1].lower()
        raise SourceError(f"{source.path}: unsupported data format {ext!r} (use builtin:NAME or a file of "
                          f"{formats.described()})")
    for p in (source.path, source.solution):
        if p and not os.path.exists(p):
            raise SourceError(f"data file not found: {p}")
    return data_format


def read_volume(source: VolumeSource) -> VolumeMesh:
    """load_volume in this process (the reader process's task)."""
    kind, _, name = source.path.partition(":")
    if kind == "builtin":
        if name not in builtin.BUILTIN:
            raise SourceError(f"unknown built-in dataset {name!r}; one of {', '.join(builtin.BUILTIN)}")
        return builtin.BUILTIN[name]()
    data_format = file_format(source)
    component = parse_component(source.component) if data_format.components else None
    return data_format.read(source.path, source.solution or None, source.field or None, component)
