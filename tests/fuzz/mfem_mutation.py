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
or was stopped on first) as `hovr render` (exit 0 or 2, one `hovr: error:` line, within the
hostile suite's 5 s and 500 MB: tests/hostile/harness.py); --bpy of them imported in bpy (the
import reports, the scene is unchanged).

    python -m tests.fuzz.mfem_mutation [--mutants 2000] [--seed 39] [--cli 40] [--bpy 12]

Results: bench/results/mfem_mutation.json; tests/io/test_mfem_mutation.py runs a sample.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from tests.fuzz.hdf5_mutation import classify
from tests.helpers import REPO, data_file
from tests.hostile import cases, harness

RESULT = REPO / "bench" / "results" / "mfem_mutation.json"
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


def _write(folder: Path, mesh: bytes, gf: bytes):
    (folder / "m.mesh").write_bytes(mesh)
    (folder / "m-u.gf").write_bytes(gf)
    return folder / "m.mesh", folder / "m-u.gf"


def run_here(items, folder: Path, seconds: float) -> dict:
    """Each mutant loaded by this process through the reader process."""
    from hovr_blender.engine import limits
    from hovr_blender.io.sources import VolumeSource, load_volume

    summary = {"mutants": 0, "outcomes": {}, "problems": [], "max_seconds": 0.0, "reader_died_or_stopped": [],
               "by_kind": {}}
    with limits.using(limits.ResourceLimits(max_read_seconds=seconds)):
        for label, _, mesh, _, gf in items:
            mesh_path, gf_path = _write(folder, mesh, gf)
            t0 = time.perf_counter()
            error = None
            try:
                load_volume(VolumeSource(str(mesh_path), str(gf_path), ""))
            except Exception as exc:  # noqa: BLE001  (classified: what the user would be told)
                error = exc
            dt = time.perf_counter() - t0
            outcome = classify(error)
            summary["mutants"] += 1
            summary["outcomes"][outcome] = summary["outcomes"].get(outcome, 0) + 1
            kind = re.sub(r" (on line|at|\d).*", "", label.split(": ", 1)[1].split("; ")[0])
            per = summary["by_kind"].setdefault(kind, {})
            per[outcome] = per.get(outcome, 0) + 1
            summary["max_seconds"] = max(summary["max_seconds"], round(dt, 2))
            if outcome.startswith("reader ") and outcome != "reader failed":
                summary["reader_died_or_stopped"].append(label)
            message = "" if error is None else str(error)
            if outcome == "unexpected" or "\n" in message or (
                    error is not None and mesh_path.name not in message and gf_path.name not in message):
                summary["problems"].append(f"{label}: {type(error).__name__}: {message[:300]}")
            if dt > seconds + 30:
                summary["problems"].append(f"{label}: took {dt:.0f} s")
    return summary


def run_cli(items, folder: Path, seconds: float) -> dict:
    """Each mutant through `hovr render`, judged as the hostile suite judges (exit 0 or one line)."""
    out = {"mutants": 0, "exit_codes": {}, "problems": [], "max_seconds": 0.0, "max_refusal_seconds": 0.0,
           "max_peak_mb": 0.0, "over_5_s_or_500_mb": []}
    for label, _, mesh, _, gf in items:
        _write(folder, mesh, gf)
        args = cases.render_args(folder, cases.base_view({"path": "m.mesh", "solution": "m-u.gf"}))
        o = harness.run_hovr(args, folder, {"HOVR_MAX_READ_SECONDS": str(seconds)})
        out["mutants"] += 1
        out["exit_codes"][str(o.returncode)] = out["exit_codes"].get(str(o.returncode), 0) + 1
        out["max_seconds"] = max(out["max_seconds"], round(o.seconds, 2))
        out["max_peak_mb"] = max(out["max_peak_mb"], round(o.peak_mb, 1))
        if o.returncode == 2:
            out["max_refusal_seconds"] = max(out["max_refusal_seconds"], round(o.seconds, 2))
            if o.seconds > harness.MAX_SECONDS or o.peak_mb > harness.MAX_PEAK_MB:
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
    for mesh, gf in items:
        before = counts()
        try:
            bpy.ops.import_scene.hovr_mfem(filepath=mesh, solution=gf, fit_range=False, frame=False)
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
    for k, (label, _, mesh, _, gf) in enumerate(items):
        sub = folder / f"b{k}"
        sub.mkdir(exist_ok=True)
        payload.append([str(p) for p in _write(sub, mesh, gf)])
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
                  "sources": {f"{m} + {g}": [len(mb), len(gb)] for m, mb, g, gb in srcs}, "in_process": here,
                  "in_process_seconds": round(time.perf_counter() - t0, 1)}
        died = set(here["reader_died_or_stopped"])
        # the CLI and bpy runs take the mutants the reader died on first, then a spread of the others
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
    result["command"] = "python -m tests.fuzz.mfem_mutation " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "in_process"} | {
        "in_process": {k: v for k, v in result["in_process"].items() if k != "reader_died_or_stopped"}}, indent=1))
    return 0 if result["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
