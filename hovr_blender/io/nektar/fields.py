"""Field files (.fld/.chk/.rst): XML or HDF5, or a multi-part .fld/ directory
(docs/spec/formats.md §2.1, §2.6, §2.7), read into blocks, and one field's coefficients from them.

Modified bases are copied as stored (local coefficients, docs/spec/formats.md §2.6);
GLL_Lagrange hexes are converted to the same polynomial in Modified_A; any other basis is
refused by name (blocks.parse_header).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ...engine import expansions as ex
from ...engine import limits
from .blocks import Block, ElementBudget, coefficient_counts, finish_block, parse_header
from .errors import NektarError, guard
from .ranges import expand_ranges, parse_ranges, range_count
from .xmlfile import endianness, file_budget, inflate_b64z, parse_xml

_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


@dataclass(frozen=True)
class FieldFile:
    """The blocks of a field file, and each field's coefficients from them."""

    path: Path
    blocks: list

    @property
    def names(self) -> list[str]:
        """The fields, in the order the file first mentions them."""
        names = []
        for block in self.blocks:
            for name in block.fields:
                if name not in names:
                    names.append(name)
        return names

    def coefficients(self, field, element_ids) -> dict:
        """{element ID: (shape, modes, Modified coefficients)} of one field, which must cover
        every one of element_ids."""
        names = self.names
        if field not in names:
            raise NektarError(f"{self.path}: no field {field!r}; it holds {', '.join(names)}")
        coeffs = guard(self.path, lambda: _field_coefficients(self.path, self.blocks, field))
        missing = [e for e in element_ids if e not in coeffs]
        if missing:
            raise NektarError(f"{self.path}: no coefficients of field {field!r} for mesh element(s) "
                              f"{missing[:10]}{' ...' if len(missing) > 10 else ''}")
        return coeffs


def read_field_file(path, num_elements=None) -> FieldFile:
    """A field file or multi-part .fld/ directory. Given the mesh's element count, every size the
    file declares is checked against it before data is inflated or read; without it (None)
    only headers are read (names, shapes, bases; no data)."""
    path = Path(path)
    return FieldFile(path, guard(path, lambda: _field_blocks(path, num_elements)))


def _field_blocks(path: Path, num_elements):
    budget = None if num_elements is None else ElementBudget(num_elements)
    if not path.is_dir():
        if not path.exists():
            raise NektarError(f"{path}: no such field file")
        return _file_blocks(path, budget)
    return _directory_blocks(path, budget)


def _directory_blocks(path: Path, budget):
    """The blocks of every part an Info.xml lists, each part holding the elements listed for it."""
    info = path / "Info.xml"
    if not info.exists():
        raise NektarError(f"{path}: a field directory needs an Info.xml listing its parts")
    root = parse_xml(info, "field directory index")
    parts = list(root.iter("Partition"))
    if not parts:
        raise NektarError(f"{info}: no <Partition> entries")
    blocks = []
    for part in parts:
        name = part.attrib.get("FileName", "")
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", name) or name in (".", ".."):
            raise NektarError(f"{info}: Partition FileName={name!r} is not a plain file name in the directory")
        ranges = parse_ranges(part.text, info, f"Partition {name}")
        if (path / name).is_symlink():  # a part is the folder's own file, never a way out of it
            raise NektarError(f"{info}: Partition {name} is a symbolic link; refused (the parts of a field "
                              "directory must be files in it)")
        part_blocks = _file_blocks(path / name, budget)
        if budget is not None:
            held = set()
            for block in part_blocks:
                held.update(block.ids.tolist())
            # compare counts before expanding the (untrusted) list
            listed = set(expand_ranges(ranges).tolist()) if range_count(ranges) == len(held) else set()
            if held != listed:
                raise NektarError(f"{info}: Partition {name} lists {range_count(ranges)} elements but the file holds "
                                  f"{len(held)} (other IDs or counts)")
        blocks.extend(part_blocks)
    return blocks


def _file_blocks(path: Path, budget):
    try:
        with limits.open_regular(path, "field file") as file:
            if file.read(8) == _HDF5_MAGIC:
                return _hdf5_blocks(path, file, budget)
    except OSError as exc:
        raise NektarError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    return _xml_blocks(path, parse_xml(path, "field file"), budget)


def _hdf5_blocks(path: Path, file, budget):
    try:
        from . import hdf5  # imports h5py: optional and heavy, and only HDF5 field files need it
    except ImportError:
        raise NektarError(f"{path}: is an HDF5 field file; reading it needs the h5py package "
                          "(pip install h5py)") from None
    return hdf5.read_blocks(path, file, budget)


def _xml_blocks(path: Path, root, budget):
    """The ELEMENTS blocks of an XML field file; with budget None their headers only. Their data
    inflates within the file's inflation budget (xmlfile.file_budget), each block to its declared size."""
    blocks = []
    inflation = file_budget(path)
    for k, node in enumerate(root.iter("ELEMENTS")):
        what = f"ELEMENTS block {k} (ID={node.attrib.get('ID', '?')[:40]})"
        shape, basis, fields, kind, counts = parse_header(
            path, what, node.attrib.get("SHAPE", ""), [s.strip() for s in node.attrib.get("BASIS", "").split(",")],
            node.attrib.get("FIELDS", "").split(","), node.attrib.get("NUMMODESPERDIR", ""), node.attrib)
        # bodies are always B64Z (docs/spec/formats.md §2.6)
        endian = endianness(node, path, what, default="B64Z-LittleEndian") or "<"
        if budget is None:
            blocks.append(Block(shape, basis, fields, None, None, None, what))
            continue
        ranges = parse_ranges(node.attrib.get("ID"), path, what)
        budget.claim(path, what, range_count(ranges), fields)

        def read_data(want, text=node.text or "", what=what, endian=endian):
            inflation.spend(8 * want, f"{path}: {what}")
            raw = inflate_b64z(text, path, what, 8 * want)
            if len(raw) % 8:
                raise NektarError(f"{path}: {what}: {len(raw)} bytes is not a whole number of float64 values")
            return np.frombuffer(raw, dtype=endian + "f8")

        blocks.append(finish_block(path, what, shape, basis, fields, kind, counts, expand_ranges(ranges), read_data))
    if not blocks:
        raise NektarError(f"{path}: no <ELEMENTS> blocks")
    return blocks


def _field_coefficients(path, blocks, field):
    """{element ID: (shape, modes, Modified coefficients)} of one field."""
    out = {}
    for block in blocks:
        if field not in block.fields:
            continue
        per_element = coefficient_counts(block.shape, block.modes)
        total = int(per_element.sum())
        f = block.fields.index(field)
        values = block.data[f * total : (f + 1) * total]
        bad = ~np.isfinite(values)
        offsets = np.concatenate([[0], np.cumsum(per_element)])
        if bad.any():
            e = int(np.searchsorted(offsets, np.flatnonzero(bad)[0], side="right") - 1)
            raise NektarError(f"{path}: {block.what}: element {int(block.ids[e])}, field {field!r}: coefficients "
                              "contain NaN or Inf")
        gll = block.basis[0] == "GLL_Lagrange"
        for i, (e, modes) in enumerate(zip(block.ids.tolist(), block.modes)):
            if e in out:
                raise NektarError(f"{path}: {block.what}: element {e} appears twice for field {field!r}")
            coeffs = np.array(values[offsets[i] : offsets[i + 1]], dtype=np.float64)
            if gll:
                coeffs = _gll_to_modal(tuple(int(v) for v in modes)) @ coeffs
            out[e] = (block.shape, modes, coeffs)
    return out


@lru_cache(maxsize=None)
def _gll_to_modal(modes):
    """The (K, K) matrix taking GLL_Lagrange nodal values of a hex to Modified_A coefficients."""
    K = int(np.prod(modes))
    return np.asarray(ex.gll_lagrange_hex_to_modal(modes, np.eye(K)), dtype=np.float64).reshape(K, K)
