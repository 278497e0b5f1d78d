"""How legacy_world_step.blend was made: the SPHERE test scene built by hovr_blender at commit
ca9cec7, the last before Step Units (the step always in world units), with the step never set
(the 0.01 default) and the volume's own look in world units. Unpack that commit to /tmp/oldhovr
(git archive ca9cec7 hovr_blender tests | tar -x -C /tmp/oldhovr) and run this with the oldest
bpy the manifest promises (4.2 LTS): python make_legacy_world_step.py OUT.blend."""
import sys
sys.path.insert(0, "/tmp/oldhovr")
import bpy
import hovr_blender
from tests.blender.blender_helpers import add_camera, set_contract_camera, set_look
from tests.helpers import SPHERE
bpy.ops.wm.read_factory_settings(use_empty=True)
hovr_blender.register()
scene = bpy.context.scene
scene.render.engine = 'HOVR'
add_camera(scene)
set_contract_camera(scene, SPHERE.PERSPECTIVE, SPHERE.W, SPHERE.H)
scene.world = bpy.data.worlds.new("World")
scene.world.color = SPHERE.BACKGROUND
bpy.ops.hovr.add_sphere_volume()
obj = bpy.context.active_object
obj.location, obj.rotation_euler = SPHERE.OBJECT_LOCATION, (0.0, 0.0, SPHERE.OBJECT_ANGLE_Z)
set_look(obj, SPHERE.STOPS, SPHERE.VALUE_RANGE, SPHERE.DENSITY_SCALE)
assert not scene.hovr.is_property_set("h")  # the step left at its default, as most users leave it
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[-1], compress=True)
