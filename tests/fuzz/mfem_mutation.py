"""Text mutation fuzzer of MFEM files (issue 39): the vendored meshes and GridFunctions
(tests/data/mfem: the curved Fichera corner v1.0 with its H1 field, its v1.2 piece, the zoo with
pyramids and its L2 field, the variable-order field on the NC mesh), one of the pair changed per
mutant, once or twice, the way text goes wrong:

- an absurd count (a line that is one whole number: element, vertex, boundary counts, the
  dimension, VDim, Ordering) or an absurd number anywhere: 0, -1, 2^31 - 1, 2^31, 10^9, 10^12,
  10^18, 10^30;
- an absurd order or type in a collection's name (P0, P14, P15, P99, P1000000, L2_T9, _Pyr7,
  H1Pos, ND, a 2-D space);
- a number made something else: nan, inf, -inf, 1e999, 1e308, 1.5, abc, 0x10;
- an element's geometry id (-1..9) or one of its vertices (negative, huge, a repeat);
- a line deleted, repeated or swapped with the next; a keyword misspelt; a byte changed;
- the file cut short at a random byte.

Through the reader process (io/isolation.py) every mutant must load or be refused with one line
naming a file, and the process that asked must live on; --cli of them (every one the reader died
or was stopped on first) as `hovr render`; --bpy of them imported in bpy; each judged as
tests/fuzz/campaign.py says.

    python -m tests.fuzz.mfem_mutation [--mutants 2000] [--seed 39] [--cli 40] [--bpy 12]

Results: bench/results/mfem_mutation.json; tests/io/test_mfem_mutation.py runs a sample.
"""
from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.fuzz.campaign import Campaign, Written
from tests.helpers import data_file

PAIRS = (("fichera.mesh", "fichera-u.gf"), ("fichera-part0.mesh", "fichera-part0-u.gf"), ("zoo.mesh", "zoo-w.gf"),
         ("var.mesh", "var.gf"))
ABSURD = (b"0", b"-1", b"2147483647", b"2147483648", b"1000000000", b"1000000000000", b"1000000000000000000",
          b"1000000000000000000000000000000")
NOT_NUMBERS = (b"nan", b"inf", b"-inf", b"1e999", b"1e308", b"1.5", b"abc", b"0x10")
COLLECTIONS = (b"P0", b"P14", b"P15", b"P99", b"P1000000", b"_T9_", b"_Pyr7", b"H1Pos_3D_P2", b"ND_3D_P1",
               b"H1_2D_P2", b"L2Int_3D_P1")
KINDS = ("count", "number", "collection", "not a number", "geometry", "vertex", "line", "keyword", "byte", "cut")
_TOKEN = re.compile(rb"\S+")
_NUMBER = re.compile(rb"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
_COUNT_LINE = re.compile(rb"^[ \t]*(\d+)[ \t]*\r?$", re.M)
_COLLECTION = re.compile(rb"(?:H1|L2)[^\s]*_3D_P\d+")
_ELEMENT_LINE = re.compile(rb"^[ \t]*\d+ \d+ [\d ]+$", re.M)
_WORD = re.compile(rb"^[ \t]*[A-Za-z_][A-Za-z_:]+", re.M)


def sources() -> list:
    """[(mesh name, mesh bytes, gf name, gf bytes)] of the vendored pairs."""
    return [(m, data_file("mfem", m).read_bytes(), g, data_file("mfem", g).read_bytes()) for m, g in PAIRS]


def _replace(data: bytes, m, new: bytes) -> bytes:
    return data[:m.start()] + new + data[m.end():]


def _pick(rng, matches):
    return matches[int(rng.integers(len(matches)))] if matches else None


def mutate(rng, data: bytes, kind: str) -> tuple[bytes, str]:
    """One change of `kind` to a text; (new text, what was done)."""
    if kind == "cut":
        cut = int(rng.integers(len(data)))
        return data[:cut], f"cut at {cut}"
    if kind == "byte":
        i = int(rng.integers(len(data)))
        value = int(rng.integers(256))
        return data[:i] + bytes([value]) + data[i + 1:], f"byte {i} = {value}"
    if kind == "line":
        lines = data.split(b"\n")
        i = int(rng.integers(len(lines)))
        how = ("deleted", "repeated", "swapped")[int(rng.integers(3))]
        if how == "deleted":
            del lines[i]
        elif how == "repeated":
            lines.insert(i, lines[i])
        elif i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        return b"\n".join(lines), f"line {i + 1} {how}"
    pattern, choices = {"count": (_COUNT_LINE, ABSURD), "number": (_NUMBER, ABSURD),
                        "not a number": (_NUMBER, NOT_NUMBERS), "collection": (_COLLECTION, COLLECTIONS),
                        "keyword": (_WORD, None), "geometry": (_ELEMENT_LINE, None),
                        "vertex": (_ELEMENT_LINE, None)}[kind]
    m = _pick(rng, list(pattern.finditer(data)))
    if m is None:
        return mutate(rng, data, "byte")
    line = data.count(b"\n", 0, m.start()) + 1
    if kind == "count":
        new = choices[int(rng.integers(len(choices)))]
        return data[:m.start(1)] + new + data[m.end(1):], f"count on line {line} = {new.decode()}"
    if kind in ("number", "not a number"):
        new = choices[int(rng.integers(len(choices)))]
        return _replace(data, m, new), f"number on line {line} = {new.decode()}"
    if kind == "collection":
        new = choices[int(rng.integers(len(choices)))]
        name = m.group()
        if new.startswith(b"P"):
            out = re.sub(rb"P\d+", new, name, count=1)
        elif new.startswith(b"_"):
            out = name.replace(b"_3D", new[:-1] + b"_3D", 1) if new == b"_T9_" else name + new
        else:
            out = new
        return _replace(data, m, out), f"collection on line {line} = {out.decode()}"
    if kind == "keyword":
        word = bytearray(m.group())
        i = int(rng.integers(len(word)))
        word[i] = ord("x") if word[i] != ord("x") else ord("y")
        return _replace(data, m, bytes(word)), f"keyword on line {line} = {bytes(word).decode('ascii', 'replace').strip()}"
    tokens = m.group().split()
    if kind == "geometry":
        tokens[1] = str(int(rng.integers(-1, 10))).encode()
        what = f"geometry on line {line} = {tokens[1].decode()}"
    else:
        j = int(rng.integers(2, len(tokens)))
        new = (b"-3", b"4294967296", b"99999", tokens[2 if j != 2 else min(3, len(tokens) - 1)])[int(rng.integers(4))]
        tokens[j] = new
        what = f"vertex on line {line} = {new.decode()}"
    return _replace(data, m, b" ".join(tokens)), what


def mutants(rng, srcs: list, count: int) -> list:
    """[(label, mesh name, mesh bytes, gf name, gf bytes)]: one of each pair changed, once or twice."""
    out = []
    while len(out) < count:
        mesh_name, mesh, gf_name, gf = srcs[int(rng.integers(len(srcs)))]
        which = int(rng.integers(2))
        data = (mesh, gf)[which]
        notes = []
        for _ in range(1 + int(rng.random() < 0.25)):
            data, note = mutate(rng, data, KINDS[int(rng.integers(len(KINDS)))])
            notes.append(note)
        name = (mesh_name, gf_name)[which]
        label = f"{name}: {'; '.join(notes)}"
        pair = (data, gf) if which == 0 else (mesh, data)
        out.append((label, mesh_name, pair[0], gf_name, pair[1]))
    return out


def write(folder: Path, mutant) -> Written:
    _, _, mesh, _, gf = mutant
    (folder / "m.mesh").write_bytes(mesh)
    (folder / "m-u.gf").write_bytes(gf)
    return Written(folder / "m.mesh", folder / "m-u.gf")


def kind(label: str) -> str:
    """The kind of a mutant's first change, from its label ("count", "line", ...)."""
    return re.sub(r" (on line|at|\d).*", "", label.split(": ", 1)[1].split("; ")[0])


CAMPAIGN = Campaign("mfem_mutation", "hovr_mfem", write, kind)


def run(count=2000, seed=39, cli=40, bpy=12, seconds=5.0) -> dict:
    rng = np.random.default_rng(seed)
    srcs = sources()
    items = mutants(rng, srcs, count)
    with tempfile.TemporaryDirectory() as tmp:
        return CAMPAIGN.run(items, Path(tmp), seed, {f"{m} + {g}": [len(mb), len(gb)] for m, mb, g, gb in srcs},
                            cli, bpy, seconds)


def main(argv=None) -> int:
    return CAMPAIGN.main(argv, __doc__, run, seed=39, seconds=5.0)


if __name__ == "__main__":
    sys.exit(main())
