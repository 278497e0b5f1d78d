"""What the add-on needs from Blender's Python beyond Blender itself, checked when it is enabled
(no bpy here: tested without Blender; nothing is imported, only looked up): Warp, and the
packages the registered data formats declare (io/formats.py).

The platform zips (scripts/build_extension.py --wheels) bundle every one of these as wheels;
the plain zip and a legacy add-on install rely on Blender's Python already having them.
"""
from __future__ import annotations

import importlib.util
import sys

from ..io import formats

# the Warp the add-on is built and tested with, and whose compiled kernels the zips ship (its APIs
# move fast): the one pin of it (pyproject.toml and scripts/build_extension.py agree: tests/ui/test_framing.py)
WARP_VERSION = "1.19.0"
RENDERING = ("warp", "warp-lang", "rendering (the ray kernels)")


def requirement(package: str) -> str:
    """What pip installs of `package`: Warp at the version the add-on needs, the others as they come."""
    return f"{package}=={WARP_VERSION}" if package == "warp-lang" else package


def dependencies() -> list[tuple[str, str, str, bool]]:
    """(module, pip package, what needs it, required for rendering at all)."""
    return [(*RENDERING, True)] + [(*p, False) for p in formats.packages()]


def missing(find_spec=importlib.util.find_spec) -> list[tuple[str, str, str, bool]]:
    """The dependencies Blender's Python cannot import."""
    out = []
    for module, package, purpose, required in dependencies():
        try:
            found = find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            out.append((module, package, purpose, required))
    return out


def report_lines(absent, python: str = sys.executable) -> list[str]:
    """What to tell the user about missing dependencies, and what to do; [] when none is missing."""
    if not absent:
        return []
    lines = []
    for _module, package, purpose, required in absent:
        lines.append(f"HOVR: {package} is missing: {purpose} {'will not work' if required else 'is unavailable'}")
    packages = " ".join(requirement(p) for _m, p, _w, _r in absent)
    lines.append("HOVR: install the extension zip built for your platform (it bundles these), or run: "
                 f"\"{python}\" -m pip install {packages}")
    return lines
