"""The <DOMAIN>: which elements are rendered, through the composites it names
(docs/spec/formats.md §2.2). Ranges are intersected with the IDs that exist, never expanded."""
from __future__ import annotations

import re

import numpy as np

from ...engine.shapes import NAMES
from .composites import read_composites
from .entities import ELEMENT_TAGS
from .errors import NektarError
from .ranges import first_missing, parse_ranges, select


def domain_elements(geometry, path, elements):
    """Element IDs of the DOMAIN (all elements when there is no DOMAIN). Each composite is read
    once, however often it is named."""
    domain = geometry.find("DOMAIN")
    if domain is None:
        return sorted(elements)
    composites = _domain_composites(geometry, domain, path)
    element_ids = np.array(sorted(elements), dtype=np.int64)
    element_shapes = np.array([elements[e][0] for e in element_ids.tolist()], dtype=np.int64)
    # count[s][k]: elements of shape s among the first k, to check a range's shapes without expanding it
    count = np.concatenate([np.zeros((4, 1), np.int64),
                            np.cumsum(element_shapes == np.arange(4)[:, None], axis=1)], axis=1)
    ranges, owners = [], []  # element ranges, and (composite, letter) of each
    for composite_id, text in composites:
        for match in re.finditer(r"([A-Z])\s*\[([^\]]*)\]", text):
            letter = match.group(1)
            if letter not in ELEMENT_TAGS:
                raise NektarError(f"{path}: composite C[{composite_id}] in the DOMAIN holds {letter}[...], "
                                  "not 3-D elements")
            composite_ranges = parse_ranges(match.group(2), path, f"composite C[{composite_id}]")
            ranges.extend(composite_ranges)
            owners.extend([(composite_id, letter)] * len(composite_ranges))
    if not ranges:
        raise NektarError(f"{path}: the DOMAIN holds no elements")
    positions, lo, hi, complete = select(element_ids, ranges)
    shapes = np.array([ELEMENT_TAGS[letter] for _, letter in owners])
    same_shape = count[shapes, hi] - count[shapes, lo] == hi - lo
    bad = np.flatnonzero(~(complete & same_shape))
    if len(bad):
        i = int(bad[0])
        composite_id, letter = owners[i]
        if not complete[i]:
            missing = first_missing(element_ids, ranges[i][0], lo[i], hi[i])
            raise NektarError(f"{path}: composite C[{composite_id}] refers to missing element {missing}")
        k = lo[i] + int(np.argmax(element_shapes[lo[i] : hi[i]] != shapes[i]))
        raise NektarError(f"{path}: composite C[{composite_id}] lists {letter}[{element_ids[k]}] but element "
                          f"{element_ids[k]} is a {NAMES[int(element_shapes[k])]}")
    return element_ids[positions].tolist()


def _domain_composites(geometry, domain, path):
    """(composite ID, its text) of every composite the DOMAIN names, each once, in ID order."""
    texts = [domain.text or ""] + [d.text or "" for d in domain if d.tag == "D"]
    ranges = []
    for text in texts:
        for match in re.finditer(r"C\s*\[([^\]]*)\]", text):
            ranges.extend(parse_ranges(match.group(1), path, "DOMAIN"))
    if not ranges:
        raise NektarError(f"{path}: DOMAIN names no composite")
    composites = {cid: c.text for cid, c in read_composites(geometry, path).items()}
    composite_ids = np.array(sorted(composites), dtype=np.int64)
    positions, lo, hi, complete = select(composite_ids, ranges)
    if not complete.all():
        i = int(np.argmin(complete))
        missing = first_missing(composite_ids, ranges[i][0], lo[i], hi[i])
        raise NektarError(f"{path}: DOMAIN refers to missing composite C[{missing}]")
    return [(c, composites[c]) for c in composite_ids[positions].tolist()]
