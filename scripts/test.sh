#!/usr/bin/env bash
# Run every test: core (no bpy), Blender (bpy module) and image tests. Sets up .venv first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/python -m pytest -q "$@"
