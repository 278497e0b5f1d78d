"""The colour legend in F12's result (Render Properties > Film > Legend in Render, off by default):
engine/legend.py's layout, the one the viewport overlay and the CLI's `--legend` draw, composited
onto the Combined pass by engine/legend.draw_legend at the rendered image's right edge: the bar of
the active volume's ramp (else the scene's first volume's) over Value Min..Max, five values beside
it and the field's name above. The text is drawn with Blender's own fonts into an image buffer
(blf.bind_imbuf, Blender 4.5 and 5.0), else with Pillow where Blender's Python has it; without
either, the render says so and leaves the image as it is."""
from __future__ import annotations

import importlib.util
import os
import tempfile

import bpy
import numpy as np

from ..engine.legend import Legend, draw_legend, pillow_text_mask
from . import compat

NO_TEXT = ("Legend in Render needs a Blender whose blf draws into images (4.5 or later) or Pillow in Blender's "
           "Python; the image has no legend")


def blf_text_mask(legend: Legend, width: int, height: int) -> np.ndarray:
    """(H, W) coverage of the legend's text, top row first: drawn with blf into an ImBuf, read back
    through a temporary PNG (Python cannot read an ImBuf's pixels)."""
    import blf
    import imbuf

    font = 0
    buf = imbuf.new((width, height))
    with blf.bind_imbuf(font, buf):
        compat.blf_size(font, legend.font_px)
        blf.color(font, 1.0, 1.0, 1.0, 1.0)
        for t in legend.texts:
            w, _ = blf.dimensions(font, t.text)
            x = t.x - w if t.anchor == "right" else t.x
            blf.position(font, x, height - t.y - 0.5 * legend.font_px * 0.7, 0)
            blf.draw_buffer(font, t.text)
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "legend.png")
        imbuf.write(buf, filepath=path)
        image = bpy.data.images.load(path, check_existing=False)
        try:
            pixels = np.empty(width * height * 4, dtype=np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1, :, 3]


def text_mask_drawer():
    """The text drawer this Blender has (blf into an image, else Pillow), or None."""
    import blf

    if hasattr(blf, "bind_imbuf"):
        return blf_text_mask
    return pillow_text_mask if importlib.util.find_spec("PIL") is not None else None


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
    drawer = text_mask_drawer()
    if drawer is None:
        return rgba, NO_TEXT
    return draw_legend(rgba, legend, drawer).astype(np.float32), None
