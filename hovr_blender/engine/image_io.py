"""Writing render outputs (render contract §5)."""
from __future__ import annotations

import json

import numpy as np


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def to_png_bytes_rgba(rgba: np.ndarray) -> np.ndarray:
    """(H, W, 4) linear RGBA -> uint8 sRGB RGB + linear alpha."""
    out = np.empty(rgba.shape, dtype=np.uint8)
    out[..., :3] = np.round(srgb_encode(rgba[..., :3]) * 255.0)
    out[..., 3] = np.round(np.clip(rgba[..., 3], 0.0, 1.0) * 255.0)
    return out


def write_png(path: str, rgba: np.ndarray, alpha: bool = True) -> None:
    from PIL import Image

    px = to_png_bytes_rgba(np.asarray(rgba, dtype=np.float64))
    Image.fromarray(px if alpha else px[..., :3], "RGBA" if alpha else "RGB").save(path)


def write_npy(path: str, rgba: np.ndarray) -> None:
    np.save(path, np.ascontiguousarray(rgba, dtype=np.float32), allow_pickle=False)


def write_json(path: str, obj: dict) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(obj, fh, indent=2, sort_keys=True)
        fh.write("\n")
