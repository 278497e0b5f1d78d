"""Mutation test of the Nektar++ reader: corrupted variants of real files must either load or raise
a NektarError naming the file, within a time bound; never another exception, never a hang.

    python -m tests.fuzz.nektar_mutation [--cases 600] [--seed 4] [--scaleho]

(from the repository root) writes bench/results/nektar_mutation.json (counts per mutation kind and
outcome; with --scaleho also the load time and peak memory of scaleHO.xml and hump3D, which live
in ../shared/data only). tests/io/test_nektar.py runs the same generator on fewer cases. The
source files are found as the tests find them (tests/helpers.find_data: tests/data, then
../shared/data).
"""
from __future__ import annotations

import argparse
import base64
import json
import re
import signal
import sys
import tempfile
import time
import tracemalloc
import zlib
from pathlib import Path

import numpy as np

from tests.helpers import REPO, find_data

RESULT = REPO / "bench" / "results" / "nektar_mutation.json"

# (mesh, field or None): small real files, so hundreds of cases stay within a minute
SOURCES = [
    ("Tet_channel_m3.xml", "Tet_channel_m3.fld"),
    ("wss_3D_periodic.xml", "wss_3D_periodic.fld"),
    ("Hex_Mushroom.xml", "Hex_Mushroom.fld"),
    ("Hex_CurvedFace.xml", "Hex_CurvedFace.fld"),
    ("Hex_01_01_01_03Modes_x2_Offset3.xml", "Hex_01_01_01_03Modes_x2_Offset3.fld"),
    ("Helmholtz3D_Pyr_Deformed.xml", None),
    ("Pyr_channel_m6.xml", None),
]
CASE_SECONDS = 10.0  # a case slower than this counts as a hang


def source(name) -> Path:
    path = find_data("nektar", name)
    if path is None:
        raise FileNotFoundError(f"Nektar++ file {name} is neither in tests/data/nektar nor in ../shared/data/nektar")
    return path


def b64z(raw: bytes) -> str:
    """Nektar++'s block encoding: zlib, NUL-padded to a multiple of 3, base64 without '=' (§2.3)."""
    z = zlib.compress(raw)
    z += b"\0" * (-len(z) % 3)
    return base64.b64encode(z).decode()


def unb64z(text: str) -> bytes:
    s = re.sub(r"\s+", "", text)
    return zlib.decompressobj().decompress(base64.b64decode(s + "=" * (-len(s) % 4)))


_BODY = re.compile(r"(<(ELEMENTS|VERTEX|EDGE|T|Q|A|P|R|H|E|INDEX|POINTS)\b[^>]*>)([A-Za-z0-9+/=\s]{16,})(<)")


def _bodies(text):
    return [m for m in _BODY.finditer(text)]


def _replace_span(text, start, end, new):
    return text[:start] + new + text[end:]


def mutate(rng: np.random.Generator, xml: str, fld: str | None):
    """(kind, xml', fld') : one corrupted variant."""
    kinds = ["truncate", "byte_flip_b64", "b64_garbage", "zlib_flip", "wrong_count", "nan_inf",
             "swap_ids", "huge_size", "record_int", "delete_line", "duplicate_line", "zlib_bomb",
             "move_vertex", "attr_garbage"]
    kind = kinds[rng.integers(len(kinds))]
    target_fld = fld is not None and rng.random() < 0.5
    text = fld if target_fld else xml

    def done(new):
        return (kind, xml, new) if target_fld else (kind, new, fld)

    if kind == "truncate":
        return done(text[: int(rng.integers(0, len(text)))])
    bodies = _bodies(text)
    if kind in ("byte_flip_b64", "b64_garbage", "zlib_flip", "nan_inf", "record_int", "zlib_bomb") and bodies:
        m = bodies[rng.integers(len(bodies))]
        s, e = m.start(3), m.end(3)
        body = m.group(3)
        if kind == "byte_flip_b64":
            i = int(rng.integers(len(body)))
            ch = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/"[rng.integers(64)]
            return done(_replace_span(text, s + i, s + i + 1, ch))
        if kind == "b64_garbage":
            i = int(rng.integers(len(body)))
            return done(_replace_span(text, s + i, s + i + 1, "!*-"[rng.integers(3)]))
        try:
            raw = bytearray(unb64z(body))
        except Exception:
            return done(text[:-1])
        if kind == "zlib_flip":
            z = bytearray(zlib.compress(bytes(raw)))
            i = int(rng.integers(len(z)))
            z[i] ^= 1 << int(rng.integers(8))
            z += b"\0" * (-len(z) % 3)
            return done(_replace_span(text, s, e, base64.b64encode(bytes(z)).decode()))
        if kind == "zlib_bomb":
            return done(_replace_span(text, s, e, b64z(bytes(int(rng.integers(1, 64)) << 20))))
        n8 = len(raw) // 8
        if n8 == 0:
            return done(text)
        i = int(rng.integers(n8))
        if kind == "nan_inf":
            raw[8 * i : 8 * i + 8] = np.array([[np.nan, np.inf, -np.inf][rng.integers(3)]], "<f8").tobytes()
        else:
            raw[8 * i : 8 * i + 8] = np.array([[-1, 2**62, 2**31, 7, -(2**63)][rng.integers(5)]], "<i8").tobytes()
        return done(_replace_span(text, s, e, b64z(bytes(raw))))
    if kind == "wrong_count":
        subs = [(r'NUMMODESPERDIR="UNIORDER:(\d+)', lambda m: f'NUMMODESPERDIR="UNIORDER:{int(m.group(1)) + 1}'),
                (r'NUMPOINTS="(\d+)"', lambda m: f'NUMPOINTS="{int(m.group(1)) + int(rng.integers(-2, 3))}"'),
                (r'FIELDS="([^"]*)"', lambda m: f'FIELDS="{m.group(1)},extra"'),
                (r'ID="(\d+)-(\d+)"', lambda m: f'ID="{m.group(1)}-{int(m.group(2)) + 1}"'),
                (r"(<[EQTAPRH] ID=\"\d+\">)([^<]*)<", lambda m: f"{m.group(1)}{m.group(2)} 0<")]
        pat, fn = subs[rng.integers(len(subs))]
        return done(re.sub(pat, fn, text, count=1))
    if kind == "nan_inf":  # plain text numbers
        nums = list(re.finditer(r"(?<=[\s>])-?\d+\.\d*(e[-+]?\d+)?(?=[\s<])", text))
        if nums:
            m = nums[rng.integers(len(nums))]
            return done(_replace_span(text, m.start(), m.end(), ["nan", "inf", "-inf", "1e400"][rng.integers(4)]))
        return done(text.replace("UNIORDER", "UNIORDER:nan", 1))
    if kind == "swap_ids":
        ents = list(re.finditer(r'<([A-Z]) ID="(\d+)"', text))
        if len(ents) >= 2:
            a, b = rng.choice(len(ents), 2, replace=False)
            ma, mb = ents[a], ents[b]
            first, second = sorted([ma, mb], key=lambda m: m.start())
            t = _replace_span(text, second.start(2), second.end(2), first.group(2))
            return done(_replace_span(t, first.start(2), first.end(2), second.group(2)))
        ids = list(re.finditer(r'\bID="([^"]*)"', text))
        if ids:
            m = ids[rng.integers(len(ids))]
            return done(_replace_span(text, m.start(1), m.end(1), str(int(rng.integers(0, 100)))))
        return done(text)
    if kind == "huge_size":
        subs = [(r'NUMPOINTS="\d+"', f'NUMPOINTS="{10**int(rng.integers(6, 19))}"'),
                (r'UNIORDER:\d+,\d+,\d+', "UNIORDER:100000,100000,100000"),
                (r'\bID="[^"]*"', f'ID="0-{10**int(rng.integers(8, 19))}"'),
                (r'UNIORDER:\d+,\d+,\d+', "MIXORDER:" + ",".join(["3"] * 3 * 10**5))]
        pat, rep = subs[rng.integers(len(subs))]
        return done(re.sub(pat, rep, text, count=1))
    if kind in ("delete_line", "duplicate_line"):
        lines = text.splitlines(True)
        i = int(rng.integers(len(lines)))
        lines[i : i + 1] = [] if kind == "delete_line" else [lines[i], lines[i]]
        return done("".join(lines))
    if kind == "move_vertex":  # inverted / degenerate / collapsed elements
        sec = re.search(r"<VERTEX>.*?</VERTEX>", xml, re.S)
        vs = list(re.compile(r'<V ID="\d+">([^<]*)</V>').finditer(xml, sec.start(), sec.end())) if sec else []
        if vs:
            a, b = rng.choice(len(vs), 2, replace=len(vs) < 2)
            rep = vs[b].group(1) if rng.random() < 0.5 else " ".join(
                str(-float(c)) for c in vs[a].group(1).split())
            return (kind, _replace_span(xml, vs[a].start(1), vs[a].end(1), rep), fld)
        faces = list(re.finditer(r'<H ID="\d+">([^<]*)</H>', xml))
        if faces:
            ids = faces[0].group(1).split()
            rng.shuffle(ids)
            return (kind, _replace_span(xml, faces[0].start(1), faces[0].end(1), " ".join(ids)), fld)
        # compressed: reverse the VERTEX records' coordinates of one vertex
        return (kind, xml.replace('TYPE="GaussLobattoLegendre"', 'TYPE="NoSuchPoints"', 1), fld)
    # attr_garbage
    attrs = list(re.finditer(r'\b([A-Z]+)="([^"]*)"', text))
    if attrs:
        m = attrs[rng.integers(len(attrs))]
        junk = ["", "x", "-1", "1e999", "B64Z-Middle", "Ortho_A,Ortho_B,Ortho_C", "Prism", "0--3", "C[99]"]
        return done(_replace_span(text, m.start(2), m.end(2), junk[rng.integers(len(junk))]))
    return done(text)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def _chain(exc):
    """exc and everything it was raised from or during (a MemoryError wrapped in a NektarError
    is still no diagnosis)."""
    out = []
    while exc is not None and len(out) < 16:
        out.append(exc)
        exc = exc.__cause__ or exc.__context__
    return out


def run_cases(n_cases=600, seed=4, memory=False, case_seconds=CASE_SECONDS):
    """Run n_cases mutations; returns the summary dict (failures listed with their messages)."""
    from hovr_blender.io.nektar import NektarError, read_nektar

    rng = np.random.default_rng(seed)
    originals = []
    for mesh, fld in SOURCES:
        originals.append((mesh, source(mesh).read_text(), source(fld).read_text() if fld else None))
    summary = {"seed": seed, "cases": 0, "loaded": 0, "nektar_error": 0, "by_kind": {},
               "unexpected": [], "crashes": [], "timeouts": [], "unnamed": [], "max_case_seconds": 0.0}
    old = signal.signal(signal.SIGALRM, _alarm)
    peak = 0
    t_all = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            for i in range(n_cases):
                name, xml, fld = originals[i % len(originals)]
                kind, x2, f2 = mutate(rng, xml, fld)
                (tmp / "m.xml").write_text(x2)
                sol = None
                if f2 is not None:
                    (tmp / "m.fld").write_text(f2)
                    sol = tmp / "m.fld"
                field = None
                if f2 is not None:
                    field = re.search(r'FIELDS="([^,"]*)', fld).group(1)
                rec = summary["by_kind"].setdefault(kind, {"loaded": 0, "nektar_error": 0})
                if memory:
                    tracemalloc.start()
                t0 = time.perf_counter()
                signal.setitimer(signal.ITIMER_REAL, case_seconds)
                try:
                    read_nektar(tmp / "m.xml", sol, field=field)
                    outcome = "loaded"
                except NektarError as exc:
                    msg = str(exc)
                    outcome = "nektar_error"
                    if any(isinstance(e, MemoryError) for e in _chain(exc)):
                        summary["unexpected"].append(f"{name} {kind}: out of memory: {msg[:300]}")
                    elif "unexpected " in msg:
                        summary["unexpected"].append(f"{name} {kind}: {msg[:300]}")
                    if "m.xml" not in msg and "m.fld" not in msg:
                        summary["unnamed"].append(f"{name} {kind}: {msg[:300]}")
                except _Timeout:
                    outcome = "timeout"
                    summary["timeouts"].append(f"{name} {kind}")
                except Exception as exc:  # the point of the test: any other type is a reader bug
                    outcome = "crash"
                    summary["crashes"].append(f"{name} {kind}: {type(exc).__name__}: {str(exc)[:300]}")
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                dt = time.perf_counter() - t0
                if memory:
                    peak = max(peak, tracemalloc.get_traced_memory()[1])
                    tracemalloc.stop()
                summary["max_case_seconds"] = max(summary["max_case_seconds"], round(dt, 3))
                summary["cases"] += 1
                if outcome in ("loaded", "nektar_error"):
                    summary[outcome] += 1
                    rec[outcome] += 1
                (tmp / "m.fld").unlink(missing_ok=True)
    finally:
        signal.signal(signal.SIGALRM, old)
    summary["total_seconds"] = round(time.perf_counter() - t_all, 2)
    if memory:
        summary["peak_traced_memory_mb"] = round(peak / 2**20, 1)
    return summary


def load_figures():
    """Load time and peak traced memory of the big real files."""
    from hovr_blender.io.nektar import read_nektar

    out = {}
    for key, mesh, sol, field in (("hump3D", "hump3D_GLL.xml", "hump3D.rst", "rho"),
                                  ("scaleHO", "scaleHO.xml", None, None)):
        tracemalloc.start()
        t0 = time.perf_counter()
        m = read_nektar(source(mesh), source(sol) if sol else None, field=field)
        dt = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        t0 = time.perf_counter()
        read_nektar(source(mesh), source(sol) if sol else None, field=field)
        out[key] = {"elements": int(m.num_elements), "shapes": np.bincount(m.shape, minlength=4).tolist(),
                    "seconds_traced": round(dt, 2), "seconds": round(time.perf_counter() - t0, 2),
                    "peak_traced_memory_mb": round(peak / 2**20, 1), "warnings": len(m.warnings)}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=600)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--scaleho", action="store_true", help="also time and measure hump3D and scaleHO")
    args = ap.parse_args()
    s = run_cases(args.cases, args.seed, memory=True)
    if args.scaleho:
        s["load"] = load_figures()
    RESULT.parent.mkdir(parents=True, exist_ok=True)
    RESULT.write_text(json.dumps(s, indent=1) + "\n")
    print(json.dumps({k: v for k, v in s.items() if k != "by_kind"}, indent=1))
    bad = len(s["unexpected"]) + len(s["crashes"]) + len(s["timeouts"]) + len(s["unnamed"])
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
