#!/usr/bin/env bash
# Create .venv (Python 3.11) with the package, bpy 5.0.1 (Blender as a module) and test tools.
# Idempotent: re-runs pip only when pyproject.toml changed since the last bootstrap.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.hovr-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --upgrade pip >/dev/null
  .venv/bin/python -m pip install -q -e ".[blender,test]"
  touch "$stamp"
fi
