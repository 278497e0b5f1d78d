"""Blender-side user interface: properties, operators, panels. Imported only by register()."""
