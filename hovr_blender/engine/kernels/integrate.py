"""Integration (kernels/quadrature.py's methods over a ray's segments): the segment classes, the
step_terms kernel (classified's own step without the transmittance), the integrate kernel (a
round's segments into each ray's colour, transmittance, depth and error, and the next round's
list) and finalize (the pixels). integrate_counted is one segment as both integrate and the
segment cache's shade take it (kernels/cache.py); integrate_counted_surfaces the same with the
look's isosurfaces and planes (kernels/isosurface.py), the compile-time variant
make_integrate_kernel(True) of integrate."""
from __future__ import annotations

import warp as wp

from . import isosurface
from . import quadrature
from . import restriction
from .args import (MAX_SAMPLES, SEG_CURVED, SEG_EVALUATE, SEG_INTERPOLANT, SEGMENTS_PER_ROUND, STAT_EMPTY, STAT_FIELD_EVALS,
                   STAT_PIECEWISE, STAT_RESTRICTION_EVALS, STAT_SMOOTH, CameraArgs, MeshArgs, QuadArgs, RayState,
                   Segments, TransferArgs)
from .quadrature import METHOD_RIEMANN, METHOD_SPLIT, RayIntegral, samples_segments
from .rays import MAX_REGISTERS, camera_ray

wp.set_module_options({"enable_backward": False})


@wp.func
def classify(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, flags: int, coeffs: wp.array(dtype=wp.float32),
             base: int, deg: int) -> wp.vec4:
    """classified and split: (lo, hi) bounding f on the segment, emitting (1 where the colour is not 0
    over them), and the segment's class: 1 empty, 2 smooth, 3 piecewise-smooth."""
    bnd = wp.vec2(0.0, 0.0)
    if (flags & (SEG_CURVED | SEG_INTERPOLANT)) != 0 and q.method != METHOD_SPLIT:
        # the paper's classes bound the true field; a curved segment's interpolant is no bound
        # of it (split integrates the interpolant itself, so its bounds decide there)
        bnd = wp.vec2(mesh.field_lo[e], mesh.field_hi[e])
    else:
        bnd = restriction.segment_bounds(coeffs, base, deg, mesh.field_err[e])
    emitting = int(0)
    if quadrature.color_max_on(tf, bnd[0], bnd[1]) > 0.0:
        emitting = 1
    piecewise = quadrature.breakpoint_inside(tf.density_s, bnd[0], bnd[1])
    if emitting == 1 and quadrature.breakpoint_inside(tf.color_s, bnd[0], bnd[1]) == 1:
        piecewise = 1
    kind = 2 + piecewise
    if quadrature.density_max_on(tf, bnd[0], bnd[1]) <= 0.0:
        kind = 1
    return wp.vec4(bnd[0], bnd[1], float(emitting), float(kind))


@wp.func
def segment_step_terms(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, flags: int,
                       coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float) -> wp.vec3:
    """A segment's quadrature.step_error_terms where it is piecewise-smooth (else 0)."""
    cls = classify(mesh, tf, q, e, flags, coeffs, base, deg)
    terms = wp.vec3(0.0, 0.0, 0.0)
    if int(cls[3]) == 3:
        terms = quadrature.step_error_terms(tf, coeffs, base, deg, a, b, cls[0], cls[1], int(cls[2]))
    return terms


@wp.kernel(enable_backward=False, module="unique")
def step_terms(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, segs: Segments, slots: wp.array(dtype=wp.int32)):
    """classified without a fixed step, one thread per sampled slot: the segment's
    quadrature.step_error_terms where it is piecewise-smooth, for integrate to turn into its steps
    with the transmittance the ray reaches it with (quadrature.auto_steps). A kernel of its own so
    that integrate's registers do not grow."""
    slot = slots[wp.tid()]
    segs.step_terms[slot] = segment_step_terms(mesh, tf, q, segs.element[slot], segs.flags[slot], segs.coeffs,
                                               slot * MAX_SAMPLES, segs.degree[slot], segs.t0[slot], segs.t1[slot])


@wp.func
def integrate_segment(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, o: wp.vec3, d: wp.vec3, a: float,
                      b: float, lo: float, hi: float, deg: int, flags: int, coeffs: wp.array(dtype=wp.float32),
                      base: int, terms: wp.vec3, state_in: RayIntegral):
    """The piece [lo, hi] of segment [a, b] into the ray state (its series at coeffs[base ..],
    restriction.py's layout, wherever it is kept: a round's slot or a cached segment; `terms`:
    its step_error_terms, for classified without a fixed step); returns the new state and
    (element evaluations, restriction evaluations, class: 1 empty, 2 smooth, 3
    piecewise-smooth, 0 unclassified)."""
    state = state_in
    evaluate = int(0)
    xo = wp.vec3(0.0, 0.0, 0.0)
    xd = wp.vec3(0.0, 0.0, 0.0)
    if (flags & SEG_EVALUATE) != 0:
        evaluate = 1
        A = mesh.ref_a[e]
        xo = A * o + mesh.ref_b[e]
        xd = A * d
    counts = wp.vec3(0.0, 0.0, 0.0)
    mode = int(0)  # 0: march (the baselines; classified's piecewise-smooth), 1: Gauss-Kronrod pieces
    trapezoid = int(1)
    piecewise = int(0)
    emitting = int(1)
    if q.method == METHOD_RIEMANN:
        trapezoid = 0
    elif samples_segments(q.method) != 0:
        cls = classify(mesh, tf, q, e, flags, coeffs, base, deg)
        emitting = int(cls[2])
        counts[2] = cls[3]
        if int(cls[3]) == 1:
            return state, counts
        piecewise = int(cls[3]) - 2
        if piecewise == 0 or q.method == METHOD_SPLIT:
            mode = 1
    if mode == 0:
        n = int(0)
        if q.h > 0.0:
            n = quadrature.fixed_steps(q, lo, hi)
        else:  # classified without a fixed step (riemann and trapezoid always have one: engine/view.py)
            nb = quadrature.auto_steps(q, terms, lo, hi, state.transmittance)
            n = int(nb[0])
            state.error = state.error + nb[1]
        state, nev = quadrature.march(mesh, tf, q, trapezoid, e, xo, xd, evaluate, coeffs, base, deg, a, b, lo, hi, n,
                                      state)
        counts[0] = nev[0]
        counts[1] = nev[1]
    else:
        piece = lo
        while piece < hi and state.transmittance >= q.min_transmittance:
            cut = hi
            if piecewise == 1:
                nc = quadrature.next_cut(tf, coeffs, base, deg, a, b, piece)
                cut = wp.min(nc[0], hi)
                counts[1] = counts[1] + nc[1]
            state = quadrature.gauss_kronrod_smooth(tf, q, coeffs, base, deg, a, b, piece, cut, emitting, state)
            piece = cut
    return state, counts


@wp.struct
class Tally:
    """What a ray's integration of its segments counted (the stats' STAT_* counters)."""

    field_evals: wp.int32
    restriction_evals: wp.float32
    empty: wp.int32
    smooth: wp.int32
    piecewise: wp.int32


@wp.func
def no_tally() -> Tally:
    t = Tally()
    t.field_evals = 0
    t.restriction_evals = 0.0
    t.empty = 0
    t.smooth = 0
    t.piecewise = 0
    return t


@wp.func
def tally_counts(tally_in: Tally, counts: wp.vec3) -> Tally:
    """integrate_segment's counts (evaluations, class) added to the tally."""
    tally = tally_in
    tally.field_evals += int(counts[0])
    tally.restriction_evals += counts[1]
    cls = int(counts[2])
    if cls == 1:
        tally.empty += 1
    elif cls == 2:
        tally.smooth += 1
    elif cls == 3:
        tally.piecewise += 1
    return tally


@wp.func
def integrate_counted(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, o: wp.vec3, d: wp.vec3, a: float,
                      b: float, deg: int, flags: int, tail: float, coeffs: wp.array(dtype=wp.float32), base: int,
                      terms: wp.vec3, state_in: RayIntegral, tally_in: Tally):
    """integrate_segment, the segment's tail added to the error estimate first, its counts to
    the tally: one segment as the integrate and shade kernels both take it."""
    state = state_in
    state.error = state.error + tail
    state, counts = integrate_segment(mesh, tf, q, e, o, d, a, b, a, b, deg, flags, coeffs, base, terms, state)
    return state, tally_counts(tally_in, counts)


@wp.func
def integrate_counted_surfaces(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, o: wp.vec3, d: wp.vec3,
                               a: float, b: float, deg: int, flags: int, tail: float,
                               coeffs: wp.array(dtype=wp.float32), base: int, terms: wp.vec3, state_in: RayIntegral,
                               tally_in: Tally):
    """integrate_counted with the look's surfaces (TransferArgs.surf): the volume is integrated
    between the surfaces the segment meets, each composited where it lies
    (isosurface.composite_event), within the span the clipping planes keep; their root finding
    counts as restriction evaluations, their points as field ones."""
    state = state_in
    tally = tally_in
    state.error = state.error + tail
    span = isosurface.kept_span(tf.surf, o, d)
    times, ids, n, evals, surface_end = isosurface.segment_events(mesh, tf.surf, e, o, d, a, b, deg, coeffs, base, span,
                                                                   tail, state.surface_end)
    state.surface_end = surface_end
    tally.restriction_evals += float(evals)
    lo = wp.max(a, span[0])
    for k in range(n + 1):
        if state.transmittance < q.min_transmittance:
            break
        hi = b
        if k < n:
            hi = times[k]
        hi = wp.min(hi, span[1])
        if hi > lo:
            state, counts = integrate_segment(mesh, tf, q, e, o, d, a, b, lo, hi, deg, flags, coeffs, base, terms,
                                              state)
            tally = tally_counts(tally, counts)
            lo = hi
        if k < n:
            state, nev = isosurface.composite_event(mesh, tf, e, o, d, times[k], ids[k], state)
            tally.field_evals += nev
    return state, tally


def make_integrate_kernel(ISOSURFACES: bool):
    # ISOSURFACES: the look has isosurfaces or planes (integrate_counted_surfaces); without, none
    # of their code is compiled in, so a plain volume's kernel pays nothing for them
    counted = integrate_counted_surfaces if ISOSURFACES else integrate_counted

    @wp.kernel(enable_backward=False, module="unique", module_options={"max_unroll": 1}, cuda_max_registers=MAX_REGISTERS)
    def integrate(mesh: MeshArgs, cam: CameraArgs, tf: TransferArgs, q: QuadArgs, pixel_offset: wp.int32,
                  rays: RayState, segs: Segments):
        i = rays.active[wp.tid()]
        if rays.phase[i] == 2:
            return
        pixel = i + pixel_offset
        o, d = camera_ray(cam, pixel)
        ct = rays.color_t[i]
        de = rays.depth_err[i]
        state = RayIntegral()
        state.color = wp.vec3(ct[0], ct[1], ct[2])
        state.transmittance = ct[3]
        state.restriction_evals = 0.0
        state.depth = de[0]
        state.error = de[1]
        if wp.static(ISOSURFACES):
            state.surface_end = rays.surface_end[i]
        tally = no_tally()
        for k in range(segs.count[i]):
            if state.transmittance < q.min_transmittance:
                break
            slot = i * SEGMENTS_PER_ROUND + k
            state, tally = wp.static(counted)(mesh, tf, q, segs.element[slot], o, d, segs.t0[slot], segs.t1[slot],
                                              segs.degree[slot], segs.flags[slot], segs.tail[slot], segs.coeffs,
                                              slot * MAX_SAMPLES, segs.step_terms[slot], state, tally)
        rays.color_t[i] = wp.vec4(state.color[0], state.color[1], state.color[2], state.transmittance)
        rays.depth_err[i] = wp.vec2(state.depth, state.error)
        if wp.static(ISOSURFACES):
            rays.surface_end[i] = state.surface_end
        rays.stats[pixel, STAT_FIELD_EVALS] += tally.field_evals
        rays.stats[pixel, STAT_RESTRICTION_EVALS] += int(tally.restriction_evals + state.restriction_evals)
        rays.stats[pixel, STAT_EMPTY] += tally.empty
        rays.stats[pixel, STAT_SMOOTH] += tally.smooth
        rays.stats[pixel, STAT_PIECEWISE] += tally.piecewise
        if state.transmittance < q.min_transmittance or rays.phase[i] == 1:
            rays.phase[i] = 2
        else:
            rays.active_next[wp.atomic_add(rays.active_count, 0, 1)] = i

    return integrate


@wp.func
def pixel_values(q: QuadArgs, ct: wp.vec4, de: wp.vec2, t_end: float):
    """A ray's pixel from its (C, T) and (depth, error): RGB = C + T background, alpha = 1 - T;
    depth (the ray's far end where the opacity never reached 0.5) and the error estimate."""
    T = ct[3]
    depth = de[0]
    if depth < 0.0:
        depth = t_end
    return (wp.vec4(ct[0] + T * q.background[0], ct[1] + T * q.background[1], ct[2] + T * q.background[2], 1.0 - T),
            wp.vec2(depth, de[1]))


@wp.kernel(enable_backward=False)
def finalize(q: QuadArgs, pixel_offset: wp.int32, rays: RayState, rgba: wp.array(dtype=wp.vec4),
             aux: wp.array(dtype=wp.vec2)):
    """Pixels of the tile (pixel_values)."""
    i = wp.tid()
    pixel = i + pixel_offset
    px, ax = pixel_values(q, rays.color_t[i], rays.depth_err[i], rays.t_end[i])
    rgba[pixel] = px
    aux[pixel] = ax
