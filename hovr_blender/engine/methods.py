"""The quadrature methods (render contract §3), one home for their names, ids and categories: the
view file and RenderOptions (view.py), the renderer's launch settings, the kernels
(kernels/quadrature.py), Blender's Method setting and panels (ui/properties.py, whose saved enum
values are these ids; ui/panels.py, ui/surface_panels.py) and the bench read them.

An id never changes once given (saved .blend files hold it): a new method goes at the end and
names its categories below. What a method is, is asked by name through the predicates, never by
comparing ids (the kernels' twin of samples_segments is kernels/quadrature.samples_segments).
"""
METHODS = ("riemann", "trapezoid", "classified", "split")
METHOD_IDS = {name: index for index, name in enumerate(METHODS)}

# the field sampled along each element segment into a Chebyshev series (restriction): what
# derived fields, isosurfaces, planes and a segment cache need; riemann and trapezoid evaluate
# the field as they march
SAMPLING_METHODS = ("classified", "split")
FIXED_STEP_METHODS = ("riemann", "trapezoid")  # the baselines: a step h is what they are
STEPLESS_METHODS = ("split",)  # adaptive Gauss-Kronrod panels: a step h means nothing to it
OWN_STEP_METHODS = ("classified",)  # without h: each segment's own step from its error bound


def samples_segments(method: str) -> bool:
    """Whether `method` integrates each segment's series (SAMPLING_METHODS)."""
    return method in SAMPLING_METHODS


def needs_step(method: str) -> bool:
    """Whether `method` cannot render without a fixed step h (FIXED_STEP_METHODS)."""
    return method in FIXED_STEP_METHODS


def takes_step(method: str) -> bool:
    """Whether a step h, where given, is the step `method` marches with (all but STEPLESS_METHODS)."""
    return method not in STEPLESS_METHODS


def chooses_own_step(method: str, h) -> bool:
    """Whether `method` without a step chooses each segment's step itself (OWN_STEP_METHODS, h None)."""
    return method in OWN_STEP_METHODS and h is None
