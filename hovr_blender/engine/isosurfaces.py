"""Isosurfaces and cut planes (render contract §7): the view file's `isosurfaces` and `planes`,
checked against the data, and what the kernels need of them (kernels/isosurface.py): levels and
planes on the device's terms, the elements each needs sampled, and the field's reference
gradient, whose expansion shades the isosurfaces.

The reference gradient of an element's field is fitted in the element's own modal space, from
the host oracle's exact derivatives (expansions.eval_modal_grad) at its fit points: exact for
hexahedra, prisms and tetrahedra, whose spaces hold the derivatives of their polynomials;
for pyramids (rational modes) a least-squares fit, so their normals are close, not exact.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import expansions as ex
from .strict_json import as_number, as_numbers, as_object, as_string, as_vector3

MAX_ISOSURFACES = 16
# a level this share of the field's sampled range beyond it may still meet the field between the
# samples (a polynomial's extremum between lattice points); beyond that there is no surface
RANGE_SLACK = 0.01
MAX_PLANES = 8
CLIP_SIDES = {"none": 0, "front": 1, "back": -1}  # front: the side the normal points to is removed


class SurfaceError(ValueError):
    """An isosurface or a plane that cannot be drawn; the message names it."""


@dataclass(frozen=True)
class Isosurface:
    value: float  # the level, in the field's own units
    color: tuple  # linear RGB
    opacity: float = 1.0
    volume: int = 0  # which volume's field (several volumes: engine/field_frame.py)
    # coloured by this field of the derived field's velocity (contract §8: "speed", ...) through
    # color_ramp ((value, r, g, b), ... ascending) instead of `color`
    color_by: str | None = None
    color_ramp: tuple = ()


@dataclass(frozen=True)
class CutPlane:
    normal: tuple  # unit normal
    offset: float  # the plane n . x = offset
    opacity: float = 1.0  # of the field's colour on the plane (0: the plane only clips)
    clip: int = 0  # +1 removes the volume where n . x > offset ("front"), -1 where n . x < offset ("back")

    @classmethod
    def through(cls, point, normal, opacity: float = 1.0, clip: int = 0) -> "CutPlane":
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        length = float(np.linalg.norm(n))
        if not np.isfinite(length) or length == 0.0:
            raise SurfaceError(f"a plane's normal must be a non-zero vector, got {list(n)}")
        n = n / length
        return cls(tuple(float(v) for v in n), float(np.dot(n, np.asarray(point, dtype=np.float64).reshape(3))),
                   float(opacity), int(clip))


@dataclass(frozen=True)
class Surfaces:
    isosurfaces: tuple = ()
    planes: tuple = ()

    def __bool__(self) -> bool:
        return bool(self.isosurfaces or self.planes)

    @property
    def clips(self) -> bool:
        return any(p.clip != 0 for p in self.planes)

    def check(self, data_ranges, lower, upper) -> None:
        """SurfaceError where a level lies outside its volume's field range over the data
        (data_ranges: one (lo, hi) per volume, in the field's units: the range of the field's
        samples, engine/looks.field_samples, widened by RANGE_SLACK of it, which the field's true
        extremes between the samples do not pass) or a plane misses the data's box [lower, upper]."""
        for k, iso in enumerate(self.isosurfaces):
            if not 0 <= iso.volume < len(data_ranges):
                raise SurfaceError(f"isosurface {k}: volume {iso.volume} does not exist ({len(data_ranges)} volumes)")
            lo, hi = data_ranges[iso.volume]
            slack = RANGE_SLACK * (hi - lo)
            if not lo - slack <= iso.value <= hi + slack:
                raise SurfaceError(f"isosurface {k}: value {iso.value:g} is outside the field's range over the "
                                   f"data [{lo:.6g}, {hi:.6g}]: no surface to draw")
        corners = np.array(np.meshgrid(*zip(lower, upper), indexing="ij")).reshape(3, -1).T
        for k, plane in enumerate(self.planes):
            side = corners @ np.asarray(plane.normal) - plane.offset
            if side.min() > 0 or side.max() < 0:
                raise SurfaceError(f"plane {k} (normal {list(np.round(plane.normal, 6))}, offset {plane.offset:g}) "
                                   f"misses the volume's box {list(lower)} .. {list(upper)}")

    def unseen(self, camera, box_lo, box_hi, field_lo, field_hi, volume) -> list[str]:
        """Words for each isosurface that meets no ray of `camera` (engine/camera.RayCamera): no
        element whose certified field range [field_lo, field_hi] holds its level (of its volume)
        has its box [box_lo, box_hi] inside the camera's view. Said of the whole image only (a band
        of rows sees less); a level a ray grazes past in a visible element is not caught."""
        out = []
        seen = None
        for k, iso in enumerate(self.isosurfaces):
            holds = (volume == iso.volume) & (field_lo <= iso.value) & (iso.value <= field_hi)
            if seen is None:
                seen = boxes_in_view(camera, box_lo, box_hi)
            if not (holds & seen).any():
                where = "no element holding it is in the camera's view" if holds.any() else "no element holds it"
                out.append(f"isosurface {k} (value {iso.value:g}) meets no ray in this frame: {where}")
        return out

    def color_ramp(self, spec) -> dict:
        """The isosurfaces' colouring for the kernels: per isosurface its colour field's name or
        None ("by"), and the one colour ramp ("s", "rgb"); SurfaceError where an isosurface is
        coloured by a field the data cannot give (spec: the mesh's DerivedSpec, or None)."""
        coloured = [i for i in self.isosurfaces if i.color_by is not None]
        for k, iso in enumerate(self.isosurfaces):
            if iso.color_by is not None and (spec is None or not spec.velocity):
                raise SurfaceError(f"isosurface {k}: color_by {iso.color_by!r} needs a velocity's derived field "
                                   f"(e.g. Q(u,v,w)); the field is {'a plain field' if spec is None else spec.name}")
        ramps = {i.color_ramp for i in coloured}
        if len(ramps) > 1:
            raise SurfaceError("isosurfaces coloured by a field share one color_ramp; they differ")
        ramp = np.array(next(iter(ramps)) if ramps else [(0.0, 1.0, 1.0, 1.0)], np.float64).reshape(-1, 4)
        return {"by": [i.color_by for i in self.isosurfaces], "s": ramp[:, 0], "rgb": ramp[:, 1:]}

    def device_arrays(self, scale, shift, volume, field_lo, field_hi, box_lo, box_hi) -> dict:
        """The kernels' SurfaceArgs as numpy float64 arrays: levels mapped into the field's frame
        (f' = scale[v] f + shift[v] of their volume v), planes as (n, c), styles (opacity, clip),
        and `keep`, per element (of volume `volume`, certified frame range [field_lo, field_hi],
        box [box_lo, box_hi]): 1 where one of its volume's levels lies in its range or a plane
        meets its box."""
        iso_s = np.array([scale[i.volume] * i.value + shift[i.volume] for i in self.isosurfaces], np.float64)
        iso_rgba = np.array([list(i.color) + [i.opacity] for i in self.isosurfaces], np.float64).reshape(-1, 4)
        plane = np.array([list(p.normal) + [p.offset] for p in self.planes], np.float64).reshape(-1, 4)
        style = np.array([[p.opacity, float(p.clip), 0.0, 0.0] for p in self.planes], np.float64).reshape(-1, 4)
        keep = np.zeros(len(volume), bool)
        for i, s in zip(self.isosurfaces, iso_s):
            keep |= (volume == i.volume) & (field_lo <= s) & (s <= field_hi)
        for p in plane:
            n, c = p[:3], p[3]
            # the box's extent along n: centre . n +- half-size . |n|
            centre, half = 0.5 * (box_lo + box_hi), 0.5 * (box_hi - box_lo)
            mid, reach = centre @ n - c, half @ np.abs(n)
            keep |= np.abs(mid) <= reach
        return {"iso_s": iso_s, "iso_rgba": iso_rgba, "plane": plane, "plane_style": style,
                "keep": keep.astype(np.int32)}


def boxes_in_view(camera, lo, hi) -> np.ndarray:
    """(E,) whether each box [lo, hi] may meet the camera's rays: False where its corners all lie
    beyond one side of the view (the image's four edges, behind the eye, past the clip planes)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    corners = np.stack([np.stack([(lo, hi)[i][:, 0], (lo, hi)[j][:, 1], (lo, hi)[k][:, 2]], axis=1)
                        for i in (0, 1) for j in (0, 1) for k in (0, 1)], axis=1)  # (E, 8, 3)
    U = camera.width / camera.height
    perspective = not (np.any(camera.ou) or np.any(camera.ov))
    # p = o0 + u ou + v ov + t (d0 + u du + v dv): perspective solves (t, t u, t v), orthographic (u, v, t)
    basis = np.stack([camera.d0, camera.du, camera.dv] if perspective else [camera.ou, camera.ov, camera.d0], axis=1)
    a = (corners - camera.o0) @ np.linalg.inv(basis).T  # (E, 8, 3)
    if perspective:  # the four edges' planes through the eye, each a half-space: tu <= U t, ...
        t, tu, tv = a[..., 0], a[..., 1], a[..., 2]
        scale = t
    else:
        tu, tv, t = a[..., 0], a[..., 1], a[..., 2]
        scale = np.ones_like(t)
    outside = ((tu > U * scale).all(axis=1) | (tu < -U * scale).all(axis=1) | (tv > scale).all(axis=1)
               | (tv < -scale).all(axis=1) | (t <= 0).all(axis=1))
    axis = np.asarray(camera.clip_axis, np.float64)
    if np.any(axis):  # a perspective camera's clip planes along its view axis
        z = (corners - camera.o0) @ axis
        outside |= (z < camera.clip_near).all(axis=1) | (z > camera.clip_far).all(axis=1)
    elif not perspective:  # an orthographic camera's clip range along its rays
        depth = t * np.linalg.norm(camera.d0)
        outside |= (depth < camera.t_min).all(axis=1) | (depth > camera.t_max).all(axis=1)
    return ~outside


def surfaces_from_view(d: dict, exc=SurfaceError) -> Surfaces:
    """The view's `isosurfaces` and `planes` (contract §7), each entry's keys checked."""
    isos = d.get("isosurfaces", [])
    planes = d.get("planes", [])
    if not isinstance(isos, list):
        raise exc(f"isosurfaces must be a list, not {type(isos).__name__}")
    if not isinstance(planes, list):
        raise exc(f"planes must be a list, not {type(planes).__name__}")
    if len(isos) > MAX_ISOSURFACES:
        raise exc(f"{len(isos)} isosurfaces; at most {MAX_ISOSURFACES}")
    if len(planes) > MAX_PLANES:
        raise exc(f"{len(planes)} planes; at most {MAX_PLANES}")
    return Surfaces(tuple(_isosurface(v, f"isosurfaces[{k}]", exc) for k, v in enumerate(isos)),
                    tuple(_plane(v, f"planes[{k}]", exc) for k, v in enumerate(planes)))


def _known_keys(v: dict, what: str, keys, exc):
    unknown = sorted(set(v) - set(keys))
    if unknown:
        raise exc(f"{what}: unknown key {unknown[0]!r} (known: {', '.join(keys)})")


def _opacity(v, what: str, exc) -> float:
    a = as_number(v, f"{what}.opacity", exc)
    if not 0.0 <= a <= 1.0:
        raise exc(f"{what}.opacity must be in [0, 1], got {a:g}")
    return a


def _isosurface(v, what: str, exc) -> Isosurface:
    v = as_object(v, what, exc)
    _known_keys(v, what, ("value", "color", "opacity", "volume", "color_by", "color_ramp"), exc)
    if "value" not in v:
        raise exc(f"{what} needs a value")
    color = as_vector3(v.get("color", [1.0, 1.0, 1.0]), f"{what}.color [r, g, b]", exc)
    if (color < 0).any():
        raise exc(f"{what}.color must not be negative, got {list(color)}")
    volume = v.get("volume", 0)
    if not isinstance(volume, int) or isinstance(volume, bool) or volume < 0:
        raise exc(f"{what}.volume must be a volume's index (0, 1, ...), got {volume!r}")
    by, ramp = _color_by(v, what, exc)
    return Isosurface(as_number(v["value"], f"{what}.value", exc), tuple(float(c) for c in color),
                      _opacity(v.get("opacity", 1.0), what, exc), volume, by, ramp)


COLOR_BY = ("speed", "vorticity", "Q")  # a velocity's fields an isosurface can be coloured by
MAX_RAMP_STOPS = 64


def _color_by(v: dict, what: str, exc):
    """(color_by, color_ramp) of an isosurface entry: both or neither."""
    if ("color_by" in v) != ("color_ramp" in v):
        raise exc(f"{what}: color_by and color_ramp go together (a field name and [[value, r, g, b], ...])")
    if "color_by" not in v:
        return None, ()
    by = as_string(v["color_by"], f"{what}.color_by", exc)
    if by not in COLOR_BY:
        raise exc(f"{what}.color_by must be one of {', '.join(COLOR_BY)}, got {by!r}")
    stops = as_numbers(v["color_ramp"], f"{what}.color_ramp [[value, r, g, b], ...]", exc, columns=4)
    if len(stops) > MAX_RAMP_STOPS:
        raise exc(f"{what}.color_ramp has {len(stops)} stops; at most {MAX_RAMP_STOPS}")
    ramp = tuple(tuple(float(x) for x in row) for row in stops)
    if any(b[0] <= a[0] for a, b in zip(ramp, ramp[1:])) or any(min(s[1:]) < 0 for s in ramp):
        raise exc(f"{what}.color_ramp: values must increase and colours must not be negative")
    return by, ramp


def _plane(v, what: str, exc) -> CutPlane:
    v = as_object(v, what, exc)
    _known_keys(v, what, ("point", "normal", "opacity", "clip"), exc)
    for key in ("point", "normal"):
        if key not in v:
            raise exc(f"{what} needs a {key} [x, y, z]")
    clip = as_string(v.get("clip", "none"), f"{what}.clip", exc)
    if clip not in CLIP_SIDES:
        raise exc(f"{what}.clip must be one of {', '.join(CLIP_SIDES)}, got {clip!r}")
    point = as_vector3(v["point"], f"{what}.point", exc)
    normal = as_vector3(v["normal"], f"{what}.normal", exc)
    try:
        return CutPlane.through(point, normal, _opacity(v.get("opacity", 1.0), what, exc), CLIP_SIDES[clip])
    except SurfaceError as err:
        raise exc(f"{what}: {err}") from err


def reference_gradient(mesh) -> np.ndarray:
    """(3, len(mesh.coeffs)): d f / d xi_k of every element as an expansion in the element's own
    modes, stored where its field's coefficients are (k-th row)."""
    out = np.zeros((3, mesh.coeffs.shape[0]), np.float64)
    keys = np.concatenate([mesh.shape[:, None], mesh.modes], axis=1)
    for key in np.unique(keys, axis=0):
        shape, modes = int(key[0]), tuple(int(m) for m in key[1:])
        idx = np.nonzero((keys == key).all(axis=1))[0]
        k = ex.num_coeffs(shape, modes)
        cols = mesh.coeff_offset[idx][:, None] + np.arange(k)[None, :]  # (E, K)
        C = mesh.coeffs[cols].T  # (K, E)
        pts = ex.fit_points(shape, modes)
        g = ex.eval_modal_grad(shape, modes, C, pts)  # (P, E, 3)
        G = ex.fit_modal(shape, modes, g)  # (K, E, 3)
        for axis in range(3):
            out[axis][cols] = G[..., axis].T
    return out
