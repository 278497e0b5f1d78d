"""Strict reading of JSON values from a view file, which may come from anywhere.

json.load gives bools where numbers are expected, strings for numbers, floats of 1e400 (inf)
for integers; numpy would coerce all of them silently. Each helper here accepts exactly the
JSON type the render contract means and raises `exc` with a message naming the key.
"""
from __future__ import annotations

import math

import numpy as np


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def as_object(v, what: str, exc=ValueError) -> dict:
    if not isinstance(v, dict):
        raise exc(f"{what} must be a JSON object, not {type(v).__name__}")
    return v


def as_string(v, what: str, exc=ValueError) -> str:
    if not isinstance(v, str):
        raise exc(f"{what} must be a string, not {type(v).__name__}")
    return v


def as_number(v, what: str, exc=ValueError) -> float:
    """A finite JSON number (int or float, not a bool)."""
    if not _is_number(v) or not math.isfinite(v):
        raise exc(f"{what} must be a finite number, got {v!r}")
    return float(v)


def as_integer(v, what: str, exc=ValueError, lo: int | None = None, hi: int | None = None) -> int:
    """A JSON integer (not a bool, not 1.9, not "32") within [lo, hi]."""
    if not isinstance(v, int) or isinstance(v, bool):
        raise exc(f"{what} must be a whole number, got {v!r}")
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise exc(f"{what} = {v} is out of range {lo}..{hi}")
    return v


def as_numbers(v, what: str, exc=ValueError, columns: int | None = None) -> np.ndarray:
    """A list of finite numbers (columns None: shape (n,)) or of rows of `columns` numbers
    (tuples and numpy arrays too, for callers in Python)."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or not v:
        raise exc(f"{what} must be a non-empty list, got {type(v).__name__}")
    rows = v if columns is not None else [v]
    for r in rows:
        if isinstance(r, np.ndarray):
            r = r.tolist()
        if not isinstance(r, (list, tuple)) or (columns is not None and len(r) != columns):
            raise exc(f"{what}: each entry must be a list of {columns} numbers, got {r!r}"[:200])
        for x in r:
            if not _is_number(x) or not math.isfinite(x):
                raise exc(f"{what}: {x!r} is not a finite number")
    return np.asarray(v, dtype=np.float64)


def as_vector3(v, what: str, exc=ValueError) -> np.ndarray:
    a = as_numbers(v, what, exc)
    if a.shape != (3,):
        raise exc(f"{what} must be [x, y, z], got {len(v)} numbers")
    return a


def _unique_keys(exc):
    def hook(pairs):
        out = {}
        for key, value in pairs:
            if key in out:
                raise exc(f"key {key!r} appears twice in one object (which one is meant is not clear)")
            out[key] = value
        return out
    return hook


def loads(raw: bytes, what: str, exc=ValueError):
    """A JSON document (UTF-8 bytes) in which no object has a key twice (json.loads keeps the
    last: a second "data" would silently switch the dataset). Errors name `what`."""
    import json

    try:
        return json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys(exc))
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise exc(f"{what}: not valid JSON ({err})") from None
    except exc as err:
        raise exc(f"{what}: {err}") from None
