"""Mutation test of the .vtu reader: corrupted variants of real solver exports (NGSolve, PyFR,
MFEM in ../shared/data/vtu, those present) and of a vtk-written Lagrange file in four encodings
must either load or raise a VtuError naming the file, within a time and memory bound; never
another exception, never read_vtu's catch-all ("unreadable (...)"), never a crash or a hang.

    python -m tests.fuzz.vtu_mutation [--cases 680] [--seed 7] [--jobs 1]      (from the repository root)

Each variant is read by read_vtu in a fresh subprocess limited to CASE_SECONDS of wall time and
CASE_MEMORY bytes of address space (RLIMIT_AS). Writes bench/results/vtu_mutation.json (counts
per mutation kind and outcome, every failure with its message). tests/io/test_vtu_mutation.py
runs a small deterministic sample of the same generator in-process.

The corruptions are made on the decoded arrays where that matters (wrong counts, out-of-range
connectivity, NaN/Inf, inverted or collapsed cells, bad HigherOrderDegrees) and re-encoded in the
file's own encoding (ascii, inline base64, appended base64 or raw, zlib/lzma blocks, UInt32/UInt64
headers, raw-appended offsets moved), or made on the bytes (truncation, bit flips, bad base64,
bad block headers, broken zlib/lzma streams, bad XML and attributes, huge declared sizes).
"""
from __future__ import annotations

import argparse
import base64
import datetime
import json
import lzma
import math
import os
import re
import subprocess
import sys
import tempfile
import time
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tests.helpers import REPO, find_data

RESULT = REPO / "bench" / "results" / "vtu_mutation.json"

# (file, field, component)
REAL_SOURCES = [
    ("mfem_fichera_poisson_mixed_p4.vtu", "u", None),  # inline base64, separate header, Float64
    ("ngsolve_ball_poisson_hex_p6.vtu", "u", None),  # appended raw, UInt32 header, Int32 connectivity
    ("pyfr_tgv_hexprism_p4_t4.vtu", "Velocity", "magnitude"),  # appended raw, UInt64, 2 pieces
]
# vtk-written Lagrange file: encoding -> writer settings
VTK_ENCODINGS = {
    "ascii": dict(mode="ascii", header=32, compressor=None, hod=False),
    "binary-zlib": dict(mode="binary", header=32, compressor="zlib", hod=True),
    "appended-base64-zlib-uint64": dict(mode="appended", header=64, compressor="zlib", hod=False),
    "raw-lzma-uint64": dict(mode="raw", header=64, compressor="lzma", hod=True),
}
CASE_SECONDS = 20.0  # a case slower than this counts as a hang
CASE_MEMORY = 2 << 30  # RLIMIT_AS of a worker: reading the largest real file peaks far below
KINDS = ["truncate", "byte_flip", "bad_base64", "bad_block_header", "bad_compressed", "count_attr",
         "conn_count", "conn_range", "offsets", "cell_type", "higher_order_degrees", "nan_inf",
         "invert", "collapse", "huge_size", "xml_struct", "attr_garbage"]

NP_TYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "<i2", "UInt16": "<u2", "Int32": "<i4", "UInt32": "<u4",
            "Int64": "<i8", "UInt64": "<u8", "Float32": "<f4", "Float64": "<f8"}


# ---------------------------------------------------------------------------------------------
# The vtk-written source

def write_vtk_lagrange(path, mode="ascii", header=32, compressor=None, hod=False, big_endian=False):
    """A small vtk-written file: Lagrange hexahedra, tetrahedra and wedges of degrees 2 and 3
    (plus an anisotropic hex and wedge when HigherOrderDegrees are written), mildly curved,
    nodes not shared, a scalar 'g' and a vector 'gvec'."""
    import vtk

    from hovr_blender.io import vtu

    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetDataTypeToDouble()
    g = vtk.vtkDoubleArray()
    g.SetName("g")
    gv = vtk.vtkDoubleArray()
    gv.SetName("gvec")
    gv.SetNumberOfComponents(3)
    degs_arr = vtk.vtkIntArray()
    degs_arr.SetName("HigherOrderDegrees")
    degs_arr.SetNumberOfComponents(3)
    cells = [(72, (2, 2, 2)), (72, (3, 3, 3)), (71, (2, 2, 2)), (71, (3, 3, 3)), (73, (2, 2, 2)), (73, (3, 3, 3))]
    if hod:
        cells += [(72, (2, 3, 1)), (73, (2, 2, 3))]
    for c, (t, degs) in enumerate(cells):
        shape = vtu.CELL_TYPES[t][1]
        r = vtu.vtk_node_params(shape, degs)
        x = np.array([1.2 * c, 0.0, 0.0]) + r + 0.08 * np.stack([r[:, 1] ** 2, r[:, 2] * r[:, 0], r[:, 0] ** 2], 1)
        ids = [pts.InsertNextPoint(*p) for p in x]
        for p in x:
            val = 1.0 + p[0] - 0.5 * p[1] ** 2 + p[0] * p[2]
            g.InsertNextValue(val)
            gv.InsertNextTuple3(val, -p[1], 0.5)
        ug.InsertNextCell(t, len(ids), ids)
        degs_arr.InsertNextTuple3(*degs)
    ug.SetPoints(pts)
    ug.GetPointData().AddArray(g)
    ug.GetPointData().AddArray(gv)
    if hod:
        ug.GetCellData().SetHigherOrderDegrees(degs_arr)
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(path))
    w.SetInputData(ug)
    {"ascii": w.SetDataModeToAscii, "binary": w.SetDataModeToBinary,
     "appended": w.SetDataModeToAppended, "raw": w.SetDataModeToAppended}[mode]()
    if mode == "raw":
        w.SetEncodeAppendedData(False)
    if header == 64:
        w.SetHeaderTypeToUInt64()
    if big_endian:
        w.SetByteOrderToBigEndian()
    {None: w.SetCompressorTypeToNone, "zlib": w.SetCompressorTypeToZLib,
     "lzma": w.SetCompressorTypeToLZMA}[compressor]()
    if w.Write() != 1:
        raise RuntimeError(f"vtk could not write {path}")
    return path


def sources(tmp: Path):
    """[(label, path, field, component)] : the real files, then the vtk-written encodings."""
    real = [(name, find_data("vtu", name), f, c) for name, f, c in REAL_SOURCES]
    out = [(name.split("_")[0], path, f, c) for name, path, f, c in real if path is not None]
    for enc, kw in VTK_ENCODINGS.items():
        p = write_vtk_lagrange(tmp / f"vtk_lagrange_{enc}.vtu", **kw)
        out.append((f"vtk-{enc}", p, "g", None))
    return out


# ---------------------------------------------------------------------------------------------
# A .vtu split into its arrays (decoded and re-encoded in the file's own encoding)

@dataclass
class Arr:
    index: int
    piece: int  # -1: FieldData outside pieces
    section: str  # Points, Cells, PointData, CellData, FieldData
    attrs: dict
    tag: tuple  # (start, end) of the opening tag in the file
    body: tuple | None = None  # inline: (start, end) of the text between the tag and the next '<'
    offset: int | None = None  # appended: offset after '_'
    length: int | None = None  # appended: bytes of the block

    @property
    def name(self):
        return self.attrs.get("Name", "")

    @property
    def fmt(self):
        return self.attrs.get("format", "ascii")

    @property
    def dtype(self):
        return np.dtype(NP_TYPES[self.attrs["type"]])

    @property
    def ncomp(self):
        return int(self.attrs.get("NumberOfComponents") or 1)


@dataclass
class Block:
    header: list  # uncompressed: [nbytes]; compressed: [nblocks, blocksize, last, csize...]
    payload: bytes  # uncompressed data, or the concatenated compressed chunks
    style: str  # "raw", "joint" (one base64 run) or "separate" (header and data encoded apart)


def _b64len(n):
    return 4 * math.ceil(n / 3)


def _attrs(tag: bytes) -> dict:
    return {k.decode(): v.decode() for k, v in re.findall(rb'([A-Za-z_][\w.-]*)="([^"]*)"', tag)}


class Doc:
    def __init__(self, raw: bytes):
        self.raw = raw
        app = re.search(rb"<AppendedData\b[^>]*>", raw)
        self.head_end = app.start() if app else len(raw)
        head = raw[: self.head_end]
        m = re.search(rb"<VTKFile\b[^>]*>", head)
        self.vtkfile_tag = (m.start(), m.end())
        self.top = _attrs(m.group(0))
        self.hsize = 8 if self.top.get("header_type") == "UInt64" else 4
        self.hdtype = np.dtype("<u8" if self.hsize == 8 else "<u4")
        self.compressor = {"vtkZLibDataCompressor": "zlib", "vtkLZMADataCompressor": "lzma"}.get(
            self.top.get("compressor"))
        self.app_tag = (app.start(), app.end()) if app else None
        self.app_encoding = _attrs(app.group(0)).get("encoding") if app else None
        if app:
            u = raw.index(b"_", app.end())
            self.app_start = u + 1
        self.arrays: list[Arr] = []
        self.pieces = []  # (start, end) of each <Piece> tag
        piece, section = -1, None
        for t in re.finditer(rb"<(/?)(Piece|Points|Cells|PointData|CellData|FieldData|DataArray)\b([^>]*?)(/?)>", head):
            closing, tag = t.group(1), t.group(2).decode()
            if closing:
                if tag in ("PointData", "CellData", "FieldData", "Points", "Cells"):
                    section = None
                continue
            if tag == "Piece":
                piece += 1
                self.pieces.append((t.start(), t.end()))
                continue
            if tag != "DataArray":
                section = tag
                continue
            a = Arr(len(self.arrays), piece if section != "FieldData" else -1, section or "", _attrs(t.group(0)),
                    (t.start(), t.end()))
            if a.fmt == "appended":
                a.offset = int(a.attrs["offset"])
            elif not t.group(4):
                a.body = (t.end(), head.index(b"<", t.end()))
            self.arrays.append(a)
        if app:
            self._block_lengths()
        self._values = {}

    def _block_lengths(self):
        apps = sorted((a for a in self.arrays if a.offset is not None), key=lambda a: a.offset)
        data = self.raw[self.app_start:]
        if self.app_encoding == "raw":
            for a in apps:
                a.length = self.hsize * len(self._raw_header(a.offset)) + self._payload_len(self._raw_header(a.offset))
        else:
            end = re.match(rb"[A-Za-z0-9+/=]*", data).end()
            for a, b in zip(apps, apps[1:] + [None]):
                a.length = (b.offset if b is not None else end) - a.offset

    def _raw_header(self, off):
        data = self.raw[self.app_start + off:]
        first = int(np.frombuffer(data[: self.hsize], self.hdtype)[0])
        if self.compressor is None:
            return [first]
        return [int(v) for v in np.frombuffer(data[: self.hsize * (3 + first)], self.hdtype)]

    def _payload_len(self, header):
        return header[0] if self.compressor is None else sum(header[3:])

    # ---- blocks
    def block_span(self, a: Arr):
        """(start, end) of the array's encoded bytes in the file."""
        if a.offset is not None:
            return self.app_start + a.offset, self.app_start + a.offset + a.length
        return a.body

    def block(self, a: Arr) -> Block:
        s, e = self.block_span(a)
        enc = self.raw[s:e]
        if a.offset is not None and self.app_encoding == "raw":
            h = self._raw_header(a.offset)
            return Block(h, enc[self.hsize * len(h):], "raw")
        text = re.sub(rb"\s+", b"", enc)
        if self.compressor is None:
            hc = _b64len(self.hsize)
            if text[hc - 1:hc] == b"=":
                n = int(np.frombuffer(base64.b64decode(text[:hc])[: self.hsize], self.hdtype)[0])
                return Block([n], base64.b64decode(text[hc:]), "separate")
            allb = base64.b64decode(text)
            n = int(np.frombuffer(allb[: self.hsize], self.hdtype)[0])
            return Block([n], allb[self.hsize:self.hsize + n], "joint")
        nb = int(np.frombuffer(base64.b64decode(text[:_b64len(self.hsize)])[: self.hsize], self.hdtype)[0])
        hc = _b64len(self.hsize * (3 + nb))
        h = [int(v) for v in np.frombuffer(base64.b64decode(text[:hc])[: self.hsize * (3 + nb)], self.hdtype)]
        return Block(h, base64.b64decode(text[hc:]), "separate")

    def encode_block(self, b: Block) -> bytes:
        hb = np.asarray(b.header, dtype=np.uint64).astype(self.hdtype).tobytes()
        if b.style == "raw":
            return hb + b.payload
        if b.style == "joint":
            return base64.b64encode(hb + b.payload)
        return base64.b64encode(hb) + base64.b64encode(b.payload)

    def pack(self, data: bytes, style: str, compressor=None) -> Block:
        """A block holding these bytes, compressed like the file (VTK's 32 KiB blocks)."""
        if compressor is None:
            return Block([len(data)], data, style)
        bs = 32768
        chunks = [data[i:i + bs] for i in range(0, len(data), bs)] or [b""]
        comp = [zlib.compress(c) if compressor == "zlib" else lzma.compress(c) for c in chunks]
        return Block([len(chunks), bs, len(chunks[-1])] + [len(c) for c in comp], b"".join(comp), style)

    def values(self, a: Arr) -> np.ndarray:
        """Decoded (flat) values of an array of the unmodified file (cached)."""
        if a.index not in self._values:
            if a.offset is None and a.fmt == "ascii":
                text = self.raw[a.body[0]:a.body[1]].decode()
                v = np.array([float(x) for x in text.split()]) if a.dtype.kind == "f" else \
                    np.array([int(x) for x in text.split()], dtype=np.int64)
                v = v.astype(a.dtype)
            else:
                b = self.block(a)
                if self.compressor is not None:
                    dec = zlib.decompress if self.compressor == "zlib" else lzma.decompress
                    offs = np.concatenate([[0], np.cumsum(b.header[3:])]).astype(np.int64)
                    data = b"".join(dec(b.payload[offs[k]:offs[k + 1]]) for k in range(b.header[0]))
                else:
                    data = b.payload
                v = np.frombuffer(data, a.dtype).copy()
            v.setflags(write=False)
            self._values[a.index] = v
        return self._values[a.index]

    def encode_values(self, a: Arr, v: np.ndarray) -> bytes:
        """The array's new encoded bytes (same format, style and compression)."""
        v = np.asarray(v).astype(a.dtype.newbyteorder("<"), copy=False).reshape(-1)
        if a.offset is None and a.fmt == "ascii":
            items = [repr(float(x)) for x in v] if v.dtype.kind == "f" else [str(int(x)) for x in v]
            return ("\n" + " ".join(items) + "\n").encode()
        style = "raw" if a.offset is not None and self.app_encoding == "raw" else self.block(a).style
        return self.encode_block(self.pack(v.tobytes(), style, self.compressor))

    # ---- edits
    def attr_edit(self, span, key, value):
        """An edit (start, end, bytes) setting attribute key of the tag at span (inserted if absent)."""
        s, e = span
        m = re.search(rb'\b' + re.escape(key.encode()) + rb'="([^"]*)"', self.raw[s:e])
        if m:
            return (s + m.start(1), s + m.end(1), str(value).encode())
        end = e - (2 if self.raw[e - 2:e] == b"/>" else 1)
        return (end, end, f' {key}="{value}"'.encode())

    def build(self, edits=(), blocks=None) -> bytes:
        """The file with byte edits (start, end, new) before the appended data applied, and
        encoded blocks {array index: bytes} replaced (inline bodies or appended blocks; appended
        offsets are rewritten to follow)."""
        blocks = dict(blocks or {})
        edits = list(edits)
        for idx, enc in list(blocks.items()):
            a = self.arrays[idx]
            if a.offset is None:
                edits.append((a.body[0], a.body[1], enc))
                del blocks[idx]
        limit = self.app_start if self.app_tag else len(self.raw)
        tail = b""
        if self.app_tag:
            data = self.raw[self.app_start:]
            apps = sorted((a for a in self.arrays if a.offset is not None), key=lambda a: a.offset)
            new, pos, seen = bytearray(), 0, {}
            for a in apps:
                if a.offset in seen:  # two arrays sharing a block
                    if seen[a.offset] != a.offset:
                        edits.append(self.attr_edit(a.tag, "offset", seen[a.offset]))
                    continue
                new += data[pos:a.offset]
                seen[a.offset] = len(new)
                if len(new) != a.offset:
                    edits.append(self.attr_edit(a.tag, "offset", len(new)))
                new += blocks.get(a.index, data[a.offset:a.offset + a.length])
                pos = a.offset + a.length
            new += data[pos:]
            tail = bytes(new)
        out = self.raw[:limit]
        for s, e, b in sorted(edits, key=lambda x: (x[0], x[1]), reverse=True):
            if e > limit:
                raise ValueError("edit inside the appended data")
            out = out[:s] + b + out[e:]
        return out + tail

    def with_values(self, a: Arr, v, edits=()) -> bytes:
        return self.build(edits, {a.index: self.encode_values(a, v)})

    def identity(self) -> bytes:
        """Every array decoded and re-encoded: must read exactly like the original."""
        return self.build((), {a.index: self.encode_values(a, self.values(a)) for a in self.arrays})

    # ---- lookups
    def find(self, piece, section, name=None):
        for a in self.arrays:
            if a.piece == piece and a.section == section and (name is None or a.name == name):
                return a
        return None

    def npieces(self):
        return len(self.pieces)

    def piece_attr(self, piece, key):
        return int(_attrs(self.raw[self.pieces[piece][0]:self.pieces[piece][1]])[key])


# ---------------------------------------------------------------------------------------------
# Mutations

def _pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


def _cell_piece(rng, doc):
    """A piece with cells, and its decoded cell arrays."""
    p = int(rng.integers(doc.npieces()))
    conn, offs, types = (doc.find(p, "Cells", n) for n in ("connectivity", "offsets", "types"))
    pts = doc.find(p, "Points")
    return p, conn, offs, types, pts


def _int_limits(dt):
    info = np.iinfo(dt)
    return int(info.min), int(info.max)


def _clip_to(dt, values):
    lo, hi = _int_limits(dt)
    return [v for v in values if lo <= v <= hi] or [hi]


def _corner_count(t):
    return {71: 4, 78: 4, 10: 4, 72: 8, 79: 8, 12: 8, 73: 6, 80: 6, 13: 6}.get(int(t), 1)


def _encoded_arrays(doc):
    return [a for a in doc.arrays if a.fmt in ("binary", "appended")]


def mutate(rng: np.random.Generator, doc: Doc, kind: str):
    """(detail, new bytes): one corrupted variant of doc of the given kind."""
    raw = doc.raw

    if kind == "truncate":
        cut = int(rng.integers(doc.head_end)) if rng.random() < 0.3 else int(rng.integers(len(raw)))
        return f"at {cut}/{len(raw)}", raw[:cut]

    if kind == "byte_flip":
        a = _pick(rng, doc.arrays)
        s, e = doc.block_span(a) if (a.body or a.offset is not None) else (a.tag[0], a.tag[1])
        buf = bytearray(raw)
        n = int(rng.integers(1, 5))
        for _ in range(n):
            i = int(rng.integers(s, max(s + 1, e)))
            if doc.app_encoding == "raw" and a.offset is not None:
                buf[i] ^= 1 << int(rng.integers(8))
            elif a.fmt == "ascii":
                if chr(buf[i]).isdigit():
                    buf[i] = ord(str(int(rng.integers(10))))
            elif chr(buf[i]).isalnum() or buf[i] in b"+/":
                buf[i] = ord(_pick(rng, "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/"))
        return f"{a.section}/{a.name} x{n}", bytes(buf)

    if kind == "bad_base64":
        b64 = [a for a in doc.arrays if a.fmt == "binary" or (a.offset is not None and doc.app_encoding == "base64")]
        if b64:
            a = _pick(rng, b64)
            s, e = doc.block_span(a)
            i = int(rng.integers(s, e))
            how = int(rng.integers(4))
            new = [b"!", b"*~", b"", b"=="][how]
            e2 = i if how == 3 else i + 1
            return f"{a.section}/{a.name} {['bang', 'junk', 'drop', 'pad'][how]} at {i - s}", raw[:i] + new + raw[e2:]
        if doc.app_tag:  # raw appended data declared base64
            return "raw data declared base64", doc.build([doc.attr_edit(doc.app_tag, "encoding", "base64")])
        a = _pick(rng, doc.arrays)  # ascii text declared binary
        return f"{a.section}/{a.name} ascii declared binary", doc.build([doc.attr_edit(a.tag, "format", "binary")])

    if kind == "bad_block_header" and not _encoded_arrays(doc):  # ascii: an unparseable number
        a = _pick(rng, [a for a in doc.arrays if a.body and a.body[1] > a.body[0] + 1])
        s, e = a.body
        i = int(rng.integers(s, e))
        junk = _pick(rng, [b" 1.0zz ", b" 0x10 ", b" --1 ", b" 1e ", b" , "])
        return f"{a.section}/{a.name} ascii junk {junk!r}", raw[:i] + junk + raw[i:]
    if kind == "bad_block_header":
        a = _pick(rng, _encoded_arrays(doc))
        b = doc.block(a)
        big = (1 << 8 * doc.hsize) - 1
        if doc.compressor is None:
            n = b.header[0]
            b.header[0] = _pick(rng, [0, max(n - 1, 0), n + 1, max(n - a.dtype.itemsize, 0), n + a.dtype.itemsize,
                                      n // 2, 2 * n, (1 << 31) - 1, big])
            what = f"nbytes {n} -> {b.header[0]}"
        else:
            j = int(rng.integers(len(b.header)))
            old = b.header[j]
            b.header[j] = _pick(rng, [0, old + 1, max(old - 1, 0), 2 * old + 7, (1 << 31) - 1, big])
            what = f"header[{j}] {old} -> {b.header[j]}"
            if j == 0 and b.header[0] > old:  # a longer header: keep the stated number of sizes
                b.header += [int(rng.integers(1, 64))] * min(b.header[0] - old, 4)
        return f"{a.section}/{a.name} {what}", doc.build((), {a.index: doc.encode_block(b)})

    if kind == "bad_compressed":
        if doc.compressor is None:
            c = _pick(rng, ["vtkZLibDataCompressor", "vtkLZMADataCompressor", "vtkLZ4DataCompressor"])
            return f"compressor {c} on uncompressed data", doc.build([doc.attr_edit(doc.vtkfile_tag, "compressor", c)])
        how = int(rng.integers(4))
        if how == 0:  # compressed data read as uncompressed
            s, e = doc.vtkfile_tag
            m = re.search(rb'\scompressor="[^"]*"', raw[s:e])
            return "compressor attribute removed", doc.build([(s + m.start(), s + m.end(), b"")])
        a = _pick(rng, _encoded_arrays(doc))
        b = doc.block(a)
        if how == 1:  # flip bits inside a compressed chunk
            p = bytearray(b.payload)
            for _ in range(int(rng.integers(1, 4))):
                p[int(rng.integers(len(p)))] ^= 1 << int(rng.integers(8))
            b.payload = bytes(p)
            return f"{a.section}/{a.name} chunk bits", doc.build((), {a.index: doc.encode_block(b)})
        if how == 2:  # not a zlib/lzma stream at all
            b.payload = bytes(rng.integers(0, 256, len(b.payload), dtype=np.uint8))
            return f"{a.section}/{a.name} chunk random", doc.build((), {a.index: doc.encode_block(b)})
        mb = int(rng.integers(1, 65))  # a bomb: a valid block inflating to mb MiB of zeros
        nb = doc.pack(bytes(mb << 20), b.style, doc.compressor)
        return f"{a.section}/{a.name} {mb} MiB of zeros", doc.build((), {a.index: doc.encode_block(nb)})

    if kind == "count_attr":
        how = int(rng.integers(3))
        if how < 2:
            p = int(rng.integers(doc.npieces()))
            key = ["NumberOfPoints", "NumberOfCells"][how]
            n = doc.piece_attr(p, key)
            v = _pick(rng, [0, n - 1, n + 1, n // 2, 2 * n, n + int(rng.integers(2, 50)), -1])
            return f"piece {p} {key} {n} -> {v}", doc.build([doc.attr_edit(doc.pieces[p], key, v)])
        a = _pick(rng, [a for a in doc.arrays if a.section != "FieldData"])
        v = _pick(rng, ["1", "2", "3", "4", "9", "0", "-1", ""])
        return f"{a.section}/{a.name} NumberOfComponents -> {v!r}", doc.build([doc.attr_edit(a.tag, "NumberOfComponents", v)])

    if kind in ("conn_count", "conn_range", "offsets", "cell_type", "invert", "collapse", "higher_order_degrees"):
        p, conn_a, offs_a, types_a, pts_a = _cell_piece(rng, doc)
        conn = doc.values(conn_a).astype(np.int64)
        offs = doc.values(offs_a).astype(np.int64)
        types = doc.values(types_a).astype(np.int64)
        nc = offs.size
        c = int(rng.integers(nc))
        start = int(offs[c - 1]) if c else 0
        end = int(offs[c])

    if kind == "conn_count":
        how = int(rng.integers(4))
        k = int(rng.integers(1, 4))
        if how == 0:  # k nodes fewer in cell c, offsets kept consistent
            k = min(k, end - start - 1)
            conn2 = np.delete(conn, np.arange(end - k, end))
            offs2 = offs.copy()
            offs2[c:] -= k
            return f"piece {p} cell {c}: {k} nodes fewer", doc.build((), {
                conn_a.index: doc.encode_values(conn_a, conn2), offs_a.index: doc.encode_values(offs_a, offs2)})
        if how == 1:  # k nodes more (repeats)
            conn2 = np.insert(conn, end, conn[start:start + k])
            offs2 = offs.copy()
            offs2[c:] += k
            return f"piece {p} cell {c}: {k} nodes more", doc.build((), {
                conn_a.index: doc.encode_values(conn_a, conn2), offs_a.index: doc.encode_values(offs_a, offs2)})
        if how == 2:  # connectivity shorter than the offsets say
            return f"piece {p}: connectivity lacks {k} entries", doc.with_values(conn_a, conn[:-k])
        return f"piece {p}: offsets lack the last {k}", doc.with_values(offs_a, offs[:-k])

    if kind == "conn_range":
        npts = doc.piece_attr(p, "NumberOfPoints")
        i = int(rng.integers(start, end))
        v = _pick(rng, _clip_to(conn_a.dtype, [npts, npts + 7, -1, (1 << 31) - 1, -(1 << 31), (1 << 63) - 1, 1 << 40]))
        conn2 = conn.copy()
        conn2[i] = v
        return f"piece {p} cell {c}: node {i - start} -> {v}", doc.with_values(conn_a, conn2.astype(conn_a.dtype))

    if kind == "offsets":
        offs2 = offs.copy()
        how = int(rng.integers(6))
        if how == 0:
            offs2[c] += _pick(rng, [-1, 1, -2, 3])
        elif how == 1 and nc > 1:
            j = min(c, nc - 2)
            offs2[[j, j + 1]] = offs2[[j + 1, j]]
        elif how == 2:
            offs2[c] = 0
        elif how == 3:
            offs2[-1] += int(rng.integers(1, 10))
        elif how == 4:
            offs2[c] = _pick(rng, _clip_to(offs_a.dtype, [-1, -(1 << 31), (1 << 62)]))
        else:
            offs2 = np.concatenate([[0], offs2])  # offsets with VTK's leading zero (legacy style)
        return f"piece {p} cell {c}: offsets how {how}", doc.with_values(offs_a, offs2.astype(offs_a.dtype))

    if kind == "cell_type":
        v = _pick(rng, [0, 1, 5, 7, 9, 10, 12, 13, 14, 25, 42, 68, 69, 70, 71, 72, 73, 74, 75, 77, 78, 79, 80, 81, 255])
        types2 = types.copy()
        if rng.random() < 0.3:
            types2[:] = v
            what = "all"
        else:
            types2[c] = v
            what = f"cell {c}"
        return f"piece {p} {what}: type {types[c]} -> {v}", doc.with_values(types_a, types2.astype(types_a.dtype))

    if kind == "higher_order_degrees":
        from hovr_blender.io import vtu
        from hovr_blender.io.vtu import cells as vtu_cells

        degs = []
        for j in range(nc):
            shape = vtu.CELL_TYPES.get(int(types[j]), (None, None))[1]
            n = int(offs[j] - (offs[j - 1] if j else 0))
            d = vtu_cells.infer_degrees(shape, n) if shape is not None else None
            degs.append(d or (1, 1, 1))
        hod_a = doc.find(p, "CellData", "HigherOrderDegrees")
        if hod_a is not None:
            degs = doc.values(hod_a).reshape(-1, 3).astype(np.int64)
        degs = np.array(degs, dtype=np.int64)
        how = int(rng.integers(6))
        d2 = degs.astype(np.float64)
        if how == 0:
            d2[c, int(rng.integers(3))] = _pick(rng, [0, -1, -7])
        elif how == 1:
            d2[c, int(rng.integers(3))] += _pick(rng, [1, -1, 2])
        elif how == 2:
            d2[c] = _pick(rng, [100, 10**6, 2**31 - 1])
        elif how == 3:
            d2[c, 0] += 0.5
        elif how == 4:
            d2 = d2[:-1]
        # how 5: the correct degrees (must load)
        if hod_a is not None and how not in (2, 3):
            return f"piece {p} cell {c}: HigherOrderDegrees how {how}", doc.with_values(hod_a, d2.astype(hod_a.dtype))
        typ = "Float64" if how == 3 else "Int32"
        text = " ".join(repr(float(x)) if how == 3 else str(int(x)) for x in d2.ravel())
        arr = f'<DataArray type="{typ}" Name="HigherOrderDegrees" NumberOfComponents="3" format="ascii">{text}</DataArray>'
        edits = []
        if hod_a is not None:  # replace the encoded one by an inline ascii one
            edits.append(doc.attr_edit(hod_a.tag, "Name", "OldHigherOrderDegrees"))
        ps, pe = doc.pieces[p]
        cd = re.search(rb"<CellData\b[^>]*?(/?)>", raw[pe:])
        nxt = raw.find(b"<Piece", pe)
        if cd and (nxt < 0 or pe + cd.start() < nxt) and not cd.group(1):
            edits.append((pe + cd.end(), pe + cd.end(), arr.encode()))
        else:
            edits.append((pe, pe, f"<CellData>{arr}</CellData>".encode()))
        return f"piece {p} cell {c}: HigherOrderDegrees how {how} (added ascii)", doc.build(edits)

    if kind == "nan_inf":
        cands = [a for a in doc.arrays if a.section in ("Points", "PointData") and a.dtype.kind == "f"]
        a = _pick(rng, cands)
        v = doc.values(a).copy()
        k = int(rng.integers(1, 4))
        bad = _pick(rng, [np.nan, np.inf, -np.inf, 1e308, -1e308, 1e300, 3e38])
        idx = rng.integers(v.size, size=k)
        v[idx] = bad
        return f"{a.section}/{a.name} {k} x {bad}", doc.with_values(a, v)

    if kind in ("invert", "collapse"):
        nodes = conn[start:end]
        P = doc.values(pts_a).reshape(-1, 3).copy()
        X = P[nodes]
        ctr = X.mean(axis=0)
        nco = min(_corner_count(types[c]), nodes.size)
        how = int(rng.integers(4))
        if kind == "invert":
            if how == 0 and nco >= 2:  # two corners swapped in the connectivity
                conn2 = conn.copy()
                i, j = rng.choice(nco, 2, replace=False)
                conn2[start + i], conn2[start + j] = conn[start + j], conn[start + i]
                return f"piece {p} cell {c}: corners {i},{j} swapped", doc.with_values(conn_a, conn2.astype(conn_a.dtype))
            if how == 1:  # node list reversed
                conn2 = conn.copy()
                conn2[start:end] = conn[start:end][::-1]
                return f"piece {p} cell {c}: nodes reversed", doc.with_values(conn_a, conn2.astype(conn_a.dtype))
            if how == 2:  # one corner pushed through the opposite side
                i = int(rng.integers(nco))
                P[nodes[i]] = ctr + 1.5 * (ctr - X[i])
                return f"piece {p} cell {c}: corner {i} pushed through", doc.with_values(pts_a, P.ravel())
            ax = int(rng.integers(3))  # whole cell mirrored in place: valid, left-handed
            P[nodes, ax] = 2 * ctr[ax] - X[:, ax]
            return f"piece {p} cell {c}: mirrored in axis {ax}", doc.with_values(pts_a, P.ravel())
        if how == 0:
            P[nodes] = ctr
            what = "to its centroid"
        elif how == 1:
            ax = int(rng.integers(3))
            P[nodes, ax] = ctr[ax]
            what = f"flattened in axis {ax}"
        elif how == 2 and nco >= 2:
            i, j = rng.choice(nco, 2, replace=False)
            P[nodes[i]] = X[j]
            what = f"corner {i} onto corner {j}"
        else:
            s = _pick(rng, [1e-12, 1e-200])
            P[nodes] = ctr + s * (X - ctr)
            what = f"scaled by {s}"
        return f"piece {p} cell {c}: collapsed {what}", doc.with_values(pts_a, P.ravel())

    if kind == "huge_size":
        how = int(rng.integers(5))
        if how == 0:
            p = int(rng.integers(doc.npieces()))
            key = _pick(rng, ["NumberOfPoints", "NumberOfCells"])
            v = 10 ** int(rng.integers(9, 20))
            return f"piece {p} {key} = {v}", doc.build([doc.attr_edit(doc.pieces[p], key, v)])
        if how == 1:
            a = _pick(rng, [a for a in doc.arrays if a.section != "FieldData"])
            v = _pick(rng, [10**6, 10**9, 2**31 - 1, 10**18])
            return f"{a.section}/{a.name} NumberOfComponents = {v}", doc.build([doc.attr_edit(a.tag, "NumberOfComponents", v)])
        enc = _encoded_arrays(doc)
        if how == 2 and enc:
            a = _pick(rng, enc)
            b = doc.block(a)
            b.header[0] = _pick(rng, [(1 << 8 * doc.hsize) - 1, 1 << (8 * doc.hsize - 2), 10**9])
            if doc.compressor is not None:
                b.header[1] = b.header[0]
            return f"{a.section}/{a.name} declared {b.header[0]} (block header)", doc.build((), {a.index: doc.encode_block(b)})
        apps = [a for a in doc.arrays if a.offset is not None]
        if how == 3 and apps:
            a = _pick(rng, apps)
            v = _pick(rng, [10**15, 2**63, -1, a.offset + 1])
            return f"{a.section}/{a.name} offset = {v}", doc.build([doc.attr_edit(a.tag, "offset", v)])
        a = _pick(rng, doc.arrays)  # NumberOfTuples (FieldData) or a RangeMax that does not matter
        v = 10 ** int(rng.integers(9, 20))
        return f"{a.section}/{a.name} NumberOfTuples = {v}", doc.build([doc.attr_edit(a.tag, "NumberOfTuples", v)])

    if kind == "xml_struct":
        head = raw[:doc.head_end]
        lines = [m.span() for m in re.finditer(rb"[^\n]*\n", head)]
        s, e = _pick(rng, lines)
        how = int(rng.integers(6))
        if how == 0:
            return f"line {s} deleted", raw[:s] + raw[e:]
        if how == 1:
            return f"line {s} duplicated", raw[:e] + raw[s:e] + raw[e:]
        if how == 2:
            tags = [m.span() for m in re.finditer(rb"</(Piece|PointData|CellData|Cells|Points|DataArray|UnstructuredGrid)>", head)]
            ts, te = _pick(rng, tags)
            return f"closing tag at {ts} removed", raw[:ts] + raw[te:]
        if how == 3:
            tags = [m.span(1) for m in re.finditer(rb"<(Piece|Points|Cells|PointData|DataArray|UnstructuredGrid)\b", head)]
            ts, te = _pick(rng, tags)
            return f"tag at {ts} renamed", raw[:ts] + b"Xyz" + raw[te:]
        if how == 4:
            return "DOCTYPE inserted", raw[:doc.vtkfile_tag[0]] + b'<!DOCTYPE v [<!ENTITY a "aaaa">]>\n' + raw[doc.vtkfile_tag[0]:]
        i = int(rng.integers(doc.head_end))
        return f"'<<&' inserted at {i}", raw[:i] + b"<<&" + raw[i:]

    # attr_garbage
    tags = [doc.vtkfile_tag] + doc.pieces + [a.tag for a in doc.arrays] + ([doc.app_tag] if doc.app_tag else [])
    span = _pick(rng, tags)
    attrs = list(_attrs(raw[span[0]:span[1]]))
    key = _pick(rng, attrs)
    v = _pick(rng, ["", "x", "-1", "1e999", "0x10", "Float128", "BigEndian", "ascii", "binary", "appended",
                    "Int8", "UInt64", "Float32", "Int32", "9.9", "nan", "raw", "UInt16"])
    return f"{key}={v!r}", doc.build([doc.attr_edit(span, key, v)])


# ---------------------------------------------------------------------------------------------
# Running a case

WORKER = r"""
import json, resource, sys
path, field, comp, mem = json.loads(sys.argv[1])
import numpy as np
from hovr_blender.io.vtu import VtuError, read_vtu
resource.setrlimit(resource.RLIMIT_AS, (mem, mem))
try:
    m = read_vtu(path, field, comp)
    ok = bool(np.isfinite(m.coeffs).all() and np.isfinite(m.geom_coeffs).all())
    out = {"outcome": "loaded" if ok else "loaded_nonfinite", "elements": m.num_elements}
except VtuError as exc:
    cause, chain = exc.__cause__, []
    e = exc
    while e is not None and len(chain) < 16:
        chain.append(type(e).__name__)
        e = e.__cause__ or e.__context__
    out = {"outcome": "vtu_error", "type": type(exc).__name__, "message": str(exc),
           "cause": None if cause is None else type(cause).__name__, "chain": chain}
except BaseException as exc:
    out = {"outcome": "other_exception", "type": type(exc).__name__, "message": str(exc)[:500]}
sys.stdout.write("\n@@RESULT@@" + json.dumps(out) + "\n")
"""


def read_in_subprocess(path, fld, comp, case_seconds=CASE_SECONDS, memory=CASE_MEMORY):
    """Result dict of read_vtu in a fresh, time- and memory-limited Python."""
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    args = json.dumps([str(path), fld, comp, memory])
    t0 = time.perf_counter()
    try:
        pr = subprocess.run([sys.executable, "-c", WORKER, args], capture_output=True, timeout=case_seconds, env=env)
    except subprocess.TimeoutExpired:
        return {"outcome": "timeout", "seconds": round(time.perf_counter() - t0, 2)}
    dt = round(time.perf_counter() - t0, 2)
    out = pr.stdout.decode(errors="replace")
    if "@@RESULT@@" in out:
        res = json.loads(out.rsplit("@@RESULT@@", 1)[1])
    elif pr.returncode < 0:
        res = {"outcome": "crash", "message": f"killed by signal {-pr.returncode}"}
    else:
        res = {"outcome": "crash", "message": f"exit {pr.returncode}: {pr.stderr.decode(errors='replace')[-500:]}"}
    res["seconds"] = dt
    return res


def read_in_process(path, fld, comp):
    """The same classification without the subprocess (tests: the sample cannot hang)."""
    from hovr_blender.io.vtu import VtuError, read_vtu

    try:
        m = read_vtu(path, fld, comp)
        ok = bool(np.isfinite(m.coeffs).all() and np.isfinite(m.geom_coeffs).all())
        return {"outcome": "loaded" if ok else "loaded_nonfinite", "elements": m.num_elements}
    except VtuError as exc:
        cause = exc.__cause__
        return {"outcome": "vtu_error", "type": type(exc).__name__, "message": str(exc),
                "cause": None if cause is None else type(cause).__name__, "chain": exception_chain(exc)}
    except Exception as exc:
        return {"outcome": "other_exception", "type": type(exc).__name__, "message": str(exc)[:500]}


def classify(res, path):
    """Final category: loaded / vtu_error / unexpected (read_vtu's catch-all, or resource
    exhaustion) / unnamed (message lacks the file) / loaded_nonfinite / other_exception /
    crash / timeout."""
    o = res["outcome"]
    if o != "vtu_error":
        return o
    msg = res["message"]
    if str(path) not in msg:
        return "unnamed"
    # running out of memory under the worker's cap is no diagnosis, whatever the wrapping says
    if any("MemoryError" in t for t in res.get("chain", [])):
        return "unexpected"
    if ": unreadable (" in msg or "MemoryError" in msg or "RecursionError" in msg:
        return "unexpected"
    return "vtu_error"


def exception_chain(exc) -> list[str]:
    """Type names of exc and everything it was raised from or during."""
    chain = []
    while exc is not None and len(chain) < 16:
        chain.append(type(exc).__name__)
        exc = exc.__cause__ or exc.__context__
    return chain


GOOD = ("loaded", "vtu_error")


def make_case(i, seed, srcs, docs):
    """(source label, kind, detail, bytes, field, component) of case i (deterministic)."""
    rng = np.random.default_rng([seed, i])
    label, path, fld, comp = srcs[i % len(srcs)]
    kind = KINDS[(i // len(srcs)) % len(KINDS)]  # every (source, kind) pair within 7 x 17 cases
    detail, data = mutate(rng, docs[label], kind)
    return label, kind, detail, data, fld, comp


def run_cases(n_cases=680, seed=7, jobs=1, in_process=False, case_seconds=CASE_SECONDS, only=None, log=None):
    """Run n_cases mutations; returns the summary dict (every failure listed with its message).
    only: restrict to sources whose label starts with one of these."""
    summary = {"seed": seed, "cases": 0, "sources": {}, "outcomes": {}, "by_kind": {}, "by_source": {},
               "failures": [], "max_case_seconds": 0.0}
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        srcs = sources(tmp)
        if only:
            srcs = [s for s in srcs if s[0].startswith(tuple(only))]
        docs = {}
        for label, path, fld, comp in srcs:
            docs[label] = Doc(path.read_bytes())
            summary["sources"][label] = {"file": path.name if path.parent != tmp else f"(vtk 9 writer) {path.name}",
                                         "bytes": len(docs[label].raw), "field": fld, "component": comp}

        def one(i):
            label, kind, detail, data, fld, comp = make_case(i, seed, srcs, docs)
            p = tmp / f"case{i:04d}.vtu"
            p.write_bytes(data)
            try:
                res = read_in_process(p, fld, comp) if in_process else read_in_subprocess(p, fld, comp, case_seconds)
            finally:
                p.unlink(missing_ok=True)
            return i, label, kind, detail, res, classify(res, p)

        def record(i, label, kind, detail, res, cat):
            summary["cases"] += 1
            summary["outcomes"][cat] = summary["outcomes"].get(cat, 0) + 1
            for key, sub in (("by_kind", kind), ("by_source", label)):
                d = summary[key].setdefault(sub, {})
                d[cat] = d.get(cat, 0) + 1
            summary["max_case_seconds"] = max(summary["max_case_seconds"], res.get("seconds", 0.0))
            if cat not in GOOD:
                summary["failures"].append({"case": i, "source": label, "kind": kind, "detail": detail,
                                            "category": cat, **{k: v for k, v in res.items() if k != "outcome"}})
            if log:
                log(f"{i:4d} {label:32s} {kind:22s} {cat:10s} {res.get('seconds', 0):6.2f}s  {detail[:60]}"
                    + ("" if cat == "loaded" else f"  | {res.get('message', '')[-110:]}"))

        if jobs <= 1:
            for i in range(n_cases):
                record(*one(i))
        else:
            with ThreadPoolExecutor(jobs) as pool:
                for r in pool.map(one, range(n_cases)):
                    record(*r)
    summary["total_seconds"] = round(time.perf_counter() - t_all, 1)
    return summary


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=680)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=1, help="cases read at once (one subprocess each)")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--output", type=Path, default=RESULT)
    args = ap.parse_args()
    import vtk

    s = run_cases(args.cases, args.seed, args.jobs, log=None if args.quiet else lambda m: print(m, flush=True))
    s = {"date": datetime.date.today().isoformat(),
         "command": "python -m tests.fuzz.vtu_mutation " + " ".join(sys.argv[1:]),
         "vtk": vtk.vtkVersion.GetVTKVersion(), "case_seconds": CASE_SECONDS, "case_memory_bytes": CASE_MEMORY,
         **s}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(s, indent=1) + "\n")
    print(json.dumps({k: v for k, v in s.items() if k not in ("by_kind", "by_source", "failures")}, indent=1))
    bad = sum(v for k, v in s["outcomes"].items() if k not in GOOD)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
