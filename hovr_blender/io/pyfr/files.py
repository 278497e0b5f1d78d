"""PyFR 3.x mesh (.pyfrm) and solution (.pyfrs) files, read with h5py under the resource policy
(docs/spec/formats.md §6).

Mesh: `mesh-uuid`; `nodes`, records whose `location` holds the coordinates; `eles/<type>`,
one record per element whose `nodes` field lists its shape points (equispaced, PyFR's order:
elements.std_ele) as indices into `nodes`; `partitionings/` (ignored: the solution is stored in
the mesh's element order whatever the partitioning of the run).
Solution: `mesh-uuid` (the mesh's), `config` and `stats` (INI text: the system, gamma, the field
names and the data group's name), and in that group `p<order>-<type>`, (elements, fields,
points) with the solution points as attribute `pts`; `p<order>-<type>-idxs` where the solution
holds only some elements (their indices in the mesh).

As in io/nektar/hdf5.py, whose `child` and `read_dataset` do the checks: HDF5 never opens the
path itself (h5py gets the checked descriptor), objects are followed through hard links only,
every dataset's size, storage and compression are checked before it is read, every header
value (text, attribute) is read with its allocation capped.
"""
from __future__ import annotations

import configparser
import os
import re
from dataclasses import dataclass

import h5py
import numpy as np

from ...engine import limits
from ..nektar.hdf5 import child, read_dataset
from . import elements as el
from .errors import PyFRError

MAX_TEXT = 1 << 20  # bytes of a text record (config, stats, uuid): real ones hold a few KB
MAX_FIELDS = 64
_SOLUTION = re.compile(r"p(\d+)-(hex|pri|tet|pyr)$")


@dataclass
class PyFRMesh:
    path: str
    uuid: str
    # {etype: (elements, shape points, 3) coordinates}, PyFR's sorted type order
    points: dict


@dataclass
class PyFRSolution:
    path: str
    fields: list  # the stored variables, in their order
    system: str
    gamma: float | None
    # {etype: (order, element indices into the mesh's, values (elements, fields, points), points (n, 3))}
    blocks: dict


def _open(path, what):
    """(open file object, its inflation budget); the caller closes the file."""
    fh = limits.open_regular(path, what)
    return fh, limits.InflationBudget(os.fstat(fh.fileno()).st_size, os.path.basename(str(path)))


def _guarded(path, what, read):
    fh, inflation = _open(path, what)
    try:
        with fh, h5py.File(fh, "r") as h5:
            return read(h5, inflation)
    except (PyFRError, limits.ResourceLimitError, limits.UnsafeFileError):
        raise
    except el.PointsError as exc:
        raise PyFRError(f"{path}: {exc}") from exc
    except MemoryError:
        raise PyFRError(f"{path}: a header value is larger than one can be (damaged file?)") from None
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError) as exc:
        raise PyFRError(f"{path}: unreadable {what} ({type(exc).__name__}: {exc})") from exc


def _text(path, h5, name):
    """A scalar text dataset (`mesh-uuid`, `config`, `stats`) as str."""
    dataset = child(h5, name, f"{path}: /{name}")
    if not isinstance(dataset, h5py.Dataset) or dataset.shape != () or dataset.dtype.kind not in "SOU":
        raise PyFRError(f"{path}: /{name} is missing or not a text record")
    if dataset.dtype.kind == "S" and dataset.dtype.itemsize > MAX_TEXT:
        raise PyFRError(f"{path}: /{name} declares {dataset.dtype.itemsize:,} bytes of text; refused")
    with limits.small_allocations():  # a damaged variable-length string asks libhdf5 for gigabytes
        value = dataset[()]
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if not isinstance(value, str) or len(value) > MAX_TEXT:
        raise PyFRError(f"{path}: /{name} is not a text record of at most {MAX_TEXT:,} bytes")
    return value


def _ini(path, text, name):
    parser = configparser.ConfigParser(interpolation=None, strict=False, inline_comment_prefixes=(";",))
    try:
        parser.read_string(text)
    except configparser.Error as exc:
        raise PyFRError(f"{path}: /{name} is not INI text ({' '.join(str(exc).split())[:200]})") from None
    return parser


def _points_attribute(path, dataset, what, etype, order):
    """The `pts` attribute of a solution dataset: the solution points, checked."""
    if "pts" not in dataset.attrs:
        raise PyFRError(f"{path}: {what} has no `pts` attribute (its solution points; PyFR 3 writes it)")
    shape = dataset.attrs.get_id("pts").shape
    if int(np.prod(shape or (1,))) > 3 * el.npts(etype, el.max_order(etype)):
        raise PyFRError(f"{path}: {what}: attribute pts holds {int(np.prod(shape)):,} values; refused")
    with limits.small_allocations():
        pts = np.asarray(dataset.attrs["pts"])
    if pts.dtype.kind not in "fi":
        raise PyFRError(f"{path}: {what}: attribute pts is not numeric")
    return el.check_points(etype, order, pts.astype(np.float64))


# ----------------------------------------------------------------------------- the mesh

def read_mesh(path) -> PyFRMesh:
    return _guarded(path, "PyFR mesh", lambda h5, inflation: _mesh(str(path), h5, inflation))


def _mesh(path, h5, inflation):
    uuid = _text(path, h5, "mesh-uuid")
    eles = child(h5, "eles", f"{path}: /eles")
    nodes_ds = child(h5, "nodes", f"{path}: /nodes")
    if not isinstance(eles, h5py.Group) or not isinstance(nodes_ds, h5py.Dataset):
        raise PyFRError(f"{path}: no /eles group and /nodes dataset: not a PyFR 3 mesh (older PyFR meshes: "
                        "convert them with PyFR 3's `pyfr import`)")
    names = sorted(eles.keys())
    flat = [n for n in names if n in ("tri", "quad")]
    if flat:
        raise PyFRError(f"{path}: a 2-D mesh ({', '.join(flat)} elements); only 3-D meshes have a volume to render")
    unknown = [n for n in names if n not in el.ETYPES]
    if unknown:
        raise PyFRError(f"{path}: element type {unknown[0]!r} is not a PyFR 3-D type (hex, pri, pyr, tet)")
    if not names:
        raise PyFRError(f"{path}: the mesh has no elements")
    location = nodes_ds.dtype.fields.get("location") if nodes_ds.dtype.fields else None
    if nodes_ds.ndim != 1 or location is None or location[0].shape != (3,) or location[0].base.kind != "f":
        raise PyFRError(f"{path}: /nodes is not a list of records with a 3-D `location`")
    file_bytes = h5.id.get_filesize()
    nodes = read_dataset(nodes_ds, file_bytes // max(nodes_ds.dtype.itemsize, 1), f"{path}: /nodes",
                         inflation)["location"].astype(np.float64)
    if not np.all(np.isfinite(nodes)):
        raise PyFRError(f"{path}: /nodes: a node's coordinates are NaN or Inf")
    points = {}
    for etype in names:
        what = f"{path}: /eles/{etype}"
        dataset = child(eles, etype, what)
        field = dataset.dtype.fields.get("nodes") if isinstance(dataset, h5py.Dataset) and dataset.dtype.fields else None
        if dataset.ndim != 1 or field is None or field[0].base.kind not in "iu" or len(field[0].shape) != 1:
            raise PyFRError(f"{what}: not a list of element records with a `nodes` field")
        count = field[0].shape[0]
        order = el.order_from_npts(etype, count)
        if order is None or order < 1 or order > el.max_order(etype):
            raise PyFRError(f"{what}: {count} shape points per {el.NAMES[etype]} is no order 1..{el.max_order(etype)} "
                            "of PyFR's")
        index = read_dataset(dataset, file_bytes // max(dataset.dtype.itemsize, 1), what, inflation)["nodes"]
        index = index.astype(np.int64).reshape(-1, count)
        if index.size and (index.min() < 0 or index.max() >= len(nodes)):
            bad = int(np.nonzero((index < 0).any(axis=1) | (index >= len(nodes)).any(axis=1))[0][0])
            raise PyFRError(f"{what}: element {bad} names a node outside /nodes ({len(nodes):,} nodes)")
        limits.check_bytes(index.size * 24, f"{what}: the shape points")
        points[etype] = nodes[index]
    return PyFRMesh(path, uuid, points)


# ----------------------------------------------------------------------------- the solution

def read_solution(path, mesh: PyFRMesh | None = None, headers_only: bool = False) -> PyFRSolution:
    """The solution file; checked against `mesh` (its uuid, element counts) where given;
    headers_only: the field names and system, no data."""
    return _guarded(path, "PyFR solution", lambda h5, inflation: _solution(str(path), h5, inflation, mesh,
                                                                            headers_only))


def _solution(path, h5, inflation, mesh, headers_only):
    uuid = _text(path, h5, "mesh-uuid")
    if mesh is not None and uuid != mesh.uuid:
        raise PyFRError(f"{path}: the solution is of another mesh (mesh-uuid {uuid[:36]!r}, "
                        f"{os.path.basename(mesh.path)} has {mesh.uuid[:36]!r})")
    config = _ini(path, _text(path, h5, "config"), "config")
    stats = _ini(path, _text(path, h5, "stats"), "stats")
    fields = [f.strip() for f in stats.get("data", "fields", fallback="").split(",") if f.strip()]
    if not fields or len(fields) > MAX_FIELDS:
        raise PyFRError(f"{path}: /stats [data] fields names {len(fields)} fields; 1..{MAX_FIELDS} expected")
    system = config.get("solver", "system", fallback="").strip()
    try:
        gamma = float(config.get("constants", "gamma")) if config.has_option("constants", "gamma") else None
    except ValueError:
        gamma = None
    if headers_only:
        return PyFRSolution(path, fields, system, gamma, {})
    prefix = stats.get("data", "prefix", fallback="soln").strip()
    group = child(h5, prefix, f"{path}: /{prefix}") if re.fullmatch(r"[\w\-]+", prefix) else None
    if not isinstance(group, h5py.Group):
        raise PyFRError(f"{path}: no solution group /{prefix} (named by /stats [data] prefix)")
    blocks = {}
    for name in sorted(group.keys()):
        match = _SOLUTION.match(name)
        if match is None:
            continue
        order, etype = int(match.group(1)), match.group(2)
        what = f"{path}: /{prefix}/{name}"
        if etype in blocks:
            raise PyFRError(f"{what}: a second solution of the {el.NAMES[etype]}s")
        if not 0 <= order <= el.max_order(etype):
            raise PyFRError(f"{what}: order {order}; 0..{el.max_order(etype)} can be rendered for "
                            f"{el.NAMES[etype]}s")
        blocks[etype] = _block(path, group, name, what, etype, order, len(fields), mesh, inflation)
    if not blocks:
        raise PyFRError(f"{path}: /{prefix} holds no solution of a 3-D element type (p<order>-hex, -pri, -tet, -pyr)")
    if mesh is not None:
        missing = [e for e in mesh.points if e not in blocks]
        if missing:
            raise PyFRError(f"{path}: no solution of the mesh's {el.NAMES[missing[0]]}s")
    return PyFRSolution(path, fields, system, gamma, blocks)


def _block(path, group, name, what, etype, order, nfields, mesh, inflation):
    dataset = child(group, name, what)
    n = el.npts(etype, order)
    if not isinstance(dataset, h5py.Dataset) or dataset.ndim != 3 or dataset.dtype.kind != "f":
        raise PyFRError(f"{what}: not a 3-D array of real numbers (elements, fields, points)")
    count, nf, npoints = dataset.shape
    if nf != nfields or npoints != n:
        raise PyFRError(f"{what}: shape {dataset.shape}; {nfields} fields at the {n} points of order {order} expected")
    total = len(mesh.points[etype]) if mesh is not None and etype in mesh.points else None
    if mesh is not None and total is None:
        raise PyFRError(f"{what}: the mesh has no {el.NAMES[etype]}s")
    pts = _points_attribute(path, dataset, what, etype, order)
    idx_name = f"{name}-idxs"
    idx_ds = child(group, idx_name, f"{path}: {idx_name}")
    if idx_ds is None:
        if total is not None and count != total:
            raise PyFRError(f"{what}: {count:,} elements, the mesh has {total:,} {el.NAMES[etype]}s")
        index = np.arange(count, dtype=np.int64)
    else:
        if not isinstance(idx_ds, h5py.Dataset) or idx_ds.shape != (count,) or idx_ds.dtype.kind not in "iu":
            raise PyFRError(f"{what}-idxs: not {count:,} element indices")
        index = read_dataset(idx_ds, count, f"{what}-idxs", inflation).astype(np.int64)
        if count and (index.min() < 0 or (total is not None and index.max() >= total)
                      or len(np.unique(index)) != count):
            raise PyFRError(f"{what}-idxs: indices repeat or lie outside the mesh's {el.NAMES[etype]}s")
    values = read_dataset(dataset, count * nf * npoints, what, inflation).astype(np.float64)
    return order, index, values, pts
