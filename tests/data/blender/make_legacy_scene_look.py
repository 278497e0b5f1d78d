"""How legacy_scene_look.blend was made: the SPHERE test scene built by hovr_blender at commit
99ed0c4, the last with a scene-level look (Scene.hovr transfer function, value range, density
per world unit). Unpack that commit to /tmp/oldhovr (git archive 99ed0c4 hovr_blender tests |
tar -x -C /tmp/oldhovr) and run this with the oldest bpy the manifest promises (4.2 LTS: newer
Blenders open its files, 4.2 cannot open 5.0's): python make_legacy_scene_look.py OUT.blend."""
import sys
sys.path.insert(0, "/tmp/oldhovr")
import bpy
import hovr_blender
from tests.helpers import SPHERE
bpy.ops.wm.read_factory_settings(use_empty=True)
hovr_blender.register()
scene = bpy.context.scene
scene.render.engine = 'HOVR'
SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[-1], compress=True)
