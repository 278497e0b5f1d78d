"""Host side of a render: upload a VolumeMesh once per device, launch the ray kernel, gather stats."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import RayCamera
from .mesh import VolumeMesh
from .transfer_function import TransferFunction
from .view import RenderOptions, View


@dataclass
class RenderResult:
    rgba: np.ndarray  # (H, W, 4) float32, RGB = C + T*background, A = 1 - T; row 0 at the top
    stats: dict


class Renderer:
    """Holds one mesh uploaded to one Warp device (BVH included); render() many views with it."""

    def __init__(self, mesh: VolumeMesh, device: str = "cpu"):
        raise NotImplementedError

    def render(self, camera: RayCamera, tf: TransferFunction, background, options: RenderOptions) -> RenderResult:
        raise NotImplementedError


def render_view(view: View, mesh: VolumeMesh | None = None) -> RenderResult:
    mesh = view.load_mesh() if mesh is None else mesh
    return Renderer(mesh, view.options.device).render(view.camera, view.transfer_function, view.background, view.options)
