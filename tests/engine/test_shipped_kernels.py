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
from hovr_blender.ui.jobs import CompiledKernels

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
    from hovr_blender.ui import jobs
    import warp as wp
    resolve_device("cpu")
    variant = KernelVariant.from_key(sys.argv[3])
    stage = jobs.KERNELS.stage(jobs.kernel_key("cpu", "float32", variant, False))  # what F12's status says first
    report = load_kernels(variant, "cpu")
    loaded = time.perf_counter()
    rgba = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.save(sys.argv[4], rgba)
    print(json.dumps({"shipped": report.shipped, "cached": report.cached, "compiled": report.compiled,
                      "message": report.message(), "stage": stage,
                      "cache": sorted(os.listdir(wp.config.kernel_cache_dir)), "load_seconds": loaded - t0,
                      "image_seconds": time.perf_counter() - t0}))
""")


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store of the sphere's kernels on the CPU, built by scripts/build_extension.py's build step
    (CPU objects only, no isosurfaces: to keep the test short)."""
    from hovr_blender.engine.kernel_loading import kernel_variant
    from hovr_blender.io import builtin
    from scripts import build_extension

    assert kernel_variant([builtin.sphere()]) == SPHERE_VARIANT
    root = tmp_path_factory.mktemp("kernel_binaries")
    built = build_extension.compile_kernels_here({"store": str(root), "cpu": True, "ptx_archs": [], "cubin_archs": [],
                                                  "variants": [SPHERE_VARIANT.key], "precisions": ["float32"],
                                                  "isosurfaces": [False]})
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
    assert build_extension.parse_variants("affine:0-2:derived,curved:7") == ("affine:0:derived", "affine:2:derived", "curved:7")
    assert {"affine:0:derived", "curved:0:derived"} <= set(build_extension.DEFAULT_KERNEL_VARIANTS)
    with pytest.raises(ValueError, match="not a kernel variant"):
        KernelVariant.from_key("bent:3")


# the data the tests read (tests/data, then ../shared/data): (kind, mesh file, solution, field)
TEST_DATA = [("nektar", "CubeAllElements.xml", "", ""), ("nektar", "Helmholtz3D_Pyr_Deformed.xml", "", ""),
             ("nektar", "Hex_01_01_01_03Modes_x2_Offset3.xml", "Hex_01_01_01_03Modes_x2_Offset3.fld", ""),
             ("nektar", "Hex_CurvedFace.xml", "Hex_CurvedFace.fld", ""), ("nektar", "Hex_Mushroom.xml", "Hex_Mushroom.fld", ""),
             ("nektar", "Pyr_channel_m6.xml", "", ""), ("nektar", "RotPerBcs3D_Annulus.xml", "", ""),
             ("nektar", "Tet_channel_m3.xml", "Tet_channel_m3.fld", "u"), ("nektar", "Womersley_PipeFlow.xml", "", ""),
             ("nektar", "hump3D_GLL.xml", "hump3D.rst", "rho"), ("nektar", "wss_3D_periodic.xml", "wss_3D_periodic.fld", "rho"),
             ("nektar", "scaleHO.xml", "", ""), ("mfem", "fichera.mesh", "fichera-u.gf", ""),
             ("mfem", "fichera.mesh", "fichera-vel.gf", ""), ("mfem", "fichera.mesh", "fichera-w.gf", ""),
             ("mfem", "fichera-part0.mesh", "fichera-part0-u.gf", ""), ("mfem", "var.mesh", "var.gf", ""),
             ("mfem", "zoo.mesh", "zoo-u.gf", ""), ("mfem", "fichera_lagrange_p3.vtu", "", ""),
             ("mfem", "var_lagrange_p4.vtu", "", ""), ("pyfr", "shell.pyfrm", "shell-0.02.pyfrs", ""),
             ("pyfr", "shell_lagrange_p2.vtu", "", ""), ("vtu", "mfem_fichera_cells_p4.vtu", "", ""),
             ("vtu", "mfem_fichera_poisson_mixed_p4.vtu", "", ""), ("vtu", "ngsolve_ball_poisson_hex_p6.vtu", "", ""),
             ("vtu", "ngsolve_post_heat_tetprism_p4.vtu", "", ""), ("vtu", "pyfr_tgv_hexprism_p4_t4.vtu", "", "")]


def test_the_build_step_ships_every_variant_of_the_test_data():
    """Issue 37: the zip ships the kernels of every file the tests read, its own field and a
    derived one (Float32 and Float64, with and without isosurfaces: compile_kernels_here builds
    each variant so), the synthetic benchmark meshes' and the built-in sphere's."""
    from hovr_blender.audit.datasets import load
    from hovr_blender.engine.kernel_loading import kernel_variant
    from hovr_blender.io import builtin
    from hovr_blender.io.sources import VolumeSource, read_volume
    from scripts import build_extension

    from ..helpers import find_data

    assert set(build_extension.DEFAULT_KERNEL_PRECISIONS) == {"float32", "float64"}
    shipped = set(build_extension.DEFAULT_KERNEL_VARIANTS)
    meshes = {"sphere": builtin.sphere(), "paper_scale": load("paper_scale")[0], "curved_cube": load("curved_mixed_cube")[0]}
    for kind, name, solution, field in TEST_DATA:
        path = find_data(kind, name)
        if path is not None:
            sol = str(path.with_name(solution)) if solution else ""
            meshes[f"{kind}/{name} {solution}"] = read_volume(VolumeSource.resolve(str(path), sol, field))
    assert len(meshes) >= 3 + 20, sorted(meshes)  # the vendored files at least
    for name, mesh in meshes.items():
        variant = kernel_variant([mesh])
        assert variant.key in shipped, name
        assert KernelVariant(variant.curved, 0, True).key in shipped, name  # a derived field of it


def _run_child(tmp_path, store_root, cache=None):
    """The sphere's first image in a fresh process with `store_root` (and Warp's kernel cache
    `cache`, else an empty one)."""
    if cache is None:
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
    assert result["compiled"] == [] == result["cached"] and len(result["shipped"]) >= 6, result
    assert result["cache"] == [], result["cache"]  # Warp's empty kernel cache: no module compiled
    assert result["message"] == "" and result["stage"] == [CompiledKernels.LOADING, ""]
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)  # kernels of this process
    np.testing.assert_array_equal(rgba, want)
    print(f"first image with shipped kernels: {result['image_seconds']:.2f} s "
          f"(kernels loaded {result['load_seconds']:.2f} s after start)")


def test_a_store_of_other_kernel_source_is_not_used(store, tmp_path):
    """The store's binary of one module built from other source (its hash differs): that module
    compiles as without a store, the others are still loaded from it, the report and F12's status
    say so; the next session reads it from Warp's kernel cache, and neither says it compiles."""
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
    cache = tmp_path / "warp-cache"
    cache.mkdir()
    result, rgba = _run_child(tmp_path, other, cache)
    assert result["compiled"] == [search.name] and result["cached"] == [] and len(result["shipped"]) >= 5, result
    assert [d for d in result["cache"] if search.name in d], result["cache"]  # compiled into Warp's cache
    assert result["message"].startswith("1 of ") and "not among the compiled kernels shipped" in result["message"]
    assert result["stage"] == [CompiledKernels.COMPILING, CompiledKernels.NOT_SHIPPED]
    want = SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)
    np.testing.assert_array_equal(rgba, want)
    again, rgba = _run_child(tmp_path, other, cache)  # the next Blender session: Warp's cache has it
    assert again["compiled"] == [] and again["cached"] == [search.name] and again["shipped"] == result["shipped"], again
    assert again["message"] == "" and again["stage"] == [CompiledKernels.LOADING, ""]
    np.testing.assert_array_equal(rgba, want)


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


class _FakeGPU:
    """What shipped_kernels reads of a CUDA device: its arch and the output format Warp would
    compile for it (CUBIN where the driver is older than Warp's NVRTC)."""
    is_cpu = False

    def __init__(self, arch, output):
        self.arch, self.output = arch, output

    def get_cuda_output_format(self, preferred=None):
        return self.output


def test_a_gpu_takes_the_cubin_of_its_arch_family_else_ptx_where_its_driver_reads_it(tmp_path):
    """Issue 37: on the H200 (driver 13.0, Warp's NVRTC 13.4) Warp compiles CUBIN and a PTX-only
    store was never used. A GPU takes the CUBIN of its major arch not above its own (sm_80's on
    sm_86), and PTX only where Warp would load PTX itself."""
    from hovr_blender.engine import shipped_kernels
    from hovr_blender.engine.devices import resolve_device
    from hovr_blender.engine.kernel_loading import session_kernels

    resolve_device("cpu")
    module = session_kernels(SPHERE_VARIANT)[0].module
    key = module.get_module_hash(int(module.options["block_dim"])).hex()[:shipped_kernels.HASH_CHARS]
    for name in (f"{key}.meta", f"{key}.sm80.cubin", f"{key}.sm90.cubin", f"{key}.sm120.cubin", f"{key}.sm75.ptx"):
        (tmp_path / name).write_bytes(b"")

    def chosen(arch, output):
        found = shipped_kernels._binary(tmp_path, module, _FakeGPU(arch, output))
        return found and (found[0].name[len(key) + 1:], found[1])

    assert chosen(90, "cubin") == ("sm90.cubin", 90)  # the H200
    assert chosen(86, "cubin") == chosen(89, "ptx") == ("sm80.cubin", 80)  # RTX 30 / 40: sm_80's machine code
    assert chosen(121, "cubin") == ("sm120.cubin", 120)
    assert chosen(100, "cubin") is None  # no sm_10x CUBIN, and a driver that refuses Warp's PTX: compile
    assert chosen(100, "ptx") == ("sm75.ptx", 75)  # a driver as new as Warp's NVRTC: the PTX
    assert chosen(75, "cubin") is None
