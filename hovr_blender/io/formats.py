"""The data formats' registry: one line a format (its module declares it: io/format_base.py).

The loader (io/sources.py), the `hovr` command, Blender's import operators and menu, the volume
panel and the dependency check all read FORMATS, so a new format is one module and one line
here. register() adds one at run time (a test's toy format, another add-on's reader); Blender
makes its import operators from the registry when the add-on registers.
"""
from __future__ import annotations

from ..engine import limits
from .format_base import SNIFF_BYTES, Format
from .mfem.format import FORMAT as MFEM
from .nektar.format import FORMAT as NEKTAR
from .pyfr.format import FORMAT as PYFR
from .vtu.format import FORMAT as VTU

FORMATS: list[Format] = [
    NEKTAR,
    VTU,
    PYFR,
    MFEM,
]


def register(data_format: Format) -> None:
    """Add a format (or replace the one of the same name)."""
    if not data_format.name.isidentifier() or not data_format.extensions or not all(
            e.startswith(".") and e == e.lower() for e in data_format.extensions):
        raise ValueError(f"format {data_format.name!r}: a Python identifier as name, lower-case extensions "
                         "with their dot")
    unregister(data_format.name)
    FORMATS.append(data_format)


def unregister(name: str) -> None:
    FORMATS[:] = [f for f in FORMATS if f.name != name]


def named(name: str) -> Format:
    for data_format in FORMATS:
        if data_format.name == name:
            return data_format
    raise ValueError(f"no data format {name!r}; one of {', '.join(f.name for f in FORMATS)}")


def described() -> str:
    """The formats in words, for messages and help: "Nektar++ (.xml), VTU (.vtu)"."""
    return ", ".join(f"{f.label} ({', '.join(f.extensions)})" for f in FORMATS)


def _head(path) -> bytes | None:
    """The file's first SNIFF_BYTES, or None where it is no regular file that can be read."""
    try:
        with limits.open_regular(path) as fh:
            return fh.read(SNIFF_BYTES)
    except (OSError, ValueError):
        return None


def format_of(path, sniff: bool = True) -> Format | None:
    """The format that reads `path`: the one its extension names; where several share the
    extension, or none has it, the one whose sniff test accepts the file's head (sniff=False:
    by extension alone, touching no file; the first of several)."""
    by_extension = [f for f in FORMATS if f.reads(path)]
    if len(by_extension) == 1 or (by_extension and not sniff):
        return by_extension[0]
    if not sniff:
        return None
    head = _head(path)
    if head is None:
        return by_extension[0] if by_extension else None
    return next((f for f in by_extension or FORMATS if f.sniff(head)), by_extension[0] if by_extension else None)


def packages() -> list[tuple[str, str, str]]:
    """(module, pip package, what needs it) of every format, each package once."""
    out, seen = [], set()
    for data_format in FORMATS:
        for module, package, purpose in data_format.packages:
            if package not in seen:
                seen.add(package)
                out.append((module, package, purpose))
    return out
