#!/usr/bin/env bash
# Download the pure-Python wheels dask.distributed needs (and their few binary ones for CPython 3.12
# on x86-64 Linux) into .gpu/dask/ (git-ignored), for a GPU machine that cannot reach PyPI: carry
# .gpu/dask there and install from it without an index.
#   bash scripts/gpu_wheels.sh            # here, with network access
#   python -m pip install --no-index --find-links .gpu/dask "dask[distributed]" cryptography    # there
# (cryptography: a local cluster's TLS keys, distributed/series.local_cluster)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-/work/main/.venv/bin/python}
[ -x "$PY" ] || PY=python3
dest=.gpu/dask
mkdir -p "$dest"
"$PY" -m pip download -q --dest "$dest" --only-binary=:all: \
  --python-version 3.12 --implementation cp --abi cp312 --platform manylinux2014_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux_2_28_x86_64 --platform any \
  "dask[distributed]>=2024.1" "cryptography>=42"
ls "$dest"
du -sh "$dest"
