"""Byte-flip and truncation fuzzer of PyFR files (issue 39): the vendored shell case's mesh
(tests/data/pyfr/shell.pyfrm) and solution (shell-0.02.pyfrs), both HDF5, one of them changed
per mutant: one byte (xor 0xFF, zero, a random value or one bit; the bytes of the HDF5 headers
and metadata, the first 4 KiB and the last 8 KiB where h5py puts them, are picked half the
time) or cut short at a random length. Through the reader process (io/isolation.py) every mutant
must load or be refused with one line naming a file, and the process that asked must live on.

    python -m tests.fuzz.pyfr_mutation [--mutants 2000] [--seed 39] [--cli 40] [--bpy 12]

Judged as tests/fuzz/hdf5_mutation.py judges (its `classify`): here through io.sources.load_volume
with a read time limit of --seconds; --cli of them (every one the reader died or was stopped on
first) as `hovr render` commands (exit 0 or 2, one `hovr: error:` line, within the hostile
suite's 5 s and 500 MB: tests/hostile/harness.py); --bpy of them imported in bpy (the import
reports, the scene is unchanged). Results: bench/results/pyfr_mutation.json; tests/io/
test_pyfr_mutation.py runs a sample.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from tests.fuzz.hdf5_mutation import CHANGES, classify
from tests.helpers import REPO, data_file
from tests.hostile import cases, harness

RESULT = REPO / "bench" / "results" / "pyfr_mutation.json"
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


def _write(folder: Path, mesh: bytes, soln: bytes):
    (folder / "m.pyfrm").write_bytes(mesh)
    (folder / "m-0.02.pyfrs").write_bytes(soln)
    return folder / "m.pyfrm", folder / "m-0.02.pyfrs"


def run_here(items, folder: Path, seconds: float) -> dict:
    """Each mutant loaded by this process through the reader process."""
    from hovr_blender.engine import limits
    from hovr_blender.io.sources import VolumeSource, load_volume

    summary = {"mutants": 0, "outcomes": {}, "problems": [], "max_seconds": 0.0, "reader_died_or_stopped": []}
    with limits.using(limits.ResourceLimits(max_read_seconds=seconds)):
        for label, mesh, soln in items:
            mesh_path, soln_path = _write(folder, mesh, soln)
            t0 = time.perf_counter()
            error = None
            try:
                load_volume(VolumeSource(str(mesh_path), str(soln_path), FIELD))
            except Exception as exc:  # noqa: BLE001  (classified: what the user would be told)
                error = exc
            dt = time.perf_counter() - t0
            outcome = classify(error)
            summary["mutants"] += 1
            summary["outcomes"][outcome] = summary["outcomes"].get(outcome, 0) + 1
            summary["max_seconds"] = max(summary["max_seconds"], round(dt, 2))
            if outcome.startswith("reader ") and outcome != "reader failed":
                summary["reader_died_or_stopped"].append(label)
            message = "" if error is None else str(error)
            if outcome == "unexpected" or "\n" in message or (
                    error is not None and mesh_path.name not in message and soln_path.name not in message):
                summary["problems"].append(f"{label}: {type(error).__name__}: {message[:300]}")
            if dt > seconds + 30:
                summary["problems"].append(f"{label}: took {dt:.0f} s")
    return summary


def run_cli(items, folder: Path, seconds: float) -> dict:
    """Each mutant through `hovr render`, judged as the hostile suite judges (exit 0 or one line)."""
    out = {"mutants": 0, "exit_codes": {}, "problems": [], "max_seconds": 0.0, "max_peak_mb": 0.0,
           "over_5_s_or_500_mb": []}
    for label, mesh, soln in items:
        _write(folder, mesh, soln)
        args = cases.render_args(folder, cases.base_view({"path": "m.pyfrm", "solution": "m-0.02.pyfrs",
                                                          "field": FIELD}))
        o = harness.run_hovr(args, folder, {"HOVR_MAX_READ_SECONDS": str(seconds)})
        out["mutants"] += 1
        out["exit_codes"][str(o.returncode)] = out["exit_codes"].get(str(o.returncode), 0) + 1
        out["max_seconds"] = max(out["max_seconds"], round(o.seconds, 2))
        out["max_peak_mb"] = max(out["max_peak_mb"], round(o.peak_mb, 1))
        if o.returncode == 2 and (o.seconds > harness.MAX_SECONDS or o.peak_mb > harness.MAX_PEAK_MB):
            out["over_5_s_or_500_mb"].append(f"{label}: {o.seconds:.1f} s, {o.peak_mb:.0f} MB")
        lines = [ln for ln in o.stderr.splitlines() if ln.strip()]
        if o.timed_out or o.returncode not in (0, 2) or "Traceback" in o.stderr or (
                o.returncode == 2 and (len(lines) != 1 or not lines[0].startswith("hovr: error: "))):
            out["problems"].append(f"{label}: exit {o.returncode}{' (hung)' if o.timed_out else ''}: {o.stderr[-300:]!r}")
    return out


_BPY = textwrap.dedent("""
    import json, sys
    import bpy
    import hovr_blender
    items = json.loads(sys.stdin.read())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    def counts():
        return {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "materials", "cameras")}
    out = []
    for mesh, soln in items:
        before = counts()
        try:
            bpy.ops.import_scene.hovr_pyfr(filepath=mesh, solution=soln, field="rho", fit_range=False, frame=False)
            outcome = "imported"
            for obj in [o for o in bpy.data.objects if o.hovr.is_volume]:
                bpy.data.objects.remove(obj)
        except RuntimeError as exc:
            outcome = "reported" if counts() == before else "reported, scene changed"
            if "\\n" in str(exc).strip():
                outcome += ", several lines"
        out.append(outcome)
    print("RESULT " + json.dumps(out), flush=True)
""")


def run_bpy(items, folder: Path, seconds: float) -> dict:
    """The mutants imported by bpy's File > Import operator in one fresh process."""
    payload = []
    for k, (label, mesh, soln) in enumerate(items):
        sub = folder / f"b{k}"
        sub.mkdir(exist_ok=True)
        payload.append([str(p) for p in _write(sub, mesh, soln)])
    env = dict(os.environ, PYTHONPATH=str(REPO), HOVR_MAX_READ_SECONDS=str(seconds))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _BPY], input=json.dumps(payload), capture_output=True, text=True,
                       env=env, timeout=60 + len(items) * (seconds + 30))
    line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
    outcomes = json.loads(line[7:]) if line else []
    problems = [] if p.returncode == 0 and line else [f"bpy process exit {p.returncode}: {p.stderr[-400:]!r}"]
    problems += [f"{label}: {o}" for (label, *_), o in zip(items, outcomes) if o not in ("imported", "reported")]
    return {"mutants": len(outcomes), "outcomes": {o: outcomes.count(o) for o in set(outcomes)}, "problems": problems,
            "exit_code": p.returncode, "seconds": round(time.perf_counter() - t0, 1)}


def run(count=2000, seed=39, cli=40, bpy=12, seconds=5.0) -> dict:
    rng = np.random.default_rng(seed)
    srcs = sources()
    items = mutants(rng, srcs, count)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        here = run_here(items, tmp, seconds)
        result = {"date": time.strftime("%Y-%m-%d"), "seed": seed, "read_seconds_limit": seconds,
                  "sources": {k: len(v) for k, v in srcs.items()}, "in_process": here,
                  "in_process_seconds": round(time.perf_counter() - t0, 1)}
        died = set(here["reader_died_or_stopped"])
        order = [it for it in items if it[0] in died] + [it for it in items if it[0] not in died]
        if cli:
            result["cli"] = run_cli(order[:cli], tmp, seconds)
        if bpy:
            result["bpy"] = run_bpy(order[:bpy], tmp, seconds)
    result["passed"] = not (here["problems"] or result.get("cli", {}).get("problems")
                            or result.get("bpy", {}).get("problems"))
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mutants", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=39)
    ap.add_argument("--cli", type=int, default=40, help="mutants also run as `hovr render` (0: none)")
    ap.add_argument("--bpy", type=int, default=12, help="mutants also imported in bpy (0: none)")
    ap.add_argument("--seconds", type=float, default=5.0, help="the reader's time limit per mutant")
    ap.add_argument("--out", type=Path, default=RESULT)
    args = ap.parse_args(argv)
    result = run(args.mutants, args.seed, args.cli, args.bpy, args.seconds)
    result["command"] = "python -m tests.fuzz.pyfr_mutation " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "in_process"} | {
        "in_process": {k: v for k, v in result["in_process"].items() if k != "reader_died_or_stopped"}}, indent=1))
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
