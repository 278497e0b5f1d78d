"""The numerical core: plain-data records (mesh, camera, transfer function, view), the Warp
kernels and their host side, and the float64 reference. Nothing here imports bpy or the
readers (hovr_blender.io): it runs on the GPU machine and in pytest, and the layers above
(io, blender, cli) import it, never the reverse.
"""
