"""The kernels' tolerances that depend on the precision, in one table: each NAME is its float32
value, and NAME_FLOAT64 beside it is the value the float64 twin takes for NAME
(kernels/precision.py, which refuses a float here without its partner, and a pair anywhere else).
The kernel modules import them by name."""
from __future__ import annotations

import warp as wp  # noqa: F401  (the float64 twin writes each value as wp.float64)

# element.reference_clip: a reference-space clip within this of a face counts as on it
CLIP_TOL = 1.0e-6
CLIP_TOL_FLOAT64 = 1.0e-12
# geometry: reference-space margin still counted as inside (float32 noise in xi)
INSIDE_TOL = 1.0e-5
INSIDE_TOL_FLOAT64 = 1.0e-11
# geometry: Newton stops after a step below this (quadratic: xi then ~1e-10 off)
NEWTON_STEP_TOL = 1.0e-5
NEWTON_STEP_TOL_FLOAT64 = 1.0e-8
# geometry: relative bracket width where boundary and level crossings stop
ROOT_RTOL = 1.0e-7
ROOT_RTOL_FLOAT64 = 1.0e-13
# raycast: a point this close to a curved element's face (reference units) is on it
SHARED_FACE_TOL = 1.0e-3
SHARED_FACE_TOL_FLOAT64 = 1.0e-8
# raycast: a stretch beyond t must reach past t + STRETCH_RTOL |t| to count (rounding of the exit
# just left); an affine neighbour's entry may lie STRETCH_RTOL (|t| + its chord) beyond the exit
STRETCH_RTOL = 1.0e-5
STRETCH_RTOL_FLOAT64 = 1.0e-11
# restriction: a curved interpolant's tail against its samples' size (refine_degree)
CURVED_TAIL_RTOL = 1.0e-6
CURVED_TAIL_RTOL_FLOAT64 = 1.0e-12
# isosurface: the arithmetic's epsilon (rounding of a series' value, Newton's stop in the root finder)
ROOT_EPS = 1.2e-7
ROOT_EPS_FLOAT64 = 2.3e-16
# the unit roundoff of the arithmetic (2^-24, 2^-53): rays.affine_clip_rounding
UNIT_ROUNDOFF = 6.0e-8
UNIT_ROUNDOFF_FLOAT64 = 1.12e-16
