"""What a render compiles and loads: the KernelVariant a mesh's walk kernels are specialised to,
the kernels a render, a trace and a shade launch (the KernelTable of kernels/raycast.py, handles
named at each launch), and their loading: the add-on's shipped binaries where they match this
source (shipped_kernels.py), else compiled on first use, the modules side by side."""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import warp as wp

from .devices import resolve_device
from .kernels.element import static_modes
from .kernels.precision import Precision
from .shipped_kernels import LoadReport, load_shipped

# threads compiling kernel modules at once on first use (Warp's NVRTC / LLVM compile one module
# per thread); HOVR_COMPILE_WORKERS=1 compiles them one after another
COMPILE_WORKERS = max(1, int(os.environ.get("HOVR_COMPILE_WORKERS", "0") or 0) or min(8, os.cpu_count() or 1))


@dataclass(frozen=True)
class KernelVariant:
    """What the walk kernels of a render are specialised to at compile time
    (kernels/raycast.walk_kernels): curved elements (Newton location, curved sampling) or affine
    only; `modes` N > 0 evaluates hexahedra and prisms of N modes unrolled (0: any); `derived`
    samples a derived field. `key` names it as warp.fem names its specialised kernels, and as
    scripts/build_extension.py's --kernel-variants does: "affine:3", "curved:0", "curved:0:derived"."""

    curved: bool = False
    modes: int = 0
    derived: bool = False

    @property
    def key(self) -> str:
        return f"{'curved' if self.curved else 'affine'}:{int(self.modes)}" + (":derived" if self.derived else "")

    @classmethod
    def from_key(cls, key: str) -> "KernelVariant":
        kind, _, rest = key.partition(":")
        modes, _, derived = rest.partition(":")
        if kind not in ("affine", "curved") or not modes.isdigit() or derived not in ("", "derived"):
            raise ValueError(f"{key!r} is not a kernel variant (affine:N or curved:N, then :derived or nothing)")
        return cls(kind == "curved", int(modes), derived == "derived")

    def __str__(self) -> str:
        return self.key


def kernel_variant(meshes) -> KernelVariant:
    """What the walk kernels of a render of `meshes` (one mesh, or several merged by
    mesh.concatenate) are specialised to."""
    meshes = list(meshes)
    curved = any(m.affine is not None and not m.affine.all() for m in meshes)
    derived = any(m.derived is not None for m in meshes)
    modes = 0 if derived else static_modes(np.concatenate([m.shape for m in meshes]),
                                           np.concatenate([m.modes for m in meshes]))
    return KernelVariant(bool(curved), int(modes), bool(derived))


def kernel_table(variant: KernelVariant, precision: str = "float32", isosurfaces: bool = False):
    """The KernelTable (kernels/raycast.py) of `variant` in `precision`; with `isosurfaces`,
    integrate and shade in their variant for isosurfaces and planes (contract §7)."""
    return Precision.named(precision).kernels.kernel_table(variant.curved, variant.modes, variant.derived,
                                                           isosurfaces=isosurfaces)


def render_kernels(variant: KernelVariant, precision: str = "float32", isosurfaces: bool = False) -> list:
    """Every kernel Renderer.render launches for a mesh of `variant` (with `isosurfaces`: a look
    with isosurfaces or planes)."""
    return list(kernel_table(variant, precision, isosurfaces).render_kernels())


def session_kernels(variant: KernelVariant, precision: str = "float32", surfaces: bool = False,
                    isosurfaces: bool = False) -> list:
    """Every kernel an interactive session launches for a mesh of `variant` in `precision`: a
    render's (render_kernels), a trace's and a shade's (F12 traces from its second render, a
    transfer-function edit shades), and with `surfaces` the opaque meshes' cast; with
    `isosurfaces`, integrate and shade in their variant for isosurfaces and planes. What Blender
    loads before its first render, and what the add-on ships compiled (scripts/build_extension.py)."""
    table = kernel_table(variant, precision, isosurfaces)
    kernels = list(dict.fromkeys(table.render_kernels() + table.trace_kernels() + table.shade_kernels()))
    if surfaces:
        from .kernels import opaque_cast

        kernels.append(opaque_cast.cast_opaque)
    return kernels


def load_kernels(variant: KernelVariant, device: str = "cpu", precision: str = "float32",
                 surfaces: bool = False, isosurfaces: bool = False) -> LoadReport:
    """Load the session_kernels of `variant` in `precision` on `device`: from the add-on's
    shipped binaries where they were built from this source, else read from Warp's kernel cache on
    disk or compiled on first use (tens of seconds on a CPU). The modules compile side by side
    in worker threads joined before it returns."""
    return load_modules(session_kernels(variant, precision, surfaces, isosurfaces), resolve_device(device))


def load_modules(kernels, device: str) -> LoadReport:
    """Load the modules of `kernels` on `device`: the shipped binaries of their source where the
    add-on has them (shipped_kernels.py), the rest read from Warp's disk cache or compiled (first
    use), side by side (on first use the largest module's compile is the wait). The report says
    which was which."""
    report = load_shipped(kernels, device)
    modules = list({id(k.module): k.module for k in kernels}.values())
    workers = min(len(modules), COMPILE_WORKERS) if COMPILE_WORKERS > 1 else 0
    wp.force_load(device=device, modules=modules, max_workers=workers)
    return report
