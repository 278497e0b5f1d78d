"""The scene's opaque surfaces for HOVR (engine/opaque.py): the visible mesh-like objects of an
evaluated depsgraph as world-space triangles, one record per (object instance, material slot)
with the material's base colour.

What counts, as Cycles sees it from the camera:
- every entry of depsgraph.object_instances whose object has geometry (meshes, curves, text,
  surfaces, metaballs: evaluated, modifiers applied, through Object.to_mesh), instances
  (collection instances, geometry-node and particle instances) included at their own matrix;
  an instancer that does not show itself (show_self false) is left out;
- not the HOVR volumes themselves (their outline objects), not objects whose ray visibility
  "Camera" is off (Object.visible_camera), and only objects the depsgraph holds: F12's render
  depsgraph leaves out Disable in Renders, the viewport's hidden objects;
- Object.is_holdout makes a holdout surface (it stops the rays, the film stays transparent).

Colour: the slot's material's Principled BSDF Base Color where it is not linked (its default
value), else the material's viewport colour (diffuse_color); no material: the object's colour
(Object.color). Textures and other shader nodes are not evaluated.
"""
from __future__ import annotations

import hashlib

import numpy as np

from ..engine.opaque import OpaqueMesh
from . import compat

GEOMETRY_TYPES = {'MESH', 'CURVE', 'SURFACE', 'FONT', 'META', 'CURVES'}


def material_color(material, fallback) -> tuple:
    """Linear RGB base colour of a material (see the module's docstring)."""
    if material is None:
        return tuple(fallback)[:3]
    tree = compat.material_nodes(material)
    if tree is not None:
        for node in tree.nodes:
            if node.type == 'BSDF_PRINCIPLED':
                inp = node.inputs.get("Base Color")
                if inp is not None and not inp.is_linked:
                    return tuple(inp.default_value)[:3]
                break
    return tuple(material.diffuse_color)[:3]


def _object_geometry(obj):
    """(vertices (n, 3) object space, triangles (m, 3), material index per triangle) of an
    evaluated object, or None when it has no faces."""
    try:
        me = obj.to_mesh()
    except RuntimeError:
        return None
    if me is None:
        return None
    try:
        me.calc_loop_triangles()
        n, m = len(me.vertices), len(me.loop_triangles)
        if m == 0:
            return None
        co = np.empty(3 * n, dtype=np.float32)
        me.vertices.foreach_get("co", co)
        tris = np.empty(3 * m, dtype=np.int32)
        me.loop_triangles.foreach_get("vertices", tris)
        mat = np.empty(m, dtype=np.int32)
        me.loop_triangles.foreach_get("material_index", mat)
        return co.reshape(n, 3).astype(np.float64), tris.reshape(m, 3).astype(np.int64), mat
    finally:
        obj.to_mesh_clear()


def _is_volume(obj) -> bool:
    hovr = getattr(obj.original if obj.original is not None else obj, "hovr", None)
    return bool(hovr is not None and hovr.is_volume)


def scene_opaque_meshes(depsgraph) -> list:
    """[OpaqueMesh] of the depsgraph's visible geometry (module docstring), in the depsgraph's order."""
    out = []
    geometry = {}  # object name -> its geometry (instances share it)
    for inst in depsgraph.object_instances:
        obj = inst.object
        if obj.type not in GEOMETRY_TYPES or _is_volume(obj):
            continue
        if not inst.is_instance and not inst.show_self:
            continue
        if not getattr(obj, "visible_camera", True):
            continue
        key = obj.name_full if hasattr(obj, "name_full") else obj.name
        if key not in geometry:
            geometry[key] = _object_geometry(obj)
        geo = geometry[key]
        if geo is None:
            continue
        verts, tris, mat = geo
        m = np.array(inst.matrix_world, dtype=np.float64)
        world = verts @ m[:3, :3].T + m[:3, 3]
        slots = obj.material_slots
        holdout = bool(getattr(obj, "is_holdout", False))
        for k in np.unique(mat):
            material = slots[int(k)].material if 0 <= k < len(slots) else None
            color = material_color(material, tuple(obj.color))
            out.append(OpaqueMesh(world, tris[mat == k], color, holdout, f"{obj.name}[{int(k)}]"))
    return out


def opaque_key(surfaces) -> str:
    """A digest of the surfaces' geometry, colours and flags (what the cast depends on)."""
    h = hashlib.blake2b(digest_size=16)
    for s in surfaces:
        h.update(np.ascontiguousarray(s.vertices).tobytes())
        h.update(np.ascontiguousarray(s.triangles).tobytes())
        h.update(np.array([*s.color, float(s.holdout)]).tobytes())
    return h.hexdigest()
