"""The quadrature methods (render contract §3), one home for their names and ids: the view file
and RenderOptions (view.py), the renderer's launch settings, the kernels (kernels/quadrature.py)
and Blender's Method setting (ui/properties.py, whose saved enum values are these ids) read them.

The ids are the methods' order, and the order is meaningful: the kernels take `method >=
classified` for the methods that sample the field along segments (classified, split). An id
never changes once given (saved .blend files hold it): a new method goes at the end.
"""
METHODS = ("riemann", "trapezoid", "classified", "split")
METHOD_IDS = {name: index for index, name in enumerate(METHODS)}
