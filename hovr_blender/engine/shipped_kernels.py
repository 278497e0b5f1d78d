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
    <hash>.sm<arch>.ptx           CUDA's PTX: the driver compiles it for any GPU of `arch` or newer
    <hash>.sm<arch>.cubin         CUDA's binary for GPUs of exactly `arch` (optional: no driver
                                  compile at all, and it loads where the driver is older than
                                  Warp's NVRTC, which PTX does not)

where <hash> is the module's hash for the launch Warp does on that device (a CPU launch runs one
thread per block, a CUDA launch the module's block_dim). A kernel source that changed (another
revision of the add-on, an edited file) has another hash: its binary is not in the store and the
module compiles as it would without one (`LoadReport.compiled`).

The CPU objects are compiled without `-march=native` (CPU_COMPILER_FLAGS, set in Warp's config when
the renderer starts Warp): Warp's default would tie an object to the building machine's
instruction set (and tag its file with that), so no shipped object would ever match a user's CPU.
Measured on this project's kernels (AMD EPYC, 160x90 classified, best of 3): the sphere 0.23 s with
either, hump3D 4.0 s portable and 5.9 s native, so nothing is lost.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import warp as wp

# Warp 1.19's default CPU flags less -march=native (see the module's docstring)
CPU_COMPILER_FLAGS = ("-mllvm=-inline-threshold=9000 -mllvm=-inline-cold-callsite-threshold=3000"
                      " -mllvm=-slp-recursion-max-depth=4")
PTX_ARCHS = (75,)  # Turing: the oldest arch Warp's features need; the driver JIT-compiles it for newer GPUs
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
    """What a load did: module names loaded from the store, and those compiled (or read from
    Warp's kernel cache) because the store had no binary of their source."""
    shipped: list = field(default_factory=list)
    compiled: list = field(default_factory=list)
    store: str = ""  # the store's folder, "" where there is none

    @property
    def stale(self) -> bool:
        """A store is there but some module's source is not the one it was built from."""
        return bool(self.store) and bool(self.compiled)

    def message(self) -> str:
        if not self.stale:
            return ""
        return (f"{len(self.compiled)} of {len(self.compiled) + len(self.shipped)} kernel modules differ from the "
                f"compiled kernels shipped with the add-on (built from other kernel source); compiling them "
                f"once (tens of seconds on a CPU)")


def _block_dim(module, device) -> int:
    """The block_dim of the module variant a launch on `device` loads (Warp's force_load default)."""
    return 1 if device.is_cpu else int(module.options["block_dim"])


def _key(module, device) -> str:
    return module.get_module_hash(_block_dim(module, device)).hex()[:HASH_CHARS]


def _cpu_suffix(module) -> str:
    """The tail of the CPU object's name Warp gives on this machine (".cpu<target>.o"). Warp's one
    private function the package calls, here only (tests/engine/test_layers.py PRIVATE_USES): Warp
    names a CPU object after its LLVM version and target triple, which no public function gives,
    and the store must find the object by that very name (Warp 1.19)."""
    name = module._get_compile_output_name(wp.get_device("cpu"), block_dim=1)
    return name[len(module.get_module_identifier(1)):]


def _binary(store: Path, module, device):
    """(binary path, arch) of `module` for `device` in `store`, or None. On a GPU: the CUBIN of
    the device's arch, else the highest PTX arch not above the device's where Warp would itself
    load PTX (a driver at least as new as Warp's NVRTC; with an older driver Warp compiles CUBIN,
    and this PTX would not load)."""
    key = _key(module, device)
    if not (store / f"{key}.meta").exists():
        return None
    if device.is_cpu:
        path = store / f"{key}{_cpu_suffix(module)}"
        return (path, None) if path.exists() else None
    cubin = store / f"{key}.sm{device.arch}.cubin"
    if cubin.exists():
        return cubin, device.arch
    if device.get_cuda_output_format(module.options.get("cuda_output")) != "ptx":
        return None
    ptx = {int(p.name[len(key) + 3:-4]): p for p in store.glob(f"{key}.sm*.ptx")}
    usable = [a for a in ptx if a <= device.arch]
    return (ptx[max(usable)], max(usable)) if usable else None


def _modules(kernels) -> list:
    return list({id(k.module): k.module for k in kernels}.values())


def covers(kernels, device: str) -> bool:
    """Whether the store has every module of `kernels` for `device` (nothing will compile), or they
    are loaded there already."""
    dev = wp.get_device(device)
    store = store_dir()
    return all(_loaded(m, dev) or _binary(store, m, dev) is not None for m in _modules(kernels))


def _loaded(module, device) -> bool:
    dim = _block_dim(module, device)
    ex = module.execs.get((device.context, dim))
    return ex is not None and ex.module_hash == module.get_module_hash(dim)


def load_shipped(kernels, device: str) -> LoadReport:
    """Load from the store the modules of `kernels` it has binaries of on `device`; the report
    names those loaded and those left for Warp to compile (or read from its kernel cache)."""
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
        report.compiled.append(m.name)
    return report


def build_store(kernels, store: Path, cpu: bool = True, ptx_archs=PTX_ARCHS, cubin_archs=()) -> list[Path]:
    """Compile the modules of `kernels` into `store` (kept: a module already there is not compiled
    again): the CPU's objects with `cpu` (this machine's platform only: Warp's LLVM compiles for
    its host), PTX for each of `ptx_archs` and CUBIN for each of `cubin_archs` with NVRTC (no GPU
    needed). Returns every file of these modules in the store, the zip's share of it."""
    assert wp.config.cpu_compiler_flags == CPU_COMPILER_FLAGS, "start Warp as a render does (renderer.resolve_device)"
    store.mkdir(parents=True, exist_ok=True)
    cpu_dev = wp.get_device("cpu")
    files = []
    for m in _modules(kernels):
        if cpu:
            key = _key(m, cpu_dev)
            target = store / f"{key}{_cpu_suffix(m)}"
            if not target.exists():
                wp.force_load(device="cpu", modules=[m], max_workers=0)  # Warp's own path: its kernel cache
                binary = Path(m.execs[(None, 1)].binary_path)
                _copy(binary.with_name(m.get_module_identifier(1) + ".meta"), store / f"{key}.meta")
                _copy(binary, target)
            files += [store / f"{key}.meta", target]
        dim = int(m.options["block_dim"])
        key = m.get_module_hash(dim).hex()[:HASH_CHARS]
        for arch, ext in [(a, "ptx") for a in ptx_archs] + [(a, "cubin") for a in cubin_archs]:
            target = store / f"{key}.sm{arch}.{ext}"
            if not target.exists():
                tmp = store / f".build-{key}"
                paths = wp.compile_aot_module(m, arch=arch, use_ptx=ext == "ptx", module_dir=tmp)
                _copy(tmp / f"{m.get_module_identifier(dim)}.meta", store / f"{key}.meta")
                _copy(Path(paths[0]), target)
                shutil.rmtree(tmp, ignore_errors=True)
            files += [store / f"{key}.meta", target]
    return sorted(set(files))


def _copy(src: Path, dst: Path):
    """Copy through a temporary name: a store is never left with half a file."""
    tmp = dst.with_name(dst.name + ".part")
    shutil.copyfile(src, tmp)
    os.replace(tmp, dst)
