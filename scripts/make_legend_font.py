"""The legend's glyphs (hovr_blender/engine/legend_font.npz), rasterised once from DejaVu Sans Condensed
with Pillow and FreeType, so that the legend draws text with numpy alone wherever it runs: the CLI,
F12 on Blender 4.2 (no Pillow there), 4.5 and 5.0 (engine/legend_text.py).

    python -m scripts.make_legend_font [--font /usr/share/fonts/truetype/dejavu/DejaVuSansCondensed.ttf]

Every size in SIZES is rasterised with FreeType's hinting at that size (none is scaled from
another). Each size holds one atlas row of glyph coverage (uint8) and per glyph its place in the
atlas, its width, its left bearing and its advance (pixels). The font's licence (Bitstream Vera,
DejaVu's changes public domain) travels with the file (legend_font.LICENSE).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "hovr_blender" / "engine" / "legend_font.npz"
FONT = "/usr/share/fonts/truetype/dejavu/DejaVuSansCondensed.ttf"
SIZES = tuple(range(7, 17)) + (18, 20, 22, 24, 26, 28, 32)
# printable ASCII and the symbols units and field names use most
CHARS = "".join(chr(c) for c in range(32, 127)) + "°µ²³·−…×±ΔΩαβγδεζηθκλμνξπρστφχψω∇"


def rasterise(font_path: str, size: int):
    """(atlas (line, width) uint8, meta (n, 4) float32: atlas x, width, left bearing, advance, ascent)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.truetype(font_path, size)
    ascent, descent = font.getmetrics()
    line = ascent + descent
    glyphs, meta, x = [], [], 0
    for ch in CHARS:
        left, _, right, _ = font.getbbox(ch, anchor="ls")
        left, right = min(left, 0), max(right, 1)
        width = right - left
        img = Image.new("L", (width, line), 0)
        ImageDraw.Draw(img).text((-left, ascent), ch, fill=255, font=font, anchor="ls")
        glyphs.append(np.asarray(img, dtype=np.uint8))
        meta.append((x, width, left, font.getlength(ch)))
        x += width
    return np.concatenate(glyphs, axis=1), np.asarray(meta, dtype=np.float32), ascent


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m scripts.make_legend_font")
    ap.add_argument("--font", default=FONT)
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    arrays = {"chars": np.array([ord(c) for c in CHARS], dtype=np.int32), "sizes": np.array(SIZES, dtype=np.int32)}
    ascents = []
    for size in SIZES:
        atlas, meta, ascent = rasterise(args.font, size)
        arrays[f"atlas_{size}"], arrays[f"meta_{size}"] = atlas, meta
        ascents.append(ascent)
    arrays["ascents"] = np.array(ascents, dtype=np.int32)
    np.savez_compressed(args.out, **arrays)
    print(f"make_legend_font: {args.out} ({Path(args.out).stat().st_size:,} bytes, {len(SIZES)} sizes, "
          f"{len(CHARS)} glyphs)")


if __name__ == "__main__":
    main()
