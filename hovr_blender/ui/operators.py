"""Operators: add the built-in sphere volume, create a default transfer function."""
import bpy
import numpy as np

from ..engine.blender_scene import load_volume_source

# The 12 edges of a hexahedron in the reference numbering (bottom face, top face, verticals).
HEX_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))

# Default ramp: three thin tents (the style of the paper's figures); (centre, half width, RGB).
DEFAULT_TENTS = ((0.2, 0.04, (1.0, 0.2, 0.1)), (0.5, 0.04, (0.1, 1.0, 0.2)), (0.8, 0.04, (0.2, 0.3, 1.0)))


def field_range(mesh, samples: int = 9):
    """(min, max) of the field over a lattice of reference points in every element."""
    g = np.linspace(-1.0, 1.0, samples)
    xi = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    lo, hi = np.inf, -np.inf
    for e in range(mesh.num_elements):
        M = mesh.ref_from_world[e]
        x = np.linalg.solve(M[:, :3], (xi - M[:, 3]).T).T  # world points of the lattice
        f = mesh.evaluate(e, x)
        lo, hi = min(lo, float(f.min())), max(hi, float(f.max()))
    return lo, hi


def new_transfer_function_texture(name: str = "HOVR Transfer Function"):
    """A Blend texture whose linear RGB ramp holds DEFAULT_TENTS (alpha 0 between tents)."""
    tex = bpy.data.textures.new(name, type='BLEND')
    tex.use_color_ramp = True
    ramp = tex.color_ramp
    ramp.interpolation = 'LINEAR'
    ramp.color_mode = 'RGB'
    # A new ramp has two stops, at 0 and 1: make them transparent black, then insert the tents.
    for element in ramp.elements:
        element.color = (0.0, 0.0, 0.0, 0.0)
    for centre, half, rgb in DEFAULT_TENTS:
        for pos, alpha in ((centre - half, 0.0), (centre, 1.0), (centre + half, 0.0)):
            ramp.elements.new(pos).color = (*rgb, alpha)
    return tex


class HOVR_OT_new_transfer_function(bpy.types.Operator):
    """Create a transfer-function texture (three coloured tents) for the scene"""

    bl_idname = "hovr.new_transfer_function"
    bl_label = "New Transfer Function"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        context.scene.hovr.transfer_function = new_transfer_function_texture()
        return {'FINISHED'}


class HOVR_OT_add_sphere_volume(bpy.types.Operator):
    """Add the paper's sphere volume (one hexahedron, f = x^2 + y^2 + z^2), shown as its outline"""

    bl_idname = "hovr.add_sphere_volume"
    bl_label = "HOVR Sphere Volume"
    bl_options = {'REGISTER', 'UNDO'}

    source = "builtin:sphere"

    def execute(self, context):
        volume = load_volume_source(self.source)
        verts = volume.vertices.reshape(-1, 3)
        edges = np.array([[a + 8 * e, b + 8 * e] for e in range(volume.num_elements) for a, b in HEX_EDGES])

        me = bpy.data.meshes.new("HOVR Sphere")
        me.vertices.add(len(verts))
        me.vertices.foreach_set("co", verts.astype(np.float32).ravel())
        me.edges.add(len(edges))
        me.edges.foreach_set("vertices", edges.astype(np.int32).ravel())
        me.update()

        obj = bpy.data.objects.new("HOVR Sphere", me)
        obj.display_type = 'WIRE'
        obj.location = context.scene.cursor.location
        obj.hovr.is_volume = True
        obj.hovr.source = self.source
        context.collection.objects.link(obj)
        for other in context.selected_objects:
            other.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj

        settings = context.scene.hovr
        if settings.transfer_function is None:
            settings.transfer_function = new_transfer_function_texture()
            settings.value_min, settings.value_max = field_range(volume)
            self.report({'INFO'}, f"HOVR: new transfer function over [{settings.value_min:.3g}, {settings.value_max:.3g}]")
        return {'FINISHED'}


def menu_add(self, _context):
    self.layout.operator(HOVR_OT_add_sphere_volume.bl_idname, icon='VOLUME_DATA')


classes = (HOVR_OT_new_transfer_function, HOVR_OT_add_sphere_volume)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.VIEW3D_MT_add.append(menu_add)


def unregister():
    bpy.types.VIEW3D_MT_add.remove(menu_add)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
