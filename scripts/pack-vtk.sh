#!/usr/bin/env bash
# Pack VTK's wheel for a CUDA machine with Python 3.12 on x86-64 (no internet there) into parts
# under 40 MB that travel one per remote command, the way ../shared/gpu/pack-warp.sh packs Warp.
# Writes .gpu/vtk-1 .. .gpu/vtk-N (git-ignored). Run from inside the checkout:
#
#   bash scripts/pack-vtk.sh                  (VTK_VERSION=9.7.2 by default: pyproject's test pin)
#
# Then, on the CUDA machine, in order and close together (parts wait in $HOME/vtk-stash):
#   bash .gpu/vtk-1/stash.sh                    (with .gpu/vtk-1 carried)
#   ... the same for every part but the last ...
#   source .gpu/vtk-N/install.sh                (with .gpu/vtk-N carried)
# install.sh joins the wheel, unpacks it into /tmp/site-vtk, exports PYTHONPATH and reports
# which OpenGL libraries VTK can use there (EGL needs libEGL.so.1 and NVIDIA's EGL vendor
# library). While the machine stays up, later commands only need
#   export PYTHONPATH=/tmp/site-vtk:$PYTHONPATH
#
# VTK_SUBSET=reference packs instead, in ONE part (.gpu/vtk-reference, ~18 MB), only what the
# independent reference imports (hovr_blender/audit/vtk_volume.import_vtk: vtkCommonCore,
# vtkCommonDataModel, vtkIOXML, the libraries they need by their ELF NEEDED entries, and
# vtkmodules' Python files): enough for scripts/audit.py gpu, not for rendering. There:
#   source .gpu/vtk-reference/install.sh        (with .gpu/vtk-reference carried; same /tmp/site-vtk)
set -euo pipefail
root=$(git rev-parse --show-toplevel)
ver=${VTK_VERSION:-9.7.2}
out=$root/.gpu
part_mb=${VTK_PART_MB:-36}
if [ "${VTK_SUBSET:-}" = reference ]; then
  d=$out/vtk-reference
  if [ -f "$d/VERSION" ] && [ "$(cat "$d/VERSION")" = "$ver" ]; then echo "already packed: $d"; exit 0; fi
  tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$tmp" "vtk==$ver"
  mkdir "$tmp/x" && (cd "$tmp/x" && python3 -m zipfile -e "$tmp"/vtk-*.whl .)
  # the three Python modules and, transitively, every library of the wheel they name as NEEDED and
  # that library's own Python module
  (cd "$tmp/x/vtkmodules" && python3 - > "$tmp/files" <<'EOP'
import glob, os, re, subprocess
todo = [glob.glob(m + ".cpython-*.so")[0] for m in ("vtkCommonCore", "vtkCommonDataModel", "vtkIOXML")]
need = set()
while todo:
    f = todo.pop()
    if f in need:
        continue
    need.add(f)
    for lib in re.findall(r"\(NEEDED\).*\[(.+?)\]", subprocess.run(["readelf", "-d", f], capture_output=True, text=True).stdout):
        if os.path.exists(lib):
            todo.append(lib)
            # a wrapped module imports the wrappers of the libraries it links (vtkCommonMath ...)
            todo += glob.glob(re.sub(r"^lib(vtk[A-Za-z0-9]+)\.so.*", r"\1", lib) + ".cpython-*.so")
need.update(glob.glob("**/*.py", recursive=True))
print("\n".join(sorted(need)))
EOP
  )
  rm -rf "$d"; mkdir -p "$d"
  (cd "$tmp/x" && sed 's#^#vtkmodules/#' "$tmp/files" | tar -cf - -T - vtk-*.dist-info) | xz -T0 -9 > "$d/vtk-reference.tar.xz"
  echo "$ver" > "$d/VERSION"
  cat > "$d/install.sh" <<'EOS'
# source me: unpacks the reference's VTK subset into /tmp/site-vtk and exports PYTHONPATH
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
[ -f /tmp/site-vtk/vtkmodules/__init__.py ] || { mkdir -p /tmp/site-vtk && tar -xJf "$here/vtk-reference.tar.xz" -C /tmp/site-vtk; }
export PYTHONPATH=/tmp/site-vtk${PYTHONPATH:+:$PYTHONPATH}
python3 -c 'from vtkmodules import vtkCommonDataModel, vtkIOXML; print("vtk reference subset ready in /tmp/site-vtk")'
EOS
  du -sh "$d"; exit 0
fi
if ls "$out"/vtk-*/VERSION >/dev/null 2>&1 && [ "$(cat "$out"/vtk-*/VERSION)" = "$ver" ]; then
  echo "already packed: vtk $ver under $out"; ls -d "$out"/vtk-*; exit 0
fi
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d "$tmp" "vtk==$ver"
whl=$(ls "$tmp"/vtk-*.whl); name=$(basename "$whl")
sum=$(sha256sum "$whl" | cut -d' ' -f1)
(cd "$tmp" && split -b "${part_mb}M" -d -a 1 "$name" piece.)
parts=$(ls "$tmp"/piece.* | wc -l)
rm -rf "$out"/vtk-*; mkdir -p "$out"
for i in $(seq 1 "$parts"); do
  d=$out/vtk-$i; mkdir -p "$d"; mv "$tmp/piece.$((i - 1))" "$d/vtk.whl.$i"
  printf '#!/usr/bin/env bash\nset -e; mkdir -p $HOME/vtk-stash; cp "$(dirname "$0")"/vtk.whl.%s $HOME/vtk-stash/; echo "stashed part %s of %s"\n' "$i" "$i" "$parts" > "$d/stash.sh"
  chmod +x "$d/stash.sh"
done
last=$out/vtk-$parts
echo "$ver" > "$last/VERSION"
# GLVND's EGL/OpenGL dispatch libraries (Debian's libegl1, libglvnd0, libopengl0): a CUDA machine
# may carry NVIDIA's EGL vendor library without the loader VTK opens (libEGL.so.1)
mkdir -p "$tmp/debs" "$last/glvnd"
(cd "$tmp/debs" && apt-get download -q libegl1 libglvnd0 libopengl0 >/dev/null 2>&1) &&
  for deb in "$tmp"/debs/*.deb; do dpkg-deb -x "$deb" "$tmp/root"; done &&
  for so in libEGL.so.1 libGLdispatch.so.0 libOpenGL.so.0; do cp -L "$tmp/root/usr/lib/x86_64-linux-gnu/$so" "$last/glvnd/"; done ||
  echo "could not fetch GLVND (apt-get download): VTK will need the machine's own libEGL.so.1"
cat > "$last/install.sh" <<EOS
# source me: joins VTK's wheel, unpacks it into /tmp/site-vtk, exports PYTHONPATH, reports OpenGL
if [ ! -f /tmp/site-vtk/vtkmodules/__init__.py ]; then
  here=\$(cd "\$(dirname "\${BASH_SOURCE[0]}")" && pwd)
  mkdir -p \$HOME/vtk-stash && cp "\$here"/vtk.whl.$parts \$HOME/vtk-stash/
  missing=0; for i in \$(seq 1 $parts); do [ -f \$HOME/vtk-stash/vtk.whl.\$i ] || { echo "part \$i missing: run .gpu/vtk-\$i/stash.sh first, on this same machine"; missing=1; }; done
  if [ \$missing = 0 ]; then
    for i in \$(seq 1 $parts); do cat \$HOME/vtk-stash/vtk.whl.\$i; done > /tmp/$name
    if [ "\$(sha256sum /tmp/$name | cut -d' ' -f1)" = "$sum" ]; then
      mkdir -p /tmp/site-vtk && python3 -m zipfile -e /tmp/$name /tmp/site-vtk && rm -f /tmp/$name
    else
      echo "vtk wheel checksum mismatch"; rm -f /tmp/$name
    fi
  fi
fi
if [ -f /tmp/site-vtk/vtkmodules/__init__.py ]; then
  export PYTHONPATH=/tmp/site-vtk\${PYTHONPATH:+:\$PYTHONPATH}; echo "vtk $ver ready in /tmp/site-vtk"
  if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1 '; then
    here=\$(cd "\$(dirname "\${BASH_SOURCE[0]}")" && pwd)
    mkdir -p /tmp/glvnd && cp "\$here"/glvnd/* /tmp/glvnd/ 2>/dev/null &&
      export LD_LIBRARY_PATH=/tmp/glvnd\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH} && echo "GLVND's libEGL.so.1 from the pack: /tmp/glvnd"
  fi
  echo "OpenGL libraries here (VTK needs libEGL.so.1 + an EGL vendor such as libEGL_nvidia, or libOSMesa):"
  (ldconfig -p 2>/dev/null | grep -E 'libEGL|libOpenGL|libGLX|libOSMesa' || echo "  none found by ldconfig")
  ls /usr/share/glvnd/egl_vendor.d/ 2>/dev/null || echo "  no /usr/share/glvnd/egl_vendor.d"
else
  false
fi
EOS
du -sh "$out"/vtk-*
