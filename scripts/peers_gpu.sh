#!/usr/bin/env bash
# The GPU half of issue 19 (bench/peers.py on cuda:0 beside VTK on the same GPU through EGL), for
# a CUDA machine with Python 3.12 and numpy, no internet. Warp and VTK travel in parts:
#   on the machine with internet:  bash ../shared/gpu/pack-warp.sh; bash scripts/pack-vtk.sh
#   on the CUDA machine, once:     bash .gpu/warp-1/stash.sh ... ; source .gpu/warp-N/install.sh
#                                  bash .gpu/vtk-1/stash.sh ... ;  source .gpu/vtk-N/install.sh
# then, one group of datasets per command (each stays under 10 minutes):
#   OUT=$OUT bash scripts/peers_gpu.sh small        Hex_CurvedFace, Hex_Mushroom, mfem_fichera, pyfr_tgv
#   OUT=$OUT bash scripts/peers_gpu.sh curved       ngsolve_ball, ngsolve_post, hump3D
#   OUT=$OUT bash scripts/peers_gpu.sh paper        paper_scale
# Extra arguments go to bench/peers.py (e.g. --size 1280x720). The tetrahedra go to the OpenGL
# projected-tetrahedra mapper only by default: VTK's unstructured ray caster is a CPU mapper
# (about 60 s a 1920x1080 frame of ngsolve_ball's lattice, from the CPU run); MAPPERS=raycast,projected
# adds it (the small group fits). Results: $OUT/peers-<group>/
# (peers.json, peers.md, figure_images/*.npz; figures too where matplotlib exists, else draw
# them back home: python -m bench.peers --plot $OUT/peers-<group>/peers.json --figures docs).
# If VTK finds no EGL there (install.sh lists the OpenGL libraries), peers.py says so and runs
# our methods only: every VTK volume mapper, the CPU ray caster included, draws through OpenGL.
# The JSON's "vtk_opengl" names the OpenGL renderer VTK got: it must name the NVIDIA GPU; if it
# says llvmpipe, VTK rendered in software on the CPU and its times are not GPU times.
set -uo pipefail
cd "$(dirname "$0")/.."
group=${1:-small}; shift || true
case $group in
  small)  sets=Hex_CurvedFace,Hex_Mushroom,mfem_fichera,pyfr_tgv ;;
  curved) sets=ngsolve_ball,ngsolve_post,hump3D ;;
  paper)  sets=paper_scale ;;
  *)      sets=$group ;;
esac
export PYTHONPATH=/tmp/site-vtk:/tmp/site${PYTHONPATH:+:$PYTHONPATH}
out=${OUT:-out}/peers-$group
mkdir -p "$out"
python3 -c "import warp, vtk; print('warp', warp.__version__, 'vtk', vtk.vtkVersion.GetVTKVersion())" ||
  { echo "warp or vtk missing: source .gpu/warp-N/install.sh and .gpu/vtk-N/install.sh first"; exit 2; }
nvidia-smi -L 2>/dev/null || true
HOVR_COMMIT=${HOVR_COMMIT:-$(git rev-parse --short HEAD 2>/dev/null)} \
  python3 -m bench.peers --device cuda:0 --size 1920x1080 --datasets "$sets" --out "$out" --figures "$out" \
  --max-minutes 8 --budget 60 --sample 0 --check-seconds 20 --repeats 2 --mappers "${MAPPERS:-projected}" \
  "$@" 2>&1 | tee "$out/peers.log"
