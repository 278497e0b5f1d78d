#!/usr/bin/env bash
# Pack what the GPU audits read besides Warp and VTK into one part for a CUDA machine with no
# internet (scripts/audit.py gpu, scripts/watertight.py): the shared data files of the audit's
# datasets (hovr_blender/audit/datasets.py, ../shared/data or HOVR_DATA; ~17 MB compressed) and
# the wheels of the readers' dependencies that machine lacks (defusedxml: io/safe_xml.py). Writes
# .gpu/data (git-ignored). Run from inside the checkout:
#
#   bash scripts/pack-data.sh
#
# Then, on the CUDA machine, with .gpu/data carried:
#   source .gpu/data/install.sh      (unpacks into /tmp/hovr-data, exports HOVR_DATA and PYTHONPATH)
set -euo pipefail
root=$(git rev-parse --show-toplevel)
cd "$root"
PY=${PYTHON:-/work/main/.venv/bin/python}
[ -x "$PY" ] || PY=python3
out=$root/.gpu/data
rm -rf "$out"; mkdir -p "$out/wheels"
shared=$(PYTHONPATH=$root "$PY" -c 'from hovr_blender.audit.datasets import SHARED; print(SHARED)')
files=$(PYTHONPATH=$root "$PY" -c '
from hovr_blender.audit.datasets import DATASETS
print("\n".join(sorted({v for spec in DATASETS.values() for k, v in spec.items() if k in ("path", "solution")})))')
(cd "$shared" && tar -cf - $files) | xz -T0 -6 > "$out/shared-data.tar.xz"
"$PY" -m pip download -q --no-deps --only-binary=:all: -d "$out/wheels" "defusedxml>=0.7"
cat > "$out/install.sh" <<'EOS'
# source me: the audit's data in /tmp/hovr-data (HOVR_DATA) and its wheels in /tmp/site-extra
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
[ -d /tmp/hovr-data/vtu ] || { mkdir -p /tmp/hovr-data && tar -xJf "$here/shared-data.tar.xz" -C /tmp/hovr-data; }
[ -d /tmp/site-extra/defusedxml ] || python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site-extra "$here"/wheels/*.whl
export HOVR_DATA=/tmp/hovr-data PYTHONPATH=/tmp/site-extra${PYTHONPATH:+:$PYTHONPATH}
echo "data ready in $HOVR_DATA: $(ls /tmp/hovr-data/*/ | tr '\n' ' ')"
EOS
du -sh "$out"
