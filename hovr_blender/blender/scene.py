"""Plain-data steps of a Blender render that need no bpy: ramp -> transfer function,
volume source -> mesh, core image -> Blender's Combined pass. Tested without Blender."""
from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..core.mesh import VolumeMesh
from ..core.transfer_function import TransferFunction, TransferFunctionError


class SourceError(ValueError):
    """An object's data source the add-on cannot load."""


def transfer_function_from_ramp(interpolation: str, color_mode: str, positions, rgba,
                                density_scale: float, value_min: float, value_max: float) -> TransferFunction:
    """A Blender ColorRamp (already read into lists) as the contract's transfer function.

    Only linear RGB interpolation is the piecewise-linear function the contract defines;
    any other mode would render something else than the ramp shows, so it is refused.
    """
    if interpolation != "LINEAR":
        raise TransferFunctionError(f"transfer function ramp must use Linear interpolation, not {interpolation.title()}")
    if color_mode != "RGB":
        raise TransferFunctionError(f"transfer function ramp must interpolate in RGB, not {color_mode}")
    if not (np.isfinite(density_scale) and density_scale >= 0):
        raise TransferFunctionError(f"density scale must be >= 0, got {density_scale}")
    if len(positions) == 0:
        raise TransferFunctionError("transfer function ramp has no colour stops")
    return TransferFunction.from_rgba_ramp(positions, rgba, density_scale, value_min, value_max)


def frame_path(path: str, frame: int) -> str:
    """Blender's numbered-file convention: the last run of '#' becomes the frame number,
    zero-padded to the run's length ("flow_####.fld", 12 -> "flow_0012.fld")."""
    if not path:
        return path
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    m = runs[-1]
    number = f"{abs(int(frame)):0{len(m.group())}d}"
    return path[: m.start()] + ("-" if frame < 0 else "") + number + path[m.end():]


@dataclass(frozen=True)
class VolumeSource:
    """One frame's data: what to read, and a key that changes exactly when the bytes may.

    `path` is "builtin:NAME" or an absolute file path (placeholders already substituted)."""

    path: str
    solution: str = ""
    field: str = ""
    stamps: tuple = ()  # (mtime_ns, size) of each file when the source was resolved
    component: str = ""  # VTU vectors: "" or "magnitude", or an index ("0", "1", ...)

    @property
    def key(self) -> tuple:
        base = (self.path, self.solution, self.field, self.stamps)
        return base + (self.component,) if self.component else base


def _stamps(*paths) -> tuple:
    out = []
    for p in paths:
        if p:
            try:
                st = os.stat(p)
                out.append((st.st_mtime_ns, st.st_size))
            except OSError:
                out.append(None)  # missing: load_volume_source reports it
    return tuple(out)


def volume_source(source: str, solution: str = "", field: str = "", frame: int = 1, abspath=None,
                  component: str = "") -> VolumeSource:
    """Object.hovr (source, solution, field, component) at a frame; `abspath` resolves Blender's '//'."""
    source, solution, field, component = source.strip(), solution.strip(), field.strip(), component.strip()
    if source.startswith("builtin:"):
        return VolumeSource(source, "", "")
    if not source:
        raise SourceError("the HOVR volume has no source: set Object > HOVR Volume > Source")
    resolve = abspath or (lambda p: p)
    path = os.path.abspath(resolve(frame_path(source, frame)))
    sol = os.path.abspath(resolve(frame_path(solution, frame))) if solution else ""
    return VolumeSource(path, sol, field, _stamps(path, sol), component)


def parse_component(text) -> int | str | None:
    """Object.hovr.component -> read_vtu's component: "" -> None (a vector's magnitude),
    "magnitude" -> "magnitude", "0", "1", ... -> the index."""
    text = str(text or "").strip()
    if not text:
        return None
    if text.lower() == "magnitude":
        return "magnitude"
    if text.isdigit():
        return int(text)
    raise SourceError(f"component {text!r}: use an index (0, 1, 2, ...), 'magnitude' or nothing")


def load_volume_source(source, solution: str = "", field: str = "", component: str = "") -> VolumeMesh:
    """Object.hovr.source -> mesh in object space: "builtin:NAME" for the shipped datasets,
    a Nektar++ .xml (with `solution`, the .fld/.chk beside it; field "|u,v,w|" is the
    magnitude of u, v, w, io/derived.py) or a .vtu file (a vector's magnitude, the default
    for vectors, is derived the same way; `component` picks one component instead)."""
    from ..io import builtin

    if isinstance(source, VolumeSource):
        source, solution, field, component = source.path, source.solution, source.field, source.component
    kind, _, name = source.partition(":")
    if kind == "builtin":
        if name not in builtin.BUILTIN:
            raise SourceError(f"unknown built-in dataset {name!r}; one of {', '.join(builtin.BUILTIN)}")
        return builtin.BUILTIN[name]()
    ext = os.path.splitext(source)[1].lower()
    if ext not in (".xml", ".vtu"):
        raise SourceError(f"unsupported volume source {source!r} (use builtin:NAME, a Nektar++ .xml or a .vtu file)")
    for p in (source, solution):
        if p and not os.path.exists(p):
            raise SourceError(f"data file not found: {p}")
    if ext == ".xml":
        from ..io import derived

        return derived.read_nektar_field(source, solution or None, field=field or None)
    comp = parse_component(component)
    try:
        from ..io.derived import read_vtu_field
    except ImportError as exc:
        raise SourceError(f"{source}: this build has no VTU reader ({exc})") from exc
    return read_vtu_field(source, field or None, comp)


# Loaded meshes (object space) by VolumeSource.key: moving the object, another device or the
# viewport and F12 share one read; a changed file (size or mtime) has another key.
_MESHES: dict = {}
MAX_CACHED_MESHES = 2


def cached_volume(source: VolumeSource) -> VolumeMesh:
    """load_volume_source(source), read again only when source.key changes."""
    key = source.key
    mesh = _MESHES.pop(key, None)
    if mesh is None:
        mesh = load_volume_source(source)
    _MESHES[key] = mesh  # most recently used last
    while len(_MESHES) > MAX_CACHED_MESHES:
        _MESHES.pop(next(iter(_MESHES)))
    return mesh


def clear_mesh_cache():
    _MESHES.clear()


# Faces of each shape in the vertex numbering of expansions.SHAPE_VERTICES (cyclic order).
SHAPE_FACES = {
    0: ((0, 1, 2, 3), (0, 1, 5, 4), (1, 2, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4), (4, 5, 6, 7)),
    1: ((0, 1, 2, 3), (0, 1, 4), (1, 2, 5, 4), (3, 2, 5), (0, 3, 5, 4)),
    2: ((0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)),
    3: ((0, 1, 2, 3), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)),
}


def outline_edges(mesh: VolumeMesh):
    """The domain's outline for the viewport: (vertices (V, 3) float64, edges (E, 2) int) of the
    faces of the elements' straight vertex hulls that belong to one element only (the
    boundary; curved faces are drawn straight). Corners are merged when they coincide to
    1e-9 of the domain's size. A quadrilateral face met by two triangles (or two triangles
    met by the other diagonal's two, as between a hexahedron and tetrahedra) is interior too."""
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    shapes = np.asarray(mesh.shape)
    size = float(np.ptp(verts.reshape(-1, 3), axis=0).max()) or 1.0
    q = np.round(verts.reshape(-1, 3) / (1e-9 * size)).astype(np.int64)
    uniq, inverse = np.unique(q, axis=0, return_inverse=True)
    vid = inverse.reshape(-1).reshape(verts.shape[:2])  # (N, 8) merged corner ids
    corners = np.zeros((len(uniq), 3))
    corners[vid.ravel()] = verts.reshape(-1, 3)
    faces = []  # (F, 4) corner ids, -1 pads triangles
    for sh, flist in SHAPE_FACES.items():
        el = np.nonzero(shapes == sh)[0]
        if el.size == 0:
            continue
        for f in flist:
            ids = vid[el][:, list(f)]
            if len(f) == 3:
                ids = np.concatenate([ids, np.full((len(el), 1), -1)], axis=1)
            faces.append(ids)
    faces = np.concatenate(faces)
    _, first, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    single = faces[first[counts == 1]]
    quads, tris = single[single[:, 3] >= 0], single[single[:, 3] < 0, :3]
    inner_q, inner_t = _split_faces_inside(quads, tris, len(corners))
    edges = np.concatenate([
        np.stack([quads[~inner_q], np.roll(quads[~inner_q], -1, axis=1)], axis=-1).reshape(-1, 2),
        np.stack([tris[~inner_t], np.roll(tris[~inner_t], -1, axis=1)], axis=-1).reshape(-1, 2),
    ])
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    used = np.unique(edges)
    remap = np.full(len(corners), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return corners[used], remap[edges]


def _split_faces_inside(quads, tris, nverts):
    """Which unmatched quads and triangles cover the same quadrilateral from two sides: a quad
    and a pair of triangles sharing a diagonal, or two pairs on different diagonals."""
    inner_q, inner_t = np.zeros(len(quads), bool), np.zeros(len(tris), bool)
    if len(tris) < 2:
        return inner_q, inner_t
    te = np.sort(np.stack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]], axis=1).reshape(-1, 2), axis=1)
    tri_of = np.repeat(np.arange(len(tris)), 3)
    ue, inv, cnt = np.unique(te, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    shared = np.nonzero(cnt[inv] == 2)[0]
    shared = shared[np.argsort(inv[shared], kind="stable")]
    t1, t2 = tri_of[shared[0::2]], tri_of[shared[1::2]]
    diag = ue[inv[shared[0::2]]]
    both = np.sort(np.concatenate([tris[t1], tris[t2]], axis=1), axis=1)  # the diagonal's ends twice
    keep = np.concatenate([np.ones((len(both), 1), bool), both[:, 1:] != both[:, :-1]], axis=1)
    ok = keep.sum(axis=1) == 4
    pair_keys = both[ok][keep[ok]].reshape(-1, 4)
    t1, t2, diag = t1[ok], t2[ok], diag[ok]
    keys = np.concatenate([np.sort(quads, axis=1), pair_keys])
    source = np.concatenate([np.full(len(quads), -1), diag[:, 0] * nverts + diag[:, 1]])
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.reshape(-1)
    distinct = np.unique(np.stack([group, source], axis=1), axis=0)
    inside = np.bincount(distinct[:, 0], minlength=group.max() + 1 if len(group) else 0) >= 2
    inner_q = inside[group[: len(quads)]]
    hit = inside[group[len(quads):]]
    inner_t[t1[hit]] = True
    inner_t[t2[hit]] = True
    return inner_q, inner_t


def render_background(world_color, film_transparent: bool) -> np.ndarray:
    """What the core composites behind the volume: nothing for a transparent film."""
    if film_transparent:
        return np.zeros(3)
    return np.asarray(world_color if world_color is not None else (0.0, 0.0, 0.0), dtype=np.float64)[:3]


def combined_pass(rgba, film_transparent: bool) -> np.ndarray:
    """Core image (row 0 at the top) -> flat float32 RGBA for RenderPass.rect (row 0 at the bottom).

    The core was given a black background for a transparent film, so its RGB is C alone
    (premultiplied) and its alpha 1 - T; an opaque film has the background composited in
    and alpha 1.
    """
    img = np.array(np.asarray(rgba, dtype=np.float32)[::-1], dtype=np.float32, order="C")
    if img.ndim != 3 or img.shape[2] != 4:
        raise ValueError(f"expected an (H, W, 4) image, got shape {img.shape}")
    if not film_transparent:
        img[..., 3] = 1.0
    return img.ravel()


def flip_rows(a) -> np.ndarray:
    """(H, W[, C]) with row 0 at the top -> flat float32, row 0 at the bottom (RenderPass.rect)."""
    return np.ascontiguousarray(np.asarray(a, dtype=np.float32)[::-1]).ravel()


def depth_pass(camera, t, alpha) -> np.ndarray:
    """Blender's Depth pass from the core's depth output (H, W, rows from the top).

    The core gives t along each unit ray where 1 - T first reaches 0.5 (t_max otherwise);
    Blender's Depth (Cycles' camera_z_depth) is the distance along the view axis, so t is
    converted per pixel. Pixels whose opacity never reaches 0.5 (alpha < 0.5: T only
    decreases along a ray) get the far clip distance, where Cycles would write 1e10."""
    from .camera import view_depth

    far = camera.extra.get("clip", (0.0, camera.t_max))[1]
    z = view_depth(camera, t)
    z = np.where(np.asarray(alpha) >= 0.5, z, far)
    return flip_rows(z)


# Transfer-function presets: (name, description, [(ramp position, (r, g, b, alpha))]).
# Colours are scene-linear; alpha x density scale is the extinction.
def _tents(spec, width):
    stops = [(0.0, (0.0, 0.0, 0.0, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
    for centre, rgb in spec:
        stops += [(centre - width, (*rgb, 0.0)), (centre, (*rgb, 1.0)), (centre + width, (*rgb, 0.0))]
    return sorted(stops, key=lambda s: s[0])


TF_PRESETS = {
    "TENTS": ("Three Tents", "Three thin coloured tents (isosurface-like shells)",
              _tents(((0.2, (1.0, 0.2, 0.1)), (0.5, (0.1, 1.0, 0.2)), (0.8, (0.2, 0.3, 1.0))), 0.04)),
    "SPIKES": ("Spikes", "Four narrow spikes, the style of the paper's figures",
               _tents(((0.2, (1.0, 0.1, 0.1)), (0.4, (1.0, 1.0, 0.1)), (0.6, (0.1, 1.0, 0.1)), (0.8, (0.1, 0.3, 1.0))), 0.01)),
    "SMOOTH": ("Smooth Ramp", "Blue to red, opacity rising with the value",
               [(0.0, (0.05, 0.1, 1.0, 0.0)), (0.5, (0.2, 1.0, 0.3, 0.3)), (1.0, (1.0, 0.1, 0.05, 1.0))]),
    "GREY": ("Grey Fog", "Uniform grey fog, denser for larger values",
             [(0.0, (0.8, 0.8, 0.8, 0.0)), (1.0, (0.8, 0.8, 0.8, 1.0))]),
}


def field_samples(mesh, samples_per_axis: int | None = None, max_values: int = 200_000) -> np.ndarray:
    """Field values on a lattice of reference points inside every element (for the value
    range and the histogram); the lattice shrinks for big meshes to keep this under ~max_values."""
    n = mesh.num_elements
    if samples_per_axis is None:
        samples_per_axis = int(np.clip(np.cbrt(max_values / max(n, 1)), 2, 9))
    values = mesh.field_samples(samples_per_axis)
    return values[np.isfinite(values)]


def value_histogram(values, value_min: float, value_max: float, bins: int = 16) -> np.ndarray:
    """Fraction of the samples in each of `bins` equal bins of [value_min, value_max]."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0 or not value_max > value_min:
        return np.zeros(bins)
    counts, _ = np.histogram(values, bins=bins, range=(value_min, value_max))
    return counts / values.size
