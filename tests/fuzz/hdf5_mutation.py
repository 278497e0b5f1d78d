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

Every mutant is loaded here through io.sources.load_volume (the reader process, a read time
limit of --seconds); --cli of them (every one the reader died or was stopped on, then others) run
as `hovr render` commands, judged like the hostile suite (exit 0 or 2, one `hovr: error:` line,
no hang); --bpy of them are imported in bpy (a fresh Blender-as-a-module process: its import
operator reports, the scene keeps its datablocks, the process exits normally). Results:
bench/results/hdf5_mutation.json. tests/io/test_isolation.py runs a small sample.
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

from tests.helpers import REPO, find_data
from tests.hostile import cases, harness

RESULT = REPO / "bench" / "results" / "hdf5_mutation.json"
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


def classify(exc: BaseException | None) -> str:
    from hovr_blender.io import isolation

    if exc is None:
        return "loaded"
    text = str(exc)
    if isinstance(exc, isolation.ReaderFailure):
        if "crashed" in text:
            return "reader crashed"
        if "longer than the limit" in text:
            return "reader stopped (time limit)"
        if "killed" in text:
            return "reader killed"
        return "unexpected" if "unexpected" in text else "reader failed"
    if isinstance(exc, (ValueError, OSError, ImportError)):
        return "unexpected" if "unexpected" in text else "refused"
    return "unexpected"


def run_here(items, folder: Path, seconds: float) -> dict:
    """Each mutant loaded by this process through the reader process."""
    from hovr_blender.engine import limits
    from hovr_blender.io.sources import VolumeSource, load_volume

    summary = {"mutants": 0, "outcomes": {}, "problems": [], "max_seconds": 0.0, "reader_died_or_stopped": []}
    with limits.using(limits.ResourceLimits(max_read_seconds=seconds)):
        for label, mesh, data, field in items:
            path = folder / "m.fld"
            path.write_bytes(data)
            t0 = time.perf_counter()
            error = None
            try:
                load_volume(VolumeSource(str(mesh), str(path), field))
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
            if outcome == "unexpected" or "\n" in message or (error is not None and "m.fld" not in message
                                                               and Path(mesh).name not in message):
                summary["problems"].append(f"{label}: {type(error).__name__}: {message[:300]}")
            if dt > seconds + 30:
                summary["problems"].append(f"{label}: took {dt:.0f} s")
    return summary


def run_cli(items, folder: Path, seconds: float) -> dict:
    """Each mutant through `hovr render`, judged as the hostile suite judges."""
    out = {"mutants": 0, "exit_codes": {}, "problems": [], "max_seconds": 0.0, "max_peak_mb": 0.0}
    for label, mesh, data, field in items:
        (folder / "m.xml").write_bytes(Path(mesh).read_bytes())
        (folder / "m.fld").write_bytes(data)
        args = cases.render_args(folder, cases.base_view({"path": "m.xml", "solution": "m.fld", "field": field}))
        o = harness.run_hovr(args, folder, {"HOVR_MAX_READ_SECONDS": str(seconds)})
        out["mutants"] += 1
        out["exit_codes"][str(o.returncode)] = out["exit_codes"].get(str(o.returncode), 0) + 1
        out["max_seconds"] = max(out["max_seconds"], round(o.seconds, 2))
        out["max_peak_mb"] = max(out["max_peak_mb"], round(o.peak_mb, 1))
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
    for mesh, fld, field in items:
        before = counts()
        try:
            bpy.ops.import_scene.hovr_nektar(filepath=mesh, solution=fld, field=field, fit_range=False, frame=False)
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
    for k, (label, mesh, data, field) in enumerate(items):
        (folder / f"b{k}.fld").write_bytes(data)
        payload.append((str(mesh), str(folder / f"b{k}.fld"), field))
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


def run(count=2000, seed=29, cli=40, bpy=12, seconds=5.0) -> dict:
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        srcs = sources(tmp)
        items = mutants(rng, srcs, count, tmp)
        t0 = time.perf_counter()
        here = run_here(items, tmp, seconds)
        result = {"date": time.strftime("%Y-%m-%d"), "seed": seed, "read_seconds_limit": seconds,
                  "sources": {name: len(data) for name, _, data, _ in srcs}, "in_process": here,
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
    ap.add_argument("--seed", type=int, default=29)
    ap.add_argument("--cli", type=int, default=40, help="mutants also run as `hovr render` (0: none)")
    ap.add_argument("--bpy", type=int, default=12, help="mutants also imported in bpy (0: none)")
    ap.add_argument("--seconds", type=float, default=5.0, help="the reader's time limit per mutant")
    ap.add_argument("--out", type=Path, default=RESULT)
    args = ap.parse_args(argv)
    result = run(args.mutants, args.seed, args.cli, args.bpy, args.seconds)
    result["command"] = "python -m tests.fuzz.hdf5_mutation " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "in_process"} | {
        "in_process": {k: v for k, v in result["in_process"].items() if k != "reader_died_or_stopped"}}, indent=1))
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
