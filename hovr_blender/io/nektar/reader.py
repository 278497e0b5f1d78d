"""The entry points: a mesh and one field of its field file -> VolumeMesh; the fields a file
holds; the field file beside a mesh; the mesh's composites and boundary regions."""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ...engine import expansions as ex
from ...engine.lru_cache import LRUCache
from ...engine.mesh import MeshError, VolumeMesh
from ...engine.shapes import NAMES
from .composites import Boundaries, read_boundaries
from .errors import NektarError, guard
from .fields import read_field_file
from .element_geometry import mesh_geometry
from .mesh_file import NektarMesh, read_mesh

SOLUTION_EXTENSIONS = (".fld", ".chk", ".rst")
NO_FIELD = "(none)"  # the field name of a mesh read without a field file

# A mesh file's elements and geometry by (path, mtime, size): a series of field files on one mesh
# (flow_0001.fld, flow_0002.fld, ...) parses the XML and fits the curved geometry once, not once a
# frame (hump3D: 0.8 of the 1.1 s a snapshot took). Read-only once made: from_elements copies.
_GEOMETRY = LRUCache(2)


def _mesh_geometry(mesh_path: Path):
    status = os.stat(mesh_path)
    key = (str(mesh_path.resolve()), status.st_mtime_ns, status.st_size)

    def read():
        mesh = read_mesh(mesh_path)
        warnings: list[str] = []
        return (mesh, *mesh_geometry(mesh, warnings), tuple(warnings))

    return _GEOMETRY.get(key, read)


def find_solution(mesh_path) -> Path | None:
    """The field file beside a mesh: its name with .fld, .chk or .rst (a file or a multi-part
    .fld/ folder), the first that exists; None if there is none."""
    mesh_path = Path(mesh_path)
    return next((p for p in (mesh_path.with_suffix(e) for e in SOLUTION_EXTENSIONS) if p.exists()), None)


_NUMBERED = re.compile(r"^(.*?)[_\-.]?(\d+)$")


def _series(stem: str) -> tuple[str, int | None]:
    """("session", 123) for "session_123"; (stem, None) for a name without a trailing number."""
    m = _NUMBERED.match(stem)
    return (m.group(1), int(m.group(2))) if m and m.group(1) else (stem, None)


def _name_prefixes(stem: str) -> set[str]:
    """The stem and its starts that end before a separator: "hump3D_GLL" -> {"hump3d_gll", "hump3d"}."""
    stem = stem.lower()
    return {stem} | {stem[:k] for k, ch in enumerate(stem) if ch in "_-." and k > 0}


def _shared_name(mesh_stem: str, p: Path) -> int:
    """Length of the longest name part a field file shares with the mesh (its stem or its series
    name equal to the mesh's stem or a separator-bounded start of it, or the other way round)."""
    mine = _name_prefixes(mesh_stem)
    base, _ = _series(p.stem)
    theirs = {p.stem.lower(), base.lower()}
    shared = [len(a) for a in theirs if a in mine] + [len(a) for a in mine if a in _name_prefixes(p.stem)]
    return max(shared, default=0)


def solution_candidates(mesh_path) -> list[tuple[Path, str]]:
    """The field files in a mesh's folder (.fld/.chk/.rst files and .fld/ folders), likeliest
    first, each with the reason in words. Likeliest: the mesh's own name (what find_solution
    takes); then the longest name part shared with the mesh ("hump3D_GLL.xml" -> "hump3D.rst",
    "session.xml" -> "session_123.chk"), the latest of a numbered series ("session_123.chk"
    over "session_12.chk"), .fld before .chk before .rst."""
    mesh_path = Path(mesh_path)
    folder = mesh_path.parent
    stem = mesh_path.stem
    try:
        entries = [p for p in folder.iterdir() if p.suffix.lower() in SOLUTION_EXTENSIONS
                   and (p.is_file() or (p.is_dir() and (p / "Info.xml").exists()))]
    except OSError:
        return []
    latest, count = {}, {}
    for p in entries:
        base, num = _series(p.stem)
        if num is not None:
            key = (base, p.suffix.lower())
            count[key] = count.get(key, 0) + 1
            latest[key] = max(latest.get(key, -1), num)

    def rank(p: Path):
        _, num = _series(p.stem)
        return (p.stem == stem, _shared_name(stem, p), num if num is not None else -1,
                -SOLUTION_EXTENSIONS.index(p.suffix.lower()), p.name)

    out = []
    for p in sorted(entries, key=rank, reverse=True):
        base, num = _series(p.stem)
        key = (base, p.suffix.lower())
        shared = _shared_name(stem, p)
        if p.stem == stem:
            why = "named like the mesh"
        elif shared:
            why = f"its name shares {p.stem[:shared]!r} with the mesh's"
        else:
            why = ""
        if num is not None and count.get(key, 0) > 1:
            place = "the latest" if num == latest[key] else "one"
            why = (why + "; " if why else "") + f"{place} of {count[key]} numbered files {base}_N{p.suffix}"
        out.append((p, why or "in the same folder"))
    return out


def pick_solution(mesh_path) -> tuple[Path | None, str, list[Path]]:
    """(the likeliest field file or None, why, all candidates) for a mesh (solution_candidates).
    A file whose name shares nothing with the mesh's is taken only when it is the folder's
    only field file: a folder of unrelated cases must not dress a mesh in another's field."""
    cands = solution_candidates(mesh_path)
    paths = [p for p, _ in cands]
    if not cands:
        return None, "no .fld, .chk or .rst file in the folder", paths
    best, why = cands[0]
    if best.stem == Path(mesh_path).stem or _shared_name(Path(mesh_path).stem, best):
        return best, why, paths
    if len(cands) == 1:
        return best, "the only field file in the folder", paths
    return None, f"{len(cands)} field files in the folder, none named like the mesh", paths


def list_fields(solution_path) -> list[str]:
    """Names of the fields in a Nektar++ field file (.fld/.chk/.rst, XML or HDF5, or a .fld/ directory)."""
    return read_field_file(solution_path).names


def read_nektar(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """VolumeMesh of one field of a Nektar++ mesh (.xml) and its field file (.fld/.chk/.rst, XML or
    HDF5, or a multi-part .fld/ directory). Without a field file (none given and none beside the
    mesh: find_solution) the geometry comes with a zero field named "(none)" and has_field False.
    The returned mesh carries ``warnings`` (list of str) and ``has_field``."""
    mesh_path = Path(mesh_path)
    if solution_path is None:
        solution_path = find_solution(mesh_path)
    if solution_path is None and field is not None:
        raise NektarError(f"{mesh_path}: field {field!r} requested but there is no field file "
                          f"(no {', '.join(mesh_path.with_suffix(e).name for e in SOLUTION_EXTENSIONS)} "
                          "beside the mesh)")
    solution = Path(solution_path) if solution_path is not None else None
    return guard(mesh_path, lambda: _read(mesh_path, solution, field))


def _read(mesh_path: Path, solution: Path | None, field):
    mesh, geometry_modes, geometry_coeffs, geometry_warnings = _mesh_geometry(mesh_path)
    shapes = np.array([s for _, s, _ in mesh.elements], dtype=np.int32)
    if solution is None:
        modes = np.full((len(mesh.elements), 3), 2, dtype=np.int32)
        field_coeffs = [np.zeros(ex.num_coeffs(int(s), (2, 2, 2))) for s in shapes]
        field = NO_FIELD
    else:
        field, coeffs = _field(mesh, solution, field)
        modes = np.array([coeffs[e][1] for e, _, _ in mesh.elements], dtype=np.int32)
        field_coeffs = [coeffs[e][2] for e, _, _ in mesh.elements]
    warnings = list(geometry_warnings)
    try:
        out = VolumeMesh.from_elements(shapes, modes, field_coeffs, geometry_modes, geometry_coeffs,
                                       field_name=field, source=str(mesh_path))
    except MeshError as exc:
        # from_elements numbers elements by position: name the Nektar++ element ID too
        match = re.match(r"element (\d+):(.*)", str(exc), re.S)
        if match and int(match.group(1)) < len(mesh.elements):
            raise NektarError(f"{mesh_path}: element {mesh.elements[int(match.group(1))][0]}:{match.group(2)}") from exc
        raise NektarError(f"{mesh_path}: {exc}") from exc
    out.element_ids = np.array([e for e, _, _ in mesh.elements], dtype=np.int64)
    out.has_field = solution is not None
    out.warnings = sorted(set(warnings))
    return out


def mesh_boundaries(mesh_path, conditions_path=None) -> Boundaries:
    """The composites and boundary regions of a Nektar++ mesh (io/nektar/composites.py), faces
    numbered by read_nektar's elements; the boundary regions from `conditions_path` (a session
    file with <CONDITIONS>) or else from the mesh file."""
    mesh_path = Path(mesh_path)
    return guard(mesh_path, lambda: read_boundaries(_mesh_geometry(mesh_path)[0], conditions_path))


def _field(mesh: NektarMesh, solution: Path, field):
    """(field name, {element ID: (shape, modes, coefficients)}) for exactly the mesh's elements;
    with field None the file must hold one field only."""
    field_file = read_field_file(solution, len(mesh.elements))
    names = field_file.names
    if field is None:
        if len(names) != 1:
            raise NektarError(f"{solution}: holds fields {', '.join(names) or '(none)'}; name the one to render")
        field = names[0]
    ids = [e for e, _, _ in mesh.elements]
    coeffs = field_file.coefficients(field, ids)
    extra = sorted(set(coeffs) - set(ids))
    if extra:
        raise NektarError(f"{solution}: element(s) {extra[:10]} are not in the mesh {mesh.path.name}")
    for e, shape, _ in mesh.elements:
        if coeffs[e][0] != shape:
            raise NektarError(f"{solution}: element {e} is a {NAMES[coeffs[e][0]]} in the field file but a "
                              f"{NAMES[shape]} in {mesh.path.name}")
    return field, coeffs
