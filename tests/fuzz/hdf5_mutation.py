"""Byte-flip fuzzer of HDF5 field files (issue 29): one changed byte in a valid Nektar++ HDF5
field file can crash libhdf5 (SIGSEGV) or send it into an endless loop; through the reader
process (io/isolation.py) every mutant must load or be refused with one line naming the file,
and the process that asked (this one, the `hovr` command, Blender) must live on.

    python -m tests.fuzz.hdf5_mutation [--mutants 2000] [--seed 29] [--cli 40] [--bpy 12]

The shared data hold no HDF5 field file (Nektar++'s own repository has no 3-D one), so the
sources are the shared XML field files rewritten as Nektar++ writes HDF5
(tests/hostile/cases.nektar_hdf5_from_xml: variable-length string attributes in the global
heap): Hex_01_01_01_03Modes_x2_Offset3 (12.7 KB, the size of the issue's file), Hex_CurvedFace,
wss_3D_periodic and Tet_channel_m3. Each mutant changes one byte (xor 0xFF, zero, a random value
or one bit) at a random position; the hostile suite's three named mutants (a vlen string type's
class bits: SIGSEGV; a global heap object of size 0: loops; a 4 GiB string length) come first.

Every mutant is loaded here through io.sources.load_volume (the reader process, at the policy's
read time limits, or a flat limit of --seconds); --cli of them (every one the reader died or was
stopped on, then others) run as `hovr render` commands, --bpy of them are imported in bpy, each
judged as tests/fuzz/campaign.py says. Results: bench/results/hdf5_mutation.json.
tests/io/test_isolation.py runs a small sample.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.fuzz.campaign import Campaign, Written
from tests.helpers import find_data
from tests.hostile import cases

SOURCES = [("Hex_01_01_01_03Modes_x2_Offset3", "p"), ("Hex_CurvedFace", "u"), ("wss_3D_periodic", "rho"),
           ("Tet_channel_m3", "w")]
NAMED = [("vlen string type bits", cases.VLEN_TYPE_BITS), ("global heap object of size 0", cases.HEAP_OBJECT_SIZE),
         ("vlen string of 4 GiB", cases.VLEN_LENGTH)]
CHANGES = ("xor 0xFF", "zero", "random", "one bit")


def sources(folder: Path) -> list:
    """[(name, mesh path, HDF5 bytes, field)] of the sources found (tests/data, then ../shared/data)."""
    out = []
    for stem, field in SOURCES:
        mesh, fld = find_data("nektar", f"{stem}.xml"), find_data("nektar", f"{stem}.fld")
        if mesh is None or fld is None:
            continue
        h5 = cases.nektar_hdf5_from_xml(fld, folder / f"{stem}.h5")
        out.append((stem, mesh, h5.read_bytes(), field))
    if not out:
        raise FileNotFoundError("none of the source Nektar++ files is in tests/data/nektar or ../shared/data/nektar")
    return out


def mutants(rng, srcs, count, folder: Path):
    """[(label, mesh, mutant bytes, field)]: the named ones, then one-byte changes."""
    out = []
    hex_mesh = next((m for name, m, _, _ in srcs if name.startswith("Hex_01")), None)
    if hex_mesh is not None:
        for label, build in NAMED:
            build(folder / "named.fld")
            out.append((f"named: {label}", hex_mesh, (folder / "named.fld").read_bytes(), "p"))
    while len(out) < count:
        name, mesh, data, field = srcs[int(rng.integers(len(srcs)))]
        i = int(rng.integers(len(data)))
        change = CHANGES[int(rng.integers(len(CHANGES)))]
        b = bytearray(data)
        b[i] = {"xor 0xFF": b[i] ^ 0xFF, "zero": 0, "random": int(rng.integers(256)),
                "one bit": b[i] ^ (1 << int(rng.integers(8)))}[change]
        out.append((f"{name} byte {i} {change}", mesh, bytes(b), field))
    return out


def write(folder: Path, mutant) -> Written:
    """The mutant as folder/m.fld; its mesh is the source's own file."""
    _, mesh, data, field = mutant
    (folder / "m.fld").write_bytes(data)
    return Written(Path(mesh), folder / "m.fld", field)


CAMPAIGN = Campaign("hdf5_mutation", "hovr_nektar", write)


def run(count=2000, seed=29, cli=40, bpy=12, seconds=None) -> dict:
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        srcs = sources(tmp)
        items = mutants(rng, srcs, count, tmp)
        return CAMPAIGN.run(items, tmp, seed, {name: len(data) for name, _, data, _ in srcs}, cli, bpy, seconds)


def main(argv=None) -> int:
    return CAMPAIGN.main(argv, __doc__, run, seed=29, seconds=None)


if __name__ == "__main__":
    sys.exit(main())
