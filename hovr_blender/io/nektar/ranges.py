"""Nektar++ ID lists ("0-7,12"): kept as inclusive ranges, because their declared sizes are
untrusted; the work done with them is bounded by the text and by the IDs that exist."""
from __future__ import annotations

import re

import numpy as np

from .errors import NektarError


def parse_ranges(text, path, what):
    """List of (first, last) inclusive ranges of an ID list."""
    out = []
    for token in (text or "").replace(" ", "").replace("\t", "").replace("\n", "").split(","):
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", token)
        if not match:
            raise NektarError(f"{path}: {what}: bad ID list {text!r}")
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) else first
        if last < first:
            raise NektarError(f"{path}: {what}: bad ID range {token!r}")
        if last >= 1 << 62:
            raise NektarError(f"{path}: {what}: ID {last} is out of range")
        out.append((first, last))
    return out


def range_count(ranges):
    return sum(last - first + 1 for first, last in ranges)


def expand_ranges(ranges):
    """The IDs themselves: only once range_count has been checked against what exists."""
    if not ranges:
        return np.zeros(0, np.int64)
    return np.concatenate([np.arange(first, last + 1, dtype=np.int64) for first, last in ranges])


def select(ids, ranges):
    """(positions in the sorted array `ids` of the IDs any range holds, (lo, hi) position bounds
    of each range, and whether each range's IDs all exist). Work is bounded by the number of
    ranges plus len(ids), never by the ranges' declared sizes."""
    bounds = np.array(ranges, dtype=np.int64).reshape(-1, 2)
    lo = np.searchsorted(ids, bounds[:, 0], "left")
    hi = np.searchsorted(ids, bounds[:, 1], "right")
    complete = hi - lo - 1 == bounds[:, 1] - bounds[:, 0]
    depth = np.zeros(len(ids) + 1, np.int64)  # how many ranges cover each position
    np.add.at(depth, lo, 1)
    np.add.at(depth, hi, -1)
    return np.flatnonzero(np.cumsum(depth[:-1]) > 0), lo, hi, complete


def first_missing(ids, first, lo, hi):
    """The first ID from `first` on that `ids` (sorted) lacks, given ids[lo:hi] are those in the range."""
    offsets = ids[lo:hi] - first - np.arange(hi - lo)
    gap = np.flatnonzero(offsets)
    return int(first + (gap[0] if len(gap) else hi - lo))
