"""Compiled kernels shipped with the add-on (engine/shipped_kernels.py, issue 30 item 11): a store
built by the extension's build step is loaded with an empty Warp kernel cache and nothing compiles;
the same image as kernels compiled here; a module whose store binary was built from other source
compiles as before, and the report says so; the store is found by hash, not by the package's name."""
import json
import os
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hovr_blender.engine.kernel_loading import KernelVariant

from ..helpers import REPO, SPHERE

SPHERE_VARIANT = KernelVariant(False, 3, False)  # the built-in sphere's kernel_variant (tested below)

CHILD = textwrap.dedent("""
    import json, os, sys, time
    t0 = time.perf_counter()
    sys.path.insert(0, sys.argv[1]); sys.path.insert(0, sys.argv[2])
    import numpy as np
    from helpers import SPHERE
    from hovr_blender.engine.devices import resolve_device
    from hovr_blender.engine.kernel_loading import KernelVariant, load_kernels
    import warp as wp
    resolve_device("cpu")
    report = load_kernels(KernelVariant.from_key(sys.argv[3]), "cpu")
    loaded = time.perf_counter()
    rgba = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.save(sys.argv[4], rgba)
    print(json.dumps({"shipped": report.shipped, "compiled": report.compiled, "message": report.message(),
                      "cache": sorted(os.listdir(wp.config.kernel_cache_dir)), "load_seconds": loaded - t0,
                      "image_seconds": time.perf_counter() - t0}))
""")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store of the sphere's kernels on the CPU, built by scripts/build_extension.py's build step
    (CPU objects only: no PTX, to keep the test short)."""
    from hovr_blender.engine.kernel_loading import kernel_variant
    from hovr_blender.io import builtin
    from scripts import build_extension

    assert kernel_variant([builtin.sphere()]) == SPHERE_VARIANT
    root = tmp_path_factory.mktemp("kernel_binaries")
    built = build_extension.compile_kernels_here({"store": str(root), "cpu": True, "ptx": False, "cubin_archs": [],
                                                  "variants": [SPHERE_VARIANT.key], "precisions": ["float32"]})
    assert built["files"] and all(os.path.exists(f) for f in built["files"])
    return root


def test_the_build_steps_variants_are_kernel_variants():
    """--kernel-variants names what kernel_variant returns for a file's field, so a store built from
    them holds the kernels a render of such a file loads."""
    from scripts import build_extension

    assert build_extension.parse_variants("affine:3,curved:0-2") == ("affine:3", "curved:0", "curved:2")
    assert [KernelVariant.from_key(k) for k in ("affine:3", "curved:0")] == [KernelVariant(False, 3), KernelVariant(True, 0)]
    assert SPHERE_VARIANT.key in build_extension.DEFAULT_KERNEL_VARIANTS
    assert KernelVariant.from_key("curved:0:derived") == KernelVariant(True, 0, True)
    with pytest.raises(ValueError, match="not a kernel variant"):
        KernelVariant.from_key("bent:3")


def _run_child(tmp_path, store_root):
    cache = tmp_path / "empty-warp-cache"
    cache.mkdir()
    env = dict(os.environ, WARP_CACHE_PATH=str(cache), HOVR_KERNEL_BINARIES=str(store_root))
    out = tmp_path / "rgba.npy"
    proc = subprocess.run([sys.executable, "-c", CHILD, str(REPO), str(REPO / "tests"), SPHERE_VARIANT.key,
                           str(out)], env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), np.load(out)


def test_shipped_kernels_load_with_an_empty_cache_and_compile_nothing(store, tmp_path):
    result, rgba = _run_child(tmp_path, store)
    assert result["compiled"] == [] and len(result["shipped"]) >= 6, result
    assert result["cache"] == [], result["cache"]  # Warp's empty kernel cache: no module compiled
    assert result["message"] == ""
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)  # kernels of this process
    np.testing.assert_array_equal(rgba, want)
    print(f"first image with shipped kernels: {result['image_seconds']:.2f} s "
          f"(kernels loaded {result['load_seconds']:.2f} s after start)")


def test_a_store_of_other_kernel_source_is_not_used(store, tmp_path):
    """The store's binary of one module built from other source (its hash differs): that module
    compiles as without a store, the others are still loaded from it, the report says so."""
    import warp as wp

    from hovr_blender.engine import shipped_kernels
    from hovr_blender.engine.kernel_loading import session_kernels

    other = tmp_path / "store"
    shutil.copytree(store, other)
    folder = other / f"warp-{wp.config.version}"
    search = session_kernels(SPHERE_VARIANT)[0].module  # the smallest module: quick to compile
    key = shipped_kernels._key(search, wp.get_device("cpu"))
    for f in folder.glob(key + ".*"):
        f.rename(f.with_name("0" * len(key) + f.name[len(key):]))
    result, rgba = _run_child(tmp_path, other)
    assert result["compiled"] == [search.name] and len(result["shipped"]) >= 5, result
    assert [d for d in result["cache"] if search.name in d], result["cache"]  # compiled into Warp's cache
    assert result["message"].startswith("1 of ") and "differ from the compiled kernels shipped" in result["message"]
    np.testing.assert_array_equal(rgba, SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False))


def test_the_hash_does_not_depend_on_where_the_package_lives(tmp_path):
    """Installed, the package is bl_ext.<repo>.hovr_blender from another folder: the module
    hashes the store is keyed by are the repository's."""
    script = textwrap.dedent("""
        import json, sys
        sys.path.insert(0, sys.argv[1])
        from hovr_blender.engine.bootstrap import import_package
        import_package("bl_ext.user_default.hovr_blender", sys.argv[2])
        from bl_ext.user_default.hovr_blender.engine import devices, kernel_loading, shipped_kernels
        import warp as wp
        devices.resolve_device("cpu")
        kernels = kernel_loading.session_kernels(kernel_loading.KernelVariant.from_key(sys.argv[3]))
        print(json.dumps(sorted(shipped_kernels._key(k.module, wp.get_device("cpu")) for k in kernels)))
    """)
    copy = tmp_path / "elsewhere" / "hovr_blender"
    shutil.copytree(REPO / "hovr_blender", copy, ignore=shutil.ignore_patterns("__pycache__"))
    proc = subprocess.run([sys.executable, "-c", script, str(REPO), str(copy), SPHERE_VARIANT.key],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    import warp as wp

    from hovr_blender.engine import shipped_kernels
    from hovr_blender.engine.devices import resolve_device
    from hovr_blender.engine.kernel_loading import session_kernels

    resolve_device("cpu")
    here = sorted(shipped_kernels._key(k.module, wp.get_device("cpu")) for k in session_kernels(SPHERE_VARIANT))
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == here
