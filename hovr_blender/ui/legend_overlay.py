"""The colour legend over the 3D viewport in Rendered shading with HOVR (Scene > HOVR > Legend):
engine/legend.py's layout, which the CLI's `--legend` draws too, drawn here with gpu and blf in a
POST_PIXEL draw handler. The legend is of the active volume (else the scene's first), its look as
the panels show it. Colours are sRGB-encoded for the screen, as the Standard view transform shows
the render."""
from __future__ import annotations

import bpy
import numpy as np

from ..engine.image_io import srgb_encode
from ..engine.legend import Legend, legend_layout
from . import compat

_handle = None


def legend_for_region(scene, region, space) -> Legend | None:
    """The layout to draw in this 3D view region, or None (another engine or shading, the legend
    off, no volume, a look that cannot be drawn). The legend is the active volume's, else the
    scene's first."""
    if scene is None or scene.render.engine != 'HOVR' or not getattr(scene.hovr, "show_legend", False):
        return None
    if space is None or space.type != 'VIEW_3D' or space.shading.type != 'RENDERED':
        return None
    world = scene.world.color if scene.world is not None else (0.0, 0.0, 0.0)
    area = getattr(bpy.context, "area", None)
    top = covered_top(region, area.regions if area is not None else ())
    try:
        return scene_legend(scene, bpy.context.view_layer, region.width, region.height, world, top)
    except ValueError:
        return None  # the render reports what is wrong with the look


def covered_top(region, regions) -> int:
    """How many pixels at the top of the 3D view's `region` other regions of its area cover
    (with Region Overlap, the tool header lies over the view: the legend's title went under it)."""
    top = region.y + region.height
    covered = [r for r in regions if r.type in ("HEADER", "TOOL_HEADER") and r.height > 1
               and region.y <= r.y < top and r.x < region.x + region.width and r.x + r.width > region.x]
    return int(top - min(r.y for r in covered)) if covered else 0


def scene_legend(scene, view_layer, width: int, height: int, background, top: int = 0) -> Legend | None:
    """The legend of the active volume (else the scene's first) for a width x height image, or
    None without a volume; ValueError where its look cannot be drawn."""
    from .snapshot import legend_volume_inputs

    active = view_layer.objects.active if view_layer is not None else None
    obj = active if active is not None and active.hovr.is_volume else None
    obj = obj or next((o for o in scene.objects if o.hovr.is_volume), None)
    if obj is None:
        return None
    tf, value_min, value_max, title, units = legend_volume_inputs(obj, scene)
    return legend_layout(tf, value_min, value_max, title, width, height, background, units=units or None, top=top)


def _rects(x0, x1, y0, y1, region_height: int):
    """(6n, 2) triangles of the pixel rectangles [x0, x1) x [y0, y1) (arrays, rows from the top),
    in Blender's region coordinates (origin at the bottom left)."""
    x0, x1, y0, y1 = (np.asarray(a, dtype=np.float64) for a in (x0, x1, y0, y1))
    top, bottom = region_height - y0, region_height - y1
    corners = np.stack([np.stack([x0, bottom], 1), np.stack([x1, bottom], 1), np.stack([x1, top], 1),
                        np.stack([x0, bottom], 1), np.stack([x1, top], 1), np.stack([x0, top], 1)], 1)
    return corners.reshape(-1, 2)


def legend_triangles(legend: Legend, region_height: int):
    """(positions (6n, 2), colours (6n, 4)) of the legend's bar, density curve and marks (ticks,
    frame, the curve's edge: engine/legend.marks_mask) as triangles in Blender's region coordinates,
    display-encoded colours."""
    x0, y0, x1, y1 = legend.bar
    cx0, cx1 = legend.curve
    rows = np.arange(y0, y1)
    n = len(rows)
    edge = np.round(cx1 - legend.density * (cx1 - cx0))
    rgb = np.concatenate([srgb_encode(legend.bar_rgb), np.ones((n, 1))], axis=1)
    marks = legend_marks(legend)
    ink = np.array([*srgb_encode(np.asarray(legend.text_rgb)), 1.0])
    positions = np.concatenate([_rects(np.full(n, x0), np.full(n, x1), rows, rows + 1, region_height),
                                _rects(edge, np.full(n, cx1), rows, rows + 1, region_height),
                                _rects(*marks, region_height)])
    colours = np.concatenate([np.repeat(rgb, 6, axis=0), np.repeat(rgb, 6, axis=0),
                              np.tile(ink, (6 * len(marks[0]), 1))])
    return positions.astype(np.float32), colours.astype(np.float32)


def legend_marks(legend: Legend):
    """(x0, x1, y0, y1) arrays of the marks' pixel rectangles (engine/legend.marks_mask's pixels, a
    rectangle each run of a row)."""
    from ..engine.legend import marks_mask

    x0, y0, x1, y1 = legend.bar
    mask = marks_mask(legend, x1 + 1, y1 + 1) > 0
    runs = []
    for y in np.flatnonzero(mask.any(axis=1)):
        row = np.concatenate([[False], mask[y], [False]])
        starts, ends = np.flatnonzero(row[1:] & ~row[:-1]), np.flatnonzero(~row[1:] & row[:-1])
        runs += [(a, b, y, y + 1) for a, b in zip(starts, ends)]
    return tuple(np.array(c, dtype=np.float64) for c in zip(*runs)) if runs else (np.zeros(0),) * 4


def draw():
    context = bpy.context
    legend = legend_for_region(context.scene, context.region, context.space_data)
    if legend is None:
        return
    import blf
    import gpu
    from gpu_extras.batch import batch_for_shader

    height = context.region.height
    positions, colours = legend_triangles(legend, height)
    shader = compat.flat_color_shader()
    batch_for_shader(shader, 'TRIS', {"pos": positions.tolist(), "color": colours.tolist()}).draw(shader)
    font = 0
    compat.blf_size(font, legend.font_px)
    r, g, b = (float(c) for c in srgb_encode(np.asarray(legend.text_rgb)))
    blf.color(font, r, g, b, 1.0)
    gpu.state.blend_set('ALPHA')
    for t in legend.texts:
        w, h = blf.dimensions(font, t.text)
        x = t.x - w if t.anchor == "right" else t.x
        blf.position(font, x, height - t.y - 0.5 * legend.font_px * 0.7, 0)
        blf.draw(font, t.text)
    gpu.state.blend_set('NONE')


def register():
    global _handle
    if _handle is None and not bpy.app.background:
        _handle = bpy.types.SpaceView3D.draw_handler_add(draw, (), 'WINDOW', 'POST_PIXEL')


def unregister():
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, 'WINDOW')
        _handle = None
