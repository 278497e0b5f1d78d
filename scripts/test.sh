#!/usr/bin/env bash
# Every test: core (no bpy), Blender (bpy module), hostile inputs and image tests, on the newest
# Blender (bpy 5.0.1, .venv); then the Blender tests again on each older Blender the manifest
# promises (BLENDER_LTS below, one cached .venv-bpy-X each). Sets up the environments first.
#   bash scripts/test.sh [pytest args]   pytest args apply to the main run only
#   HOVR_BLENDER_LTS="" bash scripts/test.sh     the newest Blender only
# Every CPU test runs, slow ones included; pass -m "not slow" for a quick pass. Tests marked gpu
# (the device fixture's cuda:0 cases) skip where there is no CUDA device.
set -euo pipefail
cd "$(dirname "$0")/.."
BLENDER_LTS=${HOVR_BLENDER_LTS-"4.2.23 4.5.15"}
bash scripts/bootstrap.sh
.venv/bin/python -m pytest -q "$@"
for v in $BLENDER_LTS; do
  echo "== Blender tests on bpy $v"
  bash scripts/bootstrap.sh "$v"
  ".venv-bpy-$v/bin/python" -m pytest -q tests/blender
done
