"""Compiled kernels shipped with the add-on: built once by scripts/build_extension.py, loaded at a
render's first use instead of compiling, and only where they were built from this very source.

A kernel module's binary is found by Warp's own module hash (Module.get_module_hash: the kernels'
and their functions' source text, argument types, constants and the module's resolved options, the
CPU compiler flags among them), never by its name or path: Warp names the cache folder of a module
by its Python module name, which is `bl_ext.<repo>.hovr_blender...` once installed, while the hash
is the same wherever the package lives. A store (`<package>/kernel_binaries/warp-<version>/`) holds

    <hash>.meta                   Warp's metadata of the module (shared memory per kernel)
    <hash>.cpu<target>.o          the CPU's object; <target> is Warp's tag of its LLVM and the
                                  platform's target triple, so an object is only taken on its platform
    <hash>.sm<arch>.cubin         CUDA's binary for GPUs of `arch`, and of the same major arch with a
                                  higher minor (sm_80's runs on sm_86 and sm_89): no driver compile,
                                  and it loads with any driver of Warp's CUDA major version
    <hash>.sm<arch>.ptx           CUDA's PTX: the driver compiles it for any GPU of `arch` or newer,
                                  but only a driver at least as new as Warp's NVRTC reads it (Warp
                                  1.19's NVRTC is CUDA 13.4: a 13.0 driver, the H200's, refuses it,
                                  and Warp compiles CUBIN there), so it serves the GPUs no CUBIN does

where <hash> is the module's hash for the launch Warp does on that device (a CPU launch runs one
thread per block, a CUDA launch the module's block_dim). A kernel source that changed (another
revision of the add-on, an edited file) has another hash: its binary is not in the store and the
module compiles as it would without one (`LoadReport.compiled`), or is read from Warp's kernel
cache if it compiled here before (`LoadReport.cached`).

The CPU objects are compiled without `-march=native` (CPU_COMPILER_FLAGS, set in Warp's config when
the renderer starts Warp): Warp's default would tie an object to the building machine's
instruction set (and tag its file with that), so no shipped object would ever match a user's CPU.
Measured on this project's kernels (AMD EPYC, 160x90 classified, best of 3): the sphere 0.23 s with
either, hump3D 4.0 s portable and 5.9 s native, so nothing is lost.
"""
from __future__ import annotations

import os
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import warp as wp

# Warp 1.19's default CPU flags less -march=native (see the module's docstring)
CPU_COMPILER_FLAGS = ("-mllvm=-inline-threshold=9000 -mllvm=-inline-cold-callsite-threshold=3000"
                      " -mllvm=-slp-recursion-max-depth=4")
# CUBIN for these archs: each runs on the later minors of its major arch too, so they cover every
# GPU Warp 1.19 compiles for: 7.5 (RTX 20), 8.x (A100, RTX 30 and 40, Orin), 9.0 (H100, H200),
# 10.x (B200, B300) and 12.x (RTX 50, DGX Spark)
CUBIN_ARCHS = (75, 80, 90, 100, 120)
PTX_ARCHS = (75,)  # Turing, the oldest arch Warp 1.19 (CUDA 13) compiles for: any later GPU whose driver reads it
HASH_CHARS = 32  # of the module hash's hex digest, in file names (128 bits; short paths on Windows)
STORE_ENV = "HOVR_KERNEL_BINARIES"  # another folder of stores (tests, benchmarks)
PACKAGE_DIR = Path(__file__).resolve().parents[1]


def store_dir() -> Path:
    """The store of this Warp version: in the package (the built extension's zip puts it there),
    or under $HOVR_KERNEL_BINARIES."""
    root = os.environ.get(STORE_ENV) or PACKAGE_DIR / "kernel_binaries"
    return Path(root) / f"warp-{wp.config.version}"


@dataclass
class LoadReport:
    """What a load did, by module name: loaded from the store (`shipped`), read from Warp's kernel
    cache on disk (`cached`: compiled here before), or compiled now (`compiled`)."""
    shipped: list = field(default_factory=list)
    cached: list = field(default_factory=list)
    compiled: list = field(default_factory=list)
    store: str = ""  # the store's folder, "" where there is none

    @property
    def stale(self) -> bool:
        """A store is there but some module's binary is not in it, and was compiled."""
        return bool(self.store) and bool(self.compiled)

    def message(self) -> str:
        if not self.stale:
            return ""
        total = len(self.compiled) + len(self.cached) + len(self.shipped)
        return (f"{len(self.compiled)} of {total} kernel modules are not among the compiled kernels shipped with "
                f"the add-on (other kernel source, or another GPU); compiling them once (tens of seconds on a CPU)")


def _block_dim(module, device) -> int:
    """The block_dim of the module variant a launch on `device` loads (Warp's force_load default)."""
    return 1 if device.is_cpu else int(module.options["block_dim"])


def _key(module, device) -> str:
    return module.get_module_hash(_block_dim(module, device)).hex()[:HASH_CHARS]


def _output_name(module, device) -> str:
    """The file name Warp gives `module`'s binary for `device` in its kernel cache (a CPU object:
    "<identifier>.cpu<target>.o", <target> a tag of its LLVM version and target triple; on a GPU
    "<identifier>.sm<arch>.cubin" or ".ptx", as Warp's load would compile it). Warp's one private
    function the package calls, here only (tests/engine/test_layers.py PRIVATE_USES): no public
    function gives these names, and the store and the cache check must use the very ones (Warp 1.19)."""
    return module._get_compile_output_name(device, block_dim=_block_dim(module, device))


def _cpu_suffix(module) -> str:
    """The tail of the CPU object's name Warp gives on this machine (".cpu<target>.o")."""
    return _output_name(module, wp.get_device("cpu"))[len(module.get_module_identifier(1)):]


def _arch(path: Path, key: str) -> int:
    return int(path.name[len(key) + 3:].split(".")[0])  # "<key>.sm<arch>.<ext>"


def _binary(store: Path, module, device):
    """(binary path, arch) of `module` for `device` in `store`, or None. On a GPU: the CUBIN of the
    highest arch of the device's major arch not above its own (SASS runs on later minors), else
    the highest PTX arch not above the device's where Warp would itself load PTX (a driver at least
    as new as Warp's NVRTC; an older driver refuses that PTX, and Warp compiles CUBIN there)."""
    key = _key(module, device)
    if not (store / f"{key}.meta").exists():
        return None
    if device.is_cpu:
        path = store / f"{key}{_cpu_suffix(module)}"
        return (path, None) if path.exists() else None
    cubin = {_arch(p, key): p for p in store.glob(f"{key}.sm*.cubin")}
    usable = [a for a in cubin if a // 10 == device.arch // 10 and a <= device.arch]
    if usable:
        return cubin[max(usable)], max(usable)
    if device.get_cuda_output_format(module.options.get("cuda_output")) != "ptx":
        return None
    ptx = {_arch(p, key): p for p in store.glob(f"{key}.sm*.ptx")}
    usable = [a for a in ptx if a <= device.arch]
    return (ptx[max(usable)], max(usable)) if usable else None


def _modules(kernels) -> list:
    return list({id(k.module): k.module for k in kernels}.values())


def _loaded(module, device) -> bool:
    dim = _block_dim(module, device)
    ex = module.execs.get((device.context, dim))
    return ex is not None and ex.module_hash == module.get_module_hash(dim)


def _in_warp_cache(module, device) -> bool:
    """Whether Warp's kernel cache on disk holds what its load of `module` on `device` reads (the
    binary and its metadata): the load compiles nothing."""
    folder = Path(wp.config.kernel_cache_dir) / module.get_module_identifier(_block_dim(module, device))
    return (folder / _output_name(module, device)).exists() and (folder / f"{folder.name}.meta").exists()


def to_compile(kernels, device: str) -> list[str]:
    """The modules of `kernels` a load on `device` would compile: neither loaded, nor in the
    store, nor in Warp's kernel cache. Empty: their first use only loads binaries."""
    dev = wp.get_device(device)
    store = store_dir()
    return [m.name for m in _modules(kernels)
            if not (_loaded(m, dev) or _binary(store, m, dev) is not None or _in_warp_cache(m, dev))]


def load_shipped(kernels, device: str) -> LoadReport:
    """Load from the store the modules of `kernels` it has binaries of on `device`; the report
    names those loaded and, of the others (left for Warp's force_load), those in Warp's kernel
    cache and those that will compile."""
    dev = wp.get_device(device)
    store = store_dir()
    report = LoadReport(store=str(store) if store.is_dir() else "")
    for m in _modules(kernels):
        if _loaded(m, dev):
            continue
        found = _binary(store, m, dev) if report.store else None
        if found is not None:
            try:
                m.load(dev, block_dim=_block_dim(m, dev), binary_path=found[0], output_arch=found[1],
                       meta_path=store / f"{_key(m, dev)}.meta")
                report.shipped.append(m.name)
                continue
            except Exception:  # noqa: BLE001  (a binary the driver refuses: compile it instead)
                pass
        (report.cached if _in_warp_cache(m, dev) else report.compiled).append(m.name)
    return report


def build_store(kernels, store: Path, cpu: bool = True, ptx_archs=PTX_ARCHS, cubin_archs=CUBIN_ARCHS,
                workers: int | None = None) -> list[Path]:
    """Compile the modules of `kernels` into `store` (kept: a binary already there is not compiled
    again): the CPU's objects with `cpu` (this machine's platform only: Warp's LLVM compiles for
    its host), PTX for each of `ptx_archs` and CUBIN for each of `cubin_archs` with NVRTC (no GPU
    needed), `workers` modules at a time (default: a thread a core; NVRTC and LLVM run outside
    Python's lock). Returns every file of these modules in the store, the zip's share of it."""
    assert wp.config.cpu_compiler_flags == CPU_COMPILER_FLAGS, "start Warp as a render does (renderer.resolve_device)"
    store.mkdir(parents=True, exist_ok=True)
    modules = _modules(kernels)
    workers = max(1, workers or os.cpu_count() or 1)
    files = []
    if cpu:
        cpu_dev = wp.get_device("cpu")
        wanted = {id(m): store / f"{_key(m, cpu_dev)}{_cpu_suffix(m)}" for m in modules}
        missing = [m for m in modules if not wanted[id(m)].exists()]
        if missing:  # Warp's own path (its kernel cache), then copied
            wp.force_load(device="cpu", modules=missing, max_workers=workers if workers > 1 else 0)
        for m in missing:
            binary = Path(m.execs[(None, 1)].binary_path)
            _copy(binary.with_name(m.get_module_identifier(1) + ".meta"), store / f"{_key(m, cpu_dev)}.meta")
            _copy(binary, wanted[id(m)])
        files += [p for m in modules for p in (store / f"{_key(m, cpu_dev)}.meta", wanted[id(m)])]
    targets = [(a, "ptx") for a in ptx_archs] + [(a, "cubin") for a in cubin_archs]
    if targets:
        with ThreadPoolExecutor(workers) as pool:
            for done in pool.map(lambda m: _build_cuda(m, store, targets), modules):
                files += done
    return sorted(set(files))


def _build_cuda(module, store: Path, targets) -> list[Path]:
    """`module`'s CUDA binaries for `targets` ((arch, "ptx" or "cubin"), ...) in `store`."""
    dim = int(module.options["block_dim"])
    key = module.get_module_hash(dim).hex()[:HASH_CHARS]
    files = []
    for arch, ext in targets:
        target = store / f"{key}.sm{arch}.{ext}"
        if not target.exists():
            tmp = store / f".build-{key}-sm{arch}.{ext}"
            paths = wp.compile_aot_module(module, arch=arch, use_ptx=ext == "ptx", module_dir=tmp)
            if not (store / f"{key}.meta").exists():
                _copy(tmp / f"{module.get_module_identifier(dim)}.meta", store / f"{key}.meta")
            _copy(Path(paths[0]), target)
            shutil.rmtree(tmp, ignore_errors=True)
        files += [store / f"{key}.meta", target]
    return files


def _copy(src: Path, dst: Path):
    """Copy through a temporary name: a store is never left with half a file."""
    tmp = dst.with_name(dst.name + ".part")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dst)
