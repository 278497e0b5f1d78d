"""Nektar++ XML at the lowest level: parsing a file safely, numbers and IDs in element text, and
the B64Z blocks of compressed meshes and field files (docs/spec/formats.md §2.3, §2.6)."""
from __future__ import annotations

import base64
import binascii
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ...engine import limits
from .. import safe_xml
from .errors import NektarError



def parse_xml(path: Path, what: str) -> ET.Element:
    """The <NEKTAR> root of an XML file, read through the resource policy and parsed by
    io/safe_xml.py as it is read (no DTDs in any encoding, bounded nesting and tokens)."""
    try:
        fh = limits.open_regular(path, what)
    except OSError as exc:
        raise NektarError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    with fh:
        size = os.fstat(fh.fileno()).st_size
        limits.check_bytes(size, f"reading {what} {path}")
        try:
            root = safe_xml.parse(fh, size)
        except OSError as exc:
            raise NektarError(f"{path}: cannot read ({exc.strerror or exc})") from exc
        except (safe_xml.XmlRefused, limits.ResourceLimitError, limits.UnsafeFileError) as exc:
            raise NektarError(f"{path}: {exc}") from None
        except safe_xml.ParseError as exc:
            raise NektarError(f"{path}: not well-formed XML ({exc})") from exc
    if root.tag != "NEKTAR":
        raise NektarError(f"{path}: root element is <{root.tag}>, expected <NEKTAR>")
    return root


def parse_int(text, path, what):
    try:
        return int(str(text).strip())
    except (TypeError, ValueError):
        raise NektarError(f"{path}: {what}: {text!r} is not an integer") from None


def parse_ints(text, count, path, what):
    try:
        values = [int(v) for v in (text or "").split()]
    except ValueError:
        raise NektarError(f"{path}: {what}: expected {count} integers, got {text!r}") from None
    if len(values) != count:
        raise NektarError(f"{path}: {what}: expected {count} integers, got {len(values)}")
    return values


def parse_floats(text, count, path, what):
    tokens = (text or "").split()
    if len(tokens) != count:
        raise NektarError(f"{path}: {what}: expected {count} numbers, got {len(tokens)}")
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        raise NektarError(f"{path}: {what}: not all numbers (expressions are not supported)") from None
    if not np.all(np.isfinite(values)):
        raise NektarError(f"{path}: {what}: coordinates are not finite")
    return values


def parse_number(text, path, what):
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise NektarError(f"{path}: {what}: {text!r} is not a number (expressions are not supported)") from None
    if not np.isfinite(value):
        raise NektarError(f"{path}: {what}: {text!r} is not finite")
    return value


def entity_id(node, path, what):
    try:
        return int(node.attrib["ID"])
    except (KeyError, ValueError):
        raise NektarError(f"{path}: {what} <{node.tag}> without a valid integer ID") from None


def endianness(node, path, what, default=None):
    """"<" or ">" for a B64Z-compressed node, None for plain text (docs/spec/formats.md §2.3)."""
    compressed = node.attrib.get("COMPRESSED", default)
    if compressed is None:
        return None
    if compressed not in ("B64Z-LittleEndian", "B64Z-BigEndian"):
        raise NektarError(f"{path}: {what}: COMPRESSED={compressed!r}; only B64Z-LittleEndian/BigEndian are known")
    bits = node.attrib.get("BITSIZE", "64").strip()
    if bits != "64":
        raise NektarError(f"{path}: {what}: BITSIZE={bits!r}; only 64-bit data is known")
    return "<" if compressed.endswith("LittleEndian") else ">"


def inflate_b64z(text, path, what, max_bytes):
    """Bytes of a B64Z block (docs/spec/formats.md §2.3): base64 without '=' padding, zlib, NUL
    padding after the stream. A stream beyond max_bytes raises limits.ResourceLimitError (the
    base64 is decoded piece by piece, only as far as inflating needs)."""
    packed_text = "".join((text or "").split())  # whitespace out (a regex takes seconds on 40 MB)
    if not packed_text:
        raise NektarError(f"{path}: {what}: empty data")
    packed_text += "=" * (-len(packed_text) % 4)

    def pieces(size=1 << 20):  # a multiple of 4 characters: each piece decodes on its own
        for start in range(0, len(packed_text), size):
            try:
                yield base64.b64decode(packed_text[start : start + size], validate=True)
            except (binascii.Error, ValueError) as exc:
                raise NektarError(f"{path}: {what}: data is not valid base64 ({exc})") from exc

    try:
        raw, rest = limits.inflate(pieces(), max_bytes, f"{path}: {what}")
    except (limits.ResourceLimitError, NektarError):
        raise
    except ValueError as exc:
        raise NektarError(str(exc)) from exc
    if rest.strip(b"\0"):  # NUL padding to a multiple of 3 is normal, anything else is not
        raise NektarError(f"{path}: {what}: {len(rest)} unexpected bytes after the zlib stream")
    return raw


def file_budget(path) -> limits.InflationBudget:
    """What all of one file's compressed blocks may inflate to, together (engine/limits.py)."""
    return limits.InflationBudget(Path(path).stat().st_size, Path(path).name)


def check_count(count, max_count, path, what, users):
    """A section's entries, at most what `users` can refer to (max_count None: no bound)."""
    if max_count is not None and count > max_count:
        raise NektarError(f"{path}: {what} holds {count:,} entries or more; the mesh's {users} can use at most "
                          f"{max_count:,}; refused")


def records(node, path, what, fields, endian, budget, max_records=None, users=""):
    """Structured array of the fixed-size records of a compressed mesh block
    (docs/spec/formats.md §2.3 table); fields: (name, numpy kind, shape or None). The block
    inflates within the file's budget (file_budget) and to at most max_records records, the
    most its users (the entities that refer to it) can use."""
    dtype = np.dtype([(name, endian + kind, shape) if shape else (name, endian + kind)
                      for name, kind, shape in fields])
    room = max(budget.allowed - budget.spent, 0)
    cap = room if max_records is None else min(room, int(max_records) * dtype.itemsize)
    try:
        raw = inflate_b64z(node.text or "", path, what, min(cap, limits.current().max_memory))
    except limits.ResourceLimitError:  # say which bound it met
        memory = limits.current().max_memory
        if max_records is not None and max_records * dtype.itemsize <= min(room, memory):
            check_count(max_records + 1, max_records, path, what, users)
        if room <= memory:
            budget.spend(room + 1, f"{path}: {what}")
        limits.check_bytes(memory + 1, f"inflating {path}: {what}")
        raise
    budget.spend(len(raw), f"{path}: {what}")
    if len(raw) % dtype.itemsize:
        raise NektarError(f"{path}: {what}: {len(raw)} bytes is not a whole number of {dtype.itemsize}-byte records")
    return np.frombuffer(raw, dtype=dtype)
