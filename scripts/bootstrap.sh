#!/usr/bin/env bash
# Create the virtual environment the tests run in (Python 3.11), idempotently: pip runs again
# only when pyproject.toml changed since the environment was last set up.
#   bash scripts/bootstrap.sh            .venv: the package, bpy 5.0.1 (the newest Blender) and
#                                        every test tool
#   bash scripts/bootstrap.sh 4.2.23     .venv-bpy-4.2.23: the package and the tools the Blender
#                                        tests need, with that bpy (an older Blender the
#                                        manifest promises)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
command -v "$PY" >/dev/null || PY=python3
bpy_version=${1:-}
if [ -z "$bpy_version" ]; then
  venv=.venv
  spec=(-e ".[blender,test]")
else
  venv=.venv-bpy-$bpy_version
  spec=(-e ".[blender-test]" "bpy==$bpy_version")
fi
if [ ! -x "$venv/bin/python" ]; then
  "$PY" -m venv "$venv"
fi
stamp=$venv/.hovr-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  "$venv/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$venv/bin/python" -m pip install -q "${spec[@]}"
  touch "$stamp"
fi
