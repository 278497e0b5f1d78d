"""Derived fields evaluated exactly at a point (render contract §8; engine/derived_fields.py).

A derived field's sample at reference point xi of element e is computed from its component
fields' own expansions there: each component's value and its reference gradient (the
gradient's expansion in the element's modes, exact on hexahedra, prisms and tetrahedra:
engine/isosurfaces.reference_gradient), turned into a gradient in the data's coordinates by
the geometry map's inverse Jacobian, grad u = (J^-1 A)^T grad_xi u (A: the object transform's
linear part, so that a moved or scaled object keeps its data's gradients). From them:

- |grad f| of one scalar;
- for a velocity u (three components, or momenta m over a density rho: u = m / rho,
  grad u_i = (grad m_i - u_i grad rho) / rho), L_ij = d u_i / d x_j:
  vorticity magnitude |curl u|, Q = 1/2 (|Omega|^2 - |S|^2) = -1/2 sum_ij L_ij L_ji, and the
  speed |u|.

Exact means exact per sample: the value of the formula on the components' expansions at that
point, to rounding. The segment's series then interpolates those samples like a curved
element's field (restriction.py; its tail refined against CURVED_TAIL_RTOL).
"""
from __future__ import annotations

import warp as wp

from . import element
from .args import DerivedArgs, MeshArgs

wp.set_module_options({"enable_backward": False})

# DerivedArgs.kind per element: the operation, plus PER_DENSITY where the velocity is momentum
# over density (component 3 the density); FIELD: the element's own field (another volume)
FIELD = 0
GRADIENT = 1
VORTICITY = 2
Q_CRITERION = 3
SPEED = 4
PER_DENSITY = 8
# engine/derived_fields.OPERATIONS by name
OPERATION_IDS = {"|grad|": GRADIENT, "vorticity": VORTICITY, "Q": Q_CRITERION, "speed": SPEED}


# out of line: derived_of evaluates 20 expansions, each eval_element with all four shapes, and
# an isosurface's composite_event inlines derived_of twice (NVRTC spent minutes on the copies)
@wp.func(inline=False)
def component_expansion(dv: DerivedArgs, shape: int, e: int, c: int, k: int, xi: wp.vec3) -> float:
    """Component c of element e at xi: its value (k = 0) or its reference derivative d/dxi_(k-1)."""
    return element.eval_element(shape, dv.coeffs, dv.offset[e] + (4 * c + k) * dv.size[e], dv.modes[e], xi)


@wp.func
def value_and_gradient(dv: DerivedArgs, shape: int, e: int, c: int, xi: wp.vec3, M: wp.mat33):
    """(u_c, grad u_c) at xi, the gradient in the data's coordinates (M = J^-1 A)."""
    g = wp.vec3(component_expansion(dv, shape, e, c, 1, xi), component_expansion(dv, shape, e, c, 2, xi),
                component_expansion(dv, shape, e, c, 3, xi))
    return component_expansion(dv, shape, e, c, 0, xi), wp.transpose(M) * g


@wp.func
def derived_value(mesh: MeshArgs, e: int, xi: wp.vec3, Jinv: wp.mat33) -> float:
    """The derived field of element e at xi in the field's own units (Jinv = dxi/dx there)."""
    return derived_of(mesh, e, xi, Jinv, mesh.derived.kind[e])


@wp.func
def derived_of(mesh: MeshArgs, e: int, xi: wp.vec3, Jinv: wp.mat33, kind: int) -> float:
    """Derived field `kind` (an operation, + PER_DENSITY where the components are momenta and
    density) of element e's components at xi, in its own units."""
    dv = mesh.derived
    shape = mesh.shape[e]
    op = kind % PER_DENSITY
    M = Jinv * dv.axes[e]
    if op == GRADIENT:
        u, g = value_and_gradient(dv, shape, e, 0, xi, M)
        return wp.length(g)
    rho = float(1.0)
    g_rho = wp.vec3(0.0, 0.0, 0.0)
    if kind >= PER_DENSITY:
        rho, g_rho = value_and_gradient(dv, shape, e, 3, xi, M)
    u0, l0 = value_and_gradient(dv, shape, e, 0, xi, M)
    u1, l1 = value_and_gradient(dv, shape, e, 1, xi, M)
    u2, l2 = value_and_gradient(dv, shape, e, 2, xi, M)
    if kind >= PER_DENSITY:
        u0 = u0 / rho
        u1 = u1 / rho
        u2 = u2 / rho
        l0 = (l0 - u0 * g_rho) / rho
        l1 = (l1 - u1 * g_rho) / rho
        l2 = (l2 - u2 * g_rho) / rho
    if op == SPEED:
        return wp.length(wp.vec3(u0, u1, u2))
    if op == VORTICITY:
        return wp.length(wp.vec3(l2[1] - l1[2], l0[2] - l2[0], l1[0] - l0[1]))
    # Q = -1/2 tr(L L), rows l_i = grad u_i
    diagonal = l0[0] * l0[0] + l1[1] * l1[1] + l2[2] * l2[2]
    off = l0[1] * l1[0] + l0[2] * l2[0] + l1[2] * l2[1]
    return -0.5 * diagonal - off


@wp.func
def sample_value(mesh: MeshArgs, e: int, xi: wp.vec3, Jinv: wp.mat33) -> float:
    """A sample of element e at xi in the field's frame (f' = a f + b: DerivedArgs.frame)."""
    if mesh.derived.kind[e] == FIELD:
        return element.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)
    ab = mesh.derived.frame[e]
    return ab[0] * derived_value(mesh, e, xi, Jinv) + ab[1]
