"""The colour legend in F12's result (Render Properties > Film > Legend in Render, off by default):
engine/legend.py's layout, the one the viewport overlay and the CLI's `--legend` draw, composited
onto the Combined pass by engine/legend.draw_legend at the rendered image's right edge: the bar of
the active volume's ramp (else the scene's first volume's) over Value Min..Max with its density as
a curve, round values beside it and the field's name and units above. Drawn with numpy alone (the
text: engine/legend_text.py), so it is the CLI's legend and needs nothing of Blender's Python on any
version (4.2 bundles no Pillow)."""
from __future__ import annotations

import numpy as np

from ..engine.legend import draw_legend


def with_legend(scene, view_layer, rgba, background):
    """(image, warning or None): F12's (H, W, 4) image (top row first) with the legend drawn on it
    where Legend in Render is on and there is a volume with a drawable look."""
    from .legend_overlay import scene_legend

    if not scene.hovr.legend_in_render:
        return rgba, None
    height, width = rgba.shape[:2]
    try:
        legend = scene_legend(scene, view_layer, width, height, background)
    except ValueError as exc:
        return rgba, f"no legend in the render: {exc}"
    if legend is None:
        return rgba, None
    return draw_legend(rgba, legend).astype(np.float32), None
