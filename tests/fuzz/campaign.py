"""What the mutation campaigns of files read through the reader process share (hdf5_mutation.py,
pyfr_mutation.py, mfem_mutation.py): each mutant loaded here through io.sources.load_volume (the
reader process), --cli of them as `hovr render` commands, --bpy of them imported by bpy's File >
Import operator, and the command line that runs the three and writes the results.

A campaign's mutants are tuples whose first item is the label; its `write(folder, mutant)` writes
the mutant's files into `folder` and says which they are (Written). Judged as the hostile suite
judges: a load here loads or fails with one line naming one of the two files (`classify`), the
process that asked lives on; `hovr render` exits 0 or 2 with one `hovr: error:` line and no hang;
the import reports and leaves the scene as it was.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from tests.helpers import REPO
from tests.hostile import cases, harness


@dataclass(frozen=True)
class Written:
    """A mutant's files as written: the mesh, its solution, the field to read ("": the format's own)."""
    mesh: Path
    solution: Path
    field: str = ""

    def source(self):
        from hovr_blender.io.sources import VolumeSource

        return VolumeSource(str(self.mesh), str(self.solution), self.field)

    def names_in(self, message: str) -> bool:
        return self.mesh.name in message or self.solution.name in message


def classify(exc: BaseException | None) -> str:
    """What a load that raised `exc` (None: it loaded) tells the user, in a word or three."""
    from hovr_blender.io import isolation

    if exc is None:
        return "loaded"
    text = str(exc)
    if isinstance(exc, isolation.ReaderFailure):
        if "crashed" in text:
            return "reader crashed"
        if "longer than the limit" in text or "no progress" in text:
            return "reader stopped (time limit)"
        if "killed" in text:
            return "reader killed"
        return "unexpected" if "unexpected" in text else "reader failed"
    if isinstance(exc, (ValueError, OSError, ImportError)):
        return "unexpected" if "unexpected" in text else "refused"
    return "unexpected"


def read_env(seconds: float | None) -> dict:
    """The environment of a `hovr` or bpy process: the flat read limit `seconds` where given (None:
    the policy's limits, engine/limits.read_seconds)."""
    return {} if seconds is None else {"HOVR_MAX_READ_SECONDS": str(seconds)}


def _in_view(path: Path, folder: Path) -> str:
    """A path as the view file in `folder` names it."""
    return path.name if path.parent == folder else str(path)


def _count(counts: dict, key: str):
    counts[key] = counts.get(key, 0) + 1


# bpy as a module in a fresh process: each mutant imported by the format's import operator
_BPY = textwrap.dedent("""
    import json, sys
    import bpy
    import hovr_blender
    payload = json.loads(sys.stdin.read())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    operator = getattr(bpy.ops.import_scene, payload["operator"])
    def counts():
        return {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "materials", "cameras")}
    out = []
    for kwargs in payload["imports"]:
        before = counts()
        try:
            operator(**kwargs, fit_range=False, frame=False)
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


@dataclass(frozen=True)
class Campaign:
    """One format's campaign: `name` its module's (tests.fuzz.NAME) and its results'
    (bench/results/NAME.json), `operator` its import operator (bpy.ops.import_scene.OPERATOR),
    `write` (folder, mutant) -> Written, and `kind`, where given, the class of a mutant's label
    that the outcomes are also counted by (by_kind)."""
    name: str
    operator: str
    write: Callable
    kind: Callable | None = None

    def run_here(self, items, folder: Path, seconds: float | None) -> dict:
        """Each mutant loaded by this process through the reader process."""
        from hovr_blender.engine import limits
        from hovr_blender.io.sources import load_volume

        summary = {"mutants": 0, "outcomes": {}, "problems": [], "max_seconds": 0.0, "reader_died_or_stopped": []}
        if self.kind is not None:
            summary["by_kind"] = {}
        with limits.using(limits.ResourceLimits(max_read_seconds=seconds)):
            for item in items:
                label, files = item[0], self.write(folder, item)
                t0 = time.perf_counter()
                error = None
                try:
                    load_volume(files.source())
                except Exception as exc:  # noqa: BLE001  (classified: what the user would be told)
                    error = exc
                dt = time.perf_counter() - t0
                outcome = classify(error)
                summary["mutants"] += 1
                _count(summary["outcomes"], outcome)
                if self.kind is not None:
                    _count(summary["by_kind"].setdefault(self.kind(label), {}), outcome)
                summary["max_seconds"] = max(summary["max_seconds"], round(dt, 2))
                if outcome.startswith("reader ") and outcome != "reader failed":
                    summary["reader_died_or_stopped"].append(label)
                message = "" if error is None else str(error)
                if outcome == "unexpected" or "\n" in message or (error is not None and not files.names_in(message)):
                    summary["problems"].append(f"{label}: {type(error).__name__}: {message[:300]}")
                if dt > (seconds or limits.READ_STALL_SECONDS) + 30:
                    summary["problems"].append(f"{label}: took {dt:.0f} s")
        return summary

    def run_cli(self, items, folder: Path, seconds: float | None) -> dict:
        """Each mutant through `hovr render`, judged as the hostile suite judges (exit 0 or one line,
        a refusal within its 5 s and 500 MB: tests/hostile/harness.py)."""
        out = {"mutants": 0, "exit_codes": {}, "problems": [], "max_seconds": 0.0, "max_refusal_seconds": 0.0,
               "max_peak_mb": 0.0, "over_5_s_or_500_mb": []}
        for item in items:
            label, files = item[0], self.write(folder, item)
            data = {"path": _in_view(files.mesh, folder), "solution": _in_view(files.solution, folder)}
            args = cases.render_args(folder, cases.base_view(data | ({"field": files.field} if files.field else {})))
            o = harness.run_hovr(args, folder, read_env(seconds))
            out["mutants"] += 1
            _count(out["exit_codes"], str(o.returncode))
            out["max_seconds"] = max(out["max_seconds"], round(o.seconds, 2))
            out["max_peak_mb"] = max(out["max_peak_mb"], round(o.peak_mb, 1))
            if o.returncode == 2:
                out["max_refusal_seconds"] = max(out["max_refusal_seconds"], round(o.seconds, 2))
                if o.seconds > harness.MAX_SECONDS or o.peak_mb > harness.MAX_PEAK_MB:
                    out["over_5_s_or_500_mb"].append(f"{label}: {o.seconds:.1f} s, {o.peak_mb:.0f} MB")
            lines = [ln for ln in o.stderr.splitlines() if ln.strip()]
            if o.timed_out or o.returncode not in (0, 2) or "Traceback" in o.stderr or (
                    o.returncode == 2 and (len(lines) != 1 or not lines[0].startswith("hovr: error: "))):
                out["problems"].append(f"{label}: exit {o.returncode}{' (hung)' if o.timed_out else ''}: "
                                       f"{o.stderr[-300:]!r}")
        return out

    def run_bpy(self, items, folder: Path, seconds: float | None) -> dict:
        """The mutants imported by bpy's File > Import operator in one fresh process."""
        imports = []
        for k, item in enumerate(items):
            sub = folder / f"b{k}"
            sub.mkdir(exist_ok=True)
            files = self.write(sub, item)
            imports.append({"filepath": str(files.mesh), "solution": str(files.solution)}
                           | ({"field": files.field} if files.field else {}))
        env = dict(os.environ, PYTHONPATH=str(REPO), **read_env(seconds))
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-c", _BPY], input=json.dumps({"operator": self.operator, "imports": imports}),
                           capture_output=True, text=True, env=env, timeout=60 + len(items) * ((seconds or 10) + 30))
        line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
        outcomes = json.loads(line[7:]) if line else []
        problems = [] if p.returncode == 0 and line else [f"bpy process exit {p.returncode}: {p.stderr[-400:]!r}"]
        problems += [f"{item[0]}: {o}" for item, o in zip(items, outcomes) if o not in ("imported", "reported")]
        return {"mutants": len(outcomes), "outcomes": {o: outcomes.count(o) for o in set(outcomes)},
                "problems": problems, "exit_code": p.returncode, "seconds": round(time.perf_counter() - t0, 1)}

    def run(self, items, folder: Path, seed: int, sources: dict, cli: int, bpy: int, seconds: float | None) -> dict:
        """All of `items` here, then the first `cli` through `hovr render` and the first `bpy`
        through bpy, those the reader died or was stopped on first."""
        t0 = time.perf_counter()
        here = self.run_here(items, folder, seconds)
        result = {"date": time.strftime("%Y-%m-%d"), "seed": seed, "read_seconds_limit": seconds,
                  "sources": sources, "in_process": here, "in_process_seconds": round(time.perf_counter() - t0, 1)}
        died = set(here["reader_died_or_stopped"])
        order = [it for it in items if it[0] in died] + [it for it in items if it[0] not in died]
        if cli:
            result["cli"] = self.run_cli(order[:cli], folder, seconds)
        if bpy:
            result["bpy"] = self.run_bpy(order[:bpy], folder, seconds)
        result["passed"] = not (here["problems"] or result.get("cli", {}).get("problems")
                                or result.get("bpy", {}).get("problems"))
        return result

    def main(self, argv, doc: str, run: Callable, seed: int, seconds: float | None) -> int:
        """The command line: `run(mutants, seed, cli, bpy, seconds)`'s result written to
        bench/results/NAME.json and printed; exit 1 where it found a problem."""
        ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
        ap.add_argument("--mutants", type=int, default=2000)
        ap.add_argument("--seed", type=int, default=seed)
        ap.add_argument("--cli", type=int, default=40, help="mutants also run as `hovr render` (0: none)")
        ap.add_argument("--bpy", type=int, default=12, help="mutants also imported in bpy (0: none)")
        ap.add_argument("--seconds", type=float, default=seconds,
                        help="the reader's time limit per mutant, flat" + (
                            "" if seconds is not None else " (default: the policy's, engine/limits.read_seconds, "
                                                           "and no progress for READ_STALL_SECONDS)"))
        ap.add_argument("--out", type=Path, default=REPO / "bench" / "results" / f"{self.name}.json")
        args = ap.parse_args(argv)
        result = run(args.mutants, args.seed, args.cli, args.bpy, args.seconds)
        result["command"] = f"python -m tests.fuzz.{self.name} " + " ".join(argv if argv is not None else sys.argv[1:])
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
        print(json.dumps({k: v for k, v in result.items() if k != "in_process"} | {
            "in_process": {k: v for k, v in result["in_process"].items() if k != "reader_died_or_stopped"}}, indent=1))
        return 0 if result["passed"] else 1
