#!/usr/bin/env python3
"""Build and validate the Blender extension.

  python -m scripts.build_extension [--output-dir dist]
      dist/hovr_blender-<version>.zip: no bundled wheels (warp-lang must already be
      importable in Blender's Python); fast, used by the tests.
  python -m scripts.build_extension --wheels [--platforms linux-x64,windows-x64,macos-arm64]
      one zip per platform, dist/hovr_blender-<version>-<platform>.zip, each carrying that
      platform's wheels of every runtime dependency (RUNTIME_REQUIREMENTS and what they need,
      numpy excepted: Blender ships it; downloaded with pip into build/wheels/<platform>/, not
      committed) and a manifest with `platforms` and `wheels` filled in (as Blender's
      --split-platforms does). Installed, such a zip needs nothing else.
  python -m scripts.build_extension validate PATH
      checks the manifest fields and the archive layout, then runs Blender's own
      validator (bl_pkg's blender_ext.py, shipped inside the bpy module) when it is installed.

  python -m scripts.build_extension kernels --kernel-store DIR [--kernel-cubin-archs 90 ...]
      only the compiled kernels' store (below), for a GPU benchmark (bench/interactive.py --cold
      --kernel-store DIR) or to fill build/kernels/ ahead of a build; prints what it built.

  Compiled kernels (--kernels; on by default with --wheels, --no-kernels leaves them out): every
      kernel module a session loads (engine/kernel_loading.session_kernels: render, trace, re-shade,
      the opaque meshes' cast; with and without isosurfaces and planes) for each --kernel-variants
      (affine and curved, the sample kernel's orders 0..6 and generic, and a derived field's) in
      --kernel-precisions (Float32 and Float64), compiled into kernel_binaries/warp-<version>/ of
      the zip (engine/shipped_kernels.py loads them where their source's hash matches): for CUDA,
      in every zip but macOS's, CUBIN for --kernel-cubin-archs (shipped_kernels.CUBIN_ARCHS: every
      GPU from Turing on, whatever its driver) and PTX for --kernel-ptx-archs (75: GPUs without a
      CUBIN, where the driver is as new as Warp's NVRTC); the CPU's objects in the zip of this
      machine's platform only (Warp's LLVM compiles for its host: the other platforms' zips compile
      their CPU kernels on first use). Compiled once into --kernel-store (build/kernels/; a binary
      there is not compiled again), in a child Python so this process's Warp is untouched, a module
      a core at a time; the first time about an hour on a 2-core machine, minutes on a large one.
      The zip's share must stay within KERNEL_BUDGET_MIB compressed.

The repository keeps blender_manifest.toml at the top and the add-on in hovr_blender/;
Blender wants the manifest and the package's __init__.py side by side, so the zip holds
the manifest plus the *contents* of hovr_blender/ at its root (no tests, no caches).
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import platform as host
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from hovr_blender.ui.dependencies import WARP_VERSION  # the add-on's one pin of Warp

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "hovr_blender"
MANIFEST = REPO / "blender_manifest.toml"
WHEEL_CACHE = REPO / "build" / "wheels"
SKIP_DIRS = {"__pycache__", "tests"}
SKIP_SUFFIXES = {".pyc", ".pyo", ".zip"}

# Everything the add-on imports beyond Blender (ui/dependencies.py checks the same packages at
# enable time, tests/ui/test_framing.py that they agree): Warp renders, h5py reads
# HDF5 solution files, defusedxml parses every XML data file (DTDs refused in any encoding:
# io/safe_xml.py). pip resolves their dependencies; numpy is left out: Blender ships its own,
# and a second copy in the extension's site-packages would shadow it.
RUNTIME_REQUIREMENTS = (f"warp-lang=={WARP_VERSION}", "h5py==3.16.0", "defusedxml==0.7.1")
NOT_BUNDLED = {"numpy"}
PYTHON_VERSION = "3.11"  # Blender 4.2 to 5.0; h5py's wheels are per Python version
# Blender platform -> the pip platform tag of the wheels. numpy is not bundled: Blender ships its own.
WHEEL_PLATFORMS = {
    "linux-x64": "manylinux_2_28_x86_64",
    "windows-x64": "win_amd64",
    "macos-arm64": "macosx_11_0_arm64",
}
DEFAULT_PLATFORMS = ("linux-x64", "windows-x64", "macos-arm64")

KERNEL_STORE = REPO / "build" / "kernels"
KERNEL_FOLDER = "kernel_binaries"  # in the zip; engine/shipped_kernels.store_dir() reads it there
# KernelVariant keys (engine/kernel_loading.py): the sample kernel's specialisations of the usual orders
# (element.STATIC_MODES: the data the tests use has 2, 3, 4, 5 and 7 modes) and the generic one (0:
# tetrahedra and pyramids only, mixed orders, any other), affine and curved, and a derived field's
DEFAULT_KERNEL_VARIANTS = tuple(f"{kind}:{modes}" for kind in ("affine", "curved") for modes in (0, 2, 3, 4, 5, 6, 7)) \
    + ("affine:0:derived", "curved:0:derived")
DEFAULT_KERNEL_PRECISIONS = ("float32", "float64")
KERNEL_BUDGET_MIB = 40  # the compiled kernels' share of a zip, compressed (Warp's wheel is ~100 MiB of it)
NO_CUDA_PLATFORMS = {"macos-arm64", "macos-x64"}

BLENDER_PLATFORMS = {"windows-x64", "windows-arm64", "macos-x64", "macos-arm64", "linux-x64"}
PERMISSIONS = {"files", "network", "clipboard", "camera", "microphone"}
REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
            "blender_version_min", "license")
SEMVER = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)(?:-[0-9A-Za-z.-]+)?(?:\+[0-9A-Za-z.-]+)?$")
WHEEL_NAME = re.compile(r"^[A-Za-z0-9_.]+-[A-Za-z0-9_.!+]+(-\d[^-]*)?-[^-]+-[^-]+-[^-]+\.whl$")


def package_files(root: Path):
    """(path, name in zip) for every file the extension ships, in a stable order."""
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if not path.is_file() or any(part in SKIP_DIRS or part.startswith(".") for part in rel.parts):
            continue
        if path.suffix in SKIP_SUFFIXES:
            continue
        yield path, rel.as_posix()


def _load_manifest() -> tuple[str, dict]:
    text = MANIFEST.read_text(encoding="utf-8")
    manifest = tomllib.loads(text)
    for key in ("id", "version"):
        if not manifest.get(key):
            raise SystemExit(f"{MANIFEST.name}: '{key}' is missing or empty")
    for key in ("platforms", "wheels"):
        if key in manifest:  # generated per platform below; the repository's copy stays generic
            raise SystemExit(f"{MANIFEST.name}: leave '{key}' out, build_extension.py --wheels fills it in")
    return text, manifest


def _with_keys(text: str, lines: list[str]) -> str:
    """Insert top-level TOML keys before the first [table] (keys after a header would join it)."""
    m = re.search(r"^\[", text, flags=re.M)
    at = m.start() if m else len(text)
    return text[:at] + "\n".join(lines) + "\n\n" + text[at:]


def _write_zip(out: Path, manifest_text: str, wheels=(), kernels=None):
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("blender_manifest.toml", manifest_text)
        for path, name in package_files(PACKAGE):
            zf.write(path, name)
        for wheel in wheels:
            zf.write(wheel, f"wheels/{wheel.name}", compress_type=zipfile.ZIP_STORED)  # already compressed
        if kernels:
            for path in kernels["files"]:
                zf.write(path, f"{KERNEL_FOLDER}/warp-{kernels['warp']}/{Path(path).name}")
    if kernel_mib(out) > KERNEL_BUDGET_MIB:
        raise SystemExit(f"{out.name}: its compiled kernels take {kernel_mib(out):.1f} MiB, over the budget of "
                         f"{KERNEL_BUDGET_MIB} MiB (KERNEL_BUDGET_MIB): ship fewer archs or variants")


def kernel_mib(zip_path: Path) -> float:
    """The compiled kernels' share of a zip, compressed, in MiB."""
    with zipfile.ZipFile(zip_path) as zf:
        return sum(i.compress_size for i in zf.infolist() if i.filename.startswith(KERNEL_FOLDER + "/")) / 2**20


def host_platform() -> str | None:
    """This machine's Blender platform name (the only one whose CPU kernels can be built here)."""
    machine = host.machine().lower()
    arch = {"x86_64": "x64", "amd64": "x64", "arm64": "arm64", "aarch64": "arm64"}.get(machine)
    system = {"linux": "linux", "win32": "windows", "darwin": "macos"}.get(sys.platform)
    return f"{system}-{arch}" if system and arch else None


def parse_variants(text: str) -> tuple:
    """"affine:3,curved:0-7,curved:0:derived" -> ("affine:3", "curved:0", "curved:2", ..., "curved:7",
    "curved:0:derived"): the KernelVariant keys (engine/kernel_loading.py) of the fields to ship."""
    out = []
    for item in filter(None, (t.strip() for t in text.split(","))):
        kind, _, rest = item.partition(":")
        modes, _, derived = rest.partition(":")
        lo, _, hi = modes.partition("-")
        if kind not in ("affine", "curved") or not lo.isdigit() or not (hi.isdigit() or not hi) \
                or derived not in ("", "derived"):
            raise SystemExit(f"--kernel-variants: {item!r} is not affine:N or curved:N (N, or N-M), then :derived or nothing")
        out += [f"{kind}:{m}" + (":derived" if derived else "") for m in range(int(lo), int(hi or lo) + 1) if m != 1]
    return tuple(out)


def compile_kernels(platform: str, variants=DEFAULT_KERNEL_VARIANTS, precisions=DEFAULT_KERNEL_PRECISIONS,
                    store: Path = KERNEL_STORE, cubin_archs=None, ptx_archs=None, cpu: bool | None = None,
                    workers: int | None = None, isosurfaces=(False, True)) -> dict:
    """The compiled kernels of a zip for `platform`: {"warp": version, "files": [paths], "seconds"}
    (see the module's docstring), compiled in a child Python into `store` where not there already.
    `cpu` None: the CPU's objects where `platform` is this machine's; archs None: shipped_kernels';
    `isosurfaces`: the looks' variants of integrate and shade to build (without, with)."""
    cpu = platform == host_platform() if cpu is None else cpu
    cuda = platform not in NO_CUDA_PLATFORMS
    if not (cpu or cuda):
        return {"warp": WARP_VERSION, "files": [], "seconds": 0.0}
    job = {"store": str(store), "cpu": cpu, "variants": [str(v) for v in variants], "precisions": list(precisions),
           "cubin_archs": cubin_archs if cuda else (), "ptx_archs": ptx_archs if cuda else (), "workers": workers,
           "isosurfaces": list(isosurfaces)}
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
    proc = subprocess.run([sys.executable, "-m", "scripts.build_extension", "compile-kernels", json.dumps(job)],
                          cwd=REPO, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"compiling the kernels failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compile_kernels_here(job: dict) -> dict:
    """compile_kernels' child: the repository's engine builds its store (shipped_kernels.build_store)
    of every module of the job's variants and precisions, with and without isosurfaces (or as
    its "isosurfaces" says)."""
    import time

    from hovr_blender.engine import shipped_kernels
    from hovr_blender.engine.devices import resolve_device
    from hovr_blender.engine.kernel_loading import KernelVariant, session_kernels

    t0 = time.perf_counter()
    resolve_device("cpu")  # starts Warp as a render does (its CPU flags, shipped_kernels.py)
    import warp as wp

    store = Path(job["store"]) / f"warp-{wp.config.version}"
    kernels = [k for precision in job["precisions"] for key in job["variants"] for iso in job.get("isosurfaces", (False, True))
               for k in session_kernels(KernelVariant.from_key(key), precision, surfaces=True, isosurfaces=iso)]
    cubin, ptx = job.get("cubin_archs"), job.get("ptx_archs")
    files = shipped_kernels.build_store(kernels, store, cpu=job["cpu"], workers=job.get("workers"),
                                        cubin_archs=shipped_kernels.CUBIN_ARCHS if cubin is None else cubin,
                                        ptx_archs=shipped_kernels.PTX_ARCHS if ptx is None else ptx)
    return {"warp": wp.config.version, "files": [str(f) for f in files], "seconds": time.perf_counter() - t0}


def _wheel_project(path: Path) -> str:
    return path.name.split("-", 1)[0].lower().replace("_", "-")


def download_wheels(platform: str, cache: Path = WHEEL_CACHE) -> list[Path]:
    """Wheels of RUNTIME_REQUIREMENTS and their dependencies for a Blender platform, numpy
    excepted, from the package index through pip (cached in build/wheels/<platform>/<digest of
    the requirements>/, so a wheel a former requirement brought is never bundled)."""
    tag = WHEEL_PLATFORMS[platform]
    dest = cache / platform / hashlib.sha256("\n".join(RUNTIME_REQUIREMENTS).encode()).hexdigest()[:12]
    dest.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pip", "download", *RUNTIME_REQUIREMENTS, "--only-binary=:all:",
                    "--platform", tag, "--python-version", PYTHON_VERSION, "--implementation", "cp",
                    "--quiet", "-d", str(dest)], check=True)
    wanted = {r.split("==")[0] for r in RUNTIME_REQUIREMENTS}
    wheels = sorted(w for w in dest.glob("*.whl") if _wheel_project(w) not in NOT_BUNDLED)
    latest = {}  # one wheel per project: the cache may hold older pins
    for w in wheels:
        latest[_wheel_project(w)] = w
    missing = wanted - set(latest)
    if missing:
        raise SystemExit(f"pip downloaded no wheel of {', '.join(sorted(missing))} for {tag}")
    pinned = {r.split("==")[0]: r.split("==")[1] for r in RUNTIME_REQUIREMENTS}
    for project, version in pinned.items():
        match = [w for w in wheels if _wheel_project(w) == project and w.name.split("-")[1] == version]
        if match:
            latest[project] = match[-1]
    return sorted(latest.values())


def download_wheel(platform: str, cache: Path = WHEEL_CACHE) -> Path:
    """warp-lang's wheel for a Blender platform (download_wheels fetches it with the others)."""
    return next(w for w in download_wheels(platform, cache) if _wheel_project(w) == "warp-lang")


def zip_name(manifest: dict, platform: str | None = None) -> str:
    """The zip's file name: hovr_blender-0.1.0.zip, or with a platform's wheels
    hovr_blender-0.1.0-linux_x64.zip (Blender's platform names, '-' as '_')."""
    tail = f"-{platform.replace('-', '_')}" if platform else ""
    return f"{manifest['id']}-{manifest['version']}{tail}.zip"


def build(output_dir: Path, kernels: dict | None = None) -> Path:
    """The zip without wheels; `kernels` are compile_kernels(...) arguments to ship compiled kernels
    of this machine's platform."""
    text, manifest = _load_manifest()
    output_dir.mkdir(parents=True, exist_ok=True)
    out = output_dir / zip_name(manifest)
    compiled = compile_kernels(host_platform(), **kernels) if kernels is not None else None
    _write_zip(out, text, kernels=compiled)
    return out


def build_with_wheels(output_dir: Path, platforms=DEFAULT_PLATFORMS, cache: Path = WHEEL_CACHE,
                      kernels: dict | None = None) -> list[Path]:
    text, manifest = _load_manifest()
    output_dir.mkdir(parents=True, exist_ok=True)
    outs = []
    for platform in platforms:
        if platform not in WHEEL_PLATFORMS:
            raise SystemExit(f"no warp-lang wheel known for platform {platform!r} (one of {', '.join(WHEEL_PLATFORMS)})")
        wheels = download_wheels(platform, cache)
        listed = ", ".join(f'"./wheels/{w.name}"' for w in wheels)
        lines = [f'platforms = ["{platform}"]', f"wheels = [{listed}]"]
        out = output_dir / zip_name(manifest, platform)
        compiled = compile_kernels(platform, **kernels) if kernels is not None else None
        if compiled and compiled["warp"] != WARP_VERSION:
            raise SystemExit(f"the kernels were compiled with Warp {compiled['warp']}, the zip ships Warp {WARP_VERSION}: "
                             f"build with warp-lang=={WARP_VERSION} installed")
        _write_zip(out, _with_keys(text, lines), wheels, compiled)
        outs.append(out)
    return outs


def _no_trailing_punctuation(s: str) -> bool:
    return not s or s[-1].isalnum() or s[-1] in ")]}\"'"


def manifest_errors(manifest: dict, names: set[str] | None = None) -> list[str]:
    """Problems with a manifest (and, given the archive's file names, its layout)."""
    errors = []
    for key in REQUIRED:
        if key not in manifest:
            errors.append(f"'{key}' is required")
    for key, value in manifest.items():
        if value in ("", [], {}):
            errors.append(f"'{key}' is empty: leave optional keys out instead")
    get = manifest.get
    if "schema_version" in manifest and get("schema_version") != "1.0.0":
        errors.append(f"schema_version must be \"1.0.0\", got {get('schema_version')!r}")
    if get("id") and not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", str(get("id"))):
        errors.append(f"id {get('id')!r} must be an identifier (letters, digits, underscores)")
    for key in ("version", "blender_version_min", "blender_version_max"):
        if get(key) and not SEMVER.match(str(get(key))):
            errors.append(f"{key} {get(key)!r} is not a semantic version")
    bmin = get("blender_version_min")
    if bmin and SEMVER.match(str(bmin)) and tuple(map(int, str(bmin).split("-")[0].split(".")[:3])) < (4, 2, 0):
        errors.append(f"blender_version_min must be at least 4.2.0, got {bmin}")
    tagline = get("tagline")
    if isinstance(tagline, str):
        if len(tagline) > 64:
            errors.append(f"tagline is {len(tagline)} characters (at most 64)")
        if not _no_trailing_punctuation(tagline):
            errors.append("tagline must not end with punctuation")
    if get("type") is not None and get("type") not in ("add-on", "theme"):
        errors.append(f"type must be \"add-on\" or \"theme\", got {get('type')!r}")
    lic = get("license")
    if lic is not None and (not isinstance(lic, list) or not all(isinstance(x, str) and x.startswith("SPDX:") for x in lic)):
        errors.append("license must be a list of \"SPDX:<identifier>\" strings")
    plat = get("platforms")
    if plat is not None and (not isinstance(plat, list) or not set(plat) <= BLENDER_PLATFORMS):
        errors.append(f"platforms must be a subset of {sorted(BLENDER_PLATFORMS)}, got {plat!r}")
    perms = get("permissions")
    if perms is not None:
        if not isinstance(perms, dict):
            errors.append("[permissions] must be a table")
        else:
            for k, reason in perms.items():
                if k not in PERMISSIONS:
                    errors.append(f"unknown permission {k!r} (one of {', '.join(sorted(PERMISSIONS))})")
                elif not isinstance(reason, str) or not reason or len(reason) > 64 or reason.endswith("."):
                    errors.append(f"permission {k!r}: the reason must be 1-64 characters without a final period")
    wheels = get("wheels")
    if wheels is not None:
        if not isinstance(wheels, list):
            errors.append("wheels must be a list of paths")
        else:
            for w in wheels:
                name = str(w).rsplit("/", 1)[-1]
                if "\\" in str(w) or not str(w).startswith("./wheels/"):
                    errors.append(f"wheel path {w!r} must be relative, with forward slashes, under ./wheels/")
                if not WHEEL_NAME.match(name):
                    errors.append(f"wheel {name!r} does not follow the wheel file-name convention")
                if names is not None and str(w)[2:] not in names:
                    errors.append(f"wheel {w!r} is listed but not in the archive")
    build_tbl = get("build")
    if isinstance(build_tbl, dict) and "paths" in build_tbl and "paths_exclude_pattern" in build_tbl:
        errors.append("[build] takes paths or paths_exclude_pattern, not both")
    if names is not None and manifest.get("type") == "add-on" and "__init__.py" not in names:
        errors.append("an add-on needs __init__.py beside blender_manifest.toml")
    return errors


def _blender_ext() -> Path | None:
    """Blender's own extension CLI, shipped inside the bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    for root in spec.submodule_search_locations:
        for cand in Path(root).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"):
            return cand
    return None


def validate(path: Path) -> list[str]:
    """Errors for a zip or a directory holding blender_manifest.toml (empty when valid)."""
    if path.is_dir():
        names = {p.relative_to(path).as_posix() for p in path.rglob("*") if p.is_file()}
        raw = (path / "blender_manifest.toml").read_bytes() if "blender_manifest.toml" in names else None
    else:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            raw = zf.read("blender_manifest.toml") if "blender_manifest.toml" in names else None
    if raw is None:
        return [f"{path}: no blender_manifest.toml at the top"]
    try:
        manifest = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        return [f"blender_manifest.toml: {exc}"]
    errors = manifest_errors(manifest, names)
    tool = _blender_ext()
    if tool is not None:
        proc = subprocess.run([sys.executable, str(tool), "validate", str(path)], capture_output=True, text=True)
        if proc.returncode != 0:
            errors.append("Blender's validator: " + (proc.stdout + proc.stderr).strip())
    return errors


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["compile-kernels"]:  # compile_kernels' child
        print(json.dumps(compile_kernels_here(json.loads(argv[1]))))
        return 0
    if argv[:1] == ["validate"]:
        p = argparse.ArgumentParser(prog="build_extension.py validate")
        p.add_argument("path", type=Path, help="the extension zip or source directory")
        args = p.parse_args(argv[1:])
        errors = validate(args.path)
        for e in errors:
            print(f"{args.path}: {e}", file=sys.stderr)
        if not errors:
            checked = "fields, layout" + (" and Blender's validator" if _blender_ext() else " (Blender's validator not found)")
            print(f"valid: {args.path} ({checked})")
        return 1 if errors else 0
    if argv[:1] == ["kernels"]:
        p = argparse.ArgumentParser(prog="build_extension.py kernels", description="build the compiled kernels' store only")
        p.add_argument("--platform", default=host_platform(), help="the zip's platform (default: this machine's)")
        p.add_argument("--no-cpu", action="store_true", help="no CPU objects (CUDA only: no CPU compiler needed)")
        _kernel_arguments(p)
        args = p.parse_args(argv[1:])
        kernels = _kernel_options(args)
        built = compile_kernels(args.platform, **kernels, cpu=False if args.no_cpu else None)
        mib = sum(Path(f).stat().st_size for f in built["files"]) / 2**20
        print(f"{len(built['files'])} files ({mib:.1f} MiB) in {args.kernel_store}/warp-{built['warp']}, "
              f"{built['seconds']:.0f} s")
        return 0
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--output-dir", type=Path, default=REPO / "dist", help="where to write the zip (default: dist/)")
    p.add_argument("--wheels", action="store_true", help="one zip per platform with the wheels of every runtime dependency bundled")
    p.add_argument("--platforms", default=",".join(DEFAULT_PLATFORMS),
                   help=f"with --wheels: comma-separated Blender platforms (default {','.join(DEFAULT_PLATFORMS)})")
    p.add_argument("--kernels", action=argparse.BooleanOptionalAction, default=None,
                   help="ship compiled kernels (default: with --wheels)")
    _kernel_arguments(p)
    args = p.parse_args(argv)
    kernels = _kernel_options(args) if args.kernels or (args.kernels is None and args.wheels) else None
    outs = (build_with_wheels(args.output_dir, [s.strip() for s in args.platforms.split(",") if s.strip()],
                              kernels=kernels)
            if args.wheels else [build(args.output_dir, kernels)])
    for out in outs:
        size = out.stat().st_size / 2**20
        with zipfile.ZipFile(out) as zf:
            shipped = [i for i in zf.infolist() if i.filename.startswith(KERNEL_FOLDER + "/")]
        note = f", {len(shipped)} compiled-kernel files ({kernel_mib(out):.1f} MiB in the zip)" if shipped else ""
        print(f"built {out} ({size:.1f} MiB{note})")
    return 0


def _kernel_arguments(p: argparse.ArgumentParser):
    p.add_argument("--kernel-variants", default=",".join(DEFAULT_KERNEL_VARIANTS),
                   help="(affine|curved):MODES[-MODES][:derived], comma-separated: the sample kernels to ship "
                        "(default %(default)s)")
    p.add_argument("--kernel-precisions", default=",".join(DEFAULT_KERNEL_PRECISIONS),
                   help="float32 and/or float64, comma-separated (default %(default)s)")
    p.add_argument("--kernel-cubin-archs", default=None,
                   help="CUBIN for these CUDA archs, comma-separated (default: engine/shipped_kernels.CUBIN_ARCHS; "
                        "'' for none)")
    p.add_argument("--kernel-ptx-archs", default=None,
                   help="PTX for these CUDA archs (default: engine/shipped_kernels.PTX_ARCHS; '' for none)")
    p.add_argument("--kernel-jobs", type=int, default=None, help="modules compiled at once (default: a core each)")
    p.add_argument("--kernel-store", type=Path, default=KERNEL_STORE, help="where compiled kernels are kept between builds")


def _kernel_options(args) -> dict:
    """compile_kernels' arguments from _kernel_arguments' options."""
    def archs(text):
        return None if text is None else tuple(int(a) for a in text.split(",") if a.strip())

    return {"variants": parse_variants(args.kernel_variants), "store": args.kernel_store,
            "precisions": tuple(x.strip() for x in args.kernel_precisions.split(",") if x.strip()),
            "cubin_archs": archs(args.kernel_cubin_archs), "ptx_archs": archs(args.kernel_ptx_archs),
            "workers": args.kernel_jobs}


if __name__ == "__main__":
    sys.exit(main())
