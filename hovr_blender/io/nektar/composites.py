"""The mesh's composites and the CONDITIONS' boundary regions (docs/spec/formats.md §2.2,
§5.1): which element faces a face composite holds, for the walls (engine/walls.py), and which
composites each boundary region names, with the names and condition types the file gives.

A composite <C ID="i" NAME="optional"> lists entities of one dimension; a face composite lists
F[...] (any face), T[...] (triangles) or Q[...] (quadrilaterals). A boundary region
<B ID="j" NAME="optional"> C[...] </B> in <CONDITIONS><BOUNDARYREGIONS> names composites;
<BOUNDARYCONDITIONS><REGION REF="j"> holds its conditions (D, N, R, P entries, each with an
optional USERDEFINEDTYPE such as WallViscous).

A face is given as (element, face): the element's index among the DOMAIN's elements (the
VolumeMesh's order) and its face in shapes.FACE_PLANES' numbering (shapes.PLANE_OF_FACE maps
Nektar++'s local face, the face's position in the element's entry). A face shared by two of
the DOMAIN's elements is given once, on the first of them in ID order (engine/walls.py then winds
its triangles outward from that element).

Untrusted input: ID lists are kept as ranges and matched against the IDs that exist
(ranges.select), never expanded unchecked.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...engine.shapes import PLANE_OF_FACE
from .errors import NektarError
from .ranges import first_missing, parse_ranges, range_count, select
from .xmlfile import entity_id, parse_xml

FACE_LETTERS = "FTQ"
_WHAT = {"V": "vertices", "E": "edges", "S": "segments", "F": "faces", "T": "triangles", "Q": "quadrilaterals",
         "A": "tetrahedra", "P": "pyramids", "R": "prisms", "H": "hexahedra"}
_CONDITION_KINDS = {"D": "Dirichlet", "N": "Neumann", "R": "Robin", "P": "Periodic"}
_TOKEN = re.compile(r"([A-Za-z])\s*\[([^\]]*)\]")
# A composite is in one boundary region, rarely a few: a file naming more in all is refused
# before the regions' composite lists are expanded.
MAX_NAMED_PER_COMPOSITE = 8


@dataclass(frozen=True)
class Composite:
    id: int
    name: str  # its NAME attribute, "" without one
    text: str  # the ID lists as written, e.g. "F[0,56,101]"

    @property
    def letters(self) -> str:
        """The entity letters it lists, in order (e.g. "F", "H", "TQ")."""
        return "".join(m.group(1) for m in _TOKEN.finditer(self.text))

    @property
    def holds_faces(self) -> bool:
        return bool(self.letters) and all(c in FACE_LETTERS for c in self.letters)

    @property
    def declared_count(self) -> int:
        """How many IDs its lists declare (unchecked: for labels only)."""
        try:
            return sum(range_count(parse_ranges(m.group(2), "", "")) for m in _TOKEN.finditer(self.text))
        except NektarError:
            return 0


@dataclass(frozen=True)
class BoundaryRegion:
    id: int
    name: str  # its NAME attribute, "" without one
    composites: tuple  # the composite IDs it names
    conditions: tuple  # its REGION's condition types, each once: USERDEFINEDTYPE, else Dirichlet/Neumann/...


def read_composites(geometry, path) -> dict:
    """{composite ID: Composite} of the GEOMETRY's COMPOSITE section (empty without one)."""
    out = {}
    section = geometry.find("COMPOSITE")
    for node in (section if section is not None else []):
        cid = entity_id(node, path, "COMPOSITE")
        out[cid] = Composite(cid, (node.attrib.get("NAME") or "").strip(), node.text or "")
    return out


def read_boundary_regions(conditions, path, composites: dict) -> dict:
    """{region ID: BoundaryRegion} of a CONDITIONS element (empty without BOUNDARYREGIONS); every
    composite a region names must exist."""
    if conditions is None or conditions.find("BOUNDARYREGIONS") is None:
        return {}
    kinds: dict = {}
    bcs = conditions.find("BOUNDARYCONDITIONS")
    for region in (bcs.findall("REGION") if bcs is not None else []):
        try:
            ref = int(region.attrib["REF"])
        except (KeyError, ValueError):
            raise NektarError(f"{path}: BOUNDARYCONDITIONS <REGION> without a valid integer REF") from None
        labels = kinds.setdefault(ref, [])
        for cond in region:
            label = (cond.attrib.get("USERDEFINEDTYPE") or "").strip() or _CONDITION_KINDS.get(cond.tag, cond.tag)
            if label not in labels:
                labels.append(label)
    composite_ids = np.array(sorted(composites), dtype=np.int64)
    out = {}
    named = 0  # composites named by the regions so far
    for node in conditions.find("BOUNDARYREGIONS").findall("B"):
        rid = entity_id(node, path, "BOUNDARYREGIONS")
        what = f"boundary region B[{rid}]"
        if rid in out:
            raise NektarError(f"{path}: {what} is defined twice")
        text = node.text or ""
        lists = re.findall(r"C\s*\[([^\]]*)\]", text)
        if not lists or re.sub(r"C\s*\[[^\]]*\]", "", text).strip():
            raise NektarError(f"{path}: {what} must list composites as C[...], got {text.strip()!r}")
        ranges = np.array([r for body in lists for r in parse_ranges(body, path, what)], dtype=np.int64)
        # searchsorted per range, not ranges.select: that walks every composite once per region
        lo = np.searchsorted(composite_ids, ranges[:, 0], "left")
        hi = np.searchsorted(composite_ids, ranges[:, 1], "right")
        complete = hi - lo - 1 == ranges[:, 1] - ranges[:, 0]
        if not complete.all():
            i = int(np.argmin(complete))
            missing = first_missing(composite_ids, int(ranges[i, 0]), lo[i], hi[i])
            raise NektarError(f"{path}: {what} names missing composite C[{missing}]")
        named += int((hi - lo).sum())
        if named > MAX_NAMED_PER_COMPOSITE * len(composite_ids) + 1000:
            raise NektarError(f"{path}: the boundary regions name {named} composites or more in all, for "
                              f"{len(composite_ids)} composites; refused")
        ids = np.unique(np.concatenate([composite_ids[a:b] for a, b in zip(lo.tolist(), hi.tolist())]))
        out[rid] = BoundaryRegion(rid, (node.attrib.get("NAME") or "").strip(), tuple(ids.tolist()),
                                  tuple(kinds.get(rid, ())))
    return out


@dataclass
class Boundaries:
    """A mesh's composites and boundary regions, and their faces as (element, face) arrays."""

    path: Path
    composites: dict  # {ID: Composite}, every composite of the file
    regions: dict  # {ID: BoundaryRegion}; empty where the file has no BOUNDARYREGIONS
    face_ids: np.ndarray  # every face ID of the file, sorted
    face_kinds: np.ndarray  # 'T' or 'Q' of each
    _owner: dict = field(default_factory=dict, repr=False)  # "ids", "element", "face": faces of the DOMAIN

    @property
    def face_composites(self) -> list:
        return [c for _, c in sorted(self.composites.items()) if c.holds_faces]

    def choices(self) -> list:
        """[(selection text, label)]: each boundary region, then each face composite."""
        out = []
        named_by: dict = {}
        for rid, region in sorted(self.regions.items()):
            for c in region.composites:
                named_by.setdefault(c, []).append(f"B[{rid}]")
        for rid, region in sorted(self.regions.items()):
            parts = [", ".join(f"C[{c}]" for c in region.composites)]
            if region.name:
                parts.insert(0, region.name)
            if region.conditions:
                parts.append("/".join(region.conditions))
            out.append((f"B[{rid}]", f"B[{rid}]: " + " ".join(parts)))
        for c in self.face_composites:
            label = f"C[{c.id}]: " + (f"{c.name} " if c.name else "") + f"{c.declared_count} faces"
            regions = named_by.get(c.id, [])
            out.append((f"C[{c.id}]", label + (f" (in {', '.join(regions)})" if regions else "")))
        return out

    def composite_faces(self, cid: int):
        """(element, face) arrays of the faces composite C[cid] lists (by face ID within each of its lists)."""
        if cid not in self.composites:
            raise NektarError(f"{self.path}: no composite C[{cid}]{self._have_composites()}")
        comp = self.composites[cid]
        what = f"composite C[{cid}]"
        tokens = list(_TOKEN.finditer(comp.text))
        if not tokens:
            raise NektarError(f"{self.path}: {what} lists nothing")
        elements, faces = [], []
        for match in tokens:
            letter = match.group(1)
            if letter not in FACE_LETTERS:
                raise NektarError(f"{self.path}: {what} holds {_WHAT.get(letter, letter)} ({letter}[...]), not faces"
                                  f"{self._have_composites()}")
            ranges = parse_ranges(match.group(2), self.path, what)
            positions, lo, hi, complete = select(self.face_ids, ranges)
            if not complete.all():
                i = int(np.argmin(complete))
                missing = first_missing(self.face_ids, ranges[i][0], lo[i], hi[i])
                raise NektarError(f"{self.path}: {what} refers to missing face {missing}")
            if letter != "F":
                wrong = positions[self.face_kinds[positions] != letter]
                if wrong.size:
                    raise NektarError(f"{self.path}: {what} lists {letter}[{self.face_ids[wrong[0]]}] but face "
                                      f"{self.face_ids[wrong[0]]} is a {_WHAT[self.face_kinds[wrong[0]]][:-1]}")
            ids = self.face_ids[positions]
            at = np.searchsorted(self._owner["ids"], ids)
            on = (at < len(self._owner["ids"])) & (self._owner["ids"][np.minimum(at, len(self._owner["ids"]) - 1)] == ids)
            if not on.all():
                raise NektarError(f"{self.path}: {what}: face {ids[~on][0]} is on no element of the DOMAIN")
            elements.append(self._owner["element"][at])
            faces.append(self._owner["face"][at])
        return np.concatenate(elements), np.concatenate(faces)

    def select(self, text: str):
        """(element, face) arrays, sorted and each face once, of a selection: C[ranges] (composites),
        B[ranges] (boundary regions), or a name (a composite's or region's NAME, or a region's
        condition type such as WallViscous, any case), separated by commas or spaces. None for an
        empty selection (the caller's default: all boundary faces)."""
        text = (text or "").strip()
        if not text:
            return None
        cids: list = []
        rest = _TOKEN.sub(lambda m: cids.extend(self._token_composites(m, text)) or " ", text)
        for word in re.split(r"[\s,]+", rest.strip(" ,")):
            if word:
                cids.extend(self._named_composites(word))
        parts = [self.composite_faces(c) for c in dict.fromkeys(cids)]
        pairs = np.unique(np.stack([np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])], 1),
                          axis=0)
        return pairs[:, 0].astype(np.int64), pairs[:, 1].astype(np.int64)

    def _token_composites(self, match, text):
        letter = match.group(1).upper()
        if letter not in "CB":
            raise NektarError(f"{self.path}: wall selection {text!r}: {match.group(0)!r} is neither C[...] "
                              "(composites) nor B[...] (boundary regions)")
        ranges = parse_ranges(match.group(2), self.path, f"wall selection {match.group(0)!r}")
        table = self.composites if letter == "C" else self.regions
        ids = np.array(sorted(table), dtype=np.int64)
        positions, lo, hi, complete = select(ids, ranges)
        if not complete.all():
            i = int(np.argmin(complete))
            missing = first_missing(ids, ranges[i][0], lo[i], hi[i])
            if letter == "C":
                raise NektarError(f"{self.path}: no composite C[{missing}]{self._have_composites()}")
            have = (f"; the file has {', '.join(f'B[{r}]' for r in sorted(self.regions))}" if self.regions
                    else "; the file has no BOUNDARYREGIONS")
            raise NektarError(f"{self.path}: no boundary region B[{missing}]{have}")
        if letter == "C":
            return ids[positions].tolist()
        return [c for r in ids[positions].tolist() for c in self.regions[r].composites]

    def _named_composites(self, word):
        w = word.lower()
        found = [c.id for c in self.face_composites if c.name.lower() == w]
        for region in self.regions.values():
            if region.name.lower() == w or w in (k.lower() for k in region.conditions):
                found.extend(region.composites)
        if not found:
            raise NektarError(f"{self.path}: no composite or boundary region named {word!r} (choose from: "
                              f"{'; '.join(label for _, label in self.choices()) or 'none'})")
        return found

    def _have_composites(self) -> str:
        faces = [f"C[{c.id}]" for c in self.face_composites]
        return f"; the file's face composites are {', '.join(faces)}" if faces else "; the file has no face composites"


def read_boundaries(mesh, conditions_path=None) -> Boundaries:
    """The Boundaries of a read mesh (io/nektar/mesh_file.py's NektarMesh): its file read again for the
    COMPOSITE section, and the CONDITIONS of `conditions_path` (a session file) or else of the
    mesh file itself."""
    path = Path(mesh.path)
    root = parse_xml(path, "mesh file")
    composites = read_composites(root.find("GEOMETRY"), path)
    if conditions_path is not None:
        conditions_path = Path(conditions_path)
        conditions = parse_xml(conditions_path, "conditions file").find("CONDITIONS")
        if conditions is None:
            raise NektarError(f"{conditions_path}: no <CONDITIONS> section")
        regions = read_boundary_regions(conditions, conditions_path, composites)
    else:
        regions = read_boundary_regions(root.find("CONDITIONS"), path, composites)
    ids, elements, local = [], [], []
    for index, (_, shape, face_ids) in enumerate(mesh.elements):
        ids.extend(face_ids)
        elements.extend([index] * len(face_ids))
        local.extend(PLANE_OF_FACE[shape][: len(face_ids)])
    ids, elements, local = (np.array(a, dtype=np.int64) for a in (ids, elements, local))
    order = np.argsort(ids, kind="stable")  # the first element in ID order keeps a shared face
    unique_ids, first = np.unique(ids[order], return_index=True)
    owner = {"ids": unique_ids, "element": elements[order][first], "face": local[order][first]}
    face_ids = np.array(sorted(mesh.faces), dtype=np.int64)
    kinds = np.array([mesh.faces[f][0] for f in face_ids.tolist()], dtype="<U1")
    return Boundaries(path, composites, regions, face_ids, kinds, owner)
