"""Opaque surfaces in F12 (issue 17): a plane object cutting the sphere volume renders as the
core test's independent reference (tests/engine/test_opaque.py): the exact integral from the
eye to the plane composited over the plane's shaded material colour; which objects count
(ui/opaque_meshes.py): modifiers, instances, hidden, camera-invisible and holdout objects."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui import render  # noqa: E402
from hovr_blender.ui.opaque_meshes import scene_opaque_meshes  # noqa: E402
from hovr_blender.engine.camera import RayCamera  # noqa: E402

from ..engine import test_opaque as ref  # noqa: E402
from .blender_helpers import add_camera, material, render_to_exr, set_contract_camera, set_look, z_combine  # noqa: E402


def add_plane(scene, name="Plane", color=ref.PLANE_COLOR):
    corners = ref.plane_mesh().vertices
    me = bpy.data.meshes.new(name)
    me.from_pydata(corners.tolist(), [], [[0, 1, 2, 3]])
    me.update()
    me.materials.append(material(name + " Material", color))
    obj = bpy.data.objects.new(name, me)
    scene.collection.objects.link(obj)
    return obj


def sphere_scene(scene, projection="perspective"):
    add_camera(scene)
    set_contract_camera(scene, ref.CAMERAS[projection], ref.W, ref.H)
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = ref.BACKGROUND
    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    obj.location = (0.0, 0.0, 0.0)
    set_look(obj, ref.STOPS, (0.0, 2.0), 2.0)
    s = scene.hovr
    s.method, s.tolerance, s.min_transmittance, s.device = "split", 1e-7, 0.0, "cpu"
    return obj


def test_plane_cuts_sphere_in_f12(scene, tmp_path):
    sphere_scene(scene)
    add_plane(scene)
    assert scene.hovr.surfaces == "NONE"  # the default: a new scene's meshes are ignored
    scene.hovr.surfaces = "SHADED"
    got = render_to_exr(scene, tmp_path / "plane.exr")
    camera = RayCamera.from_contract(ref.CAMERAS["perspective"], ref.W, ref.H)
    want, t_s = ref.reference_image(camera)
    assert np.isfinite(t_s).sum() > 0.3 * t_s.size
    np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-4)
    np.testing.assert_array_equal(got[..., 3], 1.0)  # an opaque film

    # Holdout: the volume in front of the plane, premultiplied (transparent film)
    scene.hovr.surfaces = "HOLDOUT"
    scene.render.film_transparent = True
    held = render_to_exr(scene, tmp_path / "holdout.exr")
    want_h, _ = ref.reference_image(camera, holdout=True)
    hit = np.isfinite(t_s)
    np.testing.assert_allclose(held[hit], want_h[hit], atol=1e-4)
    # off: the plane is ignored
    scene.hovr.surfaces = "NONE"
    off = render_to_exr(scene, tmp_path / "off.exr")
    assert np.abs(off - held).max() > 0.05


def test_which_objects_are_surfaces(scene):
    sphere_scene(scene)
    plane = add_plane(scene)
    dg = bpy.context.evaluated_depsgraph_get()
    (only,) = scene_opaque_meshes(dg)  # the volume's outline object is not a surface
    assert only.color == pytest.approx(ref.PLANE_COLOR) and not only.holdout
    np.testing.assert_allclose(only.vertices, ref.plane_mesh().vertices, atol=1e-6)
    assert len(only.triangles) == 2

    # modifiers are applied, transforms too
    plane.location = (0.0, 0.0, 1.0)
    mod = plane.modifiers.new("Array", 'ARRAY')
    mod.count = 3
    dg = bpy.context.evaluated_depsgraph_get()
    (only,) = scene_opaque_meshes(dg)
    assert len(only.triangles) == 6
    assert only.vertices[:, 2].min() > ref.plane_mesh().vertices[:, 2].min() + 0.99

    # instances: a collection instanced twice at its own matrices
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    cube_me = bpy.data.meshes.new("Cube")
    cube_me.from_pydata([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [], [[0, 1, 2, 3]])
    cube = bpy.data.objects.new("Quad", cube_me)
    cube.color = (0.25, 0.5, 0.75, 1.0)
    coll.objects.link(cube)
    coll.hide_render = False
    for k in range(2):
        empty = bpy.data.objects.new(f"Inst{k}", None)
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = coll
        empty.location = (10.0 * (k + 1), 0.0, 0.0)
        scene.collection.objects.link(empty)
    dg = bpy.context.evaluated_depsgraph_get()
    quads = [s for s in scene_opaque_meshes(dg) if s.name.startswith("Quad")]
    xs = sorted(float(q.vertices[:, 0].min()) for q in quads)
    assert xs == pytest.approx([0.0, 10.0, 20.0])  # the collection's own object and its two instances
    assert all(q.color == pytest.approx((0.25, 0.5, 0.75)) for q in quads)  # no material: object colour

    # the camera ray visibility flag, holdout
    cube.visible_camera = False
    plane.is_holdout = True
    dg = bpy.context.evaluated_depsgraph_get()
    names = [s.name for s in scene_opaque_meshes(dg)]
    assert not any(n.startswith("Quad") for n in names)
    assert [s.holdout for s in scene_opaque_meshes(dg) if s.name.startswith("Plane")] == [True]


def test_hidden_in_renders_is_no_surface(scene, tmp_path):
    """F12's depsgraph leaves out Disable in Renders: the plane then stops nothing."""
    sphere_scene(scene)
    plane = add_plane(scene)
    plane.hide_render = True
    got = render_to_exr(scene, tmp_path / "hidden.exr")
    scene.hovr.surfaces = "NONE"
    plain = render_to_exr(scene, tmp_path / "plain.exr")
    np.testing.assert_array_equal(got, plain)
    assert render.OPAQUE is not None


def test_compositing_over_cycles_is_the_alpha_over(scene, tmp_path):
    """Set Up Compositing: F12 of the HOVR scene gives Alpha Over of HOVR's Combined pass (the
    volume in front of the surfaces, premultiplied) on Cycles' render of the same objects,
    against the two images rendered apart and laid over each other here (<= 1/255)."""
    sphere_scene(scene)
    add_plane(scene)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.rotation_euler = (0.4, 0.2, 0.3)
    scene.collection.objects.link(sun)
    bpy.ops.hovr.setup_compositing(engine="CYCLES")
    other = bpy.data.scenes[scene.name + " Surfaces"]
    assert other.render.engine == "CYCLES" and scene.hovr.surfaces == "HOLDOUT" and scene.render.film_transparent
    assert {o.name for o in other.objects} >= {"Plane", "Sun", "HOVR Sphere"}  # shared, not copied
    assert bpy.data.objects["Plane"].users_scene and len(bpy.data.objects) == 4
    other.cycles.samples, other.cycles.use_denoising, other.cycles.device = 4, False, 'CPU'
    other.cycles.seed = 7
    composed = render_to_exr(scene, tmp_path / "composed.exr")

    surfaces = render_to_exr(other, tmp_path / "cycles.exr")
    scene.render.use_compositing = False
    hovr = render_to_exr(scene, tmp_path / "hovr.exr")
    assert 0.05 < hovr[..., 3].max() < 1.0 and surfaces[..., :3].max() > 0.05  # both contribute
    want = hovr + (1.0 - hovr[..., 3:4]) * surfaces
    assert np.abs(composed - hovr).max() > 0.05  # the compositor did lay HOVR over Cycles
    np.testing.assert_allclose(composed, want, atol=1 / 255)
    # and HOVR's pass is the reference's holdout image
    want_h, t_s = ref.reference_image(RayCamera.from_contract(ref.CAMERAS["perspective"], ref.W, ref.H), holdout=True)
    hit = np.isfinite(t_s)
    np.testing.assert_allclose(hovr[hit], want_h[hit], atol=1e-4)


def test_depth_pass_z_combines_with_cycles(scene, tmp_path):
    """The Depth pass the other way round: HOVR's volume alone (Surfaces Off) and Cycles' render of
    the plane, joined by the compositor's Z Combine (Use Alpha off): each pixel is HOVR's where its
    Depth (the view-axis distance where the volume's opacity reaches 0.5, else the clip end) is
    nearer than Cycles' Depth of the plane, else Cycles', against that choice made here from the
    two images and depths rendered apart."""
    from hovr_blender.ui.compat import new_compositor

    sphere_volume = sphere_scene(scene)
    sphere_volume.hovr.density = 6.0  # opaque enough to reach 0.5 in front of the plane in places
    add_plane(scene)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.rotation_euler = (0.4, 0.2, 0.3)
    scene.collection.objects.link(sun)
    bpy.ops.hovr.setup_compositing(engine="CYCLES")  # the scene sharing the objects, rendered by Cycles
    other = bpy.data.scenes[scene.name + " Surfaces"]
    other.cycles.samples, other.cycles.use_denoising, other.cycles.device, other.cycles.seed = 4, False, 'CPU', 7
    scene.hovr.surfaces = "NONE"  # the volume whole: the compositor decides what is in front
    for sc in (scene, other):
        sc.view_layers[0].use_pass_z = True
    tree, out = new_compositor(scene, "HOVR Z Combine")
    hovr_layer, surf_layer = tree.nodes.new("CompositorNodeRLayers"), tree.nodes.new("CompositorNodeRLayers")
    hovr_layer.scene, surf_layer.scene = scene, other
    node, image_a, depth_a, image_b, depth_b = z_combine(tree)
    tree.links.new(hovr_layer.outputs["Image"], image_a)
    tree.links.new(hovr_layer.outputs["Depth"], depth_a)
    tree.links.new(surf_layer.outputs["Image"], image_b)
    tree.links.new(surf_layer.outputs["Depth"], depth_b)
    tree.links.new(node.outputs[0], out)
    combined = render_to_exr(scene, tmp_path / "zcombine.exr")

    def through_compositor(socket, name):
        """One input of the Z Combine, rendered on its own (a depth arrives as grey RGB)."""
        for link in [lk for lk in tree.links if lk.to_socket == out]:
            tree.links.remove(link)
        tree.links.new(socket, out)
        return render_to_exr(scene, tmp_path / f"{name}.exr")

    hovr = through_compositor(hovr_layer.outputs["Image"], "hovr")
    z_hovr = through_compositor(hovr_layer.outputs["Depth"], "hovr_depth")[..., 0]
    cycles = through_compositor(surf_layer.outputs["Image"], "cycles")
    z_cycles = through_compositor(surf_layer.outputs["Depth"], "cycles_depth")[..., 0]

    far = scene.camera.data.clip_end
    volume_near = z_hovr < 0.999 * far  # the volume reaches 0.5 on these rays
    plane = z_cycles < 1e9  # Cycles writes 1e10 where its ray hits nothing
    front = z_hovr < z_cycles
    clear = np.abs(z_hovr - z_cycles) > 1e-4 * np.minimum(z_hovr, z_cycles)  # no ties
    assert (front & volume_near & plane).sum() >= 10  # the volume in front of the plane
    assert (~front & volume_near & plane).sum() >= 10  # the plane in front of the volume's depth
    assert (front & ~plane).sum() >= 10 and (~front & ~volume_near).sum() >= 10
    assert clear.mean() > 0.95
    want = np.where(front[..., None], hovr, cycles)
    np.testing.assert_allclose(combined[clear], want[clear], atol=1e-5)
    # HOVR's pixel where chosen is its whole volume, behind the plane too: a per-pixel choice, not
    # the exact composite (the alpha-over route above is that)
    assert np.abs(hovr - cycles)[front & volume_near & plane].max() > 0.05
