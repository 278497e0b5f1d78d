"""The numerical core: plain-data scene records, Warp kernels and the float64 reference.

Nothing in this package imports bpy, so it runs on the GPU machine and in pytest.
The Blender glue lives in ``render_engine.py`` (imported only by the add-on's register()).
"""
