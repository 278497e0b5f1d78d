"""The MFEM format as the registry (io/formats.py) sees it: a mesh .mesh whose GridFunctions
(.gf) lie beside it, as GLVis takes them (`glvis -m mesh -g sol.gf`).

A GridFunction holds one field, named after its file (sol.gf: "sol"); a vector one (VDim 3)
renders as its magnitude or one component, and Q(sol), vorticity(sol) take it as a velocity.

Element orders. MFEM writes no element orders (FiniteElementSpace::Save has no section for
them, and a variable-order space's own values cannot be read back, by MFEM or here); a
variable-order field is saved raised to its largest order (GridFunction::ProlongateToMaxOrder).
Each element's order is recovered from its polynomial: the modified basis is hierarchical, so an
element of order q has no modes above q, and the reader keeps the smallest order whose modes
hold every coefficient to ORDER_TOLERANCE of the field's largest value (an element of a
uniform field whose polynomial has a lower degree renders at that degree: the same polynomial).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...engine import limits, validity
from ...engine.derived_fields import derived_mesh, parse_derived
from ...engine.mesh import MeshError, VolumeMesh
from ..magnitude import component_reads, magnitude_mesh
from ..format_base import Format
from . import elements as el
from .dofs import Gathered, Topology, gather
from .files import MFEMMesh, read_gridfunction, read_mesh
from .text import MFEMError

ORDER_TOLERANCE = 1e-10  # relative to the field's largest value: what counts as a vanished mode


def field_name(gf_path) -> str:
    return Path(gf_path).stem


def list_fields(gf_path) -> dict:
    """{name: components} of a .gf file (its header only is checked)."""
    gf = _guarded(gf_path, lambda: read_gridfunction(gf_path, header_only=True))
    return {field_name(gf_path): gf.vdim}


def _guarded(path, read):
    """read(), every failure one MFEMError naming `path` (the resource policy's errors as they are)."""
    try:
        return read()
    except (MFEMError, limits.ResourceLimitError, limits.UnsafeFileError, FileNotFoundError):
        raise
    except MeshError as exc:
        raise MFEMError(f"{path}: {exc}") from exc
    except MemoryError:
        raise MFEMError(f"{path}: more data than memory holds (a damaged count?)") from None
    except (ValueError, IndexError, KeyError, np.linalg.LinAlgError) as exc:
        raise MFEMError(f"{path}: unreadable ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from exc


def _geometry(mesh: MFEMMesh, topology: Topology):
    """{geom: (element indices, gmodes, G (n, K, 3))}: each element's geometry as modal coefficients,
    certified (engine/validity.py)."""
    out = {}
    if mesh.nodes is not None:
        if mesh.nodes.vdim != 3:
            raise MFEMError(f"{mesh.path}: line {mesh.nodes.line}: nodes of VDim {mesh.nodes.vdim}; "
                            "a 3-D mesh's coordinates have 3")
        gathered = gather(topology, mesh.nodes, mesh.path)
    else:
        gathered = [Gathered(geom, idx, mesh.coordinates[conn], el.VERTICES[geom], 1)
                    for geom, (idx, conn) in topology.groups.items()]
    for g in gathered:
        limits.progress()
        T = el.conversion(g.geom, g.order, g.nodes)
        G = np.matmul(T, g.values)  # (K, n) @ (elements, n, 3)
        limits.progress()
        gmodes = el.modes(g.geom, g.order)
        shape = el.SHAPES[g.geom]
        try:
            validity.check_elements(shape, gmodes, G, g.elements)
        except MeshError as exc:
            raise MFEMError(f"{mesh.path}: {el.PLURALS[g.geom]}: {exc}") from exc
        out[g.geom] = (g.elements, gmodes, G)
    return out


def _read(mesh_path, gf_path, reads, own_orders):
    """One VolumeMesh per (component index or None) in `reads`, on one reading of the files."""
    mesh = read_mesh(mesh_path)
    topology = Topology(mesh)
    geometry = _geometry(mesh, topology)
    gf = read_gridfunction(gf_path)
    for _, comp in reads:
        if comp is not None and not 0 <= comp < gf.vdim:
            raise MFEMError(f"{gf_path}: component {comp}; the field has {gf.vdim} (0..{gf.vdim - 1})")
    gathered = gather(topology, gf, str(gf_path))
    scale = float(np.abs(gf.values).max()) if gf.values.size else 0.0
    out = []
    for read_name, comp in reads:
        c = comp or 0
        n = mesh.num_elements
        shapes, modes, coeffs = [None] * n, [None] * n, [None] * n
        gmodes, gcoeffs = [None] * n, [None] * n
        for g in gathered:
            limits.progress()
            T = el.conversion(g.geom, g.order, g.nodes)
            C = g.values[:, :, c] @ T.T  # (n, K)
            limits.progress()
            orders = (el.truncated_order(g.geom, g.order, C, ORDER_TOLERANCE * scale) if own_orders
                      else np.full(len(C), g.order))
            keep = {q: el.keep_modes(g.geom, g.order, int(q)) for q in np.unique(orders)}
            _, gm, G = geometry[g.geom]
            for row, e in enumerate(g.elements):
                limits.progress()
                q = int(orders[row])
                shapes[e], modes[e], coeffs[e] = el.SHAPES[g.geom], el.modes(g.geom, q), C[row, keep[q]]
                gmodes[e], gcoeffs[e] = gm, G[row]
        label = read_name if comp is None or gf.vdim == 1 else f"{read_name}[{comp}]"
        try:
            out.append(VolumeMesh.from_elements(shapes, modes, coeffs, gmodes, gcoeffs, field_name=label,
                                                source=str(gf_path)))
        except MeshError as exc:
            raise MFEMError(f"{gf_path}: {exc}") from exc
    return out


def read_mfem(mesh_path, gf_path=None, field=None, component=None, own_orders: bool = True) -> VolumeMesh:
    """A field of an MFEM mesh and GridFunction: the GridFunction's field (named after its file),
    one component or the magnitude of a vector one, or a derived field of engine/derived_fields.py.
    own_orders=False keeps every element at the file's order (the field as it is stored)."""
    if gf_path is None:
        gf_path = find_solution(mesh_path)
    if gf_path is None:
        raise MFEMError(f"{mesh_path}: no GridFunction (.gf) given or found beside the mesh")
    return _guarded(gf_path, lambda: _field(mesh_path, gf_path, field, component, own_orders))


def _field(mesh_path, gf_path, field, component, own_orders):
    name = field_name(gf_path)
    sizes = list_fields(gf_path)
    spec = parse_derived(field)
    if spec is not None:
        return derived_mesh(spec, _read(mesh_path, gf_path, component_reads(spec, sizes), own_orders))
    if field not in (None, "", name):
        raise MFEMError(f"{gf_path}: no field {field!r}; the file holds {name!r}")
    vdim = sizes[name]
    if vdim > 1 and component in (None, "magnitude"):
        return magnitude_mesh(_read(mesh_path, gf_path, [(name, i) for i in range(vdim)], own_orders), f"|{name}|")
    return _read(mesh_path, gf_path, [(name, component if vdim > 1 else None)], own_orders)[0]


# ----------------------------------------------------------------------------- the GridFunction beside a mesh

def solution_candidates(mesh_path) -> list[Path]:
    """The .gf files beside a mesh, likeliest first: those named after the mesh ("beam.mesh" ->
    "beam.gf", "beam-sol.gf", "beam_u.gf"), then the others, by name."""
    mesh_path = Path(mesh_path)
    try:
        found = [p for p in mesh_path.parent.iterdir() if p.suffix.lower() == ".gf" and p.is_file()]
    except OSError:
        return []

    def named(p: Path) -> bool:
        return p.stem == mesh_path.stem or p.stem.startswith((mesh_path.stem + "-", mesh_path.stem + "_",
                                                              mesh_path.stem + "."))

    return sorted(found, key=lambda p: (not named(p), p.name))


def pick_solution(mesh_path):
    """(the likeliest .gf or None, why, all candidates): by name only (no file is opened here:
    this runs in Blender's process)."""
    cands = solution_candidates(mesh_path)
    if not cands:
        return None, "no .gf file in the folder", cands
    stem = Path(mesh_path).stem
    best = cands[0]
    if best.stem == stem or best.stem.startswith((stem + "-", stem + "_", stem + ".")):
        return best, "named after the mesh", cands
    if len(cands) == 1:
        return best, "the only .gf file in the folder", cands
    return None, f"{len(cands)} .gf files in the folder, none named after the mesh", cands


def find_solution(mesh_path) -> Path | None:
    return pick_solution(mesh_path)[0]


def _sniff(head: bytes) -> bool:
    return head.lstrip().startswith((b"MFEM mesh v", b"MFEM NC mesh v"))


FORMAT = Format(
    name="mfem", label="MFEM", extensions=(".mesh",),
    sniff=_sniff,
    read=lambda path, solution=None, field=None, component=None: read_mfem(path, solution, field, component),
    list_fields=list_fields, error=MFEMError,
    description="Import an MFEM mesh (.mesh) and a GridFunction (.gf) beside it as a HOVR volume",
    field_help="The GridFunction's field (named after its file: sol.gf -> sol); Q(sol), vorticity(sol) for a "
               "velocity, |grad|(sol); empty: the file's field",
    components=True,
    find_solution=find_solution, pick_solution=pick_solution,
    solution_help=("GridFunction file (.gf), relative to the mesh's folder; empty: the .gf named after the mesh "
                   "(beam.mesh -> beam.gf, beam-u.gf), or the only one in the folder"),
)
