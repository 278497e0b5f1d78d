"""The hostile inputs, one generator each: every class an attacker's probe found (issue 13), built
fresh in a folder (no stored bombs), with the exit code and the words the error must carry.

Each case's `build(folder)` writes its files and returns the `hovr` arguments; the harness runs
them in a subprocess and judges exit code, message, wall time and peak memory.
"""
from __future__ import annotations

import base64
import functools
import json
import lzma
import os
import re
import struct
import zlib
from pathlib import Path

import numpy as np

from .harness import Case, write_view

# -------------------------------------------------------------------------------- base data

# One affine hexahedron [-1, 1]^2 x [-4, -2] with 3 modes per direction (the layout of Nektar++'s
# Hex_01_01_01 regression mesh); f = x^2 + y^2 + z^2 exactly.
HEX_VERTICES = [(-1, -1, -4), (1, -1, -4), (1, 1, -4), (-1, 1, -4), (-1, -1, -2), (1, -1, -2), (1, 1, -2), (-1, 1, -2)]
HEX_EDGES = [(0, 1), (1, 2), (2, 3), (0, 3), (0, 4), (1, 5), (2, 6), (3, 7), (4, 5), (5, 6), (7, 6), (4, 7)]
HEX_FACES = [(0, 1, 2, 3), (0, 5, 8, 4), (1, 6, 9, 5), (2, 6, 10, 7), (3, 7, 11, 4), (8, 9, 10, 11)]


def nektar_mesh(composite="H[0]", domain="C[0]", vertex_scale=1.0, extra_composites="") -> str:
    verts = "".join(f'<V ID="{i}">{x * vertex_scale} {y * vertex_scale} {z * vertex_scale}</V>'
                    for i, (x, y, z) in enumerate(HEX_VERTICES))
    edges = "".join(f'<E ID="{i}">{a} {b}</E>' for i, (a, b) in enumerate(HEX_EDGES))
    faces = "".join(f'<Q ID="{i}">{" ".join(map(str, f))}</Q>' for i, f in enumerate(HEX_FACES))
    return (f'<?xml version="1.0"?>\n<NEKTAR><GEOMETRY DIM="3" SPACE="3"><VERTEX>{verts}</VERTEX>'
            f'<EDGE>{edges}</EDGE><FACE>{faces}</FACE><ELEMENT><H ID="0">0 1 2 3 4 5</H></ELEMENT>'
            f'<COMPOSITE><C ID="0">{composite}</C>{extra_composites}</COMPOSITE><DOMAIN>{domain}</DOMAIN>'
            f'</GEOMETRY></NEKTAR>\n')


def hex_coefficients() -> np.ndarray:
    """Modified_A coefficients (3 modes per direction) of x^2 + y^2 + z^2 on the hexahedron."""
    from hovr_blender.engine.expansions import fit_tensor_coefficients

    return fit_tensor_coefficients(lambda a, b, c: a * a + b * b + (c - 3.0) ** 2, (3, 3, 3))


def b64z(raw: bytes) -> str:
    z = zlib.compress(raw)
    z += b"\0" * (-len(z) % 3)
    return base64.b64encode(z).decode()


def nektar_field(values=None, ids="0", body=None) -> str:
    if body is None:
        body = b64z(np.asarray(hex_coefficients() if values is None else values, "<f8").tobytes())
    return (f'<?xml version="1.0"?>\n<NEKTAR><ELEMENTS FIELDS="p" SHAPE="Hexahedron" '
            f'BASIS="Modified_A,Modified_A,Modified_A" NUMMODESPERDIR="UNIORDER:3,3,3" ID="{ids}">'
            f'{body}</ELEMENTS></NEKTAR>\n')


def base_view(data: dict, width=32, height=24) -> dict:
    return {
        "data": data,
        "camera": {"projection": "perspective", "eye": [0.0, 0.0, 0.0], "target": [0.0, 0.0, -2.0],
                   "up": [0.0, 1.0, 0.0], "fov_y_deg": 60.0},
        "image": {"width": width, "height": height},
        "transfer_function": {"color": [[4.0, 1, 1, 1], [6.2, 1, 0, 0]],
                              "density": [[4.0, 0], [5.1, 10], [6.2, 0]]},
        "background": [1.0, 1.0, 1.0],
        "render": {"method": "split"},
    }


def render_args(folder: Path, view: dict, *extra) -> list[str]:
    return ["render", str(write_view(folder, view)), "-o", str(folder / "out.npy"), *extra]


def nektar_case(folder: Path, mesh=None, fld=None, view_extra=None, args=()):
    (folder / "m.xml").write_text(nektar_mesh() if mesh is None else mesh)
    data = {"path": "m.xml", "field": "p"}
    if fld is not None:
        if isinstance(fld, bytes):
            (folder / "m.fld").write_bytes(fld)
        elif isinstance(fld, str):
            (folder / "m.fld").write_text(fld)
        else:
            fld(folder / "m.fld")
        data["solution"] = "m.fld"
    view = base_view(data)
    view.update(view_extra or {})
    return render_args(folder, view, *args)


# -------------------------------------------------------------------------------- VTU bytes

VTK_TYPES = {np.dtype("<f4"): "Float32", np.dtype("<f8"): "Float64", np.dtype("<i4"): "Int32",
             np.dtype("<i8"): "Int64", np.dtype("u1"): "UInt8"}


def vtu_hex(blocks_for=None, compressor="vtkZLibDataCompressor", npoints=8) -> bytes:
    """A one-cell .vtu (a linear hexahedron, field f = z), appended raw, UInt32 headers, every
    array compressed in one block; `blocks_for` {array name: raw appended bytes} replaces an
    array's encoded data (the hostile part)."""
    pts = np.array(HEX_VERTICES, "<f4")
    arrays = [("Points", pts, 3, "Points"), ("connectivity", np.arange(8, dtype="<i4"), 1, "Cells"),
              ("offsets", np.array([8], "<i4"), 1, "Cells"), ("types", np.array([12], "u1"), 1, "Cells"),
              ("f", pts[:, 2].copy(), 1, "PointData")]
    codec = lzma.compress if compressor == "vtkLZMADataCompressor" else zlib.compress
    blob, tags = b"", {"Points": [], "Cells": [], "PointData": []}
    for name, a, nc, group in arrays:
        if blocks_for and name in blocks_for:
            enc = blocks_for[name]
        else:
            raw = a.tobytes()
            c = codec(raw)
            enc = struct.pack("<4I", 1, len(raw), len(raw), len(c)) + c
        tags[group].append(f'<DataArray type="{VTK_TYPES[a.dtype]}" Name="{name}" NumberOfComponents="{nc}" '
                           f'format="appended" offset="{len(blob)}"/>')
        blob += enc
    head = (f'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="2.1" byte_order="LittleEndian" '
            f'header_type="UInt32" compressor="{compressor}"><UnstructuredGrid>'
            f'<Piece NumberOfPoints="{npoints}" NumberOfCells="1"><Points>{"".join(tags["Points"])}</Points>'
            f'<Cells>{"".join(tags["Cells"])}</Cells><PointData>{"".join(tags["PointData"])}</PointData>'
            f'</Piece></UnstructuredGrid><AppendedData encoding="raw">_')
    return head.encode() + blob + b"</AppendedData></VTKFile>\n"


@functools.lru_cache(maxsize=None)
def zlib_zeros(nbytes: int, level=6) -> bytes:
    """zlib stream of nbytes zeros, made in 1 MiB pieces (never holds nbytes in memory; cached:
    a GiB takes ~3 s)."""
    c = zlib.compressobj(level)
    piece = bytes(1 << 20)
    out = []
    for _ in range(nbytes >> 20):
        out.append(c.compress(piece))
    out.append(c.compress(bytes(nbytes & ((1 << 20) - 1))))
    out.append(c.flush())
    return b"".join(out)


@functools.lru_cache(maxsize=None)
def lzma_zeros(nbytes: int) -> bytes:
    c = lzma.LZMACompressor(preset=0)
    piece = bytes(1 << 20)
    out = [c.compress(piece) for _ in range(nbytes >> 20)]
    out.append(c.flush())
    return b"".join(out)


def vtu_case(folder: Path, data: bytes, view_data=None):
    (folder / "m.vtu").write_bytes(data)
    return render_args(folder, base_view(view_data or {"path": "m.vtu", "field": "f"}))


def many_blocks_of_zeros(folder: Path):
    """800 zlib blocks of 1 MiB zeros as the 96-byte Points array."""
    block = zlib.compress(bytes(1 << 20), 9)
    header = struct.pack(f"<{3 + 800}I", 800, 1 << 20, 1 << 20, *([len(block)] * 800))
    return vtu_case(folder, vtu_hex({"Points": header + block * 800}))


def one_block_bomb(folder: Path, codec="zlib"):
    """The Points header declares 96 bytes; its one block inflates to 3 GiB (zlib) or 512 MiB (LZMA)."""
    c = zlib_zeros(3 << 30) if codec == "zlib" else lzma_zeros(512 << 20)
    header = struct.pack("<4I", 1, 96, 96, len(c))
    comp = "vtkZLibDataCompressor" if codec == "zlib" else "vtkLZMADataCompressor"
    return vtu_case(folder, vtu_hex({"Points": header + c}, compressor=comp))


def consistent_huge_vtu(folder: Path):
    """NumberOfPoints 10^8 and a Points header that agrees (1.2 GB of zeros in 1 MiB blocks): a
    small file whose declared size is consistent but far beyond what its bytes can hold."""
    n = 100_000_000
    total = 12 * n
    block = zlib.compress(bytes(1 << 20), 9)
    nb = -(-total // (1 << 20))
    last = total - (nb - 1) * (1 << 20)
    lastblock = zlib.compress(bytes(last), 9)
    header = struct.pack(f"<{3 + nb}I", nb, 1 << 20, last, *([len(block)] * (nb - 1) + [len(lastblock)]))
    return vtu_case(folder, vtu_hex({"Points": header + block * (nb - 1) + lastblock}, npoints=n))


# -------------------------------------------------------------------------------- HDF5 fields

def hdf5_field(path: Path, data=None, data_kwargs=None, mutate=None):
    """A Nektar++ HDF5 field file of the hexahedron: /NEKTAR/{DECOMPOSITION, ELEMENTIDS, DATA,
    <hash> definition group}. `mutate(h5)` changes it after it is written."""
    import h5py

    coeffs = hex_coefficients()
    with h5py.File(path, "w") as h5:
        g = h5.create_group("NEKTAR")
        g.attrs["FORMAT_VERSION"] = 1
        sub = g.create_group("1000")
        sub.attrs["FIELDS"] = np.array([b"p"])
        sub.attrs["BASIS"] = np.array([4, 4, 4], dtype=np.int64)
        sub.attrs["SHAPE"] = b"Hexahedron"
        sub.attrs["NUMMODESPERDIR"] = b"UNIORDER:3,3,3"
        g.create_dataset("DECOMPOSITION", data=np.array([1, coeffs.size, 0, 0, 0, 0, 1000], np.uint64))
        g.create_dataset("ELEMENTIDS", data=np.array([0], np.uint64))
        if data_kwargs is not None:
            g.create_dataset("DATA", **data_kwargs)
        else:
            g.create_dataset("DATA", data=coeffs if data is None else data)
        if mutate is not None:
            mutate(h5, folder=path.parent)


# BasisType enum indices (io/nektar/hdf5.BASIS_ENUM) of the bases XML field files name
_BASIS_INDEX = {"Modified_A": 4, "Modified_B": 5, "Modified_C": 6, "ModifiedPyr_C": 8, "GLL_Lagrange": 10}


def nektar_hdf5_from_xml(xml_field: Path, out: Path) -> Path:
    """An XML field file (.fld) rewritten as Nektar++ writes HDF5 field files (FieldIOHdf5,
    docs/spec/formats.md §2.7): /NEKTAR with FORMAT_VERSION, a Metadata group (its Provenance
    subgroup) of variable-length string attributes, one definition group per block named by a
    hash, with FIELDS (a variable-length string array), BASIS (BasisType indices), SHAPE and
    NUMMODESPERDIR; DECOMPOSITION, ELEMENTIDS and DATA. The strings are variable-length, as
    Nektar++'s H5::DataType::String(0) makes them, so they live in HDF5's global heap."""
    import h5py

    from hovr_blender.io.nektar.blocks import FIELD_SHAPES
    from hovr_blender.io.nektar.fields import read_field_file

    shape_names = {shape: name for name, shape in FIELD_SHAPES.items()}

    blocks = read_field_file(xml_field, num_elements=1 << 30).blocks
    text = lambda s: np.array(s, dtype=h5py.string_dtype())  # noqa: E731
    with h5py.File(out, "w") as h5:
        root = h5.create_group("NEKTAR")
        root.attrs["FORMAT_VERSION"] = np.uint32(1)
        meta = root.create_group("Metadata")
        for key, value in (("ChkFileNum", "0"), ("SessionName0", xml_field.with_suffix(".xml").name), ("Time", "0")):
            meta.attrs[key] = text(value)
        prov = meta.create_group("Provenance")
        for key, value in (("GitBranch", "refs/heads/master"), ("GitSHA1", "72b466000a11"),
                           ("Hostname", "hovr-tests"), ("NektarVersion", "5.9.0"),
                           ("Timestamp", "25-Aug-2025 12:00:00")):
            prov.attrs[key] = text(value)
        decomposition, ids, data = [], [], []
        for k, block in enumerate(blocks):
            definition = 1_000_003 * (k + 1)
            group = root.create_group(str(definition))
            group.attrs["FIELDS"] = text(block.fields)
            group.attrs["BASIS"] = np.array([_BASIS_INDEX[b] for b in block.basis], dtype=np.int32)
            group.attrs["SHAPE"] = text(shape_names[block.shape])
            modes = ",".join(str(int(m)) for m in block.modes[0])
            group.attrs["NUMMODESPERDIR"] = text(f"UNIORDER:{modes}")
            decomposition.extend([len(block.ids), block.data.size, 0, 0, 0, 0, definition])
            ids.extend(block.ids.tolist())
            data.append(block.data)
        root.create_dataset("DECOMPOSITION", data=np.array(decomposition, np.uint64))
        root.create_dataset("ELEMENTIDS", data=np.array(ids, np.uint64))
        root.create_dataset("DATA", data=np.concatenate(data).astype("<f8"))
    return out


def _external_data(target):
    def build(path):
        hdf5_field(path, data_kwargs=dict(shape=(27,), dtype="<f8", external=[(str(target), 0, 27 * 8)]))
    return build


def _external_fifo(path):
    fifo = path.parent / "pipe"
    os.mkfifo(fifo)
    hdf5_field(path, data_kwargs=dict(shape=(27,), dtype="<f8", external=[(str(fifo), 0, 27 * 8)]))


def _private_file(path):
    secret = path.parent / "secret.bin"
    secret.write_bytes(np.arange(27, dtype="<f8").tobytes())
    os.chmod(secret, 0o600)
    _external_data(secret)(path)


def _external_link(path):
    import h5py

    other = path.parent / "other.h5"
    with h5py.File(other, "w") as h5:
        h5.create_dataset("DATA", data=hex_coefficients())

    def link(h5, folder):
        del h5["NEKTAR/DATA"]
        h5["NEKTAR/DATA"] = h5py.ExternalLink(str(other), "/DATA")
    hdf5_field(path, mutate=link)


def _soft_link(path):
    import h5py

    def link(h5, folder):
        h5.create_dataset("ELSEWHERE", data=hex_coefficients())
        del h5["NEKTAR/DATA"]
        h5["NEKTAR/DATA"] = h5py.SoftLink("/ELSEWHERE")
    hdf5_field(path, mutate=link)


def _virtual(path):
    import h5py

    src = path.parent / "src.h5"
    with h5py.File(src, "w") as h5:
        h5.create_dataset("D", data=hex_coefficients())

    def virt(h5, folder):
        layout = h5py.VirtualLayout(shape=(27,), dtype="<f8")
        layout[:] = h5py.VirtualSource(str(src), "D", shape=(27,))
        del h5["NEKTAR/DATA"]
        h5["NEKTAR"].create_virtual_dataset("DATA", layout)
    hdf5_field(path, mutate=virt)


def _fill_value(n):
    def build(path):
        def declare(h5, folder):
            g = h5["NEKTAR"]
            del g["DATA"], g["DECOMPOSITION"]
            g.create_dataset("DATA", shape=(n,), dtype="<f8")  # never written: no storage
            g.create_dataset("DECOMPOSITION", data=np.array([1, n, 0, 0, 0, 0, 1000], np.uint64))
        hdf5_field(path, mutate=declare)
    return build


def _chunk_bomb(path):
    """gzip-compressed DATA whose one chunk is a 64 MiB zlib stream of zeros (HDF5's own filter
    would inflate all of it)."""
    def bomb(h5, folder):
        g = h5["NEKTAR"]
        del g["DATA"]
        ds = g.create_dataset("DATA", shape=(27,), chunks=(27,), dtype="<f8", compression="gzip")
        ds.id.write_direct_chunk((0,), zlib_zeros(64 << 20))
    hdf5_field(path, mutate=bomb)


def _chunks_beyond_the_file(path):
    """4,000 fields of 15 modes a direction on the one hexahedron: a DATA of 13.5 M values (108 MB)
    the mesh can use, gzip chunks of 2^20 zeros each inflating to exactly its declared size, in a
    file of 137 KiB: within every per-chunk bound, 780x the file in all."""
    import h5py

    fields, values, chunk = 4000, 4000 * 15 ** 3, 1 << 20

    def declare(h5, folder):
        g = h5["NEKTAR"]
        del g["DATA"], g["DECOMPOSITION"], g["1000"]
        sub = g.create_group("1000")
        sub.attrs["FIELDS"] = np.array([b"p"] + [f"f{k}".encode() for k in range(1, fields)])
        sub.attrs["BASIS"] = np.array([4, 4, 4], dtype=np.int64)
        sub.attrs["SHAPE"] = b"Hexahedron"
        sub.attrs["NUMMODESPERDIR"] = b"UNIORDER:15,15,15"
        g.create_dataset("DECOMPOSITION", data=np.array([1, values, 0, 0, 0, 0, 1000], np.uint64))
        ds = g.create_dataset("DATA", shape=(values,), chunks=(chunk,), dtype="<f8", compression="gzip")
        zeros = zlib_zeros(chunk * 8, 9)
        for start in range(0, values, chunk):
            ds.id.write_direct_chunk((start,), zeros)
    hdf5_field(path, mutate=declare)
    assert h5py.is_hdf5(path)


# -------------------------------------------------------------------------------- the cases

def _view_mutation(mutate):
    def build(folder):
        v = base_view({"builtin": "sphere"})
        mutate(v)
        p = folder / "view.json"
        p.write_text(json.dumps(v, allow_nan=True).replace("Infinity", "1e400"))
        return ["render", str(p), "-o", str(folder / "out.npy")]
    return build


def _symlink(target, name):
    def place(folder):
        os.symlink(target, folder / name)
    return place


def _fifo(name):
    def place(folder):
        os.mkfifo(folder / name)
    return place


def _special_mesh(place, name, data):
    def build(folder):
        place(folder)
        return render_args(folder, base_view(data))
    return build


def _special_solution(place):
    def build(folder):
        (folder / "m.xml").write_text(nektar_mesh())
        place(folder)
        return render_args(folder, base_view({"path": "m.xml", "solution": "m.fld", "field": "p"}))
    return build


def _special_view(place):
    def build(folder):
        place(folder)
        return ["render", str(folder / "view.json"), "-o", str(folder / "out.npy")]
    return build


def _output(out, *extra):
    def build(folder):
        (folder / "m.xml").write_text(nektar_mesh())
        (folder / "m.fld").write_text(nektar_field())
        args = render_args(folder, base_view({"path": "m.xml", "solution": "m.fld", "field": "p"}))
        args[args.index("-o") + 1] = out.format(d=folder)
        return args + [a.format(d=folder) for a in extra]
    return build


def _fifo_output(folder):
    os.mkfifo(folder / "out.npy")
    return _output("{d}/out.npy")(folder)


def _linked_output(folder):
    """-o names a link to a file of the user's: refused, as the README says (os.replace would have
    replaced the link quietly)."""
    (folder / "precious.npy").write_bytes(b"the user's")
    os.symlink(folder / "precious.npy", folder / "out.npy")
    return _output("{d}/out.npy")(folder)


def _link_kept(folder, outcome):
    kept = os.path.islink(folder / "out.npy") and (folder / "precious.npy").read_bytes() == b"the user's"
    return [] if kept else ["the link or its target changed"]


def _step(method, h):
    def build(folder):
        return nektar_case(folder, fld=nektar_field(), args=("--method", method, "--h", str(h)))
    return build


def _domain_repeat(folder):
    return nektar_case(folder, mesh=nektar_mesh(domain=",".join(["C[0-1048575]"] * 2000)), fld=nektar_field())


def _composite_repeat(folder):
    return nektar_case(folder, mesh=nektar_mesh(composite=" ".join(["H[0]"] * 2000),
                                                domain="C[" + ",".join(["0"] * 2000) + "]"), fld=nektar_field())


def _field_id_range(folder):
    """ID="0-9999999" with a zlib stream that holds exactly 10^7 x 27 values (zeros)."""
    body = zlib_zeros(10_000_000 * 27 * 8)
    body += b"\0" * (-len(body) % 3)
    return nektar_case(folder, fld=nektar_field(ids="0-9999999", body=base64.b64encode(body).decode()))


def _hdf5(builder):
    def build(folder):
        return nektar_case(folder, fld=builder)
    return build


def _folded_hex(folder):
    """Issue 29: a quadratic hexahedron whose det J is -0.40 between its 4 x 4 x 4 fit points."""
    from tests.helpers import folded_hex_map, lagrange_hex_vtu

    return vtu_case(folder, lagrange_hex_vtu(folded_hex_map))


def _huge_image(folder):
    v = base_view({"builtin": "sphere"}, 32768, 32768)
    return render_args(folder, v)


CASES = [
    # view files: values the contract does not mean
    Case("camera is a list", "view values", _view_mutation(lambda v: v.update(camera=[1, 2, 3])), expect=("camera",)),
    Case("data is a number", "view values", _view_mutation(lambda v: v.update(data=5)), expect=("data",)),
    Case("path is a number", "view values", _view_mutation(lambda v: v.update(data={"path": 5})), expect=("data.path",)),
    Case("builtin is a list", "view values", _view_mutation(lambda v: v.update(data={"builtin": [1]})),
         expect=("data.builtin",)),
    Case("width 1e400", "view values", _view_mutation(lambda v: v["image"].update(width=float("inf"))), expect=("width",)),
    Case("width true", "view values", _view_mutation(lambda v: v["image"].update(width=True)), expect=("width",)),
    Case("width 1.9", "view values", _view_mutation(lambda v: v["image"].update(width=1.9)), expect=("width",)),
    Case('width "32"', "view values", _view_mutation(lambda v: v["image"].update(width="32")), expect=("width",)),
    Case("background NaN", "view values", _view_mutation(lambda v: v.update(background=[0, float("nan"), 0])),
         expect=("background",)),
    Case("32768 x 32768 image", "view values", _huge_image, expect=("memory limit",)),
    # small steps
    Case("classified h = 1e-12", "small step", _step("classified", 1e-12), expect=("h = 1e-12", "samples per ray")),
    Case("riemann h = 1e-6", "small step", _step("riemann", 1e-6), expect=("h = 1e-06", "samples per ray")),
    Case("trapezoid h = 1e-9", "small step", _step("trapezoid", 1e-9), expect=("h = 1e-09", "samples per ray")),
    Case("riemann h = 0.05 renders", "small step", _step("riemann", 0.05), expect_rc=0),
    # amplification: small files declaring huge work
    Case("DOMAIN C[0-1048575] x 2000", "amplification", _domain_repeat, expect=("m.xml",)),
    Case("composite H[0] x 2000, DOMAIN C[0,0,...]", "amplification", _composite_repeat, expect_rc=0),
    Case('field ID="0-9999999", matching zlib stream', "amplification", _field_id_range, expect=("m.fld",)),
    Case("HDF5 DATA of 10^8 unwritten values", "amplification", _hdf5(_fill_value(100_000_000)), expect=("m.fld",)),
    Case("HDF5 DATA of 2.68e8 unwritten values", "amplification", _hdf5(_fill_value(268_000_000)), expect=("m.fld",)),
    Case("HDF5 gzip chunk inflating to 64 MiB", "amplification", _hdf5(_chunk_bomb), expect=("m.fld", "inflates")),
    Case("HDF5 gzip chunks, each within its size, 780x the file", "amplification", _hdf5(_chunks_beyond_the_file),
         expect=("m.fld", "DATA", "100x")),
    # HDF5 references to other files
    Case("HDF5 external storage -> /etc/passwd", "HDF5 references", _hdf5(_external_data("/etc/passwd")),
         expect=("m.fld", "external")),
    Case("HDF5 external storage -> a FIFO", "HDF5 references", _hdf5(_external_fifo), expect=("m.fld", "external")),
    Case("HDF5 external storage -> a private file", "HDF5 references", _hdf5(_private_file),
         expect=("m.fld", "external")),
    Case("HDF5 ExternalLink", "HDF5 references", _hdf5(_external_link), expect=("m.fld", "link")),
    Case("HDF5 SoftLink", "HDF5 references", _hdf5(_soft_link), expect=("m.fld", "link")),
    Case("HDF5 virtual dataset", "HDF5 references", _hdf5(_virtual), expect=("m.fld", "virtual")),
    # HDF5 values
    Case("HDF5 complex DATA", "HDF5 values", _hdf5(lambda p: hdf5_field(p, data=hex_coefficients() * (1 + 1j))),
         expect=("m.fld", "complex")),
    Case("HDF5 integer DATA", "HDF5 values", _hdf5(lambda p: hdf5_field(p, data=np.arange(27))), expect=("m.fld",)),
    Case("HDF5 string DATA", "HDF5 values", _hdf5(lambda p: hdf5_field(p, data=np.array([b"x"] * 27))),
         expect=("m.fld",)),
    # numbers a mesh cannot hold
    Case("vertex at 1e200", "mesh values", lambda f: nektar_case(f, mesh=nektar_mesh(vertex_scale=1e200), fld=nektar_field()),
         expect=("m.xml", "too large")),
    Case("quadratic hex folded between its fit points", "mesh values", _folded_hex,
         expect=("m.vtu", "cell 0: inverted or tangled hexahedron", "-0.4")),
    # VTU compressed blocks
    Case("VTU 800 blocks of 1 MiB zeros", "VTU compressed blocks", many_blocks_of_zeros, expect=("m.vtu",)),
    Case("VTU 3 GiB zlib bomb in one block", "VTU compressed blocks", one_block_bomb, expect=("m.vtu",)),
    Case("VTU 512 MiB LZMA bomb in one block", "VTU compressed blocks", lambda f: one_block_bomb(f, "lzma"),
         expect=("m.vtu",)),
    Case("VTU 10^8 points, consistent header", "VTU compressed blocks", consistent_huge_vtu, expect=("m.vtu",)),
    # special files
    Case("mesh is /dev/zero", "special files", _special_mesh(_symlink("/dev/zero", "m.xml"), "m.xml",
                                                             {"path": "m.xml"}), expect=("device",)),
    Case("mesh is a FIFO", "special files", _special_mesh(_fifo("m.xml"), "m.xml", {"path": "m.xml"}),
         expect=("FIFO",)),
    Case("VTU is /dev/zero", "special files", _special_mesh(_symlink("/dev/zero", "m.vtu"), "m.vtu",
                                                            {"path": "m.vtu"}), expect=("device",)),
    Case("VTU is a FIFO", "special files", _special_mesh(_fifo("m.vtu"), "m.vtu", {"path": "m.vtu"}),
         expect=("FIFO",)),
    Case("solution is /dev/zero", "special files", _special_solution(_symlink("/dev/zero", "m.fld")),
         expect=("device",)),
    Case("solution is a FIFO", "special files", _special_solution(_fifo("m.fld")), expect=("FIFO",)),
    Case("view file is /dev/zero", "special files", _special_view(_symlink("/dev/zero", "view.json")),
         expect=("device",)),
    Case("view file is a FIFO", "special files", _special_view(_fifo("view.json")), expect=("FIFO",)),
    Case("view file is /proc/self/mem", "special files", _special_view(_symlink("/proc/self/mem", "view.json")),
         expect=("view.json", "cannot be read")),
    Case("mesh is /proc/self/mem", "special files", _special_mesh(_symlink("/proc/self/mem", "m.xml"), "m.xml",
                                                                  {"path": "m.xml"}), expect=("m.xml", "cannot read")),
    # output paths
    Case("-o an existing folder", "output paths", _output("{d}"), expect=(".npy",)),
    Case("-o /dev/full", "output paths", _output("/dev/full"), expect=(".npy",)),
    Case("-o without .npy", "output paths", _output("{d}/name"), expect=(".npy",)),
    Case("-o a FIFO", "output paths", _fifo_output, expect=("not a regular file",)),
    Case("-o a link to another file", "output paths", _linked_output, expect=("out.npy", "symbolic link"),
         after=_link_kept),
    Case("--png in a missing folder", "output paths", _output("{d}/out.npy", "--png", "{d}/no/x.png"),
         expect=("does not exist",)),
    Case("-o .npy in an existing folder renders", "output paths", _output("{d}/out.npy"), expect_rc=0),
]


# -------------------------------------------------------------------------------- issue 29: readers

def _hdf5_of_hex(folder: Path) -> bytes:
    """The hexahedron's field (nektar_field) as Nektar++ writes HDF5 (nektar_hdf5_from_xml):
    12.7 KB, like the issue's file."""
    (folder / "src.fld").write_text(nektar_field())
    nektar_hdf5_from_xml(folder / "src.fld", folder / "src.h5")
    data = (folder / "src.h5").read_bytes()
    (folder / "src.fld").unlink()
    (folder / "src.h5").unlink()
    return data


def _vlen_string_attribute(data: bytes, name: bytes) -> tuple[int, int]:
    """(offset of the datatype, offset of the value's heap reference) of the variable-length
    string attribute `name` of an HDF5 file: the attribute message's name, then its datatype
    (class 9, size 16), then the value's (length, global heap collection address)."""
    at = data.index(name + b"\0")
    datatype = at + re.search(rb"\x19[\x00-\xff]{3}\x10\x00\x00\x00", data[at:]).start()
    value = data[datatype:].index(struct.pack("<I", len("UNIORDER:3,3,3")))
    return datatype, datatype + value


def _global_heap_object(data: bytes, content: bytes) -> int:
    """Offset of the size field of the global heap object (GCOL collection) that holds `content`."""
    at = data.index(b"GCOL") + 16  # signature, version, reserved, collection size
    while True:
        index, size = struct.unpack_from("<H6xQ", data, at)
        if index == 0:
            raise ValueError("no such global heap object")
        if data[at + 16 : at + 16 + size] == content:
            return at + 8
        at += 16 + -(-size // 8) * 8


def hdf5_one_byte(position, change):
    """A field file: the HDF5 hexahedron with one byte changed, at position(data), by change(byte)."""
    def build(path: Path):
        data = bytearray(_hdf5_of_hex(path.parent))
        i = position(bytes(data))
        data[i] = change(data[i])
        path.write_bytes(bytes(data))
    return build


# the bytes 5937/6017 of its 12 KB file: the type of a variable-length string attribute,
# its class bits flipped (a string becomes a sequence: libhdf5 crashes converting it, SIGSEGV);
# bytes 8273/8328: a global heap object's size 0 (H5HG__cache_heap_deserialize never advances);
# and a string length of 4 GiB (libhdf5 allocates and fills it: refused at once, a header's allocations are capped)
VLEN_TYPE_BITS = hdf5_one_byte(lambda d: _vlen_string_attribute(d, b"NUMMODESPERDIR")[0] + 1, lambda b: b ^ 0xFF)
VLEN_LENGTH = hdf5_one_byte(lambda d: _vlen_string_attribute(d, b"NUMMODESPERDIR")[1] + 3, lambda b: b ^ 0xFF)
HEAP_OBJECT_SIZE = hdf5_one_byte(lambda d: _global_heap_object(d, b"p"), lambda b: 0)


def pyfr_vlen_uuid(folder: Path, flip: bool = True) -> tuple[Path, Path]:
    """(m.pyfrm, m-0.02.pyfrs): the vendored PyFR shell case, its solution's `mesh-uuid` a
    variable-length string (as h5py writes a str; the reader takes it), and with `flip` that
    string's datatype's class bits flipped, as VLEN_TYPE_BITS's: libhdf5 crashes reading it
    (SIGSEGV). The byte is found from the dataset's object header, not a fixed offset."""
    import h5py

    from tests.helpers import data_file

    mesh, soln = folder / "m.pyfrm", folder / "m-0.02.pyfrs"
    mesh.write_bytes(data_file("pyfr", "shell.pyfrm").read_bytes())
    soln.write_bytes(data_file("pyfr", "shell-0.02.pyfrs").read_bytes())
    with h5py.File(soln, "r+") as h5:
        uuid = h5["mesh-uuid"][()].decode()
        del h5["mesh-uuid"]
        h5.create_dataset("mesh-uuid", data=uuid, dtype=h5py.string_dtype())
    with h5py.File(soln, "r") as h5:
        header = h5py.h5o.get_info(h5["mesh-uuid"].id).addr
    if flip:
        data = bytearray(soln.read_bytes())
        # its datatype message: class 9 (variable-length), version 1, size 16
        at = header + re.search(rb"\x19[\x00-\xff]{3}\x10\x00\x00\x00", data[header:]).start()
        data[at + 1] ^= 0xFF
        soln.write_bytes(bytes(data))
    return mesh, soln


def _utf16_with_decoy(root: str, decoy: str) -> bytes:
    """An entity bomb in UTF-16: DOCTYPE and ENTITY are not ASCII bytes there, and a comment whose
    UTF-16 code units spell `decoy` in ASCII bytes satisfies a check of the raw bytes."""
    decoy_chars = (decoy + " " * (len(decoy) % 2)).encode().decode("utf-16-le")
    lol = "".join(f'<!ENTITY l{i + 1} "{f"&l{i};" * 10}">' for i in range(9))
    text = (f'<?xml version="1.0" encoding="UTF-16"?>\n<!DOCTYPE {root} [<!ENTITY l0 "{"x" * 64}">{lol}]>\n'
            f"<!--{decoy_chars}-->\n<{root}>&l9;</{root}>\n")
    return text.encode("utf-16")


def _utf16_vtu(folder: Path):
    decoy = '<VTKFile type="UnstructuredGrid" version="2.1" byte_order="LittleEndian" header_type="UInt32">'
    return vtu_case(folder, _utf16_with_decoy("VTKFile", decoy))


def _utf16_mesh(folder: Path):
    args = nektar_case(folder, fld=nektar_field())
    (folder / "m.xml").write_bytes(_utf16_with_decoy("NEKTAR", "<NEKTAR><GEOMETRY>"))
    return args


def _nested_mesh(folder: Path, depth=3_000_000):
    (folder / "m.xml").write_bytes(b"<NEKTAR>" + b"<a>" * depth + b"</a>" * depth + b"</NEKTAR>")
    return render_args(folder, base_view({"path": "m.xml"}))


def _huge_attribute(folder: Path):
    """A mesh whose <GEOMETRY> has a 1 GiB attribute (written in 1 MiB pieces): expat 2.5 took 10
    minutes and 2.1 GB on it; the token limit refuses it after reading ~16 MiB."""
    with open(folder / "m.xml", "wb") as fh:
        fh.write(b'<?xml version="1.0"?>\n<NEKTAR><GEOMETRY DIM="3" SPACE="3" X="')
        piece = b"x" * (1 << 20)
        for _ in range(1024):
            fh.write(piece)
        fh.write(b'"/></NEKTAR>\n')
    return render_args(folder, base_view({"path": "m.xml"}))


def _compressed_vertices(count: int) -> str:
    """A B64Z VERTEX section (records: int64 ID, 3 float64) of `count` vertices, made in pieces."""
    c = zlib.compressobj(1)
    out, step = [], 1 << 20
    for start in range(0, count, step):
        n = min(step, count - start)
        rec = np.zeros(n, dtype=[("id", "<i8"), ("x", "<f8", (3,))])
        rec["id"] = np.arange(start, start + n)
        rec["x"][:n] = np.array(HEX_VERTICES * (-(-n // 8)), "<f8")[:n]
        out.append(c.compress(rec.tobytes()))
    out.append(c.flush())
    z = b"".join(out)
    z += b"\0" * (-len(z) % 3)
    return f'<VERTEX COMPRESSED="B64Z-LittleEndian" BITSIZE="64">{base64.b64encode(z).decode()}</VERTEX>'


def _unused_vertices(folder: Path):
    """8 M vertices (the first 8 the hexahedron's) in a compressed VERTEX section: 21 MB of file."""
    mesh = re.sub(r"<VERTEX>.*</VERTEX>", lambda m: _compressed_vertices(8_000_000), nektar_mesh())
    return nektar_case(folder, mesh=mesh, fld=nektar_field())


def _element_bomb(folder: Path):
    """A compressed ELEMENT block of zeros (1 GiB, ~1 MB of file) after the hexahedron's: no section
    above bounds the elements, the whole file's 100x inflation budget does."""
    z = zlib_zeros(1 << 30)
    z += b"\0" * (-len(z) % 3)
    block = f'<H COMPRESSED="B64Z-LittleEndian" BITSIZE="64">{base64.b64encode(z).decode()}</H>'
    return nektar_case(folder, mesh=nektar_mesh().replace("</ELEMENT>", block + "</ELEMENT>"), fld=nektar_field())


def _partition_symlink(folder: Path):
    """A field directory whose one part is a symbolic link to a file outside it."""
    (folder / "outside").mkdir()
    (folder / "outside" / "P0000000.fld").write_text(nektar_field())
    (folder / "m.fld").mkdir()
    os.symlink(folder / "outside" / "P0000000.fld", folder / "m.fld" / "P0000000.fld")
    (folder / "m.fld" / "Info.xml").write_text('<?xml version="1.0"?>\n<NEKTAR><Metadata>'
                                               '<Partition FileName="P0000000.fld">0</Partition></Metadata></NEKTAR>\n')
    return nektar_case(folder, fld=lambda path: None)


# libhdf5's endless loop is stopped when it uses READ_STALL_SECONDS (2 s) of processor time without progress,
# at default settings: ~3 s on an idle machine, longer on a loaded one
STALL_SECONDS = 10.0

READER_CASES = [
    Case("HDF5 one byte: vlen string type bits (SIGSEGV)", "reader process", _hdf5(VLEN_TYPE_BITS),
         expect=("m.fld", "crashed")),
    Case("HDF5 one byte: vlen string of 4 GiB", "reader process", _hdf5(VLEN_LENGTH), expect=("m.fld",)),
    Case("HDF5 one byte: global heap object of size 0 (loops)", "reader process", _hdf5(HEAP_OBJECT_SIZE),
         expect=("m.fld", "no progress for 2 s of processor time"), max_seconds=STALL_SECONDS),
    Case("VTU in UTF-16, entity bomb behind an ASCII decoy", "XML", _utf16_vtu, expect=("m.vtu", "DOCTYPE")),
    Case("mesh in UTF-16, entity bomb", "XML", _utf16_mesh, expect=("m.xml", "DOCTYPE")),
    Case("mesh of 3 M nested elements", "XML", _nested_mesh, expect=("m.xml", "nest")),
    Case("mesh with a 1 GiB attribute", "XML", _huge_attribute, expect=("m.xml", "token", "16 MiB")),
    Case("compressed VERTEX of 8 M unused vertices", "reader budgets", _unused_vertices,
         expect=("m.xml", "VERTEX", "edges can use at most 24")),
    Case("compressed ELEMENT block beyond 100x the file", "reader budgets", _element_bomb, expect=("m.xml", "100x")),
    Case("partition file is a symbolic link", "reader budgets", _partition_symlink,
         expect=("P0000000.fld", "symbolic link")),
]
CASES.extend(READER_CASES)
