"""HDF5 field files (docs/spec/formats.md §2.7): the /NEKTAR group's DECOMPOSITION rows index
the ELEMENTIDS, DATA and POLYORDERS datasets and name a definition group per block.

Imports h5py, which only HDF5 files need: fields.py imports this module when it meets one.
HDF5 can open and read other paths behind the file's back, so objects are followed through
hard links only (`child`), and a dataset is read only after its size, its storage in this file
and its compression have been checked (`read_dataset`).
"""
from __future__ import annotations

import os

import h5py
import numpy as np

from ...engine import limits
from ...engine.shapes import MAX_MODES, NAMES
from .blocks import Block, checked_coefficient_counts, finish_block, mode_counts, parse_header
from .errors import NektarError

# BasisType enum order (docs/spec/formats.md §2.6): HDF5 definitions store the index
BASIS_ENUM = ("NoBasisType", "Ortho_A", "Ortho_B", "Ortho_C", "Modified_A", "Modified_B", "Modified_C",
              "OrthoPyr_C", "ModifiedPyr_C", "Fourier", "GLL_Lagrange", "Gauss_Lagrange", "Legendre",
              "Chebyshev", "Monomial", "FourierSingleMode", "FourierHalfModeRe", "FourierHalfModeIm")
# Entries of one attribute of a field definition (FIELDS, BASIS, ...): real ones hold a few.
MAX_ATTRIBUTE_VALUES = 4096


# ----------------------------------------------------------------------------- safe access

def child(group, name: str, what: str):
    """Member `name` of an open h5py group, or None when there is none. Only a hard link to an
    object whose data lies in this file is followed: soft and external links, external raw
    storage and virtual datasets can each make HDF5 open or read another path."""
    link = group.get(name, getlink=True)  # the link itself: nothing is traversed yet
    if link is None:
        return None
    if isinstance(link, h5py.ExternalLink):
        raise limits.UnsafeFileError(f"{what} is an external link to {link.filename}:{link.path}; refused")
    if not isinstance(link, h5py.HardLink):
        raise limits.UnsafeFileError(f"{what} is a soft link; only hard links are followed")
    obj = group[name]
    if isinstance(obj, h5py.Dataset):
        if obj.is_virtual:
            raise limits.UnsafeFileError(f"{what} is a virtual dataset (its data lies in other files); refused")
        if obj.external:
            raise limits.UnsafeFileError(f"{what} keeps its data in external file {obj.external[0][0]}; refused")
    return obj


def read_dataset(dataset, max_values: int, what: str, inflation: limits.InflationBudget):
    """All values of an h5py dataset (reached through `child`), in its own dtype, read only
    after its declared size (at most max_values), its storage in the file and its compression
    have been checked. Compressed chunks are inflated here, each bounded by its declared size
    (HDF5's own deflate filter grows its buffer until the stream ends), all of them together
    first spent from the file's `inflation` budget, which every dataset of the file shares."""
    count = int(dataset.size)
    if count > max_values:
        raise limits.ResourceLimitError(f"{what} declares {count:,} values, more than the {max_values:,} it can need")
    itemsize = dataset.dtype.itemsize
    limits.check_bytes(count * itemsize, f"reading {what}")
    stored = dataset.id.get_storage_size()
    if count and not stored:
        raise limits.ResourceLimitError(f"{what} declares {count:,} values but stores none (only a fill value); "
                                        "refused")
    if stored > dataset.file.id.get_filesize():
        raise limits.ResourceLimitError(f"{what} claims {stored:,} stored bytes, more than the whole file holds")
    plist = dataset.id.get_create_plist()
    filters = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
    if not filters:
        return dataset[()]
    deflate, shuffle = h5py.h5z.FILTER_DEFLATE, h5py.h5z.FILTER_SHUFFLE
    if filters not in ([deflate], [shuffle, deflate]):
        raise ValueError(f"{what}: HDF5 filter pipeline {filters} is not read; only gzip (deflate) "
                         "compression, optionally after shuffle")
    chunk = dataset.chunks
    per_chunk = int(np.prod(chunk))
    if per_chunk > max(count, 1 << 16):
        raise limits.ResourceLimitError(f"{what}: chunks of {per_chunk:,} values for {count:,} values; refused")
    chunks = dataset.id.get_num_chunks()
    inflation.spend(chunks * per_chunk * itemsize, f"{what} ({chunks:,} compressed chunks)")
    out = np.full(dataset.shape, dataset.fillvalue, dtype=dataset.dtype)
    for i in range(chunks):
        offset = dataset.id.get_chunk_info(i).chunk_offset
        skipped, raw = dataset.id.read_direct_chunk(offset)  # bit k: filter k was skipped
        if not skipped & (1 << filters.index(deflate)):
            raw, _ = limits.inflate(raw, per_chunk * itemsize, f"{what} chunk {offset}", exact=True)
        elif len(raw) != per_chunk * itemsize:
            raise ValueError(f"{what} chunk {offset}: {len(raw)} bytes, expected {per_chunk * itemsize}")
        if filters[0] == shuffle and not skipped & 1:
            raw = np.frombuffer(raw, np.uint8).reshape(itemsize, per_chunk).T.tobytes()
        target = tuple(slice(o, max(o, min(o + c, s))) for o, c, s in zip(offset, chunk, dataset.shape))
        block = np.frombuffer(raw, dataset.dtype).reshape(chunk)
        out[target] = block[tuple(slice(0, t.stop - t.start) for t in target)]
    return out


# ----------------------------------------------------------------------------- field files

def read_blocks(path, file, budget):
    """The blocks of the HDF5 field file open as `file`; with budget None their headers only.
    Its compressed datasets inflate within one budget for the file (engine/limits.py)."""
    inflation = limits.InflationBudget(os.fstat(file.fileno()).st_size, os.path.basename(path))
    try:
        with h5py.File(file, "r") as h5:  # the checked descriptor: HDF5 never opens the path itself
            return _blocks(path, h5, budget, inflation)
    except (NektarError, limits.ResourceLimitError, limits.UnsafeFileError):
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise NektarError(f"{path}: unreadable HDF5 field file ({type(exc).__name__}: {exc})") from exc


def _blocks(path, h5, budget, inflation):
    root = child(h5, "NEKTAR", f"{path}: /NEKTAR")
    if not isinstance(root, h5py.Group):
        raise NektarError(f"{path}: HDF5 file without a /NEKTAR group (not a Nektar++ field file)")
    rows = _decomposition(path, h5, root, inflation)
    headers = _headers(path, root, rows)
    if budget is None:
        return [Block(shape, basis, fields, None, None, None, f"definition {definition}")
                for definition, (shape, basis, fields, _, _) in headers.items()]
    _check_declared_sizes(path, rows, headers, budget)
    all_ids = _values(path, _dataset(path, root, "ELEMENTIDS", "iu"), "ELEMENTIDS", sum(row[0] for row in rows),
                      inflation)
    all_data = _values(path, _dataset(path, root, "DATA", "f"), "DATA", sum(row[1] for row in rows), inflation)
    all_orders = _values(path, _dataset(path, root, "POLYORDERS", "iu", required=False), "POLYORDERS",
                         sum(row[2] for row in rows), inflation)
    blocks = []
    id_start = data_start = order_start = 0
    for index, (num_elements, num_values, num_orders, _, _, _, definition) in enumerate(rows):
        what = f"DECOMPOSITION row {index} (definition {definition})"
        shape, basis, fields, kind, counts = headers[definition]
        if kind == "MIXORDER":
            if num_orders != 3 * num_elements:
                raise NektarError(f"{path}: {what}: {num_orders} POLYORDERS entries for {num_elements} elements "
                                  "(3 each expected)")
            counts = all_orders[order_start : order_start + num_orders].astype(np.int64).tolist()
        ids = all_ids[id_start : id_start + num_elements].astype(np.int64)
        chunk = all_data[data_start : data_start + num_values].astype(np.float64)
        blocks.append(finish_block(path, what, shape, basis, fields, kind, counts, ids, lambda want, c=chunk: c))
        id_start, data_start, order_start = id_start + num_elements, data_start + num_values, order_start + num_orders
    return blocks


def _decomposition(path, h5, root, inflation):
    """The DECOMPOSITION rows (elements, values, POLYORDERS entries, 0, 0, 0, definition hash)."""
    dataset = _dataset(path, root, "DECOMPOSITION", "iu")
    # the index of the data, read for headers too: bounded by the file (it is far smaller than the data)
    table = read_dataset(dataset, h5.id.get_filesize() // dataset.dtype.itemsize, f"{path}: /NEKTAR/DECOMPOSITION",
                         inflation)
    if table.size % 7:
        raise NektarError(f"{path}: DECOMPOSITION has {table.size} entries, not a multiple of 7")
    if dataset.dtype.kind == "i" and np.any(table < 0):
        raise NektarError(f"{path}: DECOMPOSITION has negative entries")
    return table.reshape(-1, 7).tolist()


def _headers(path, root, rows):
    """{definition hash: parse_header's tuple}, in the order of first use."""
    headers = {}
    for index, (_, _, _, homogeneous_y, homogeneous_z, strips, definition) in enumerate(rows):
        what = f"DECOMPOSITION row {index} (definition {definition})"
        if homogeneous_y or homogeneous_z or strips:
            raise NektarError(f"{path}: {what}: homogeneous (Fourier-extruded) fields are not supported")
        if definition not in headers:
            headers[definition] = _header(path, root, definition, what)
    if not headers:
        raise NektarError(f"{path}: HDF5 field file holds no field definitions")
    return headers


def _check_declared_sizes(path, rows, headers, budget):
    """Each row's elements, values and POLYORDERS entries against the budget and its header."""
    for index, (num_elements, num_values, num_orders, _, _, _, definition) in enumerate(rows):
        what = f"DECOMPOSITION row {index} (definition {definition})"
        shape, _, fields, kind, counts = headers[definition]
        budget.claim(path, what, num_elements, fields)
        largest = mode_counts(path, what, kind, counts, 1) if kind == "UNIORDER" else [[MAX_MODES] * 3]
        most = len(fields) * num_elements * int(checked_coefficient_counts(path, what, shape, largest)[0])
        if num_values > most:
            raise NektarError(f"{path}: {what}: declares {num_values:,} values; {len(fields)} fields on "
                              f"{num_elements:,} {NAMES[shape]}s hold at most {most:,}")
        if num_orders > 3 * num_elements:
            raise NektarError(f"{path}: {what}: {num_orders:,} POLYORDERS entries for {num_elements:,} elements")


def _dataset(path, root, name, kinds, required=True):
    """The 1-D dataset /NEKTAR/name (None if absent and not required); kinds "f": real
    floating point, "iu": integer."""
    what = f"{path}: /NEKTAR/{name}"
    dataset = child(root, name, what)
    if dataset is None:
        if required:
            raise NektarError(f"{path}: HDF5 field file lacks /NEKTAR/{name}")
        return None
    if not isinstance(dataset, h5py.Dataset) or dataset.ndim != 1:
        raise NektarError(f"{what}: not a 1-D dataset")
    if dataset.dtype.kind == "c":
        raise NektarError(f"{what}: holds complex values ({dataset.dtype}); only real values can be rendered")
    if dataset.dtype.kind not in kinds:
        raise NektarError(f"{what}: values of type {dataset.dtype}, expected "
                          f"{'real floating point' if kinds == 'f' else 'integers'}")
    return dataset


def _values(path, dataset, name, count, inflation):
    """The values of a dataset from _dataset, which must hold exactly `count` of them."""
    size = 0 if dataset is None else dataset.size
    if size != count:
        raise NektarError(f"{path}: DECOMPOSITION accounts for {count:,} values of /NEKTAR/{name}, "
                          f"which holds {size:,}")
    if dataset is None:
        return np.zeros(0)
    values = read_dataset(dataset, count, f"{path}: /NEKTAR/{name}", inflation)
    if dataset.dtype.kind == "i" and np.any(values < 0):
        raise NektarError(f"{path}: /NEKTAR/{name}: negative entries")
    return values


def _attribute(path, attributes, key, what):
    if key not in attributes:
        raise NektarError(f"{path}: {what}: definition lacks the {key} attribute")
    if int(np.prod(attributes.get_id(key).shape or ())) > MAX_ATTRIBUTE_VALUES:
        raise NektarError(f"{path}: {what}: attribute {key} holds more than {MAX_ATTRIBUTE_VALUES} values")
    try:
        with limits.small_allocations():  # a damaged string length asks libhdf5 for gigabytes
            return attributes[key]
    except MemoryError:
        raise NektarError(f"{path}: {what}: attribute {key} is larger than a header value can be "
                          "(damaged file?)") from None


def _text(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _text(value.item())
    return str(value)


def _text_list(value):
    if isinstance(value, (bytes, str)):
        return [s.strip() for s in _text(value).split(",")]
    return [_text(x).strip() for x in np.asarray(value).ravel().tolist()]


def _header(path, root, definition, what):
    """parse_header's tuple for the field definition group /NEKTAR/<definition>."""
    group = child(root, str(definition), f"{path}: /NEKTAR/{definition}")
    if not isinstance(group, h5py.Group):
        raise NektarError(f"{path}: {what}: no field definition group /NEKTAR/{definition}")
    attributes = group.attrs
    try:
        basis = [BASIS_ENUM[int(b)] for b in np.asarray(_attribute(path, attributes, "BASIS", what)).ravel()]
    except (IndexError, ValueError, TypeError):
        raise NektarError(f"{path}: {what}: unknown BASIS attribute") from None
    fields, shape, nummodes = (_attribute(path, attributes, k, what) for k in ("FIELDS", "SHAPE", "NUMMODESPERDIR"))
    return parse_header(path, what, _text(shape).strip(), basis, _text_list(fields), _text(nummodes),
                        set(attributes.keys()))
