"""The error of a vector magnitude's fit (io/magnitude.py: the stated bound and the largest
measured |fit - |u||), on a real file:

    python -m bench.magnitude_error MESH.xml SOLUTION "|u,v,w|"       (Nektar++)
    python -m bench.magnitude_error FILE.vtu FIELD                     (a VTU vector)

The numbers io/magnitude.py's docstring quotes come from it (seed 0).
"""
from __future__ import annotations

import sys


def main(argv=None) -> int:
    """The mesh's size and its magnitude's error line (the last of the mesh's warnings)."""
    from hovr_blender.io.formats import format_of

    argv = sys.argv[1:] if argv is None else argv
    data = format_of(argv[0])
    if data.takes_solution:
        mesh = data.read(argv[0], argv[1], argv[2])
    else:
        mesh = data.read(argv[0], None, argv[1] if len(argv) > 1 else None)
    print(f"{mesh.num_elements} elements; {mesh.fit_report}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
