"""Writing render outputs (render contract §5). A path is opened by limits.open_output: never
through a link, never a FIFO or device."""
from __future__ import annotations

import json

import numpy as np

from .limits import open_output


def _is_path(target) -> bool:
    return isinstance(target, (str, bytes)) or hasattr(target, "__fspath__")


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def to_png_bytes_rgba(rgba: np.ndarray) -> np.ndarray:
    """(H, W, 4) linear RGBA -> uint8 sRGB RGB + linear alpha."""
    out = np.empty(rgba.shape, dtype=np.uint8)
    out[..., :3] = np.round(srgb_encode(rgba[..., :3]) * 255.0)
    out[..., 3] = np.round(np.clip(rgba[..., 3], 0.0, 1.0) * 255.0)
    return out


PNG_BACKGROUNDS = ("view", "transparent")  # or an (r, g, b) colour


def png_pixels(rgba: np.ndarray, background, over="view") -> np.ndarray:
    """(H, W, 4) linear RGBA to encode as a PNG, from the contract's image (RGB = C + T background,
    alpha = 1 - T, T the transmittance): over "view", the image flattened on the view's background
    (alpha 1: what the .npy's RGB shows); over an (r, g, b), flattened on that colour instead
    (C + T colour); "transparent", the volume alone with straight alpha (C / (1 - T), 1 - T), which
    image viewers composite over their own background as PNG intends."""
    rgba = np.asarray(rgba, dtype=np.float64)
    transmittance = 1.0 - rgba[..., 3:4]
    emitted = rgba[..., :3] - transmittance * np.asarray(background, dtype=np.float64)[:3]
    out = np.empty_like(rgba)
    if isinstance(over, str) and over == "transparent":
        alpha = rgba[..., 3:4]
        out[..., :3] = np.where(alpha > 0, emitted / np.maximum(alpha, 1e-12), 0.0)
        out[..., 3:] = alpha
        return out
    if isinstance(over, str) and over == "view":
        out[..., :3] = rgba[..., :3]
    elif isinstance(over, str):
        raise ValueError(f"PNG background must be one of {', '.join(PNG_BACKGROUNDS)} or an r,g,b colour, "
                         f"not {over!r}")
    else:
        out[..., :3] = emitted + transmittance * np.asarray(over, dtype=np.float64)[:3]
    out[..., 3] = 1.0
    return out


def write_png(target, rgba: np.ndarray, alpha: bool = True) -> None:
    """target: a path or a binary file object."""
    from PIL import Image

    if _is_path(target):
        with open_output(target, "PNG") as fh:
            return write_png(fh, rgba, alpha)
    px = to_png_bytes_rgba(np.asarray(rgba, dtype=np.float64))
    Image.fromarray(px if alpha else px[..., :3], "RGBA" if alpha else "RGB").save(target, format="PNG")


def write_npy(target, rgba: np.ndarray) -> None:
    """target: a binary file object, or a path, which is written as given (np.save would add
    .npy to a path without it)."""
    if _is_path(target):
        with open_output(target, ".npy") as fh:
            return write_npy(fh, rgba)
    np.save(target, np.ascontiguousarray(rgba, dtype=np.float32), allow_pickle=False)


def write_json(target, obj: dict) -> None:
    """target: a path or a binary file object."""
    text = json.dumps(obj, indent=2, sort_keys=True) + "\n"
    if _is_path(target):
        with open_output(target, "JSON") as fh:
            fh.write(text.encode("utf-8"))
    else:
        target.write(text.encode("utf-8"))
