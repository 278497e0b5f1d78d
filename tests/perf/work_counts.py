"""The traversal's work counts on fixed small scenes (issue 28): what a change to the kernels costs,
measured on the CPU where it is deterministic, against budgets committed beside this file.

Each scene is a real or paper-scale dataset at 96x54, seen from the benchmarks' oblique direction
(tests/helpers.framing) through three tents over its field's 2..98 % range, rendered at the user's
defaults (classified, its own step per segment). Per scene and precision the budget file holds each
counter's mean per ray and its divergence (engine/work_counts.py: over 32-ray blocks, the
largest count over the block's mean). tests/perf/test_work_counts.py fails where a count passes its
budget by more than TOLERANCE.

A change that costs more work updates the budget in the same commit, and says why, in the budget
file's "updates" (newest first: commit subject and reason) and in the commit message (a line
"Work budget: <reason>"):

    python -m tests.perf.work_counts --update --reason "why the counts moved"
    python -m tests.perf.work_counts              (print the counts against the budgets)
    python -m tests.perf.work_counts --scenes hump3D --precisions float32,float64
"""
from __future__ import annotations

import argparse
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..helpers import COLORS, find_data, framing, mesh_bounds, tents

BUDGETS = Path(__file__).with_name("work_budgets.json")
TOLERANCE = 0.10  # a count more than this above its budget fails
SIZE = (96, 54)
COUNTERS = ("bvh_candidates", "newton_search", "newton_walk", "newton_sample", "element_locations", "segments",
            "samples", "walks", "rounds", "work")


@dataclass(frozen=True)
class Scene:
    name: str
    load: Callable  # () -> VolumeMesh
    files: tuple = ()  # (kind, name) data files it needs (skipped, named, without them)
    precisions: tuple = ("float32",)


def _paper_scale():
    from hovr_blender.io.paper_scale import paper_scale_mesh

    return paper_scale_mesh()


def _data(kind, name, **view_data):
    def load():
        from hovr_blender.io.sources import VolumeSource, load_volume

        data = {"path": str(find_data(kind, name)), **view_data}
        if "solution" in data:
            data["solution"] = str(find_data(kind, data["solution"]))
        return load_volume(VolumeSource.from_view_data(data))

    return load


def _curved_cube():
    from hovr_blender.io.synthetic import curved_cube

    return curved_cube(2)


SCENES = {s.name: s for s in (
    # the paper's scale: 11,008 curved order-6 hexahedra and prisms
    Scene("paper_scale", _paper_scale),
    # Nektar++'s hump3D (curved hexahedra, GLL), vendored
    Scene("hump3D", _data("nektar", "hump3D_GLL.xml", solution="hump3D.rst", field="rho"),
          (("nektar", "hump3D_GLL.xml"), ("nektar", "hump3D.rst"))),
    # all four shapes, curved: small, so both precisions (the search's float32 cases showed here)
    Scene("curved_mixed_cube", _curved_cube, precisions=("float32", "float64")),
    Scene("ngsolve_ball", _data("vtu", "ngsolve_ball_poisson_hex_p6.vtu", field="u"),
          (("vtu", "ngsolve_ball_poisson_hex_p6.vtu"),)),
    Scene("mfem_fichera", _data("vtu", "mfem_fichera_poisson_mixed_p4.vtu", field="u"),
          (("vtu", "mfem_fichera_poisson_mixed_p4.vtu"),)),
    # 24 of its cells (tetrahedra, hexahedra, wedges at the re-entrant corner), vendored: a real
    # curved VTU on a fresh clone
    Scene("mfem_fichera_cells", _data("vtu", "mfem_fichera_cells_p4.vtu", field="u"),
          (("vtu", "mfem_fichera_cells_p4.vtu"),)),
    Scene("pyfr_tgv", _data("vtu", "pyfr_tgv_hexprism_p4_t4.vtu", field="Pressure"),
          (("vtu", "pyfr_tgv_hexprism_p4_t4.vtu"),)),
)}


def missing_files(scene: Scene) -> list[str]:
    return [f"{kind}/{name}" for kind, name in scene.files if find_data(kind, name) is None]


_RENDERERS = {}


def measure(scene: Scene, precision: str, method: str = "classified") -> dict:
    """The scene's work counts (engine/work_counts.work_counts) in `precision`, on the CPU."""
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.kernels.precision import Precision
    from hovr_blender.engine.work_counts import work_counts
    from hovr_blender.engine.view import RenderOptions

    if scene.name not in _RENDERERS:
        mesh = scene.load()
        lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
        # an optical depth of a few across the data
        _RENDERERS[scene.name] = (Renderer(mesh, "cpu"), tents(lo, hi, COLORS, 12.0 / diagonal(mesh)))
    renderer, tf = _RENDERERS[scene.name]
    camera = framing(renderer.mesh, *SIZE)
    res = renderer.render(camera, tf, np.zeros(3), RenderOptions(method=method, precision=precision, device="cpu"),
                          ray_counts=True)
    return work_counts(Precision.named(precision).kernels, res.ray_counts)


def diagonal(mesh) -> float:
    lo, hi = mesh_bounds(mesh)
    return float(np.linalg.norm(hi - lo))


def load_budgets() -> dict:
    return json.loads(BUDGETS.read_text()) if BUDGETS.exists() else {"scenes": {}, "updates": []}


def over_budget(counts: dict, budget: dict) -> list[str]:
    """The counters of `counts` more than TOLERANCE above `budget` (per ray and divergence), in words."""
    out = []
    for name in COUNTERS:
        for key in ("per_ray", "divergence"):
            have, allowed = counts[name][key], budget[name][key]
            if have > allowed * (1.0 + TOLERANCE) + 1e-9:
                out.append(f"{name} {key} {have:.4g} > budget {allowed:.4g} (+{100 * (have / allowed - 1):.1f} %)")
    return out


def _dumps(budgets: dict) -> str:
    """The budget file: one line a counter, so a diff shows which counts moved."""
    text = json.dumps(budgets, indent=1)
    return re.sub(r'\{\s*"per_ray": ([^,]+),\s*"divergence": ([^\s}]+)\s*\}', r'{"per_ray": \1, "divergence": \2}', text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--precisions", default=None, help="default: each scene's own")
    ap.add_argument("--update", action="store_true", help="write the counts as the new budgets")
    ap.add_argument("--reason", default=None, help="why the budgets change (required with --update)")
    ap.add_argument("--subject", default="", help="the commit's subject, for the budget file's log")
    args = ap.parse_args(argv)
    if args.update and not args.reason:
        ap.error("--update needs --reason")
    budgets = load_budgets()
    for name in args.scenes.split(","):
        scene = SCENES[name]
        if missing_files(scene):
            print(f"{name}: skipped, missing {', '.join(missing_files(scene))}")
            continue
        for precision in (args.precisions.split(",") if args.precisions else scene.precisions):
            counts = measure(scene, precision)
            old = budgets["scenes"].get(name, {}).get(precision)
            words = over_budget(counts, old) if old else ["no budget"]
            print(f"{name} {precision}: " + ", ".join(f"{k} {counts[k]['per_ray']:.4g} (div {counts[k]['divergence']:.3g})"
                                                       for k in COUNTERS))
            print("   " + ("; ".join(words) if words else "within budget"))
            if args.update:
                budgets["scenes"].setdefault(name, {})[precision] = {
                    k: {m: float(f"{counts[k][m]:.6g}") for m in ("per_ray", "divergence")} for k in COUNTERS}
    if args.update:
        budgets["updates"].insert(0, {"subject": args.subject, "reason": args.reason})
        budgets["size"] = list(SIZE)
        budgets["tolerance"] = TOLERANCE
        BUDGETS.write_text(_dumps(budgets) + "\n")
        print(f"wrote {BUDGETS}")


if __name__ == "__main__":
    main()
