"""The reader process's wire protocol, the one module both ends import (io/isolation.py in the
parent, io/reader_process.py in the reader): each message is HEADER (its length) and a JSON body,
then the raw bytes of the arrays it names, in order, each of a dtype in ARRAY_DTYPES; `encode`
turns a task's result into that JSON (its arrays appended beside it) and `decode` turns it back.

The messages: a request {"task", "args", "limits", "cap"}; while it runs, {"stage", "file"} (a
file opened: the parent counts its size towards the time limit) and {"progress", "cpu"} (the
reader's limits.progress() count moved; the processor time it used), the parent's stall check;
then one reply, {"result"} or {"error": {"kind", "message"}}.
"""
from __future__ import annotations

import json
import os
import struct
from dataclasses import fields as dataclass_fields
from pathlib import Path

# dtypes an array may come back in (a reader process that misbehaves cannot make this one build objects)
ARRAY_DTYPES = frozenset(("|b1", "|u1", "<i4", "<i8", "<u4", "<u8", "<f4", "<f8"))  # numpy's dtype.str
HEADER = struct.Struct("<Q")


class ReaderFailure(ValueError):
    """The reader process crashed, hung, ran out of its memory or failed to start: one line that
    names the file being read."""


def send(fd: int, message: dict, arrays=()):
    """One JSON message, then the raw bytes of `arrays` (their dtypes and shapes in it)."""
    body = json.dumps(message).encode()
    write_all(fd, HEADER.pack(len(body)) + body)
    for a in arrays:
        write_all(fd, memoryview(a).cast("B"))


def write_all(fd: int, data):
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def encode(value, arrays: list):
    """A task's result as JSON, its arrays appended to `arrays`: numbers, strings, lists,
    tuples, dicts with string keys, arrays, VolumeMesh and its DerivedField."""
    import numpy as np

    from ..engine.derived_fields import DerivedField
    from ..engine.mesh import VolumeMesh

    if isinstance(value, np.ndarray):
        if value.dtype.str not in ARRAY_DTYPES:  # a big-endian array goes as its native copy
            value = value.astype(value.dtype.newbyteorder("<")) if value.dtype.byteorder == ">" else value
        if value.dtype.str not in ARRAY_DTYPES:
            raise TypeError(f"array of dtype {value.dtype} cannot leave the reader process")
        arrays.append(np.ascontiguousarray(value))
        return {"$array": len(arrays) - 1, "dtype": value.dtype.str, "shape": list(value.shape)}
    if isinstance(value, VolumeMesh):
        names = [f.name for f in dataclass_fields(VolumeMesh)]
        extra = {k: v for k, v in vars(value).items() if k not in names}
        return {"$mesh": {k: encode(getattr(value, k), arrays) for k in names},
                "extra": {k: encode(v, arrays) for k, v in extra.items()}}
    if isinstance(value, DerivedField):  # a derived field's components (engine/derived_fields.py)
        spec = value.spec
        return {"$derived": {f.name: encode(getattr(value, f.name), arrays) for f in dataclass_fields(DerivedField)
                             if f.name != "spec"},
                "spec": [spec.operation, list(spec.components), spec.density]}
    if isinstance(value, tuple):
        return {"$tuple": [encode(v, arrays) for v in value]}
    if isinstance(value, list):
        return [encode(v, arrays) for v in value]
    if isinstance(value, dict):
        return {"$dict": {str(k): encode(v, arrays) for k, v in value.items()}}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"a {type(value).__name__} cannot leave the reader process")


def array_specs(tree, out: list):
    """The array entries of an encoded tree, in index order."""
    if isinstance(tree, dict):
        if "$array" in tree:
            out.append(tree)
        for v in tree.values():
            array_specs(v, out)
    elif isinstance(tree, list):
        for v in tree:
            array_specs(v, out)
    return out


def decode(tree, arrays: list):
    from ..engine.mesh import VolumeMesh

    if isinstance(tree, list):
        return [decode(v, arrays) for v in tree]
    if not isinstance(tree, dict):
        return tree
    if "$array" in tree:
        return arrays[tree["$array"]]
    if "$tuple" in tree:
        return tuple(decode(v, arrays) for v in tree["$tuple"])
    if "$dict" in tree:
        return {k: decode(v, arrays) for k, v in tree["$dict"].items()}
    if "$derived" in tree:
        from ..engine.derived_fields import DerivedField, DerivedSpec

        op, components, density = tree["spec"]
        given = {f.name: decode(tree["$derived"][f.name], arrays) for f in dataclass_fields(DerivedField)
                 if f.name != "spec"}
        return DerivedField(spec=DerivedSpec(str(op), tuple(str(c) for c in components),
                                             None if density is None else str(density)), **given)
    if "$mesh" in tree:
        names = {f.name for f in dataclass_fields(VolumeMesh)}
        given = {k: decode(v, arrays) for k, v in tree["$mesh"].items() if k in names}
        mesh = VolumeMesh(**given)
        for k, v in tree.get("extra", {}).items():
            if k.isidentifier() and not k.startswith("_") and k not in names:
                setattr(mesh, k, decode(v, arrays))
        return mesh
    raise ReaderFailure("the reader process sent a malformed result")
