"""A toy data format, all in this one module, to show what adding a format takes: this module
and one registry line (hovr_blender.io.formats.register(FORMAT)). The tests that register it
import and render a .toy file through the loader, the `hovr` command and Blender's File > Import
(tests/io/test_formats.py, tests/blender/test_formats.py).

A .toy file is text: the word TOY, then the box and its cells,

    TOY
    lower -1 -1 -1
    upper 1 1 1
    cells 2 2 2

and offers two fields on that brick of hexahedra: r2 = x^2 + y^2 + z^2 (the default) and x.
"""
from __future__ import annotations

from hovr_blender.engine import limits
from hovr_blender.io.format_base import Format
from hovr_blender.io.synthetic import brick

FIELDS = {"r2": lambda x, y, z: x * x + y * y + z * z, "x": lambda x, y, z: x + 0.0 * y}


class ToyError(ValueError):
    """A .toy file or setting that cannot be read."""


def _header(path) -> dict:
    try:
        lines = limits.read_regular(path, "toy file").decode("ascii").split("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise ToyError(f"{path}: unreadable ({exc})") from exc
    if not lines or lines[0].strip() != "TOY":
        raise ToyError(f"{path}: not a toy file (its first line is not TOY)")
    try:
        out = {key: [float(v) for v in values] for key, *values in (ln.split() for ln in lines[1:] if ln.strip())}
        return {"lower": out["lower"], "upper": out["upper"], "cells": [int(c) for c in out["cells"]]}
    except (KeyError, ValueError) as exc:
        raise ToyError(f"{path}: needs lines lower, upper and cells of three numbers ({exc})") from exc


def list_fields(path) -> list[str]:
    _header(path)
    return list(FIELDS)


def read(path, solution=None, field=None, component=None):
    box = _header(path)
    name = field or next(iter(FIELDS))
    if name not in FIELDS:
        raise ToyError(f"{path}: no field {name!r}; one of {', '.join(FIELDS)}")
    return brick(box["lower"], box["upper"], box["cells"], 3, FIELDS[name], field_name=name)


FORMAT = Format(name="toy", label="Toy", extensions=(".toy",), sniff=lambda head: head.startswith(b"TOY"),
                read=read, list_fields=list_fields, error=ToyError,
                description="Import a toy brick (.toy) as a HOVR volume")


def write(path, lower=(-1.0, -1.0, -1.0), upper=(1.0, 1.0, 1.0), cells=(2, 2, 2)):
    """A .toy file."""
    rows = ["TOY"] + [f"{key} {' '.join(str(v) for v in values)}"
                      for key, values in (("lower", lower), ("upper", upper), ("cells", cells))]
    path.write_text("\n".join(rows) + "\n")
    return path
