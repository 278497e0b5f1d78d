"""The element container every importer produces and every renderer path consumes.

Struct-of-arrays so it uploads to Warp unchanged. One row per element:
- ``shape``: element shape id (HEX for now; prisms, tets, pyramids share the container);
- geometry: the 8 vertices (local numbering of docs/spec/formats.md §2.8) and, for affine
  elements, the exact world->reference map xi = A x + b (the traversal's fast path);
- field: per-direction mode counts, basis id, offset into one flat coefficient array.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from . import expansions as ex
from . import limits
from .expansions import MODIFIED_A
from .mesh_base import TOLERANCE, DerivedFieldError, MeshError
from .shapes import HEX, MAX_MODES, NAMES, PRISM, PYR, TET, VERTICES

_AFFINE_BATCH = 2048  # elements a call of _affine_maps: a reader reports progress between calls


def affine_from_hex_vertices(v: np.ndarray, element: int = 0, rtol: float = 1e-9):
    """(A, b, J, x0) with xi = A x + b for a parallelepiped hex; MeshError if not affine."""
    v = np.asarray(v, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise MeshError(f"element {element}: vertex coordinates are not finite")
    x0 = v.mean(axis=0)
    J = 0.5 * np.stack([v[1] - v[0], v[3] - v[0], v[4] - v[0]], axis=1)  # columns dx/dxi_k
    mapped = x0 + VERTICES[HEX] @ J.T
    scale = max(np.abs(v - x0).max(), 1e-300)
    if np.abs(mapped - v).max() > rtol * scale * 1e3:
        raise MeshError(
            f"element {element}: hexahedron is not a parallelepiped (trilinear and curved "
            "geometry arrive with the element issue)"
        )
    det = np.linalg.det(J)
    if not np.isfinite(det) or abs(det) <= TOLERANCE * np.prod(np.linalg.norm(J, axis=0)):
        raise MeshError(f"element {element}: degenerate hexahedron (Jacobian determinant {det:.3g})")
    if det < 0:
        raise MeshError(f"element {element}: inverted hexahedron (negative Jacobian)")
    A = np.linalg.inv(J)
    return A, -A @ x0, J, x0


AFFINE_RTOL = 1e-12  # an element whose map is affine to this (of its size and place) is affine
# ... in float32 renders: to float32's own rounding of its coordinates (a file's straight edges
# given by rounded points: hump3D's GLL edge points make 1,555 of its 1,760 hexahedra "curved")
AFFINE_RTOL_FLOAT32 = 2.0**-24


def _affine_maps(shape: int, gmodes, G: np.ndarray, rtol: float = AFFINE_RTOL):
    """For m elements of one shape and geometry order, G (m, K, 3): padded vertices (m, 8, 3),
    world->reference maps (m, 3, 4) and whether each map is affine (to rtol of the element's size
    and place, at the fit points)."""
    ref_v = VERTICES[shape]
    V = np.einsum("vk,mkc->mvc", ex.basis_matrix(shape, gmodes, ref_v), G)
    verts = np.concatenate([V, np.repeat(V[:, -1:], 8 - len(ref_v), axis=1)], axis=1)
    axes = [int(np.nonzero((ref_v == -1 + 2 * np.eye(3)[d]).all(axis=1))[0][0]) for d in range(3)]
    J = 0.5 * np.transpose(V[:, axes] - V[:, :1], (0, 2, 1))  # (m, 3, 3): columns dx/dxi_d
    extent = np.abs(V - V.mean(axis=1, keepdims=True)).max(axis=(1, 2))
    det = np.linalg.det(J)
    good = np.isfinite(det) & (extent > 0) & (np.abs(det) > 1e-12 * extent**3)
    pts = ex.fit_points(shape, gmodes)
    B = ex.basis_matrix(shape, gmodes, pts)
    dev = np.abs(np.matmul(B, G) - (V[:, None, 0] + np.einsum("pd,mcd->mpc", pts + 1.0, J))).max(axis=(1, 2))
    ok = good & (dev <= rtol * (extent + np.abs(V).max(axis=(1, 2))))
    maps = np.zeros((len(G), 3, 4))
    if ok.any():
        A = np.linalg.inv(J[ok])
        maps[ok, :, :3] = A
        maps[ok, :, 3] = -np.einsum("mij,mj->mi", A, V[ok, 0]) - 1.0
    return verts, maps, ok


def _grouped_affine_maps(shapes, geom_modes, elements, geometry, rtol: float = AFFINE_RTOL):
    """_affine_maps over `elements`, in groups of one shape and geometry order and batches of
    _AFFINE_BATCH (a reader reports progress between them); geometry(e): element e's (K, 3)
    coefficients. Yields each batch's (elements, vertices, maps, affine)."""
    keys = np.concatenate([shapes[elements, None], geom_modes[elements]], axis=1)
    for key in np.unique(keys, axis=0):
        sh, gm = int(key[0]), tuple(int(v) for v in key[1:])
        group = elements[(keys == key).all(axis=1)]
        for idx in np.array_split(group, -(-group.size // _AFFINE_BATCH)):  # each element on its own
            limits.progress()
            yield (idx, *_affine_maps(sh, gm, np.stack([geometry(e) for e in idx]), rtol))


def affine_twin(mesh, rtol: float):
    """The mesh with those of its curved elements whose maps are affine to rtol (_affine_maps)
    marked affine, with those maps; the mesh itself where there are none. Only the geometry's
    view changes (affine, ref_from_world): the field and everything else are the mesh's."""
    if mesh.affine is None or mesh.geom_coeffs is None or mesh.affine.all():
        return mesh
    affine = np.asarray(mesh.affine, bool).copy()
    maps = mesh.ref_from_world.copy()

    def geometry(e):
        k = ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e])
        return mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] + k]

    for idx, _, m, ok in _grouped_affine_maps(mesh.shape, mesh.geom_modes, np.nonzero(~affine)[0], geometry, rtol):
        affine[idx[ok]] = True
        maps[idx[ok]] = m[ok]
    if affine.sum() == np.asarray(mesh.affine, bool).sum():
        return mesh
    return dataclasses.replace(mesh, affine=affine, ref_from_world=maps)


@dataclass
class VolumeMesh:
    shape: np.ndarray  # (N,) int32
    vertices: np.ndarray  # (N, 8, 3) float64
    ref_from_world: np.ndarray  # (N, 3, 4) float64: xi = M[:, :3] x + M[:, 3]
    modes: np.ndarray  # (N, 3) int32
    basis: np.ndarray  # (N,) int32
    coeff_offset: np.ndarray  # (N,) int64
    coeffs: np.ndarray  # (M,) float64
    field_name: str = "f"
    source: str = ""
    # geometry map x(xi) as a modal expansion of the element's shape (engine/expansions.py);
    # None for meshes built by from_affine_hexes before the general path existed
    geom_modes: np.ndarray | None = None  # (N, 3) int32
    geom_offset: np.ndarray | None = None  # (N,) int64
    geom_coeffs: np.ndarray | None = None  # (G, 3) float64
    affine: np.ndarray | None = None  # (N,) bool: ref_from_world is exact for these
    # (lo (N,), hi (N,)) that element_field_ranges must also enclose: a derived field (io/magnitude.py)
    # is rendered through a polynomial fit, and its true values may leave the fit's own range
    field_range_hull: tuple | None = None
    # (N,) which volume each element belongs to (0..V-1), for meshes that merge several volumes
    # (concatenate); None: all one volume
    volume: np.ndarray | None = None
    # a derived field (engine/derived_fields.py): its components, which the renderer samples
    # exactly; the field above is then its fit (ranges, frame, normals)
    derived: object | None = None

    def __post_init__(self):
        n = self.shape.shape[0]
        if n == 0:
            raise MeshError("the mesh has no elements")
        if np.any(self.modes < 1) or np.any(self.modes > MAX_MODES):
            bad = int(np.argwhere((self.modes < 1) | (self.modes > MAX_MODES))[0][0])
            raise MeshError(f"element {bad}: {self.modes[bad].tolist()} modes; 1..{MAX_MODES} per direction are supported")
        if not np.all(np.isfinite(self.coeffs)):
            bad = int(np.searchsorted(self.coeff_offset, np.argwhere(~np.isfinite(self.coeffs))[0][0], side="right") - 1)
            raise MeshError(f"element {bad}: field coefficients contain NaN or Inf")

    @classmethod
    def from_elements(cls, shapes, modes, coeffs_per_element, geom_modes, geom_coeffs_per_element,
                      field_name="f", source="") -> "VolumeMesh":
        """General constructor: any shape, field and geometry as modal expansions
        (engine/expansions.py). Elements whose geometry is affine get the exact
        world->reference map (the traversal's fast path); MeshError names a bad element."""
        shapes = np.asarray(shapes, dtype=np.int32).ravel()
        n = shapes.size
        modes = np.broadcast_to(np.asarray(modes, dtype=np.int32), (n, 3)).copy()
        geom_modes = np.broadcast_to(np.asarray(geom_modes, dtype=np.int32), (n, 3)).copy()
        if len(coeffs_per_element) != n or len(geom_coeffs_per_element) != n:
            raise MeshError(f"{n} elements but {len(coeffs_per_element)} field and "
                            f"{len(geom_coeffs_per_element)} geometry blocks")
        flat, gflat = [], []
        for e in range(n):  # validate every block (cheap), then do the geometry per group
            limits.progress()
            sh = int(shapes[e])
            if sh not in NAMES:
                raise MeshError(f"element {e}: unknown shape id {sh}")
            c = np.asarray(coeffs_per_element[e], dtype=np.float64).ravel()
            k = ex.num_coeffs(sh, modes[e])
            if c.size != k:
                raise MeshError(f"element {e}: {c.size} field coefficients for {NAMES[sh]} "
                                f"modes {modes[e].tolist()} (needs {k})")
            g = np.asarray(geom_coeffs_per_element[e], dtype=np.float64).reshape(-1, 3)
            kg = ex.num_coeffs(sh, geom_modes[e])
            if g.shape[0] != kg:
                raise MeshError(f"element {e}: {g.shape[0]} geometry coefficients for modes "
                                f"{geom_modes[e].tolist()} (needs {kg})")
            if not np.all(np.isfinite(g)):
                raise MeshError(f"element {e}: geometry is not finite")
            flat.append(c)
            gflat.append(g)
        vertices = np.zeros((n, 8, 3))
        M = np.zeros((n, 3, 4))
        affine = np.zeros(n, dtype=bool)
        for idx, v, m, ok in _grouped_affine_maps(shapes, geom_modes, np.arange(n), gflat.__getitem__):
            vertices[idx], M[idx], affine[idx] = v, m, ok
        sizes = np.array([f.size for f in flat], dtype=np.int64)
        gsizes = np.array([g.shape[0] for g in gflat], dtype=np.int64)
        out = cls(
            shape=shapes,
            vertices=vertices,
            ref_from_world=M,
            modes=modes,
            basis=np.full(n, MODIFIED_A, np.int32),
            coeff_offset=np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64),
            coeffs=np.concatenate(flat),
            field_name=field_name,
            source=source,
            geom_modes=geom_modes,
            geom_offset=np.concatenate([[0], np.cumsum(gsizes)[:-1]]).astype(np.int64),
            geom_coeffs=np.concatenate(gflat, axis=0),
            affine=affine,
        )
        return out

    @property
    def num_elements(self) -> int:
        return int(self.shape.shape[0])

    @classmethod
    def from_affine_hexes(cls, vertices, modes, coeffs_per_element, basis=MODIFIED_A, field_name="f", source=""):
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 8, 3)
        n = vertices.shape[0]
        modes = np.broadcast_to(np.asarray(modes, dtype=np.int32), (n, 3)).copy()
        M = np.zeros((n, 3, 4))
        for e in range(n):
            A, b, _, _ = affine_from_hex_vertices(vertices[e], e)
            M[e, :, :3], M[e, :, 3] = A, b
        sizes = np.prod(modes, axis=1).astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        flat = []
        for e, c in enumerate(coeffs_per_element):
            c = np.asarray(c, dtype=np.float64).ravel()
            if c.size != sizes[e]:
                raise MeshError(f"element {e}: {c.size} coefficients for modes {modes[e].tolist()} (needs {sizes[e]})")
            flat.append(c)
        if len(flat) != n:
            raise MeshError(f"{len(flat)} coefficient blocks for {n} elements")
        return cls(
            shape=np.full(n, HEX, np.int32),
            vertices=vertices,
            ref_from_world=M,
            modes=modes,
            basis=np.full(n, basis, np.int32),
            coeff_offset=offsets,
            coeffs=np.concatenate(flat),
            field_name=field_name,
            source=source,
        )

    def bounds(self):
        """Axis-aligned (lowers, uppers) per element; exact for straight-sided elements."""
        return self.vertices.min(axis=1), self.vertices.max(axis=1)

    def reference_coords(self, e: int, x) -> np.ndarray:
        M = self.ref_from_world[e]
        return np.asarray(x, dtype=np.float64) @ M[:, :3].T + M[:, 3]

    def element_coeffs(self, e: int) -> np.ndarray:
        o = int(self.coeff_offset[e])
        return self.coeffs[o : o + ex.num_coeffs(int(self.shape[e]), self.modes[e])]

    def evaluate(self, e: int, x) -> np.ndarray:
        """float64 field of element e at world points x (..., 3), any shape (no inside test);
        curved and non-affine elements are inverted by Newton (expansions.invert_map)."""
        sh = int(self.shape[e])
        x = np.asarray(x, dtype=np.float64)
        if self.affine is None or self.affine[e]:
            xi = self.reference_coords(e, x)
        else:
            o = int(self.geom_offset[e])
            g = self.geom_coeffs[o : o + ex.num_coeffs(sh, self.geom_modes[e])]
            xi = ex.invert_map(sh, self.geom_modes[e], g, x.reshape(-1, 3))[0].reshape(x.shape)
        return ex.eval_modal(sh, self.modes[e], self.element_coeffs(e), xi)

    def field_samples(self, per_axis: int) -> np.ndarray:
        """Field values at a lattice of reference points inside every element (all shapes,
        curved ones too: nothing to invert), grouped by (shape, modes) for speed."""
        g = np.linspace(-1.0, 1.0, per_axis)
        lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        keys = np.concatenate([self.shape[:, None], self.modes], axis=1)
        out = []
        for key in np.unique(keys, axis=0):
            sh, m = int(key[0]), tuple(int(v) for v in key[1:])
            idx = np.nonzero((keys == key).all(axis=1))[0]
            pts = lattice[ex.inside(sh, lattice, tol=1e-12)]
            C = self.coeffs[self.coeff_offset[idx][:, None] + np.arange(ex.num_coeffs(sh, m))[None, :]]
            out.append((C @ ex.basis_matrix(sh, m, pts).T).ravel())
        return np.concatenate(out)

    def element_sample_ranges(self, per_axis: int) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) per element: the least and greatest of field_samples' values in it."""
        g = np.linspace(-1.0, 1.0, per_axis)
        lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        keys = np.concatenate([self.shape[:, None], self.modes], axis=1)
        lo, hi = np.empty(self.num_elements), np.empty(self.num_elements)
        for key in np.unique(keys, axis=0):
            sh, m = int(key[0]), tuple(int(v) for v in key[1:])
            idx = np.nonzero((keys == key).all(axis=1))[0]
            pts = lattice[ex.inside(sh, lattice, tol=1e-12)]
            C = self.coeffs[self.coeff_offset[idx][:, None] + np.arange(ex.num_coeffs(sh, m))[None, :]]
            values = C @ ex.basis_matrix(sh, m, pts).T
            lo[idx], hi[idx] = values.min(axis=1), values.max(axis=1)
        return lo, hi

    def field_sample_weights(self, per_axis: int) -> np.ndarray:
        """The volume each of field_samples' values stands for, in their order: its element's volume
        (the box of its corners, times the share of the box its shape fills) over the element's
        samples, so that weighted quantiles are quantiles over the domain's volume."""
        g = np.linspace(-1.0, 1.0, per_axis)
        lattice = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
        fill = {HEX: 1.0, PRISM: 0.5, TET: 1.0 / 6.0, PYR: 1.0 / 3.0}
        size = np.prod(self.vertices.max(axis=1) - self.vertices.min(axis=1), axis=1)
        keys = np.concatenate([self.shape[:, None], self.modes], axis=1)
        out = []
        for key in np.unique(keys, axis=0):
            sh = int(key[0])
            idx = np.nonzero((keys == key).all(axis=1))[0]
            k = int(ex.inside(sh, lattice, tol=1e-12).sum())
            out.append(np.repeat(fill[sh] * size[idx] / k, k))
        return np.concatenate(out)

    def transformed(self, matrix) -> "VolumeMesh":
        """The same field on geometry moved by a 4x4 affine world matrix (object transform).

        Field values are attached to reference coordinates, so they travel with the element;
        densities stay per world unit of the transformed geometry."""
        M = np.asarray(matrix, dtype=np.float64).reshape(4, 4)
        if not np.all(np.isfinite(M)) or np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-12:
            raise MeshError("object transform must be a finite affine matrix")
        if self.geom_coeffs is not None:
            # x' = A x + t: every geometry mode scales by A; the vertex modes sum to one, so the
            # translation goes onto them alone (per group of one shape and geometry order)
            A, t = M[:3, :3], M[:3, 3]
            geoms = self.geom_coeffs @ A.T
            for sh in np.unique(self.shape):
                for gm in np.unique(self.geom_modes[self.shape == sh], axis=0):
                    sel = np.nonzero((self.shape == sh) & (self.geom_modes == gm).all(axis=1))[0]
                    rows = self.geom_offset[sel][:, None] + ex.vertex_mode_indices(int(sh), tuple(int(m) for m in gm))
                    geoms[rows.ravel()] += t
            out = VolumeMesh.from_elements(self.shape, self.modes, [self.element_coeffs(e) for e in range(self.num_elements)],
                                           self.geom_modes, [geoms[int(o):int(o) + ex.num_coeffs(int(sh), gm)] for o, sh, gm
                                                             in zip(self.geom_offset, self.shape, self.geom_modes)],
                                           field_name=self.field_name, source=self.source)
            for attr in ("warnings", "has_field", "element_ids", "field_range_hull", "volume"):
                if hasattr(self, attr):
                    setattr(out, attr, getattr(self, attr))
            out.derived = None if self.derived is None else self.derived.transformed(A)
            return out
        verts = self.vertices @ M[:3, :3].T + M[:3, 3]
        out = VolumeMesh.from_affine_hexes(
            verts, self.modes, [self.element_coeffs(e) for e in range(self.num_elements)],
            basis=int(self.basis[0]), field_name=self.field_name, source=self.source,
        )
        out.basis = self.basis.copy()
        out.volume = self.volume
        out.derived = None if self.derived is None else self.derived.transformed(M[:3, :3])
        return out


_BOUND_CACHE: dict = {}


def mode_bounds(shape: int, modes) -> tuple[np.ndarray, np.ndarray]:
    """(B, vertex_idx): B[m] >= max |phi_m| over the element (certified:
    expansions.mode_max_bounds), and the vertex modes' indices (a non-negative partition of
    unity, so their part of a sum lies between its coefficients)."""
    key = (int(shape), tuple(int(m) for m in modes))
    if key not in _BOUND_CACHE:
        B = ex.mode_max_bounds(*key)
        vidx = ex.vertex_mode_indices(shape, modes) if min(key[1]) >= 2 else np.zeros(0, np.int64)
        _BOUND_CACHE[key] = (B, vidx)
    return _BOUND_CACHE[key]


def _modal_ranges(shape, modes, C):
    """Certified (lo, hi) of m modal expansions, C (m, K) or (m, K, 3)."""
    B, vidx = mode_bounds(shape, modes)
    C = np.asarray(C, dtype=np.float64)
    rest = np.ones(C.shape[1], dtype=bool)
    rest[vidx] = False
    Bx = B[rest] if C.ndim == 2 else B[rest][:, None]
    spread = (np.abs(C[:, rest]) * Bx).sum(axis=1)
    if vidx.size:
        return C[:, vidx].min(axis=1) - spread, C[:, vidx].max(axis=1) + spread
    return -spread, spread


def _per_group(shapes, modes, offsets, flat, fn):
    """fn(shape, modes, C) over every element, grouped by (shape, modes) for speed; fn returns a
    tuple of per-element arrays."""
    n = len(shapes)
    keys = np.concatenate([np.asarray(shapes)[:, None], np.asarray(modes)], axis=1)
    out = None
    for key in np.unique(keys, axis=0):
        sh, m = int(key[0]), tuple(int(v) for v in key[1:])
        idx = np.nonzero((keys == key).all(axis=1))[0]
        k = ex.num_coeffs(sh, m)
        gather = offsets[idx][:, None] + np.arange(k)[None, :]
        parts = fn(sh, m, flat[gather])
        if out is None:
            out = [np.empty((n,) + np.shape(p)[1:]) for p in parts]
        for o, p in zip(out, parts):
            o[idx] = p
    return out


def _grouped_ranges(shapes, modes, offsets, flat):
    """_modal_ranges over every element."""
    return _per_group(shapes, modes, offsets, flat, _modal_ranges)


def element_coefficient_scale(mesh: "VolumeMesh", coeffs: np.ndarray | None = None) -> np.ndarray:
    """(N,) sum_m |c_m| max|phi_m|: the size of the terms an evaluation of the element's field
    adds up, so its rounding error is about this times the precision's epsilon (of the mesh's
    coefficients, or of `coeffs` laid out as they are)."""
    def scale(shape, modes, C):
        B, _ = mode_bounds(shape, modes)
        return ((np.abs(C) * B).sum(axis=1),)

    flat = mesh.coeffs if coeffs is None else coeffs
    return _per_group(mesh.shape, mesh.modes, mesh.coeff_offset, flat, scale)[0]


def element_volumes(mesh: "VolumeMesh") -> np.ndarray:
    """(N,) the volume of each element (all 0 for a mesh of one volume)."""
    return np.zeros(mesh.num_elements, np.int64) if mesh.volume is None else np.asarray(mesh.volume, np.int64)


def mapped_coefficients(mesh: "VolumeMesh", scale: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """The coefficients of f' = scale[e] f + shift[e] on each element e: every mode scales, and
    the shift goes onto the vertex modes alone, which sum to one on every shape."""
    out = mesh.coeffs.copy()
    keys = np.concatenate([mesh.shape[:, None], mesh.modes], axis=1)
    for key in np.unique(keys, axis=0):
        sh, m = int(key[0]), tuple(int(v) for v in key[1:])
        idx = np.nonzero((keys == key).all(axis=1))[0]
        if np.any(shift[idx] != 0) and min(m) < 2:
            raise MeshError(f"element {int(idx[0])}: {list(m)} modes cannot hold a constant, so its field "
                            "cannot be shifted; render with precision float64")
        gather = mesh.coeff_offset[idx][:, None] + np.arange(ex.num_coeffs(sh, m))[None, :]
        out[gather] = mesh.coeffs[gather] * scale[idx][:, None]
        if min(m) >= 2:
            out[mesh.coeff_offset[idx][:, None] + ex.vertex_mode_indices(sh, m)[None, :]] += shift[idx][:, None]
    return out


def with_geometry_expansion(mesh: "VolumeMesh") -> "VolumeMesh":
    """A mesh of affine hexahedra (from_affine_hexes: no geometry expansion) as the general
    container: trilinear geometry whose vertex modes are the vertices (exact for a
    parallelepiped), the same field, so it can be merged with curved meshes."""
    if mesh.geom_coeffs is not None:
        return mesh
    if np.any(mesh.shape != HEX) or np.any(mesh.basis != MODIFIED_A):
        raise MeshError("cannot merge meshes built with and without geometry expansions "
                        "(only modified-basis hexahedra convert)")
    idx = ex.vertex_mode_indices(HEX, (2, 2, 2))
    geoms = []
    for e in range(mesh.num_elements):
        g = np.zeros((8, 3))
        g[idx] = mesh.vertices[e]
        geoms.append(g)
    out = VolumeMesh.from_elements(mesh.shape, mesh.modes, [mesh.element_coeffs(e) for e in range(mesh.num_elements)],
                                   (2, 2, 2), geoms, field_name=mesh.field_name, source=mesh.source)
    for attr in ("warnings", "has_field", "element_ids", "field_range_hull", "volume", "derived"):
        if hasattr(mesh, attr):
            setattr(out, attr, getattr(mesh, attr))
    return out


def concatenate(meshes) -> "VolumeMesh":
    """One mesh of several volumes, element e of meshes[k] tagged volume k (VolumeMesh.volume):
    one BVH and one pass render them together, each through its own transfer function."""
    meshes = list(meshes)
    if len(meshes) == 1:
        return meshes[0]
    curved = any(m.geom_coeffs is not None for m in meshes)
    if curved:
        meshes = [m if m.geom_coeffs is not None else with_geometry_expansion(m) for m in meshes]

    def cat(name):
        return np.concatenate([getattr(m, name) for m in meshes])

    def offsets(name, values):
        starts = np.cumsum([0] + [len(getattr(m, values)) for m in meshes[:-1]])
        return np.concatenate([getattr(m, name) + s for m, s in zip(meshes, starts)])

    hulls = [m.field_range_hull for m in meshes]
    if any(h is not None for h in hulls):
        lo_hi = [h if h is not None else element_field_ranges(m) for m, h in zip(meshes, hulls)]
        hull = (np.concatenate([h[0] for h in lo_hi]), np.concatenate([h[1] for h in lo_hi]))
    else:
        hull = None
    return VolumeMesh(
        shape=cat("shape"), vertices=cat("vertices"), ref_from_world=cat("ref_from_world"), modes=cat("modes"),
        basis=cat("basis"), coeff_offset=offsets("coeff_offset", "coeffs"), coeffs=cat("coeffs"),
        field_name=" + ".join(dict.fromkeys(m.field_name for m in meshes)),
        source=" + ".join(m.source for m in meshes if m.source),
        geom_modes=cat("geom_modes") if curved else None,
        geom_offset=offsets("geom_offset", "geom_coeffs") if curved else None,
        geom_coeffs=cat("geom_coeffs") if curved else None,
        affine=np.concatenate([np.ones(m.num_elements, bool) if m.affine is None else m.affine for m in meshes]),
        field_range_hull=hull,
        volume=np.concatenate([np.full(m.num_elements, k, np.int32) for k, m in enumerate(meshes)]),
        derived=concatenate_derived(meshes),
    )


def subset(mesh: "VolumeMesh", elements) -> "VolumeMesh":
    """The mesh of `elements` (indices, in this order): their shapes, geometry and field, each
    element's coefficients unchanged (engine/sort_last.py gives each device one such part)."""
    e = np.asarray(elements, dtype=np.int64)
    if e.size == 0:
        raise MeshError("a part of a mesh needs at least one element")

    def gather(offset, values):
        ends = np.append(offset[1:], len(values))
        lengths = ends[e] - offset[e]
        index = np.concatenate([np.arange(offset[k], offset[k] + n) for k, n in zip(e, lengths)])
        return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(offset.dtype), values[index]

    coeff_offset, coeffs = gather(mesh.coeff_offset, mesh.coeffs)
    curved = mesh.geom_coeffs is not None
    geom_offset, geom_coeffs = gather(mesh.geom_offset, mesh.geom_coeffs) if curved else (None, None)
    hull = None if mesh.field_range_hull is None else (mesh.field_range_hull[0][e], mesh.field_range_hull[1][e])
    return VolumeMesh(
        shape=mesh.shape[e], vertices=mesh.vertices[e], ref_from_world=mesh.ref_from_world[e], modes=mesh.modes[e],
        basis=mesh.basis[e], coeff_offset=coeff_offset, coeffs=coeffs, field_name=mesh.field_name, source=mesh.source,
        geom_modes=mesh.geom_modes[e] if curved else None, geom_offset=geom_offset, geom_coeffs=geom_coeffs,
        affine=None if mesh.affine is None else mesh.affine[e], field_range_hull=hull,
        volume=None if mesh.volume is None else mesh.volume[e],
        derived=None if mesh.derived is None else mesh.derived.subset(e),
    )


def element_field_ranges(mesh: "VolumeMesh"):
    lo, hi = _grouped_ranges(mesh.shape, mesh.modes, mesh.coeff_offset, mesh.coeffs)
    if mesh.field_range_hull is not None:
        lo, hi = np.minimum(lo, mesh.field_range_hull[0]), np.maximum(hi, mesh.field_range_hull[1])
    return lo, hi


def element_boxes(mesh: "VolumeMesh"):
    """Axis-aligned boxes that enclose each element, curved ones included (modal bound);
    affine elements get their vertex hull."""
    if mesh.geom_coeffs is None:
        return mesh.bounds()
    lo, hi = _grouped_ranges(mesh.shape, mesh.geom_modes, mesh.geom_offset, mesh.geom_coeffs)
    if mesh.affine is not None and mesh.affine.any():
        nv = np.array([8, 6, 4, 5])[mesh.shape]
        for count in np.unique(nv):
            sel = mesh.affine & (nv == count)
            lo[sel] = mesh.vertices[sel, :count].min(axis=1)
            hi[sel] = mesh.vertices[sel, :count].max(axis=1)
    return lo, hi


def padded_element_boxes(mesh: "VolumeMesh"):
    """element_boxes widened by 1e-5 of each box's size or distance from the origin: the
    renderer's BVH boxes (float32 in both precisions: conservative either way)."""
    lowers, uppers = element_boxes(mesh)
    pad = 1e-5 * np.maximum(np.abs(lowers).max(axis=1, keepdims=True), np.abs(uppers - lowers).max(axis=1, keepdims=True))
    return lowers - pad, uppers + pad


def boxes_diagonal(lowers, uppers) -> float:
    """The diagonal of the box around all the boxes: no ray is longer inside the data."""
    return float(np.linalg.norm(np.asarray(uppers).max(axis=0) - np.asarray(lowers).min(axis=0)))


def data_diagonal(mesh: "VolumeMesh") -> float:
    """The renderer's data_diagonal of `mesh` (the fixed-step methods' samples per ray), without Warp."""
    return boxes_diagonal(*padded_element_boxes(mesh))


def concatenate_derived(meshes):
    """The DerivedField (engine/derived_fields.py) of meshes merged by concatenate: at most one
    derived field among them (its elements derived, the others' fields their own); None where none
    is derived."""
    fields = [m.derived for m in meshes if m.derived is not None]
    if not fields:
        return None
    if len({f.spec for f in fields}) > 1 or len(fields) > 1:
        raise DerivedFieldError("one derived field per scene: "
                                + ", ".join(f.spec.name for f in fields) + " cannot render together")
    field = fields[0]
    parts = []
    for m in meshes:
        if m.derived is not None:
            parts.append(m.derived)
        else:
            n = m.num_elements
            parts.append(dataclasses.replace(field, modes=np.ones((n, 3), np.int32), size=np.zeros(n, np.int64),
                                             offset=np.zeros(n, np.int64), coeffs=np.zeros(0),
                                             axes=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
                                             derived=np.zeros(n, bool)))
    starts = np.cumsum([0] + [len(p.coeffs) for p in parts[:-1]])
    return dataclasses.replace(field, modes=np.concatenate([p.modes for p in parts]),
                               size=np.concatenate([p.size for p in parts]),
                               offset=np.concatenate([p.offset + s for p, s in zip(parts, starts)]),
                               coeffs=np.concatenate([p.coeffs for p in parts]),
                               axes=np.concatenate([p.axes for p in parts]),
                               derived=np.concatenate([p.derived for p in parts]))
