"""What a data format declares, once, for the loader (io/sources.py), the `hovr` command and
Blender (File > Import, the volume panel, the dependency check) to read: its extensions, a sniff
test, how to read it, the fields it offers and the packages it needs. Each format is one module
holding a `Format` (io/nektar/format.py, io/vtu/format.py); io/formats.py is the registry.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable, Iterable

from ..engine.mesh import VolumeMesh

SNIFF_BYTES = 4096  # how much of a file's head a sniff test sees


@dataclass(frozen=True)
class Choice:
    """An import's data settings once the defaults are filled in, with what to tell the user."""

    solution: str
    field: str
    component: str
    notes: list
    warnings: list


# the package an XML format needs: io/safe_xml.py parses through defusedxml (DTDs refused)
XML_PACKAGE = ("defusedxml", "defusedxml", "reading XML data files (Nektar++, VTU) with DTDs refused")


@dataclass(frozen=True)
class Format:
    """One data format. `read(path, solution, field, component)` returns the VolumeMesh (solution,
    field and component None where not given; component as sources.parse_component gives it) and raises
    `error` for a file it cannot read; `list_fields(file)` names the fields a file offers (the
    solution file where the format keeps its fields apart, else the data file)."""

    name: str  # the registry's key; Blender's import operator is import_scene.hovr_<name>
    label: str  # "Nektar++": File > Import > HOVR Nektar++ (.xml)
    extensions: tuple[str, ...]  # lower case, with the dot; the first is the file browser's
    sniff: Callable[[bytes], bool]  # the file's first SNIFF_BYTES: is it this format's?
    read: Callable[..., VolumeMesh]
    list_fields: Callable[[str], Iterable[str]]
    error: type = ValueError  # what read and list_fields raise for a bad file
    description: str = ""  # the import operator's tooltip
    packages: tuple[tuple[str, str, str], ...] = ()  # (module, pip package, what needs it) beyond numpy and Warp
    field_help: str = "Field to render; empty: the file's first one"
    components: bool = False  # vector fields: a component or the magnitude (Component setting)
    # fields in solution files of their own (Nektar++): the one beside a data file for the loader,
    # the likeliest with its reasons (picked, why, others) for an import, the Solution setting's help
    find_solution: Callable[[str], object] | None = None
    pick_solution: Callable[[str], tuple] | None = None
    solution_help: str = ""
    boundaries: Callable[[str], object] | None = None  # named boundary faces for Walls From (.choices(), .select())

    @property
    def takes_solution(self) -> bool:
        return self.find_solution is not None

    def reads(self, path: str) -> bool:
        """Whether the path's extension is one of this format's."""
        return os.path.splitext(str(path))[1].lower() in self.extensions

    def menu_text(self) -> str:
        return f"HOVR {self.label} ({', '.join(self.extensions)})"

    def choose(self, path: str, solution: str = "", field: str = "", component: str = "",
               list_fields: Callable[[str], Iterable[str]] | None = None,
               settings: tuple[str, str] = ("set Field", "set Solution")) -> Choice:
        """An import's settings with the defaults filled in: the solution given or the likeliest
        beside the data, the field given or the file's first; raises `error` for bad settings.
        `list_fields` lists a file's fields in its stead (io.isolation's, in the reader process);
        `settings`: how the notes tell the user to choose the field and the solution."""
        notes, warnings = [], []
        if self.takes_solution and not solution and self.pick_solution is not None:
            picked, why, others = self.pick_solution(path)
            if picked is not None:
                solution = str(picked)
                rest = [p.name for p in others if p != picked]
                notes.append(f"solution {picked.name} ({why})"
                             + (f"; also in the folder: {', '.join(rest[:4])}{' ...' if len(rest) > 4 else ''}"
                                if rest else ""))
            elif others:
                warnings.append(f"{why} ({', '.join(p.name for p in others[:4])}): {settings[1]} to pick one")
        field = field.strip()
        fields_file = solution if self.takes_solution else path
        if fields_file and not field:
            names = list((list_fields or self.list_fields)(fields_file))
            if not names:
                raise self.error(f"{fields_file}: holds no fields to render")
            field = names[0]
            if len(names) > 1:
                notes.append(f"showing {field!r} of {', '.join(names)} ({settings[0]} to choose)")
        if self.takes_solution and not solution and field:
            raise self.error(f"{path}: field {field!r} requested but no solution file is given or found beside it")
        return Choice(solution, field, component.strip() if self.components else "", notes, warnings)
