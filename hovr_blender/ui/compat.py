"""Where the Blender versions the manifest promises (4.2 LTS, 4.5 LTS, 5.x) differ in an API the
add-on or its tests use, answered once, here, by looking for the feature rather than at the
version number. Everything else in the Blender layer calls these instead of branching itself.

- The EEVEE engine's id: BLENDER_EEVEE_NEXT in 4.2-4.5, BLENDER_EEVEE again from 5.0.
- The compositor: 4.x keeps one tree per scene (scene.use_nodes, scene.node_tree, a Composite
  node); 5.0 links a node group (scene.compositing_node_group, a Group Output node).
- Still-image output: 5.0 adds ImageFormatSettings.media_type, which must say IMAGE before a
  still format is chosen.
- Background mode's log: 4.x prints every update_stats, 5.0 none (HOVR prints its own lines there).
- RenderPass.rect.foreach_set takes a flat buffer in 4.x/5.x and (pixels, channels) in 3.4.
- A material's nodes: 5.0 always renders with them (Material.use_nodes is deprecated there).
- Mesh.shade_smooth() exists from 4.1 on; before, each polygon's use_smooth is set.
- A path property declares '//' support in 4.5+ (PATH_SUPPORTS_BLEND_RELATIVE); older versions
  have no such option.
- bpy as a Python module (`pip install bpy`) hangs at interpreter exit in 4.5 while a Python
  class is still registered, so the add-on unregisters itself first; in 4.2 (and 4.3) it crashes
  at exit once any Python property callback was ever registered, unregistered or not (Blender
  issue #125376, fixed in 4.4): finish_script() ends such scripts without the teardown.
  docs/blender-versions.md has the reproductions. The Blender program is not affected.
"""
from __future__ import annotations

import os
import sys

import bpy


_EXIT_HOOKED = False


def unregister_before_exit(unregister) -> None:
    """Call `unregister` when the Python interpreter exits, in bpy-as-a-module only (the Blender
    program has an executable path and tears its add-ons down itself)."""
    global _EXIT_HOOKED
    if bpy.app.binary_path or _EXIT_HOOKED:
        return
    import atexit

    atexit.register(unregister)
    _EXIT_HOOKED = True


def finish_script(code: int = 0):
    """End a script run by bpy as a Python module with exit status `code`. Where Blender's
    module crashes in its own teardown (bpy 4.2-4.3), flush and leave without it."""
    if bpy.app.binary_path or bpy.app.version >= (4, 4, 0):
        sys.exit(code)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def update_stats_printed_in_background() -> bool:
    """Whether Blender in background mode prints each RenderEngine.update_stats as a log line
    ("Fra:1 Mem:... | HOVR | ..."): 4.x does, 5.0 prints none. Only the version tells (nothing to
    look for), so this one branch is on it."""
    return bpy.app.version < (5, 0, 0)


def flat_color_shader():
    """The built-in shader of 2-D triangles with a colour per vertex: FLAT_COLOR from 4.0
    (2D_FLAT_COLOR before)."""
    import gpu

    try:
        return gpu.shader.from_builtin('FLAT_COLOR')
    except (ValueError, TypeError):
        return gpu.shader.from_builtin('2D_FLAT_COLOR')


def blf_size(font: int, size: int) -> None:
    """blf.size in pixels: (font, size) from 4.0, (font, size, dpi) before."""
    import blf

    try:
        blf.size(font, size)
    except TypeError:
        blf.size(font, size, 72)


def eevee_engine() -> str:
    """The identifier of Blender's EEVEE render engine in this Blender."""
    items = bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items
    return "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in items else "BLENDER_EEVEE"


def new_compositor(scene, name: str = "HOVR Compositor"):
    """(node tree, input socket of the final image) of a new, empty compositor for `scene`:
    what is linked into the socket is what F12 shows and writes."""
    if hasattr(scene, "compositing_node_group"):  # 5.0+
        tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
        scene.compositing_node_group = tree
        out = tree.nodes.new("NodeGroupOutput")
        tree.interface.new_socket("Image", in_out='OUTPUT', socket_type='NodeSocketColor')
        return tree, out.inputs["Image"]
    scene.use_nodes = True
    tree = scene.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("CompositorNodeComposite")
    return tree, out.inputs["Image"]


def alpha_over(tree):
    """(node, background socket, foreground socket) of a new Alpha Over node computing
    foreground + (1 - foreground alpha) background with a premultiplied foreground: 5.0 names
    the inputs Background/Foreground (Straight Alpha off); 4.x has Image, Image_001 and
    use_premultiply (Convert Premultiplied) off."""
    node = tree.nodes.new("CompositorNodeAlphaOver")
    if "Foreground" in node.inputs:  # 5.0+
        if "Straight Alpha" in node.inputs:
            node.inputs["Straight Alpha"].default_value = False
        return node, node.inputs["Background"], node.inputs["Foreground"]
    node.use_premultiply = False
    return node, node.inputs[1], node.inputs[2]


def still_image_output(image_settings) -> None:
    """Let image_settings take a still format (OPEN_EXR, PNG, ...)."""
    if hasattr(image_settings, "media_type"):  # 5.0+
        image_settings.media_type = 'IMAGE'


def write_pass_pixels(render_pass, flat) -> None:
    """A render pass's pixels from a flat float32 buffer."""
    try:
        render_pass.rect.foreach_set(flat)
    except TypeError:  # Blender 3.4: shaped (pixels, channels)
        render_pass.rect.foreach_set(flat.reshape(-1, render_pass.channels))


def material_nodes(material):
    """The material's node tree where Blender renders with it, else None."""
    tree = getattr(material, "node_tree", None)
    if tree is not None and (bpy.app.version >= (5, 0, 0) or material.use_nodes):
        return tree
    return None


def shade_smooth(mesh) -> None:
    """Every polygon of the mesh smooth shaded."""
    if hasattr(mesh, "shade_smooth"):  # Blender 4.1+
        mesh.shade_smooth()
    else:
        mesh.polygons.foreach_set("use_smooth", [True] * len(mesh.polygons))


def path_property_options() -> set:
    """String options of a data path property: '//' paths declared as supported where Blender
    (4.5+) asks for it."""
    if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties:
        return {'ANIMATABLE', 'PATH_SUPPORTS_BLEND_RELATIVE'}
    return {'ANIMATABLE'}
