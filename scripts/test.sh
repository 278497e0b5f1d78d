#!/usr/bin/env bash
# Run every test: core (no bpy), Blender (bpy module) and image tests. Sets up .venv first.
# Every CPU test runs, slow ones included; pass -m "not slow" for a quick pass. Tests marked gpu
# (the device fixture's cuda:0 cases) skip where there is no CUDA device.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/python -m pytest -q "$@"
