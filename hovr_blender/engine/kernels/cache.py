"""The segment cache's kernels (engine/renderer.py Renderer.trace / shade): a trace's rounds keep
every segment of every ray with its series (trace_reserve, trace_write and trace_ends in
integrate's place), and shade integrates a ray's cached segments through any transfer function as
integrate would have, then writes its pixel (make_shade_kernel: with or without the look's
isosurfaces and planes, as integrate); sum_counts adds up a shade's per-ray counters."""
from __future__ import annotations

import warp as wp

from .args import (MAX_SAMPLES, NO_SURFACE_END, NUM_STATS, SEGMENTS_PER_ROUND, STAT_BVH_CANDIDATES, STAT_EMPTY,
                   STAT_FIELD_EVALS, STAT_LOCATES, STAT_NEWTON_SAMPLE, STAT_NEWTON_SEARCH, STAT_NEWTON_WALK,
                   STAT_PIECEWISE, STAT_RESTRICTION_EVALS, STAT_ROUNDS, STAT_SEGMENTS, STAT_SMOOTH, STAT_WALKS,
                   CameraArgs, MeshArgs, QuadArgs, RayState, SegmentCache, Segments, TransferArgs)
from .integrate import integrate_counted, integrate_counted_surfaces, no_tally, pixel_values, segment_step_terms
from .quadrature import METHOD_CLASSIFIED, RayIntegral, samples_segments
from .rays import MAX_REGISTERS, camera_ray
from .walk import density_transparent, element_transparent

wp.set_module_options({"enable_backward": False})

CounterSums = wp.types.vector(length=NUM_STATS, dtype=wp.int64)  # sum_counts' per-thread sums


@wp.kernel(enable_backward=False)
def trace_reserve(rays: RayState, segs: Segments, cache: SegmentCache, reserved: wp.array(dtype=wp.vec3i)):
    """A trace's round, after the samples, one thread per active ray (the integrate kernel's
    place): reserve (first segment, chunk, first coefficient) in the cache for the ray's segments
    of the round, one chunk, and put the ray on the next round's list unless its traversal has
    finished. Nothing is integrated, so no ray stops early: the cache holds the whole ray."""
    i = rays.active[wp.tid()]
    reserved[i] = wp.vec3i(-1, -1, -1)
    if rays.phase[i] == 2:
        return
    k = segs.count[i]
    if k > 0:
        n_coeffs = int(0)
        for j in range(k):
            deg = segs.degree[i * SEGMENTS_PER_ROUND + j]
            if deg >= 0:
                n_coeffs += deg + 3
        reserved[i] = wp.vec3i(wp.atomic_add(cache.counts, 0, k), wp.atomic_add(cache.counts, 1, 1),
                               wp.atomic_add(cache.counts, 2, n_coeffs))
    if rays.phase[i] == 1:
        rays.phase[i] = 2
    else:
        rays.active_next[wp.atomic_add(rays.active_count, 0, 1)] = i


@wp.kernel(enable_backward=False)
def trace_write(rays: RayState, segs: Segments, cache: SegmentCache, reserved: wp.array(dtype=wp.vec3i),
                last_chunk: wp.array(dtype=wp.int32), ray_offset: wp.int32):
    """One thread per slot of the active rays: the ray's segment k into its reserved place, with
    its series (degree + 3 values); thread 0 of a ray writes the chunk and links it after the
    ray's last one (last_chunk, per ray of the tile), so the chunks go in the rounds' order."""
    tid = wp.tid()
    i = rays.active[tid // SEGMENTS_PER_ROUND]
    k = tid % SEGMENTS_PER_ROUND
    r = reserved[i]
    if r[0] < 0 or k >= segs.count[i]:
        return
    first_slot = i * SEGMENTS_PER_ROUND
    offset = r[2]
    for j in range(k):
        dj = segs.degree[first_slot + j]
        if dj >= 0:
            offset += dj + 3
    slot = first_slot + k
    s = r[0] + k
    deg = segs.degree[slot]
    cache.element[s] = segs.element[slot]
    cache.t0[s] = segs.t0[slot]
    cache.t1[s] = segs.t1[slot]
    cache.degree[s] = deg
    cache.flags[s] = segs.flags[slot]
    cache.tail[s] = segs.tail[slot]
    cache.coeff_offset[s] = offset
    for m in range(deg + 3):  # none for deg = -1
        cache.coeffs[offset + m] = segs.coeffs[slot * MAX_SAMPLES + m]
    if k == 0:
        c = r[1]
        cache.chunk_start[c] = r[0]
        cache.chunk_count[c] = segs.count[i]
        cache.chunk_next[c] = -1
        prev = last_chunk[i]
        if prev < 0:
            cache.head[i + ray_offset] = c
        else:
            cache.chunk_next[prev] = c
        last_chunk[i] = c


@wp.kernel(enable_backward=False)
def trace_ends(rays: RayState, cache: SegmentCache, ray_offset: wp.int32):
    """Each ray's far end into the cache (the depth output where its opacity stays below 0.5)."""
    i = wp.tid()
    cache.t_end[i + ray_offset] = rays.t_end[i]


def make_shade_kernel(ISOSURFACES: bool):
    # ISOSURFACES as in integrate.make_integrate_kernel; without surfaces no element is kept for them
    counted = integrate_counted_surfaces if ISOSURFACES else integrate_counted
    transparent = element_transparent if ISOSURFACES else density_transparent

    @wp.kernel(enable_backward=False, module="unique", module_options={"max_unroll": 1}, cuda_max_registers=MAX_REGISTERS)
    def shade(mesh: MeshArgs, cam: CameraArgs, tf: TransferArgs, q: QuadArgs, pixel_offset: wp.int32,
              ray_offset: wp.int32, cache: SegmentCache, rgba: wp.array(dtype=wp.vec4), aux: wp.array(dtype=wp.vec2),
              stats: wp.array2d(dtype=wp.int32), nonfinite: wp.array(dtype=wp.int32)):
        """One thread per ray of a trace (ray i is pixel i + pixel_offset): its cached segments front
        to back through integrate_counted (or _surfaces), as the integrate kernel takes them, then
        its pixel (pixel_values) into rgba[i], aux[i]. Classified and split skip the elements the
        traverse kernel would not have sampled under tf (element_transparent), and the ray stops
        where integrate stops it (transmittance below q.min_transmittance), so the pixel is a fresh
        render's. Its counters go to stats[i] (segments: those walked up to the stop), and a pixel
        that is not finite counts in nonfinite[0]."""
        i = wp.tid() + ray_offset
        o, d = camera_ray(cam, i + pixel_offset)
        state = RayIntegral()
        state.color = wp.vec3(0.0, 0.0, 0.0)
        state.transmittance = 1.0
        state.restriction_evals = 0.0
        state.depth = -1.0
        state.error = 0.0
        state.surface_end = wp.vec2(NO_SURFACE_END, 0.0)
        tally = no_tally()
        skip_transparent = int(0)
        if samples_segments(q.method) != 0:
            skip_transparent = 1
        n_seg = int(0)
        n_skipped = int(0)
        going = int(1)
        c = cache.head[i]
        while c >= 0 and going == 1:
            s = cache.chunk_start[c]
            s_end = s + cache.chunk_count[c]
            while s < s_end:
                e = cache.element[s]
                if skip_transparent == 1 and wp.static(transparent)(mesh, tf, e) == 1:
                    n_skipped += 1
                else:
                    if state.transmittance < q.min_transmittance:
                        going = 0
                        break
                    terms = wp.vec3(0.0, 0.0, 0.0)
                    if q.method == METHOD_CLASSIFIED and q.h <= 0.0:  # its own steps: step_terms' work, here
                        terms = segment_step_terms(mesh, tf, q, e, cache.flags[s], cache.coeffs, cache.coeff_offset[s],
                                                   cache.degree[s], cache.t0[s], cache.t1[s])
                    state, tally = wp.static(counted)(mesh, tf, q, e, o, d, cache.t0[s], cache.t1[s], cache.degree[s],
                                                      cache.flags[s], cache.tail[s], cache.coeffs,
                                                      cache.coeff_offset[s], terms, state, tally)
                n_seg += 1
                s += 1
            c = cache.chunk_next[c]
        px, ax = pixel_values(q, wp.vec4(state.color[0], state.color[1], state.color[2], state.transmittance),
                              wp.vec2(state.depth, state.error), cache.t_end[i])
        rgba[i] = px
        aux[i] = ax
        if not (wp.isfinite(px) and wp.isfinite(ax)):
            wp.atomic_add(nonfinite, 0, 1)
        stats[i, STAT_FIELD_EVALS] = tally.field_evals
        stats[i, STAT_RESTRICTION_EVALS] = int(tally.restriction_evals + state.restriction_evals)
        stats[i, STAT_SEGMENTS] = n_seg
        stats[i, STAT_EMPTY] = n_skipped + tally.empty
        stats[i, STAT_SMOOTH] = tally.smooth
        stats[i, STAT_PIECEWISE] = tally.piecewise
        stats[i, STAT_LOCATES] = 0
        stats[i, STAT_WALKS] = 0
        stats[i, STAT_BVH_CANDIDATES] = 0
        stats[i, STAT_NEWTON_SEARCH] = 0
        stats[i, STAT_NEWTON_WALK] = 0
        stats[i, STAT_NEWTON_SAMPLE] = 0
        stats[i, STAT_ROUNDS] = 0

    return shade


@wp.kernel(enable_backward=False)
def sum_counts(stats: wp.array2d(dtype=wp.int32), threads: wp.int32, out: wp.array(dtype=wp.int64)):
    """The per-ray counters summed on the device into out: thread t takes rows t, t + threads, ...
    (neighbouring threads read neighbouring rows), then adds its sums."""
    acc = CounterSums()
    r = wp.tid()
    while r < stats.shape[0]:
        for k in range(NUM_STATS):
            acc[k] += wp.int64(stats[r, k])
        r += threads
    for k in range(NUM_STATS):
        wp.atomic_add(out, k, acc[k])
