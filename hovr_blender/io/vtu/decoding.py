"""One DataArray's values, decoded with numpy: ascii; inline or appended base64; raw appended;
zlib or lzma blocks; UInt32/UInt64 headers; either byte order.

Every array's size is fixed in advance by the piece's counts: a block header must declare
exactly that size before anything is allocated or inflated, and compressed blocks are inflated
one by one, bounded, into one preallocated buffer (linear time).
"""
from __future__ import annotations

import base64
import binascii
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...engine import limits
from .errors import VtuError

NUMPY_TYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
               "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
CODECS = {"vtkZLibDataCompressor": "zlib", "vtkLZMADataCompressor": "lzma"}
_WHITESPACE = b" \t\n\r\f\v"


@dataclass(frozen=True)
class LoadedFile:
    """A loaded file: what decoding its DataArrays needs."""
    path: Path
    order: str  # "<", ">" or "=": byte_order
    header: np.dtype  # block header words (header_type) in that byte order
    codec: str | None  # "zlib", "lzma" or None
    appended: memoryview | None  # after <AppendedData>'s '_', up to its closing tag
    appended_base64: bool
    budget: limits.InflationBudget  # what all compressed arrays together may inflate to


def decode(file: LoadedFile, array, what, count, why):
    """The array's values, flat and in native byte order: exactly `count` of them, which `why`
    explains (for the error). Ascii arrays come as int64/uint64/float64 (no wrap-around)."""
    path = file.path
    type_name = array.attrib.get("type")
    if type_name not in NUMPY_TYPES:
        raise VtuError(f"{path}: {what}: data type {type_name!r} is not supported")
    dtype = np.dtype(file.order + NUMPY_TYPES[type_name])
    need = (count * dtype.itemsize, f"{why}: {count} x {type_name}")
    encoding = array.attrib.get("format", "ascii")
    try:
        limits.check_bytes(need[0], what)
        if encoding == "ascii":
            return _ascii(file, array.text or "", type_name, count, what, why)
        if encoding == "binary":
            text = (array.text or "").encode("ascii", "replace").translate(None, _WHITESPACE)
            data = _base64_array(file, text, 0, need, what, "its inline data")
        elif encoding == "appended":
            data = _appended_array(file, array, need, what)
        else:
            raise VtuError(f"{path}: {what}: format {encoding!r} (ascii, binary or appended)")
    except VtuError:
        raise
    except ValueError as exc:  # limits: the memory limit, a bomb, a broken or truncated zlib/lzma stream
        raise VtuError(f"{path}: {exc}") from exc
    return np.frombuffer(data, dtype).astype(dtype.newbyteorder("="), copy=False)


def _appended_array(file: LoadedFile, array, need, what):
    if file.appended is None:
        raise VtuError(f"{file.path}: {what}: format=\"appended\" but the file has no <AppendedData>")
    try:
        offset = int(array.attrib["offset"])
    except (KeyError, ValueError):
        raise VtuError(f"{file.path}: {what}: missing or bad offset") from None
    if not 0 <= offset < len(file.appended):
        raise VtuError(f"{file.path}: {what}: offset {offset} is outside the appended data "
                       f"({len(file.appended)} bytes)")
    block = _base64_array if file.appended_base64 else _raw_array
    return block(file, file.appended, offset, need, what, "the appended data")


def _ascii(file, text, type_name, count, what, why):
    """An ascii array's `count` numbers, parsed wide (int64, uint64 or float64)."""
    chars = np.frombuffer(text.encode(), np.uint8)
    space = np.isin(chars, np.frombuffer(_WHITESPACE, np.uint8))
    found = int(np.count_nonzero(space[:-1] & ~space[1:])) + int(chars.size > 0 and not space[0])
    if found != count:  # counted first: the parse below is bounded by the piece's count
        raise VtuError(f"{file.path}: {what}: {found} values, the piece needs {count} ({why})")
    wide = np.float64 if type_name.startswith("Float") else np.uint64 if type_name == "UInt64" else np.int64
    if found == 0:
        return np.empty(0, wide)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy's "could not be read to its end"
        try:
            data = np.fromstring(text, wide, sep=" ")
        except (DeprecationWarning, ValueError):
            data = None
    if data is None or data.size != found:
        raise VtuError(f"{file.path}: {what}: not a list of {type_name} numbers")
    return data


def _base64_length(nbytes):
    return 4 * -(-nbytes // 3)


def _base64_run(file, text, pos, nbytes, what, where, exact=True):
    """Bytes of the base64 run encoding `nbytes` at text[pos:] (exact=False: a run's first
    nbytes; no padding expected there)."""
    nchars = _base64_length(nbytes)
    if pos + nchars > len(text):
        raise VtuError(f"{file.path}: {what}: needs {nchars} base64 characters at {pos}, past the end of "
                       f"{where} ({len(text)} characters)")
    try:
        out = base64.b64decode(text[pos:pos + nchars], validate=True)
    except binascii.Error as exc:
        raise VtuError(f"{file.path}: {what}: not valid base64 ({exc})") from None
    if len(out) < nbytes or exact and len(out) != nbytes:
        raise VtuError(f"{file.path}: {what}: base64 run of {nchars} characters decodes to {len(out)} "
                       f"bytes, not {nbytes}")
    return out


def _check_declared(file, declared, need, what):
    if declared != need[0]:
        raise VtuError(f"{file.path}: {what}: its data header declares {declared} bytes, the piece needs "
                       f"{need[0]} ({need[1]})")


def _check_blocks(file, head, need, what):
    """The compression header [blocks, block size, last block size] against the piece's size."""
    num_blocks, size, last = head
    _check_declared(file, 0 if num_blocks == 0 else (num_blocks - 1) * size + (last or size), need, what)
    if num_blocks and (size == 0 or last > size):
        raise VtuError(f"{file.path}: {what}: compression header [{num_blocks}, {size}, {last}, ...] is inconsistent")
    file.budget.spend(need[0], what)


def _block_ends(file, sizes, room, what, where):
    """End offsets of the compressed blocks, all inside `room` bytes."""
    ends = np.cumsum(sizes, dtype=np.uint64)
    wrapped = bool(np.any(ends[1:] < ends[:-1]))  # every size is below 2**64: a wrap-around shows as a decrease
    if ends.size and (wrapped or int(ends[-1]) > room):
        total = "more than 2**64" if wrapped else int(ends[-1])
        raise VtuError(f"{file.path}: {what}: its compressed blocks ({total} bytes) run past the end of {where} "
                       f"({room} bytes left)")
    return ends


def _inflate(file, compressed, ends, head, need, what):
    """The compressed blocks compressed[0:ends[0]], compressed[ends[0]:ends[1]], ... inflated,
    each to exactly its declared size, into one buffer."""
    num_blocks, size, last = head
    out = bytearray(need[0])
    view = memoryview(out)
    start = pos = 0
    for k in range(num_blocks):
        end = int(ends[k])
        n = last if k == num_blocks - 1 and last else size
        block, _ = limits.inflate(compressed[start:end], n, f"{what} block {k}", file.codec, exact=True)
        view[pos:pos + n] = block
        start, pos = end, pos + n
    return out


def _raw_array(file, data, offset, need, what, where):
    """A raw appended block at data[offset:]: header words, then the (compressed) data."""
    word = file.header.itemsize

    def words(pos, n):
        if pos + n * word > len(data):
            raise VtuError(f"{file.path}: {what}: its {n}-word block header at {pos} runs past the end of "
                           f"{where} ({len(data)} bytes)")
        return np.frombuffer(data, file.header, n, pos)

    if file.codec is None:
        _check_declared(file, int(words(offset, 1)[0]), need, what)
        if offset + word + need[0] > len(data):
            raise VtuError(f"{file.path}: {what}: {need[0]} bytes at {offset + word} run past the end of {where} "
                           f"({len(data)} bytes)")
        return data[offset + word:offset + word + need[0]]
    head = [int(v) for v in words(offset, 3)]
    _check_blocks(file, head, need, what)
    start = offset + (3 + head[0]) * word
    ends = _block_ends(file, words(offset + 3 * word, head[0]), len(data) - start, what, where)
    return _inflate(file, data[start:], ends, head, need, what)


def _base64_array(file, text, pos, need, what, where):
    """A base64 block at text[pos:]: uncompressed, [nbytes][data] in one run (VTK) or in two
    (MFEM); compressed, the header and the blocks in two runs."""
    word = file.header.itemsize
    if file.codec is None:
        first = _base64_run(file, text, pos, word, what, where, exact=False)
        _check_declared(file, int(np.frombuffer(first, file.header, 1)[0]), need, what)
        if len(first) == word:  # the header is a run of its own, not the start of one with the data
            return _base64_run(file, text, pos + _base64_length(word), need[0], what, where)
        return _base64_run(file, text, pos, word + need[0], what, where)[word:]
    head = [int(v) for v in np.frombuffer(_base64_run(file, text, pos, 3 * word, what, where, False), file.header, 3)]
    _check_blocks(file, head, need, what)
    header_bytes = (3 + head[0]) * word
    sizes = np.frombuffer(_base64_run(file, text, pos, header_bytes, what, where), file.header)[3:]
    start = pos + _base64_length(header_bytes)
    ends = _block_ends(file, sizes, (len(text) - start) * 3 // 4, what, where)
    compressed = _base64_run(file, text, start, int(ends[-1]) if ends.size else 0, what, where)
    return _inflate(file, memoryview(compressed), ends, head, need, what)
