"""What a field file holds, whatever its format: blocks of elements of one shape and basis,
their mode counts and their coefficients (docs/spec/formats.md §2.5-§2.7), every size checked
against the mesh before any data is inflated or read."""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ...engine import expansions as ex
from ...engine.shapes import HEX, MAX_MODES, NAMES, PRISM, PYR, TET
from .errors import NektarError

FIELD_SHAPES = {"Hexahedron": HEX, "Prism": PRISM, "Tetrahedron": TET, "Pyramid": PYR}
# The Modified basis each shape must carry in a field file (docs/spec/formats.md §2.5);
# GLL_Lagrange only for hexes.
MODIFIED_BASES = {
    HEX: ("Modified_A",) * 3,
    PRISM: ("Modified_A", "Modified_A", "Modified_B"),
    TET: ("Modified_A", "Modified_B", "Modified_C"),
    PYR: ("Modified_A", "Modified_A", "ModifiedPyr_C"),
}


@dataclass
class Block:
    shape: int
    basis: tuple
    fields: list
    ids: np.ndarray  # (n,) element IDs; None when only the headers were read
    modes: np.ndarray  # (n, 3)
    data: np.ndarray  # all values, field-major
    what: str  # names the block in errors


def coefficient_counts(shape, modes):
    """(n,) coefficients per element of the (n, 3) mode counts."""
    unique, inverse = np.unique(np.asarray(modes).reshape(-1, 3), axis=0, return_inverse=True)
    per_unique = np.array([ex.num_coeffs(shape, m) for m in unique.tolist()], dtype=np.int64)
    return per_unique[inverse.ravel()]


def parse_header(path, what, shape_name, basis, fields, nummodes, attributes):
    """(shape, basis, fields, "UNIORDER" or "MIXORDER", the mode counts' text) of a block's
    definition; attributes: the names of all its attributes (some are refused)."""
    if "Homogen" in shape_name or "Strips" in shape_name or "HOMOGENEOUSLENGTHS" in attributes:
        raise NektarError(f"{path}: {what}: SHAPE={shape_name!r}: homogeneous (Fourier-extruded) fields are "
                          "not supported")
    if shape_name not in FIELD_SHAPES:
        raise NektarError(f"{path}: {what}: SHAPE={shape_name!r}; only 3-D elements (Hexahedron, Prism, Tetrahedron, "
                          "Pyramid)")
    shape = FIELD_SHAPES[shape_name]
    for key in ("POINTSTYPE", "NUMPOINTSPERDIR"):
        if key in attributes:
            raise NektarError(f"{path}: {what}: {key} (point data rather than coefficients) is not supported")
    basis = tuple(basis)
    if basis != MODIFIED_BASES[shape] and not (shape == HEX and basis == ("GLL_Lagrange",) * 3):
        raise NektarError(f"{path}: {what}: BASIS={','.join(basis)} for {NAMES[shape]}s is not supported; "
                          f"expected {','.join(MODIFIED_BASES[shape])}"
                          + (" or GLL_Lagrange x3" if shape == HEX else ""))
    fields = [f.strip() for f in fields]
    if not fields or any(not f for f in fields) or len(set(fields)) != len(fields):
        raise NektarError(f"{path}: {what}: bad FIELDS list {','.join(fields)!r}")
    match = re.fullmatch(r"\s*(UNIORDER|MIXORDER)\s*:?\s*([\d,\s]*)", nummodes or "")
    if not match:
        raise NektarError(f"{path}: {what}: NUMMODESPERDIR={nummodes!r}; expected UNIORDER:a,b,c or MIXORDER:...")
    return shape, basis, fields, match.group(1), match.group(2)


def mode_counts(path, what, kind, counts, num_elements):
    """(1, 3) for UNIORDER or (num_elements, 3) for MIXORDER mode counts, from text or a list."""
    try:
        if isinstance(counts, str):
            values = [int(v) for v in counts.replace(" ", "").split(",") if v != ""]
        else:
            values = list(counts)
    except ValueError:
        raise NektarError(f"{path}: {what}: bad mode counts {counts!r}") from None
    want = 3 if kind == "UNIORDER" else 3 * num_elements
    if len(values) != want:
        raise NektarError(f"{path}: {what}: {kind} gives {len(values)} mode counts, expected {want}")
    modes = np.array(values, dtype=np.int64).reshape(-1, 3)
    if np.any(modes < 1) or np.any(modes > MAX_MODES):
        raise NektarError(f"{path}: {what}: mode counts {sorted(set(modes.ravel().tolist()))[:6]} outside "
                          f"1..{MAX_MODES} (the renderer's limit)")
    return modes


def checked_coefficient_counts(path, what, shape, modes):
    try:
        return coefficient_counts(shape, modes)
    except ValueError as exc:  # e.g. a prism with more modes in direction 0 than in direction 2
        raise NektarError(f"{path}: {what}: mode counts invalid for {NAMES[shape]}s ({exc})") from None


class ElementBudget:
    """What the mesh lets a field file declare: each field once per mesh element. Claimed from
    the headers before any data is inflated or read, so the data is bounded by elements x
    fields x the coefficients of the declared modes."""

    def __init__(self, num_elements):
        self.num_elements = num_elements
        self.claimed = {}

    def claim(self, path, what, num_elements, fields):
        if num_elements > self.num_elements:
            raise NektarError(f"{path}: {what}: declares {num_elements:,} elements; the mesh has {self.num_elements:,}")
        for f in fields:
            self.claimed[f] = self.claimed.get(f, 0) + num_elements
            if self.claimed[f] > self.num_elements:
                raise NektarError(f"{path}: {what}: gives field {f!r} for {self.claimed[f]:,} elements in all; "
                                  f"the mesh has {self.num_elements:,}")


def finish_block(path, what, shape, basis, fields, kind, counts, ids, read_data):
    """The block, its modes and data checked against its element IDs (already bounded by an
    ElementBudget); read_data(number of values wanted) reads the data only then."""
    num_elements = len(ids)
    if num_elements == 0:
        raise NektarError(f"{path}: {what}: no element IDs")
    modes = mode_counts(path, what, kind, counts, num_elements)
    per_element = checked_coefficient_counts(path, what, shape, modes)
    want = len(fields) * (num_elements * int(per_element[0]) if kind == "UNIORDER" else int(per_element.sum()))
    data = read_data(want)
    if data.size != want:
        raise NektarError(f"{path}: {what}: {data.size} values, expected {want} "
                          f"({len(fields)} fields x {num_elements} elements, {NAMES[shape]} modes)")
    if len(np.unique(ids)) != num_elements:
        raise NektarError(f"{path}: {what}: an element ID appears twice")
    if kind == "UNIORDER":
        modes = np.broadcast_to(modes, (num_elements, 3)).copy()
    return Block(shape, basis, fields, ids, modes, data, what)
