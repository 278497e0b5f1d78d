"""Byte-flip and truncation fuzzer of PyFR files (issue 39): the vendored shell case's mesh
(tests/data/pyfr/shell.pyfrm) and solution (shell-0.02.pyfrs), both HDF5, one of them changed
per mutant: one byte (xor 0xFF, zero, a random value or one bit; the bytes of the HDF5 headers
and metadata, the first 4 KiB and the last 8 KiB where h5py puts them, are picked half the
time) or cut short at a random length. Through the reader process (io/isolation.py) every mutant
must load or be refused with one line naming a file, and the process that asked must live on.

    python -m tests.fuzz.pyfr_mutation [--mutants 2000] [--seed 39] [--cli 40] [--bpy 12]

Judged as tests/fuzz/campaign.py judges: here through io.sources.load_volume with a read time
limit of --seconds; --cli of them (every one the reader died or was stopped on first) as `hovr
render` commands; --bpy of them imported in bpy. Results: bench/results/pyfr_mutation.json;
tests/io/test_pyfr_mutation.py runs a sample.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.fuzz.campaign import Campaign, Written
from tests.fuzz.hdf5_mutation import CHANGES
from tests.helpers import data_file

FIELD = "rho"
HEAD, TAIL = 4096, 8192  # where h5py writes the superblock, the object headers and the heaps of these files


def sources() -> dict:
    """{"mesh": bytes, "soln": bytes} of the vendored shell case."""
    return {"mesh": data_file("pyfr", "shell.pyfrm").read_bytes(),
            "soln": data_file("pyfr", "shell-0.02.pyfrs").read_bytes()}


def mutants(rng, srcs: dict, count: int) -> list:
    """[(label, mesh bytes, solution bytes)]: one of the two files changed in each."""
    out = []
    while len(out) < count:
        which = ("mesh", "soln")[int(rng.integers(2))]
        data = bytearray(srcs[which])
        if rng.random() < 0.1:
            cut = int(rng.integers(len(data)))
            label = f"{which} cut at {cut}"
            data = data[:cut]
        else:
            if rng.random() < 0.5:
                i = int(rng.integers(HEAD)) if rng.random() < 0.5 else len(data) - 1 - int(rng.integers(TAIL))
            else:
                i = int(rng.integers(len(data)))
            change = CHANGES[int(rng.integers(len(CHANGES)))]
            data[i] = {"xor 0xFF": data[i] ^ 0xFF, "zero": 0, "random": int(rng.integers(256)),
                       "one bit": data[i] ^ (1 << int(rng.integers(8)))}[change]
            label = f"{which} byte {i} {change}"
        pair = dict(srcs, **{which: bytes(data)})
        out.append((label, pair["mesh"], pair["soln"]))
    return out


def write(folder: Path, mutant) -> Written:
    _, mesh, soln = mutant
    (folder / "m.pyfrm").write_bytes(mesh)
    (folder / "m-0.02.pyfrs").write_bytes(soln)
    return Written(folder / "m.pyfrm", folder / "m-0.02.pyfrs", FIELD)


CAMPAIGN = Campaign("pyfr_mutation", "hovr_pyfr", write)


def run(count=2000, seed=39, cli=40, bpy=12, seconds=5.0) -> dict:
    rng = np.random.default_rng(seed)
    srcs = sources()
    items = mutants(rng, srcs, count)
    with tempfile.TemporaryDirectory() as tmp:
        return CAMPAIGN.run(items, Path(tmp), seed, {k: len(v) for k, v in srcs.items()}, cli, bpy, seconds)


def main(argv=None) -> int:
    return CAMPAIGN.main(argv, __doc__, run, seed=39, seconds=5.0)


if __name__ == "__main__":
    sys.exit(main())
