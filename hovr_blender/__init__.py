"""HOVR: volume rendering of high-order finite-element fields (Blender add-on and core).

Importing this package, or ``hovr_blender.engine``/``hovr_blender.io``, never imports bpy:
the numerical engine runs on machines without Blender. The Blender side is imported only
inside register()/unregister(). Installed as an extension the package is
``bl_ext.<repo>.hovr_blender``, so everything below uses relative imports.
"""

# Read by Blender when loaded as a legacy add-on (3.4+); extensions use blender_manifest.toml.
bl_info = {
    "name": "HOVR",
    "author": "HOVR developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Properties > Render > Render Engine: HOVR; Add > HOVR Sphere Volume; File > Import > HOVR",
    "description": "Volume rendering of high-order finite element fields with NVIDIA Warp",
    "category": "Render",
}


def _modules():
    """bpy-side submodules in registration order (properties before their users)."""
    from .ui import properties, operators, import_operators, panels, surface_panels, versioning, legend_overlay
    from .ui import engine as render_engine

    return (properties, render_engine, operators, import_operators, panels, surface_panels, versioning, legend_overlay)


_registered = False


def register():
    global _registered
    for module in _modules():
        module.register()
    _registered = True
    from .ui import compat

    compat.unregister_before_exit(unregister)


def unregister():
    """Once per register(): at the exit of bpy as a module both Blender (disabling its enabled
    add-ons) and compat.unregister_before_exit call this, in either order."""
    global _registered
    if not _registered:
        return
    _registered = False
    for module in reversed(_modules()):
        module.unregister()
