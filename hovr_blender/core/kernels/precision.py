"""float64 kernels from the float32 source: one kernel text, two precisions.

Warp types every float literal and `float(...)` as float32 and refuses to mix them with
float64, so a float64 kernel cannot simply take other argument types. Instead the
kernel modules (_MODULES) are rewritten once, mechanically, on their syntax
tree: float literals and `float(...)` become wp.float64, the float32 vector/matrix types
their float64 twins; the BVH query (Warp's BVH is float32) gets float32 ray arguments.
The result is written to a cache folder as a package (Warp compiles from source files)
and imported. The float32 files stay the only source anyone edits.
"""
from __future__ import annotations

import ast
import hashlib
import importlib
import os
import sys
from pathlib import Path

_TYPE_MAP = {"float32": "float64", "vec2": "vec2d", "vec3": "vec3d", "vec4": "vec4d", "mat33": "mat33d",
             "vec2f": "vec2d", "vec3f": "vec3d", "vec4f": "vec4d", "mat33f": "mat33d"}
_MODULES = ("args", "element", "geometry", "restriction", "quadrature", "raycast")
# float32-sized tolerances of raycast.py, retightened for float64 (same names, new values)
FLOAT64_CONSTANTS = {"CLIP_TOL": 1.0e-12, "INSIDE_TOL": 1.0e-11, "NEWTON_STEP_TOL": 1.0e-8, "ROOT_RTOL": 1.0e-13,
                     "STRETCH_RTOL": 1.0e-11, "CURVED_TAIL_RTOL": 1.0e-12}
_loaded = {}


def _f64(node):
    return ast.Call(func=ast.Attribute(value=ast.Name("wp", ast.Load()), attr="float64", ctx=ast.Load()),
                    args=[node], keywords=[])


def _is_warp_decorated(fn: ast.FunctionDef) -> bool:
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name) and target.value.id == "wp" \
                and target.attr in ("func", "kernel", "struct"):
            return True
    return False


class _ToFloat64(ast.NodeTransformer):
    """Rewrites the inside of Warp functions (and float constants they read)."""

    def __init__(self):
        self.in_warp = 0

    def visit_FunctionDef(self, node):
        warp = _is_warp_decorated(node)
        self.in_warp += warp
        if warp:
            node.decorator_list = [self.visit(d) for d in node.decorator_list]
            node.args = self.visit(node.args)
            node.returns = self.visit(node.returns) if node.returns else None
            node.body = [self.visit(b) for b in node.body]
        else:
            self.generic_visit(node)
        self.in_warp -= warp
        return node

    def visit_ClassDef(self, node):  # @wp.struct classes: their annotations
        self.generic_visit(node)
        return node

    def visit_Attribute(self, node):
        self.generic_visit(node)
        if isinstance(node.value, ast.Name) and node.value.id == "wp":
            if node.attr in _TYPE_MAP:
                node.attr = _TYPE_MAP[node.attr]
            elif node.attr == "pi" and self.in_warp:
                return _f64(node)
        return node

    def visit_Name(self, node):
        if self.in_warp and node.id == "float":
            return ast.Attribute(value=ast.Name("wp", ast.Load()), attr="float64", ctx=node.ctx)
        return node

    def visit_Constant(self, node):
        if self.in_warp and isinstance(node.value, float):
            return _f64(node)
        return node

    def visit_Call(self, node):
        self.generic_visit(node)
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr == "bvh_query_next" and len(node.args) == 3:
            # the ray query's max_dist is float32 too
            node.args[2] = ast.Call(func=ast.Attribute(value=ast.Name("wp", ast.Load()), attr="float32", ctx=ast.Load()),
                                    args=[node.args[2]], keywords=[])
        if isinstance(f, ast.Attribute) and f.attr == "bvh_query_ray":
            node.args = [node.args[0]] + [ast.Call(func=ast.Attribute(value=ast.Name("wp", ast.Load()), attr="vec3f",
                                                                      ctx=ast.Load()), args=[a], keywords=[])
                                          for a in node.args[1:]]
        return node

    def visit_ImportFrom(self, node):
        # the twin package sits outside hovr_blender: imports from above the kernels become absolute
        if node.level >= 2:
            node.module = "hovr_blender." + "core" + (f".{node.module}" if node.module else "")
            node.level = 0
        return node

    def visit_Assign(self, node):
        # module-level float constants read inside kernels (INSIDE_TOL = 1.0e-5)
        if not self.in_warp and isinstance(node.value, ast.Constant) and isinstance(node.value.value, float):
            name = node.targets[0].id if isinstance(node.targets[0], ast.Name) else None
            value = FLOAT64_CONSTANTS.get(name, node.value.value)
            node.value = _f64(ast.Constant(value))
            return node
        self.generic_visit(node)
        return node


def float64_source(path: Path) -> str:
    tree = ast.parse(path.read_text())
    tree = _ToFloat64().visit(tree)
    ast.fix_missing_locations(tree)
    return "# generated by hovr_blender/core/kernels/precision.py from " + path.name + "; do not edit\n" \
        + ast.unparse(tree) + "\n"


def _cache_dir() -> Path:
    base = os.environ.get("HOVR_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "hovr_blender")
    return Path(base)


def kernels(precision: str = "float32"):
    """The raycast module for `precision`: the package's own for float32, the generated
    float64 twin otherwise (built on first use, cached by the source's hash)."""
    from . import raycast

    if precision == "float32":
        return raycast
    if precision != "float64":
        raise ValueError(f"precision must be 'float32' or 'float64', not {precision!r}")
    here = Path(__file__).resolve().parent
    sources = {m: (here / f"{m}.py") for m in _MODULES}
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in sources.values())
                            + Path(__file__).read_bytes()).hexdigest()[:12]
    if digest in _loaded:
        return _loaded[digest]
    pkg = f"hovr_f64_{digest}"
    root = _cache_dir() / "kernels"
    target = root / pkg
    if not (target / "raycast.py").exists():
        tmp = root / f"{pkg}.tmp{os.getpid()}"
        tmp.mkdir(parents=True, exist_ok=True)
        (tmp / "__init__.py").write_text("")
        for m, p in sources.items():
            (tmp / f"{m}.py").write_text(float64_source(p))
        try:
            os.replace(tmp, target)
        except OSError:  # another process won the race: use its copy
            import shutil

            shutil.rmtree(tmp, ignore_errors=True)
    if str(root) not in sys.path:
        sys.path.append(str(root))
    mod = importlib.import_module(f"{pkg}.raycast")
    _loaded[digest] = mod
    return mod
