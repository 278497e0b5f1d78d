"""The colour legend (engine/legend.py, engine/legend_text.py), issue 40: a continuous bar of the ramp
with its density as a curve, round tick values that never overlap at any size down to 160x90, the
field's name and units, drawn with numpy alone (no Pillow: Blender 4.2 has none)."""
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from hovr_blender.engine import first_view
from hovr_blender.engine.legend import draw_legend, legend_layout, nice_ticks, text_mask, tick_labels
from hovr_blender.engine.legend_text import face, fit_text, text_width
from hovr_blender.engine.transfer_function import TransferFunction


def tents():
    """The import's first look (three quantile tents) over 0.3..0.36, as hump3D's rho gets it."""
    values = np.random.default_rng(0).normal(0.334, 0.012, 20000)
    look = first_view.first_look(values)
    return look, first_view.look_transfer_function(look, 1.0)


def boxes(layout):
    """Each text's pixel box (x0, y0, x1, y1)."""
    out = []
    for t in layout.texts:
        w = text_width(t.text, layout.font_px)
        x0 = t.x - w if t.anchor == "right" else t.x
        out.append((x0, t.y - 0.5 * layout.font_px, x0 + w, t.y + 0.5 * layout.font_px))
    return out


def test_the_default_tents_read_as_a_bar_and_three_peaks():
    """With the import's tents the bar is the ramp's colour on every row (not three tiny ticks over
    the background), and the density curve peaks at the three tents."""
    look, tf = tents()
    layout = legend_layout(tf, look.value_min, look.value_max, "rho", 480, 270, first_view.FACTORY_WORLD)
    x0, y0, x1, y1 = layout.bar
    s = look.value_max - (np.arange(y1 - y0) + 0.5) / (y1 - y0) * (look.value_max - look.value_min)
    np.testing.assert_allclose(layout.bar_rgb, np.clip(tf.color(s), 0, None))
    assert (np.abs(layout.bar_rgb - first_view.FACTORY_WORLD).max(axis=1) > 0.1).mean() > 0.9
    d = layout.density
    peaks = np.flatnonzero((d[1:-1] > d[:-2]) & (d[1:-1] >= d[2:]) & (d[1:-1] > 0.2)) + 1
    assert len(peaks) == 3 and d.max() == pytest.approx(1.0)
    assert (d < 0.05).mean() > 0.4  # between the tents the curve is at its foot


@settings(max_examples=200, deadline=None)
@given(lo=st.floats(-1e6, 1e6), span=st.floats(1e-9, 1e7), exponent=st.integers(-12, 12),
       size=st.sampled_from([(160, 90), (200, 120), (320, 180), (640, 360), (1920, 1080), (90, 160), (3840, 2160)]))
def test_tick_labels_never_overlap_and_stay_inside(lo, span, exponent, size):
    """Any range at any size from 160x90: at least two labels, each inside the image, none closer
    to another than a line of text, none under the title; the ticks lie in the range."""
    scale = 10.0 ** exponent
    lo, hi = lo * scale, (lo + span) * scale
    if not hi - lo >= 1e-6 * max(abs(lo), abs(hi)):  # finer than float32 tells apart: not a range to label
        return
    tf = TransferFunction.from_rgba_ramp([0.0, 1.0], [(0, 0, 1, 0), (1, 0, 0, 1)], 1.0, lo, hi)
    w, h = size
    layout = legend_layout(tf, lo, hi, "temperature", w, h, units="K")
    b = boxes(layout)
    labels, title = b[:-1], b[-1]
    assert len(labels) >= 2
    for x0, y0, x1, y1 in b:
        assert 0 <= x0 and x1 <= w and 0 <= y0 - 1 and y1 <= h
    ys = sorted(y for _, y, _, _ in labels)
    assert all(b2 - a2 >= layout.font_px for a2, b2 in zip(ys, ys[1:]))
    assert all(y0 >= title[3] for _, y0, _, _ in labels)
    assert len(set(t.text for t in layout.texts[:-1])) == len(labels)  # each label its own value


def test_nice_ticks_and_their_digits():
    assert nice_ticks(0.3032, 0.364, 3) == pytest.approx([0.36, 0.34, 0.32])
    assert tick_labels(nice_ticks(0.3032, 0.364, 3)) == ["0.36", "0.34", "0.32"]
    assert tick_labels(nice_ticks(56232.8, 60455.3, 5)) == ["60000", "59000", "58000", "57000"]
    assert tick_labels(nice_ticks(-0.5, 2.5, 7)) == ["2.5", "2.0", "1.5", "1.0", "0.5", "0.0", "-0.5"]
    assert tick_labels(nice_ticks(1e-7, 3e-7, 3)) == ["3e-7", "2e-7", "1e-7"]
    assert tick_labels(nice_ticks(2.0e5, 2.0e5 + 3.0, 4)) == ["200003", "200002", "200001", "200000"]
    assert tick_labels(nice_ticks(2.0e7, 2.0e7 + 30.0, 4)) == ["2.000003e7", "2.000002e7", "2.000001e7", "2.000000e7"]
    assert nice_ticks(0.0, 1.0, 1) == [1.0]  # no room for two: the top value alone


def test_title_and_units_are_shortened_to_fit():
    look, tf = tents()
    layout = legend_layout(tf, look.value_min, look.value_max, "a rather long field name, longer than the picture is wide", 160, 90,
                           units="kg/m^3")
    title = layout.texts[-1].text
    assert title.endswith("\u2026") and text_width(title, layout.font_px) <= 160
    assert fit_text("rho [kg/m^3]", 9, 1000) == "rho [kg/m^3]"
    assert face(7).size == 7 and face(17).size == 16 and face(100).size == 32 and face(3).size == 7


def test_text_is_drawn_where_the_layout_puts_it():
    look, tf = tents()
    layout = legend_layout(tf, look.value_min, look.value_max, "rho", 320, 180, units="kg/m^3")
    mask = text_mask(layout, 320, 180)
    for x0, y0, x1, y1 in boxes(layout):
        inside = mask[int(y0):int(np.ceil(y1)) + 1, int(x0):int(np.ceil(x1)) + 1]
        assert inside.max() > 0.6 and inside.sum() > 10  # each text has ink in its box
    assert mask[:, : int(min(b[0] for b in boxes(layout))) - 1].max() == 0  # and none elsewhere


def test_the_legend_draws_without_pillow(tmp_path):
    """Blender 4.2 bundles no Pillow: the legend (glyphs included) draws with numpy alone."""
    code = ("import sys; sys.modules['PIL'] = None\n"
            "import numpy as np\n"
            "from hovr_blender.engine.legend import draw_legend, legend_layout\n"
            "from hovr_blender.engine.transfer_function import TransferFunction\n"
            "tf = TransferFunction.from_rgba_ramp([0, 1], [(0, 0, 1, 0), (1, 0, 0, 1)], 1.0, 0.0, 1.0)\n"
            "img = draw_legend(np.zeros((90, 160, 4)), legend_layout(tf, 0.0, 1.0, 'u', 160, 90))\n"
            "print(int((img[..., 3] > 0).sum()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert int(out) > 300


def test_draw_legend_changes_only_the_legends_corner():
    look, tf = tents()
    img = np.zeros((90, 160, 4))
    img[..., :3] = first_view.FACTORY_WORLD
    layout = legend_layout(tf, look.value_min, look.value_max, "rho", 160, 90, first_view.FACTORY_WORLD)
    out = draw_legend(img, layout)
    changed = np.abs(out - img).max(axis=2) > 0
    left = int(min(b[0] for b in boxes(layout))) - 2
    assert changed[:, :left].sum() == 0 and changed.sum() > 200
    x0, y0, x1, y1 = layout.bar
    np.testing.assert_allclose(out[y0:y1, x0:x1, :3], np.broadcast_to(layout.bar_rgb[:, None], (y1 - y0, x1 - x0, 3)))


def test_counts_in_words():
    """Issue 40: '1 element', not '1 elements'."""
    from hovr_blender.engine.words import plural

    assert plural(1, "element") == "1 element" and plural(1760, "element") == "1,760 elements"
    assert plural(0, "frame") == "0 frames" and plural(2, "vertex", "vertices") == "2 vertices"
