#!/usr/bin/env bash
# Render the bundled demo (the paper's sphere) through Blender's render pipeline to a PNG.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/python -m scripts.render_demo "$@"
