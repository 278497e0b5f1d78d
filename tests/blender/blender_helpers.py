"""Scene set-up shared by the in-Blender tests and the extension-install child script.

Imports bpy but not hovr_blender, so the child script exercises the installed extension only;
compat() finds the add-on's version differences in whichever copy is loaded.
"""
import importlib
import math
import shutil
import sys
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix


def compat():
    """hovr_blender.ui.compat of the loaded add-on: the installed extension's in the
    install test's child process, the repository's otherwise."""
    pkg = next((m for m in ("bl_ext.user_default.hovr_blender", "hovr_blender") if m in sys.modules), "hovr_blender")
    return importlib.import_module(pkg + ".ui.compat")


def look_at(eye, target, up) -> np.ndarray:
    """Camera-to-world matrix of a Blender camera (looks down -Z, +Y up) at eye facing target."""
    eye = np.asarray(eye, float)
    fwd = np.asarray(target, float) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    up2 = np.cross(right, fwd)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up2, -fwd, eye
    return m


def add_camera(scene, name="Camera"):
    cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    scene.collection.objects.link(cam)
    scene.camera = cam
    return cam


def set_contract_camera(scene, contract: dict, width: int, height: int):
    """Make scene.camera the contract's camera (§4) for a width x height render, sensor fit AUTO."""
    cam = scene.camera
    cam.matrix_world = Matrix(look_at(contract["eye"], contract["target"], contract["up"]).tolist())
    cam.data.sensor_fit = 'AUTO'  # AUTO: the lens/ortho scale spans the larger image side
    aspect = max(width, height) / height
    if contract.get("projection", "perspective") == "perspective":
        cam.data.type = 'PERSP'
        cam.data.angle = 2 * math.atan(math.tan(math.radians(contract["fov_y_deg"]) / 2) * aspect)
    else:
        cam.data.type = 'ORTHO'
        cam.data.ortho_scale = contract["height"] * aspect
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0


def set_ramp(texture, stops):
    """Replace a colour ramp's stops with [(position, (r, g, b, a)), ...] (linear RGB)."""
    ramp = texture.color_ramp
    ramp.interpolation, ramp.color_mode = 'LINEAR', 'RGB'
    while len(ramp.elements) > 1:
        ramp.elements.remove(ramp.elements[-1])
    ramp.elements[0].position, ramp.elements[0].color = stops[0]
    for pos, rgba in stops[1:]:
        ramp.elements.new(pos).color = rgba


def render_to_exr(scene, path) -> np.ndarray:
    """F12 through bpy.ops.render.render into a 32-bit float EXR; (H, W, 4) with row 0 at the top."""
    r = scene.render
    r.filepath = str(path)
    r.use_file_extension = False
    compat().still_image_output(r.image_settings)
    r.image_settings.file_format = 'OPEN_EXR'
    r.image_settings.color_depth = '32'
    r.image_settings.exr_codec = 'ZIP'  # lossless
    scene.view_settings.view_transform = 'Standard'  # keep values linear and untouched
    scene.view_settings.look = 'None'
    scene.view_settings.exposure, scene.view_settings.gamma = 0.0, 1.0
    bpy.ops.render.render(write_still=True, scene=scene.name)  # this scene, whichever is the context's
    return read_image(path)


def read_image(path) -> np.ndarray:
    """An image file's pixels as Blender reads them: (H, W, 4) float32 with row 0 at the top."""
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = img.size
        px = np.empty(w * h * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1].copy()


def build_sphere_scene(scene, contract, width, height, stops, value_range, density_scale, background,
                       location, angle_z, method="classified", film_transparent=False, percentage=100):
    """Camera, world colour and one HOVR sphere volume (added with the add-on's operator)."""
    add_camera(scene)
    set_contract_camera(scene, contract, width, height)
    scene.render.resolution_x, scene.render.resolution_y = width * 100 // percentage, height * 100 // percentage
    scene.render.resolution_percentage = percentage
    scene.render.film_transparent = film_transparent
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = background
    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    obj.location, obj.rotation_euler = location, (0.0, 0.0, angle_z)
    set_look(obj, stops, value_range, density_scale)
    s = scene.hovr
    s.method, s.step_units, s.h, s.tolerance, s.device = method, 'WORLD', 0.01, 1e-6, "cpu"
    return obj


def set_look(obj, stops, value_range, density_scale, units="WORLD"):
    """A volume's own look: ramp, value range and a density in the contract's units (per world unit)."""
    h = obj.hovr
    set_ramp(h.transfer_function, stops)
    h.value_min, h.value_max = value_range
    h.density_units = units
    h.density = density_scale


def f12_and_engine(scene, obj, mesh, contract, width, height, density, folder, background=(0.0625, 0.0625, 0.125)):
    """F12 of one imported volume `obj` (classified, h = 0.01 world units, `density` per world
    unit) seen by the contract camera, and the engine's image of `mesh` (the volume's data in
    object space) placed by the object's transform, with the transfer function of its ramp:
    (F12 image, engine image with alpha 1 as F12 writes it)."""
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    from hovr_blender.ui import scene as blender_scene
    from hovr_blender.ui.blender_camera import ray_camera_from_blender

    add_camera(scene)
    set_contract_camera(scene, contract, width, height)
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = background
    s, h = scene.hovr, obj.hovr
    h.density_units, h.density = 'WORLD', density
    s.method, s.step_units, s.h = "classified", 'WORLD', 0.01
    img = render_to_exr(scene, Path(folder) / "f12.exr")
    ramp = h.transfer_function.color_ramp
    tf = blender_scene.transfer_function_from_ramp(
        ramp.interpolation, ramp.color_mode, [e.position for e in ramp.elements],
        [tuple(e.color) for e in ramp.elements], h.density, h.value_min, h.value_max)
    cam = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    engine = Renderer(mesh.transformed(np.array(obj.matrix_world)), "cpu").render(
        cam, tf, np.array(background), RenderOptions(method="classified", h=0.01, tolerance=1e-5)).rgba
    engine[..., 3] = 1.0
    assert np.abs(engine[..., :3] - np.array(background)).max() > 0.05  # the volume is in view
    return img, engine


def volume(scene, k=0):
    """The k-th HOVR volume of the scene, by name (the render order)."""
    return sorted((o for o in scene.objects if o.hovr.is_volume), key=lambda o: o.name)[k]


def material(name, color, roughness=None):
    """A new material whose Principled BSDF has this base colour (linear RGB)."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # before 5.0 a new material has no nodes until asked
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED')
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    if roughness is not None:
        bsdf.inputs["Roughness"].default_value = roughness
    return mat


def set_world(scene, color):
    """A new world of one colour: HOVR's background (World.color) and Cycles' (its Background node)."""
    world = bpy.data.worlds.new("World")
    world.color = color
    if world.node_tree is None:
        world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs["Color"].default_value = (*color, 1.0)
    scene.world = world
    return world


def z_combine(tree):
    """(node, image A, depth A, image B, depth B) of a new Z Combine node that picks, per pixel, the
    input with the smaller depth: Use Alpha and Anti-Alias off. 5.0 has them as input sockets
    (A, Depth A, B, Depth B, Use Alpha, Anti-Alias); 4.x as properties (Image, Z, Image, Z)."""
    node = tree.nodes.new("CompositorNodeZcombine")
    if "Use Alpha" in node.inputs:  # 5.0+
        node.inputs["Use Alpha"].default_value = False
        node.inputs["Anti-Alias"].default_value = False
    else:
        node.use_alpha = False
        node.use_antialias_z = False
    return (node, *node.inputs[:4])


TET = "Tet_channel_m3"  # 48 straight tets on the unit cube, fields u, v, w, p (3 modes)


def copy_tet(folder: Path) -> Path:
    """The vendored Tet_channel_m3 mesh and its solution copied into `folder`; the mesh's path."""
    from tests.helpers import data_file

    folder.mkdir(parents=True, exist_ok=True)
    for ext in (".xml", ".fld"):
        shutil.copy(data_file("nektar", TET + ext), folder / (TET + ext))
    return folder / (TET + ".xml")


def datablock_counts() -> dict:
    """How many of each kind of datablock an import could add."""
    return {name: len(getattr(bpy.data, name)) for name in ("objects", "meshes", "textures", "collections",
                                                            "materials", "images")}
