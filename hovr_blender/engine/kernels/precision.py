"""float32 and float64 kernels from one source, and the Precision record the renderer uses.

Warp types every float literal and `float(...)` as float32 and refuses to mix them with
float64, so a float64 kernel cannot simply take other argument types. The float32 kernel
modules are the only source anyone edits; their float64 twins are generated from it in
memory, once per process:

- the module's syntax tree is rewritten (_ToFloat64): inside Warp functions float literals,
  `float(...)` and `wp.pi` become wp.float64, everywhere the float32 vector/matrix types become
  their float64 twins; the BVH query gets float32 ray arguments (Warp's BVH is float32); a
  module-level float literal constant becomes a float64 constant;
- the tolerances that depend on the precision sit in one table, kernels/tolerances.py: each
  NAME is its float32 value and NAME_FLOAT64 beside it the float64 twin's, which the twin takes
  for NAME (every float there needs its partner; a NAME_FLOAT64 anywhere else is an error);
- a float the rewrite cannot convert is an error at generation time, naming it: a module
  constant that Warp code reads but that is computed (`2 * TOL`) rather than written as a
  literal, or one imported from a module that is not twinned; it would stay float32 and mix
  with float64 (or silently keep float32's value);
- the new text is compiled and executed into a module object registered in sys.modules as
  a sibling package of the kernels (TWIN_PACKAGE), so the modules' relative imports resolve
  unchanged: `.args` to the twin of args.py, `..shapes` to the core's own shapes;
- the modules to twin are raycast and what it imports from its package, found in the source's
  relative imports (dependencies first).

Warp reads each function's source to compile it: the generated text is registered in
linecache (where Warp looks first) and is what the module's loader returns (where inspect
falls back). Nothing is written to disk and sys.path is not touched. Warp's module hash covers
that text, so identical source loads the cached binary as the float32 kernels do.

Two alternatives Warp offers were not taken: warp.fem's factories over a scalar type would
turn every literal into `Scalar(1.0)` and every module into a function; a code transformer on
wp.Function rewrites one function's tree, but the functions, structs and constants it names
would still be the float32 module's, and Warp's hash covers the untransformed source (a
changed transform would reuse stale binaries).
"""
from __future__ import annotations

import ast
import importlib.abc
import importlib.util
import linecache
import operator
import sys
import threading
from dataclasses import dataclass
from types import ModuleType

import numpy as np
import warp as wp

from . import raycast

KERNELS_PACKAGE = __package__
TWIN_PACKAGE = KERNELS_PACKAGE.rpartition(".")[0] + "._kernels_float64"
FLOAT64_SUFFIX = "_FLOAT64"  # NAME_FLOAT64 = value: NAME's value in the float64 twin
TOLERANCES = "tolerances"  # the one module of float32 / float64 tolerance pairs


class TwinError(ValueError):
    """A kernel module the float64 generator cannot convert (the message names the constant)."""

_TYPE_MAP = {"float32": "float64", "vec2": "vec2d", "vec3": "vec3d", "vec4": "vec4d", "mat33": "mat33d",
             "vec2f": "vec2d", "vec3f": "vec3d", "vec4f": "vec4d", "mat33f": "mat33d"}


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


def _literal(node):
    """The value of a number literal, signed (`-1.0e30` is a unary minus on 1.0e30), else None."""
    sign = 1
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        sign = -1 if isinstance(node.op, ast.USub) else 1
        node = node.operand
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return sign * node.value
    return None


def _number_constants(tree: ast.Module) -> dict:
    """Module-level `NAME = <number literal>` assignments: {NAME: value}."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name) \
                and _literal(node.value) is not None:
            out[node.targets[0].id] = _literal(node.value)
    return out


def _float_constants(tree: ast.Module) -> dict:
    """Module-level `NAME = <float literal>` assignments: {NAME: value}."""
    return {k: v for k, v in _number_constants(tree).items() if isinstance(v, float)}


class _ToFloat64(ast.NodeTransformer):
    """Rewrites the inside of Warp functions (and the float constants they read)."""

    def __init__(self, float64_values: dict, constants: dict):
        self.in_warp = 0
        self.float64_values = float64_values  # NAME -> its NAME_FLOAT64
        # number constants Warp code may read: this module's and those imported from twinned modules
        self.constants = constants

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
        if self.in_warp and isinstance(f, ast.Attribute) and f.attr == "float64" and len(node.args) == 1 \
                and isinstance(node.args[0], ast.Name) and node.args[0].id in self.constants:
            # the literal, not the name: Warp turns wp.float64(<constant>) into a float64 variable by
            # retyping the constant's own Var, which the name keeps for the whole function, so a
            # later write to the cast's result (m_lo = float(NEWTON_FAILED) ... m_lo = rq[3] in a
            # loop) changed NEWTON_FAILED too
            name = node.args[0].id
            return _f64(ast.Constant(self.float64_values.get(name, self.constants[name])))
        if isinstance(f, ast.Attribute) and f.attr == "bvh_query_next" and len(node.args) == 3:
            # the ray query's max_dist is float32 too
            node.args[2] = ast.Call(func=ast.Attribute(value=ast.Name("wp", ast.Load()), attr="float32", ctx=ast.Load()),
                                    args=[node.args[2]], keywords=[])
        if isinstance(f, ast.Attribute) and f.attr == "bvh_query_ray":
            # start and direction float32; a root (a group's subtree) stays an int
            node.args = [node.args[0]] + [ast.Call(func=ast.Attribute(value=ast.Name("wp", ast.Load()), attr="vec3f",
                                                                      ctx=ast.Load()), args=[a], keywords=[])
                                          for a in node.args[1:3]] + node.args[3:]
        return node

    def visit_Assign(self, node):
        # module-level float constants read inside kernels (INSIDE_TOL = 1.0e-5, NEWTON_FAILED = -1.0e30:
        # left a Python float, a float32 constant, -1e30 in float64 compared above it)
        if not self.in_warp and isinstance(_literal(node.value), float):
            name = node.targets[0].id if isinstance(node.targets[0], ast.Name) else None
            if name is not None and name.endswith(FLOAT64_SUFFIX):
                return None  # its value went to NAME
            value = self.float64_values.get(name, _literal(node.value))
            node.value = _f64(ast.Constant(value))
            return node
        self.generic_visit(node)
        return node


def _float32_spec(name: str):
    return importlib.util.find_spec(f"{KERNELS_PACKAGE}.{name}")


def _float32_tree(name: str) -> ast.Module:
    spec = _float32_spec(name)
    return ast.parse(spec.loader.get_source(spec.name))


def _float64_pairs(name: str, tree: ast.Module) -> dict:
    """{NAME: its NAME_FLOAT64} of module `name`: only the tolerance table has pairs, and there every
    float constant has one (TwinError otherwise)."""
    constants = _float_constants(tree)
    pairs = {}
    for key, value in constants.items():
        if key.endswith(FLOAT64_SUFFIX):
            base = key[: -len(FLOAT64_SUFFIX)]
            if name != TOLERANCES:
                raise TwinError(f"kernels/{name}.py: {key}: float32/float64 pairs belong in kernels/{TOLERANCES}.py")
            if base not in constants:
                raise TwinError(f"kernels/{name}.py: {key} has no float constant {base} beside it")
            pairs[base] = value
    if name == TOLERANCES:
        for key in constants:
            if not key.endswith(FLOAT64_SUFFIX) and key not in pairs:
                raise TwinError(f"kernels/{TOLERANCES}.py: {key} has no {key}{FLOAT64_SUFFIX} beside it")
    return pairs


def _warp_names(tree: ast.Module) -> set:
    """The names read inside the module's Warp functions."""
    names = set()
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef) and _is_warp_decorated(fn):
            names.update(n.id for n in ast.walk(fn) if isinstance(n, ast.Name))
    return names


def _imported_constants(tree: ast.Module, twinned) -> dict:
    """{NAME: value} of the number constants this module imports by name from twinned modules
    (`from .geometry import INSIDE_TOL`), each with the value the float64 twin gives it (read
    from the module's own source: the trees being rewritten change)."""
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module in twinned:
            source = _float32_tree(node.module)
            constants = _number_constants(source)
            pairs = _float64_pairs(node.module, source)
            for alias in node.names:
                if alias.name in constants:
                    out[alias.asname or alias.name] = pairs.get(alias.name, constants[alias.name])
    return out


_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
           ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.Pow: operator.pow}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}


def _arithmetic(node: ast.AST, known: dict):
    """The number an expression of number literals, names in `known` and + - * / // % ** makes;
    ValueError for anything else (a call, attribute, subscript, unknown name, huge power). Walked
    by hand: nothing is given to eval."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
        return node.value
    if isinstance(node, ast.Name) and node.id in known:
        return known[node.id]
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_arithmetic(node.operand, known))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        left, right = _arithmetic(node.left, known), _arithmetic(node.right, known)
        if isinstance(node.op, ast.Pow) and abs(right) > 1024:
            raise ValueError("power too large")
        return _BINARY[type(node.op)](left, right)
    raise ValueError(f"not arithmetic: {ast.dump(node)[:60]}")


def _unconvertible_floats(tree: ast.Module, twinned, imported: dict) -> dict:
    """{NAME: value} of the module-level names bound to a float the rewrite cannot make float64: a
    computed constant (`TWICE = 2 * TOL`, evaluated from the number constants before it) or a float
    imported from a module that has no twin (`from ..shapes import X`)."""
    import importlib

    known = {**imported, **_number_constants(tree)}
    out = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            name = node.targets[0].id
            if name in known:
                continue
            # the package's own kernel source (never a file or view a user gives); only arithmetic
            # on names and numbers counts
            try:
                value = _arithmetic(node.value, known)
            except (ValueError, ArithmeticError):  # not arithmetic on number constants: no number
                continue
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                known[name] = value
                if isinstance(value, float):
                    out[name] = value
        elif isinstance(node, ast.ImportFrom) and node.level >= 1 and not (node.level == 1 and node.module in twinned):
            package = KERNELS_PACKAGE.rsplit(".", node.level - 1)[0] if node.level > 1 else KERNELS_PACKAGE
            module = importlib.import_module(f"{package}.{node.module}" if node.module else package)
            for alias in node.names:
                value = getattr(module, alias.name, None)
                if isinstance(value, float):
                    out[alias.asname or alias.name] = value
    return out


def _check_convertible(name: str, tree: ast.Module, twinned, imported: dict):
    """TwinError naming the first float that Warp code of module `name` reads but the rewrite
    cannot make float64 (_unconvertible_floats): it would stay float32."""
    bad = _unconvertible_floats(tree, twinned, imported)
    for n in sorted(_warp_names(tree) & set(bad)):
        raise TwinError(f"kernels/{name}.py: Warp code reads {n} = {bad[n]!r}, a float the float64 twin cannot convert "
                        f"(write it as a literal in this module, or as a pair in kernels/{TOLERANCES}.py)")


def _to_float64(name: str, tree: ast.Module, twinned) -> str:
    """The float64 twin's source from kernels module `name`'s syntax tree (rewritten in place);
    `twinned`: the names of the modules with a twin (their constants are converted there)."""
    imported = _imported_constants(tree, twinned)
    constants = {**imported, **_number_constants(tree)}
    float64_values = _float64_pairs(name, tree)
    _check_convertible(name, tree, twinned, imported)
    tree = _ToFloat64(float64_values, constants).visit(tree)
    ast.fix_missing_locations(tree)
    return ast.unparse(tree) + "\n"


def float64_source(name: str) -> str:
    """The float64 twin's source of kernels module `name` (e.g. "geometry")."""
    trees = _dependency_order(name)
    return _to_float64(name, trees[name], set(trees))


def _dependency_order(root: str) -> dict:
    """{name: syntax tree} of `root` and the kernels modules it imports (its relative imports of
    level 1, and theirs), dependencies first; each source is parsed once."""
    order = {}

    def visit(name):
        if name in order:
            return
        tree = _float32_tree(name)
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                for dep in [a.name for a in node.names] if node.module is None else [node.module]:
                    visit(dep)
        order[name] = tree

    visit(root)
    return order


def float64_modules(root: str = "raycast") -> tuple:
    """The kernels modules with a float64 twin: `root` and what it imports, dependencies first."""
    return tuple(_dependency_order(root))


class _TwinLoader(importlib.abc.InspectLoader):
    """Executes a float64 twin from its generated source, and gives that source to inspect."""

    def __init__(self, source: str, filename: str):
        self.source = source
        self.filename = filename

    def get_source(self, fullname):
        return self.source

    def exec_module(self, module):
        exec(compile(self.source, self.filename, "exec"), module.__dict__)


def _load_twin(name: str, source: str) -> ModuleType:
    fullname = f"{TWIN_PACKAGE}.{name}"
    # not a path anything could exist at (linecache would read that file instead)
    filename = f"{_float32_spec(name).origin} (float64)"
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    loader = _TwinLoader(source, filename)
    spec = importlib.util.spec_from_loader(fullname, loader, origin=filename)
    module = importlib.util.module_from_spec(spec)
    module.__file__ = filename  # inspect finds a function's module by its file
    sys.modules[fullname] = module
    try:
        loader.exec_module(module)
    except BaseException:
        del sys.modules[fullname]
        raise
    setattr(sys.modules[TWIN_PACKAGE], name, module)
    return module


def _float64_kernels() -> ModuleType:
    """The float64 twin of raycast (with the twins of the modules it imports)."""
    if TWIN_PACKAGE not in sys.modules:
        package = ModuleType(TWIN_PACKAGE, "float64 twins of the kernels (kernels/precision.py)")
        package.__path__ = []
        sys.modules[TWIN_PACKAGE] = package
    trees = _dependency_order("raycast")
    for name, tree in trees.items():
        if f"{TWIN_PACKAGE}.{name}" not in sys.modules:
            _load_twin(name, _to_float64(name, tree, set(trees)))
    return sys.modules[f"{TWIN_PACKAGE}.raycast"]


_PRECISIONS = {}
_BUILD_LOCK = threading.Lock()  # the Blender add-on may render from more than one thread


@dataclass(frozen=True)
class Precision:
    """What the host side needs of one kernel precision: its kernels and their types."""

    name: str  # "float32" / "float64" (RenderOptions.precision)
    scalar: type  # Warp scalar
    vec2: type
    vec3: type
    vec4: type
    mat33: type
    dtype: np.dtype  # numpy twin of scalar
    eps: float  # dtype's machine epsilon
    kernels: ModuleType  # the raycast module of this precision

    @staticmethod
    def named(name: str) -> Precision:
        """float32: the package's own kernels; float64: their twins, generated on first use."""
        with _BUILD_LOCK:
            if name not in _PRECISIONS:
                if name == "float32":
                    _PRECISIONS[name] = Precision(name, wp.float32, wp.vec2, wp.vec3, wp.vec4, wp.mat33,
                                                  np.dtype(np.float32), float(np.finfo(np.float32).eps), raycast)
                elif name == "float64":
                    _PRECISIONS[name] = Precision(name, wp.float64, wp.vec2d, wp.vec3d, wp.vec4d, wp.mat33d,
                                                  np.dtype(np.float64), float(np.finfo(np.float64).eps),
                                                  _float64_kernels())
                else:
                    raise ValueError(f"precision must be 'float32' or 'float64', not {name!r}")
            return _PRECISIONS[name]
