"""What a render gives back and how it fails: RenderResult, and the errors every renderer raises
(RenderError; SegmentCacheError for a segment cache). No Warp here: the callers that only read
results (the CLI's outputs, Blender's passes, the bench) import this without the kernels."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class RenderError(RuntimeError):
    """A render that could not run (device unavailable, out of memory); the message says why."""


class SegmentCacheError(RenderError):
    """A segment cache that cannot be built (out of device memory, beyond 32-bit offsets) or
    that does not hold this view's segments (traced for another camera, field or frame)."""


@dataclass
class RenderResult:
    rgba: np.ndarray  # (H, W, 4) float32, RGB = C + T*background, A = 1 - T; row 0 at the top
    stats: dict
    depth: np.ndarray | None = None  # (H, W) t where 1 - T first reaches 0.5, else the far value
    error: np.ndarray | None = None  # (H, W) sum of the Gauss-Kronrod panel error estimates
    cancelled: bool = False
    # (H,) the work each row took (ray_cost of its pixels' counters): what a render split over
    # several devices balances its rows by (engine/multi_device.py)
    row_cost: np.ndarray | None = None
    # (rows, W, NUM_STATS) int32: every ray's counters, with render(ray_counts=True) (work_counts)
    ray_counts: np.ndarray | None = None
    opaque_hits: object = None  # engine/opaque.OpaqueHits: where opaque meshes stopped the rays


FLOAT32_LIMIT = 1.0e30  # beyond this, products in the kernel overflow float32 (max 3.4e38)


def check_float32_range(what: str, values, offsets):
    """float32 kernels need data well inside float32's range: name the first element that is not."""
    if values is None or values.size == 0:
        return
    big = np.abs(values.reshape(len(values), -1)).max(axis=1) > FLOAT32_LIMIT
    if big.any():
        e = int(np.searchsorted(offsets, int(np.argmax(big)), side="right") - 1)
        raise RenderError(f"element {e}: {what} exceed the float32 kernels' range (|value| > {FLOAT32_LIMIT:.0e}); "
                          f"render with precision float64 or rescale the data")
