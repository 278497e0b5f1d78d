"""The layers hold: LAYERS below is who may import whom, for every folder of the package, and
docs/architecture.md's table is made from it (test_the_architecture_doc_states_the_layers); the
sources' imports are checked against it row by row, and no layer's modules import one another in
a loop; hovr_blender.engine imports no reader and no
Blender module even at run time, the add-on package imports without bpy, and no module of the
package edits sys.path.

Two independent checks of the engine: every engine module is imported in a fresh Python whose
import system refuses bpy, gpu, blf, hovr_blender.io and hovr_blender.ui (a module that
catches the refusal still fails the test: every attempt is recorded); and the sources are read
(an AST walk over every import statement, those inside functions included), which also sees
imports no module runs at import time.
"""
import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from ..helpers import REPO

PACKAGE = REPO / "hovr_blender"
ENGINE = PACKAGE / "engine"
BLENDER_MODULES = ("bpy", "gpu", "blf", "bmesh", "mathutils", "bpy_extras", "addon_utils")
ABOVE_ENGINE = ("hovr_blender.io", "hovr_blender.ui", "hovr_blender.cli")
BLOCKED_AT_RUNTIME = ("bpy", "gpu", "blf", "hovr_blender.io", "hovr_blender.ui")


_IMPORT_EVERY_ENGINE_MODULE = r"""
import importlib, importlib.abc, json, pkgutil, sys

BLOCKED = tuple(json.loads(sys.argv[1]))
touched = []

class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if any(name == b or name.startswith(b + ".") for b in BLOCKED):
            touched.append((name, importer()))
            raise ImportError(f"layering test: {name} may not be imported by hovr_blender.engine")
        return None

def importer():
    f = sys._getframe(2)
    while f is not None:
        mod = f.f_globals.get("__name__", "")
        if mod.startswith("hovr_blender") and not mod.startswith("importlib"):
            return mod
        f = f.f_back
    return "?"

sys.meta_path.insert(0, Refuse())
import hovr_blender.engine as engine

names = [engine.__name__] + [m.name for m in pkgutil.walk_packages(engine.__path__, engine.__name__ + ".")]
failed = {}
for name in names:
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed[name] = f"{type(exc).__name__}: {exc}"
loaded = sorted(m for m in sys.modules if any(m == b or m.startswith(b + ".") for b in BLOCKED))
print(json.dumps({"modules": names, "touched": touched, "failed": failed, "loaded": loaded}))
"""


def _run(code, *args):
    proc = subprocess.run([sys.executable, "-c", code, *args], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout


def test_every_core_module_imports_with_readers_and_blender_blocked():
    out = json.loads(_run(_IMPORT_EVERY_ENGINE_MODULE, json.dumps(BLOCKED_AT_RUNTIME)).splitlines()[-1])
    want = {"hovr_blender.engine." + ".".join(p.relative_to(ENGINE).with_suffix("").parts)
            for p in ENGINE.rglob("*.py") if p.name != "__init__.py"}
    assert want <= set(out["modules"]), f"not walked: {sorted(want - set(out['modules']))}"
    assert out["touched"] == [], f"hovr_blender.engine tried to import (module, importer): {out['touched']}"
    assert out["failed"] == {}, out["failed"]
    assert out["loaded"] == []


def test_addon_package_and_its_bpy_free_modules_import_without_bpy():
    """The add-on's package imports bpy only inside register(): the package, the Blender layer's
    bpy-free helpers (camera and scene conversions), the renderer and a reader load without it."""
    code = (
        "import sys, hovr_blender, hovr_blender.ui.blender_camera, hovr_blender.ui.scene, "
        "hovr_blender.ui.framing, hovr_blender.ui.viewport, hovr_blender.ui.dependencies, "
        "hovr_blender.ui.jobs, "
        "hovr_blender.engine.renderer, hovr_blender.io.builtin, hovr_blender.ui; "
        "assert 'bpy' not in sys.modules, 'bpy imported'; "
        "assert callable(hovr_blender.register) and hovr_blender.bl_info['name'] == 'HOVR'"
    )
    _run(code)


# ----------------------------------------------------------------------------- the sources


def _modules(root: Path):
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent)
        parts = rel.with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        package = ".".join(parts[:-1])
        yield path, name, package, ast.parse(path.read_text(), str(path))


def _imported_names(tree, package):
    """(line, absolute module name) of every import statement, relative ones resolved."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            yield node.lineno, mod
            for alias in node.names:  # "from .. import io" names a module too
                yield node.lineno, f"{mod}.{alias.name}"


def _under(name, prefixes):
    return any(name == p or name.startswith(p + ".") for p in prefixes)


# ------------------------------------------------------------------------------ the layer table
# (layer, its modules, what of the package it may import, what else it may import beyond the
# standard library, which layers of the package may import it). A "may import" entry is a layer
# or, written as a module, that module alone. docs/architecture.md's table says the same.
BLENDER = ("bpy", "bpy_extras", "blf", "gpu", "gpu_extras", "imbuf", "mathutils")
LAYERS = (
    ("engine", "hovr_blender.engine", ("engine/kernels",), ("numpy", "warp", "PIL"),
     ("engine/kernels", "io", "ui", "distributed", "cli", "audit")),
    ("engine/kernels", "hovr_blender.engine.kernels", ("hovr_blender.engine.shapes", "hovr_blender.engine.methods"),
     ("numpy", "warp"), ("engine", "audit")),
    ("io", "hovr_blender.io", ("engine",), ("numpy", "h5py", "defusedxml", "psutil"),
     ("ui", "distributed", "cli", "audit")),
    ("ui", "hovr_blender.ui", ("engine", "io", "package"), ("numpy",) + BLENDER, ("package",)),
    ("distributed", "hovr_blender.distributed", ("engine", "io"), ("numpy", "distributed", "dask"), ("cli",)),
    ("cli", "hovr_blender.cli", ("engine", "io", "distributed"), ("distributed",), ()),
    ("audit", "hovr_blender.audit", ("engine", "engine/kernels", "io"), ("numpy", "warp", "vtk", "vtkmodules"), ()),
    ("package", "hovr_blender", ("ui",), (), ("ui",)),
)


def _layer_of(module: str):
    """The row of LAYERS a module of the package belongs to (the most specific), else None."""
    rows = [row for row in LAYERS if module == row[1] or module.startswith(row[1] + ".")]
    if module.startswith("hovr_blender.engine._kernels_float64"):  # the kernels' float64 twins
        return next(row for row in LAYERS if row[0] == "engine/kernels")
    return max(rows, key=lambda row: len(row[1])) if rows else None


def _package_imports():
    """(importing module's row, path, line, imported module) of every import in the package."""
    for path, name, package, tree in _modules(PACKAGE):
        row = _layer_of(name if path.name != "__init__.py" or name != "hovr_blender" else "hovr_blender")
        for line, mod in _imported_names(tree, package):
            yield row, path, line, mod


def test_every_folder_of_the_package_has_its_row():
    folders = {f"hovr_blender.{p.name}" for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    folders |= {"hovr_blender.engine.kernels", "hovr_blender.cli", "hovr_blender"}
    assert folders == {row[1] for row in LAYERS}


def test_each_layer_imports_only_what_its_row_allows():
    stdlib = set(sys.stdlib_module_names) | {"__future__"}
    bad = []
    for row, path, line, mod in _package_imports():
        if mod.startswith("hovr_blender"):
            target = _layer_of(mod)
            allowed = target is row or target[0] in row[2] or any(mod == m or mod.startswith(m + ".") for m in row[2])
            # "from . import x" of a package also names the package itself: that is no import of it
            if not allowed and not (mod == target[1] and target[1] in ("hovr_blender", row[1])):
                bad.append(f"{path.relative_to(REPO)}:{line}: {mod} ({row[0]} may import {', '.join(row[2])})")
        elif mod.split(".")[0] not in stdlib and mod.split(".")[0] not in row[3]:
            bad.append(f"{path.relative_to(REPO)}:{line}: {mod} ({row[0]} may import {', '.join(row[3]) or 'none'})")
    assert bad == [], "imports the layer table (LAYERS) does not allow:\n" + "\n".join(bad)


def test_each_layer_is_imported_only_by_the_rows_that_may():
    bad = []
    for row, path, line, mod in _package_imports():
        target = _layer_of(mod) if mod.startswith("hovr_blender") else None
        if target is None or target is row or (mod == target[1] and target[0] == "package"):
            continue
        if row[0] not in target[4]:
            bad.append(f"{path.relative_to(REPO)}:{line}: {row[0]} imports {mod} ({target[0]} is imported by "
                       f"{', '.join(target[4]) or 'nothing in the package'} only)")
    assert bad == [], "\n".join(bad)


def _imported_modules(tree, package, modules):
    """The modules of `modules` an import statement names (those inside functions too): `from . import
    x` names the module x where there is one, else the package."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules:
                    yield alias.name
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")[: len(package.split(".")) - (node.level - 1)] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module
            for alias in node.names:
                name = f"{mod}.{alias.name}" if f"{mod}.{alias.name}" in modules else mod
                if name in modules:
                    yield name


def _layer_graph() -> dict:
    """{module: the modules of its own layer (LAYERS' row) it imports}."""
    modules = {name: (package, tree) for _, name, package, tree in _modules(PACKAGE)}
    return {name: {m for m in _imported_modules(tree, package, modules) if m != name and _layer_of(m) is _layer_of(name)}
            for name, (package, tree) in modules.items()}


def circles(graph: dict) -> list:
    """The import circles of `graph` ({module: modules it imports}): each set of modules that reach
    one another (a strongly connected component of more than one), sorted (Tarjan's algorithm)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def test_no_layer_imports_itself_in_a_circle():
    """Within a layer, no modules import one another in a loop (imports inside functions count: a
    circle hidden behind a function-level import is still one). What two modules both need goes
    to a module below them (engine/mesh_base.py, io/reader_protocol.py, io/volume_source.py,
    ui/snapshot.py)."""
    found = circles(_layer_graph())
    assert found == [], "modules of one layer that import one another in a loop (move what they share below " \
                        "them):\n" + "\n".join(" <-> ".join(c) for c in found)


def test_the_circle_check_sees_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": set()}) == []
    # the package's own graph with one import inside a function added (mesh_base's of mesh)
    graph = _layer_graph()
    graph["hovr_blender.engine.mesh_base"] = graph["hovr_blender.engine.mesh_base"] | {"hovr_blender.engine.mesh"}
    assert ["hovr_blender.engine.mesh", "hovr_blender.engine.mesh_base"] in circles(graph)
    tree = ast.parse("def f():\n    from .mesh import VolumeMesh\n")
    assert list(_imported_modules(tree, "hovr_blender.engine", {"hovr_blender.engine.mesh"})) == \
        ["hovr_blender.engine.mesh"]


# the renderer's modules, split by job (engine/renderer.py's docstring): the CLI and the add-on
# import them only when they render
RENDERER_MODULES = tuple(f"hovr_blender.engine.{m}" for m in ("renderer", "devices", "kernel_loading", "launch_args",
                                                              "segment_cache", "shipped_kernels"))


def test_warp_is_imported_at_module_level_only_by_the_renderer_and_the_kernels():
    """Elsewhere in the engine Warp is imported inside the functions that launch, so that the view,
    the readers and the Blender layer's bpy-free parts load without it (the shipped kernels' loader
    is the renderer's: it is imported at module level by the devices and the kernel loading alone)."""
    top = sorted(str(path.relative_to(REPO)) for path, name, _, tree in _modules(ENGINE)
                 for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))
                 and any(n.split(".")[0] == "warp" for n in ([a.name for a in node.names] if isinstance(node, ast.Import)
                                                             else [node.module or ""]))
                 and not name.startswith("hovr_blender.engine.kernels")
                 and name not in RENDERER_MODULES)
    assert top == []
    importers = sorted(name for path, name, _, tree in _modules(PACKAGE) for node in tree.body
                       if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("shipped_kernels"))
    assert importers == ["hovr_blender.engine.devices", "hovr_blender.engine.kernel_loading"]


def test_only_compat_asks_which_blender_this_is():
    """ui/compat.py answers every difference between the Blender versions; no other module of the
    package reads bpy.app.version."""
    found = [f"{path.relative_to(REPO)}:{node.lineno}" for path, _, _, tree in _modules(PACKAGE)
             if path.name != "compat.py" for node in ast.walk(tree)
             if isinstance(node, ast.Attribute) and node.attr == "version" and isinstance(node.value, ast.Attribute)
             and node.value.attr == "app" and isinstance(node.value.value, ast.Name) and node.value.value.id == "bpy"]
    assert found == []


def layer_table() -> str:
    """docs/architecture.md's table, from LAYERS."""
    def names(items, what):
        return ", ".join(f"`{i}`" for i in items) or what

    rows = ["| layer | may import of the package | may import beyond the standard library | imported by |",
            "|---|---|---|---|"]
    for layer, module, package, others, importers in LAYERS:
        rows.append(f"| `{layer}` (`{module}`) | {names(package, 'nothing')} | {names(others, 'nothing')} | "
                    f"{names(importers, 'nothing in the package')} |")
    return "\n".join(rows)


def test_the_architecture_doc_states_the_layers():
    doc = (REPO / "docs" / "architecture.md").read_text()
    assert layer_table() in doc, "docs/architecture.md's layer table differs from LAYERS; it should read:\n" + layer_table()


def test_core_sources_import_nothing_above_the_core():
    bad = [f"{path.relative_to(REPO)}:{line}: {mod}"
           for path, name, package, tree in _modules(ENGINE)
           for line, mod in _imported_names(tree, package)
           if _under(mod, ABOVE_ENGINE + BLENDER_MODULES)]
    assert bad == [], "the core imports a layer above it or Blender:\n" + "\n".join(bad)


def _edits_sys_path(tree):
    """Lines that change sys.path: a call of one of its mutating methods, an assignment to it or
    to an item of it, an augmented assignment, site.addsitedir."""
    def is_sys_path(node):
        return (isinstance(node, ast.Attribute) and node.attr == "path" and isinstance(node.value, ast.Name)
                and node.value.id == "sys")

    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            f = node.func
            if is_sys_path(f.value) and f.attr in ("insert", "append", "extend", "remove", "pop", "clear"):
                yield node.lineno
            if f.attr == "addsitedir" and isinstance(f.value, ast.Name) and f.value.id == "site":
                yield node.lineno
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
            node, (ast.AugAssign, ast.AnnAssign)) else []
        for t in targets:
            if is_sys_path(t) or (isinstance(t, ast.Subscript) and is_sys_path(t.value)):
                yield node.lineno


def test_no_module_of_the_package_edits_sys_path():
    found = {str(path.relative_to(REPO)): lines for path, _, _, tree in _modules(PACKAGE)
             if (lines := sorted(set(_edits_sys_path(tree))))}
    assert found == {}, f"sys.path edited at {found}: import through the package instead"


def test_bench_and_scripts_run_as_modules_without_sys_path_or_the_tests():
    """bench/ and scripts/ run as modules from the repository's root (python -m bench.suite): none
    edits sys.path, and none imports the tests (what both use is in the package or bench/common.py)."""
    found = {}
    for root in (REPO / "bench", REPO / "scripts"):
        for path, _, package, tree in _modules(root):
            if path.name.startswith("test_"):
                continue  # bench's own checks are tests, collected by pytest
            lines = sorted(set(_edits_sys_path(tree))) + [
                f"{line}: {mod}" for line, mod in _imported_names(tree, package) if _under(mod, ("tests",))]
            if lines:
                found[str(path.relative_to(REPO))] = lines
    assert found == {}, f"bench/scripts edit sys.path or import the tests at {found}"


def _private_imports(tree, package):
    """(line, module.name) of every `from module import _name` (a private name of another module)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    yield node.lineno, f"{'.' * node.level}{node.module or ''}.{alias.name}"


def test_no_module_imports_another_modules_private_names():
    found = [f"{path.relative_to(REPO)}:{line}: {name}"
             for root in (PACKAGE, REPO / "bench", REPO / "scripts")
             for path, _, package, tree in _modules(root) for line, name in _private_imports(tree, package)]
    assert found == [], "private names used across modules (make them public with a name that says what they " \
                        "are, or move them):\n" + "\n".join(found)


# file names more than one module of the package has, each for the same job in parallel places:
# every data format's own error, reader and declaration (io/nektar/, io/vtu/), and its files and
# element spaces (io/pyfr/, io/mfem/)
SHARED_FILE_NAMES = {"__init__.py", "errors.py", "reader.py", "format.py", "files.py", "elements.py"}


def test_no_two_modules_share_a_file_name_for_different_jobs():
    """A file name names one job (engine/opaque.py's meshes are not engine/isosurfaces.py's
    surfaces): no two modules of the package share one, but for SHARED_FILE_NAMES."""
    by_name = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        by_name.setdefault(path.name, []).append(str(path.relative_to(REPO)))
    shared = {name: paths for name, paths in by_name.items() if len(paths) > 1 and name not in SHARED_FILE_NAMES}
    assert shared == {}, f"modules sharing a file name: {shared}"


# Another library's private names the package reads, each in one place and with why (no public
# name does what it needs): {(file, expression): why}
PRIVATE_USES = {
    **{(f, "os._exit"): "the standard library's exit without cleanup, for a child process or Blender's exit"
       for f in ("hovr_blender/engine/processes.py", "hovr_blender/io/reader_process.py", "hovr_blender/ui/compat.py")},
    ("hovr_blender/engine/shipped_kernels.py", "module._get_compile_output_name"):
        "Warp names a CPU object after its LLVM version and target triple, which no public function gives; "
        "the store of shipped kernels must find the object by that very name",
    ("hovr_blender/distributed/local_workers.py", "super()._start"):
        "Dask's LocalCluster always makes its scheduler of Dask's own Scheduler class; its _start, where the "
        "scheduler is made from scheduler_spec, is the one place to make it a scheduler without an HTTP server",
    ("hovr_blender/io/isolation.py", "proc._handle"):
        "on Windows a child's processor time comes from GetProcessTimes, which needs the process handle that "
        "subprocess.Popen keeps only as _handle: the child's for certain, where one opened by its id names "
        "whatever process has that id once the child has ended",
}


def _private_attributes(tree):
    """(line, expression) of every `x._name` read where x is not self or cls (a private name of
    another module or object)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            yield node.lineno, ast.unparse(node)


def test_no_module_reads_another_modules_private_names():
    """Nothing in the package, bench/ or scripts/ reads a private name through another module or
    object (ex._basis, renderer._upload), but for the few of other libraries in PRIVATE_USES."""
    found, used = [], set()
    for root in (PACKAGE, REPO / "bench", REPO / "scripts"):
        for path, _, _, tree in _modules(root):
            if path.name.startswith("test_"):
                continue
            rel = str(path.relative_to(REPO))
            for line, expression in _private_attributes(tree):
                if (rel, expression) in PRIVATE_USES:
                    used.add((rel, expression))
                else:
                    found.append(f"{rel}:{line}: {expression}")
    assert found == [], "private names read across modules (make them public with a name that says what they " \
                        "are, or move them):\n" + "\n".join(found)
    assert used == set(PRIVATE_USES), f"PRIVATE_USES names uses that are gone: {sorted(set(PRIVATE_USES) - used)}"


@pytest.mark.parametrize("source,expect", [
    ("import sys\nsys.path.insert(0, 'x')", [2]),
    ("import sys\nsys.path.append('x')", [2]),
    ("import sys\nsys.path[:0] = ['x']", [2]),
    ("import sys\nsys.path += ['x']", [2]),
    ("import site\nsite.addsitedir('x')", [2]),
    ("import sys\nprint(sys.path[0])\nsys.modules.pop('x', None)", []),
])
def test_the_sys_path_check_sees_each_way(source, expect):
    assert sorted(_edits_sys_path(ast.parse(source))) == expect


def test_the_import_check_resolves_relative_imports():
    tree = ast.parse("from ..io import sources\nfrom .. import ui\nfrom . import mesh\n"
                     "def f():\n    import bpy\n")
    got = [m for _, m in _imported_names(tree, "hovr_blender.engine")]
    assert "hovr_blender.io" in got and "hovr_blender.ui" in got and "bpy" in got
    assert "hovr_blender.engine.mesh" in got
    assert [m for m in got if _under(m, ABOVE_ENGINE + BLENDER_MODULES)] == [
        "hovr_blender.io", "hovr_blender.io.sources", "hovr_blender.ui", "bpy"]
