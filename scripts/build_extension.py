#!/usr/bin/env python3
"""Build the Blender extension zip: dist/hovr_blender-<version>.zip.

The repository keeps blender_manifest.toml at the top and the add-on in hovr_blender/;
Blender wants the manifest and the package's __init__.py side by side, so the zip holds
the manifest plus the *contents* of hovr_blender/ at its root (no tests, no caches).
Usage: python scripts/build_extension.py [--output-dir dist]
"""
from __future__ import annotations

import argparse
import sys
import tomllib
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "hovr_blender"
MANIFEST = REPO / "blender_manifest.toml"
SKIP_DIRS = {"__pycache__", "tests"}
SKIP_SUFFIXES = {".pyc", ".pyo", ".zip"}


def package_files(root: Path):
    """(path, name in zip) for every file the extension ships, in a stable order."""
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root)
        if not path.is_file() or any(part in SKIP_DIRS or part.startswith(".") for part in rel.parts):
            continue
        if path.suffix in SKIP_SUFFIXES:
            continue
        yield path, rel.as_posix()


def build(output_dir: Path) -> Path:
    with open(MANIFEST, "rb") as fh:
        manifest = tomllib.load(fh)
    for key in ("id", "version"):
        if not manifest.get(key):
            raise SystemExit(f"{MANIFEST.name}: '{key}' is missing or empty")
    output_dir.mkdir(parents=True, exist_ok=True)
    out = output_dir / f"{manifest['id']}-{manifest['version']}.zip"
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.write(MANIFEST, "blender_manifest.toml")
        for path, name in package_files(PACKAGE):
            zf.write(path, name)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--output-dir", type=Path, default=REPO / "dist", help="where to write the zip (default: dist/)")
    args = p.parse_args(argv)
    out = build(args.output_dir)
    print(f"built {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
