"""What users do today: resample the high-order field onto a regular grid and ray-march it
with trilinear interpolation (as VTK's GPU ray caster does), against the pixel-exact image.

1. ``resample(mesh, h_g)``: a grid of spacing h_g over the mesh's bounding box,
   n_k = ceil(L_k / h_g) + 1 points per axis from the box's lower corner, float32 values,
   4 bytes a point (``grid_memory_bytes``). Each point is located in an element (affine
   elements: the exact world->reference map; curved ones: batched damped Newton on the
   geometry map, seeded by the element's vertex-affine map) and the element's expansion is
   evaluated there, vectorised over (point, element) pairs. Points in no element are NaN
   (empty; no extra memory).
2. ``march(grid, camera, tf, background, step)``: a Warp kernel (cpu or cuda), one thread per
   pixel, the contract's rays (docs/spec/render-contract.md §4) clipped to the grid's box, front to
   back with step = h_g / 2 by default: at each step's midpoint the trilinear value s gives
   tau(s), kappa(s) from the exact piecewise-linear transfer function (not a lookup table,
   so only the resampling and the step are measured), alpha = 1 - exp(-tau dt),
   C += T alpha kappa, T *= 1 - alpha; RGB = C + T background, alpha = 1 - T (contract §3).
   A sample with any of its 8 grid corners empty counts as empty.
3. ``compare``: grid build time, render time, grid memory and the largest RGB difference
   (also its 99th percentile and mean over pixels: the largest sits on the domain's
   silhouette, where the grid's boundary is off by up to h_g) against the pixel-exact reference
   (engine/reference.pixel_exact_reference: the Renderer in float64 with RenderOptions.pixel_exact(),
   split at tolerance 1e-9, min_transmittance 0).

    python -m bench.resample_baseline --device cpu --size 48x36        (sphere, quick look)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import dataclass

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.mesh import VolumeMesh, element_boxes
from hovr_blender.engine.kernels.quadrature import ramp_segment  # the renderer's own transfer-function lookup

BYTES_PER_POINT = 4  # float32 value; NaN marks empty points


def grid_shape(lower, upper, h_g) -> tuple[int, int, int]:
    """Points per axis: ceil(L / h_g) + 1, so the grid covers [lower, upper]."""
    L = np.asarray(upper, float) - np.asarray(lower, float)
    return tuple(int(math.ceil(float(v) / h_g - 1e-9)) + 1 for v in L)


def grid_memory_bytes(lower, upper, h_g) -> int:
    nx, ny, nz = grid_shape(lower, upper, h_g)
    return BYTES_PER_POINT * nx * ny * nz


@dataclass
class GridField:
    values: np.ndarray  # (nx, ny, nz) float32, NaN outside the mesh
    lower: np.ndarray  # (3,) world position of point (0, 0, 0)
    spacing: float
    build_seconds: float
    newton_unconverged: int = 0  # points kept although Newton stalled (residual < 1e-6 h_g)

    @property
    def nbytes(self) -> int:
        return int(self.values.nbytes)

    @property
    def upper(self) -> np.ndarray:
        return self.lower + self.spacing * (np.array(self.values.shape) - 1)


def mesh_bounds(mesh: VolumeMesh):
    lo, hi = element_boxes(mesh)
    return lo.min(axis=0), hi.max(axis=0)


def estimate_pairs(mesh: VolumeMesh, h_g: float) -> float:
    """(point, element) candidate pairs resample() will test: the work it does, for budgets."""
    lo, hi = element_boxes(mesh)
    return float(np.prod(np.floor((hi - lo) / h_g) + 1.0, axis=1).sum())


def _vertex_affine(shape, verts):
    """xi ~ A x + b through vertex 0 and the three axis vertices, per element (Newton seed)."""
    ref = shapes.VERTICES[shape]
    axes = [int(np.nonzero((ref == -1 + 2 * np.eye(3)[d]).all(axis=1))[0][0]) for d in range(3)]
    J = 0.5 * np.transpose(verts[:, axes] - verts[:, :1], (0, 2, 1))  # (m, 3, 3)
    A = np.linalg.inv(J)
    b = -np.einsum("mij,mj->mi", A, verts[:, 0]) - 1.0
    return A, b


def _newton(shape, gm, G, X, xi, iters=30, tol=1e-11):
    """Batched Newton for x(xi) = X, one geometry per pair: G (P, Kg, 3), X (P, 3), xi (P, 3).
    (xi, converged, outside): a pair is dropped as outside once its step is below 1e-2 (the
    iterate is then within ~1e-4 of the solution) while it lies 0.05 outside the element."""
    conv = np.zeros(len(X), dtype=bool)
    out = np.zeros(len(X), dtype=bool)
    act = np.arange(len(X))
    for _ in range(iters):
        if act.size == 0:
            break
        B, D = ex.modal_basis(shape, gm, xi[act], True)  # values (a, Kg), d/dxi (a, Kg, 3)
        g = G[act]
        r = X[act] - np.matmul(B[:, None, :], g)[:, 0, :]
        J = np.matmul(g.transpose(0, 2, 1), D)  # (a, 3 coordinates, 3 reference directions)
        det = np.linalg.det(J)
        ok = np.isfinite(det) & (np.abs(det) > 1e-300)
        step = np.zeros_like(r)
        step[ok] = np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
        xi[act] = ex.hold_inside(shape, xi[act] + step)
        size = np.abs(step).max(axis=1)
        small = ok & (size <= tol)
        far = ok & ~small & (size < 1e-2) & ~ex.inside(shape, xi[act], tol=0.05)
        conv[act[small]] = True
        out[act[far]] = True
        act = act[ok & ~small & ~far]
    return xi, conv, out


def _map_deviation(shape, gm, G, A, b) -> float:
    """Largest distance (reference units) between the curved maps' inverse and their
    vertex-affine seeds, at the geometry fit points: how far candidates may lie outside."""
    pts = ex.fit_points(shape, gm)
    X = np.einsum("pk,ekc->epc", ex.basis_matrix(shape, gm, pts), G)
    xi = np.einsum("eij,epj->epi", A, X) + b[:, None, :]
    return float(np.abs(xi - pts[None]).max())


_JOB: dict = {}  # the mesh and grid of the resample in progress (inherited by forked workers)


def _block(task):
    """Grid points of one block of elements of one class: (flat indices, values, kept-stalled)."""
    J = _JOB
    mesh, lower, h_g, n, i0, i1, count, margin = (J[k] for k in ("mesh", "lower", "h_g", "n", "i0", "i1", "count", "margin"))
    curved, sh, m, gm, els = task
    k, kg = ex.num_coeffs(sh, m), ex.num_coeffs(sh, gm)
    c = count[els]
    pe = np.repeat(np.arange(els.size), c)  # pair -> element (local)
    local = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
    ext = (i1[els] - i0[els] + 1)[pe]
    ii = i0[els][pe] + np.stack([local % ext[:, 0], (local // ext[:, 0]) % ext[:, 1],
                                  local // (ext[:, 0] * ext[:, 1])], axis=1)
    flat = (ii[:, 0] * n[1] + ii[:, 1]) * n[2] + ii[:, 2]
    X = lower + h_g * ii
    e = els[pe]
    kept = 0
    if not curved:
        M = mesh.ref_from_world[e]
        xi = np.einsum("pij,pj->pi", M[:, :, :3], X) + M[:, :, 3]
        ins = ex.inside(sh, xi, tol=1e-9)
    else:
        nv = len(shapes.VERTICES[sh])
        A, b = _vertex_affine(sh, mesh.vertices[els][:, :nv])
        Ge = mesh.geom_coeffs[mesh.geom_offset[els][:, None] + np.arange(kg)[None, :]]
        grow = margin if margin is not None else 2.0 * _map_deviation(sh, gm, Ge, A, b) + 0.05
        xi = np.einsum("pij,pj->pi", A[pe], X) + b[pe]
        near = ex.inside(sh, (xi - shapes.CENTROIDS[sh]) / (1.0 + grow) + shapes.CENTROIDS[sh], tol=0.0)
        pe, flat, X, e, xi = pe[near], flat[near], X[near], e[near], xi[near]
        xi, conv, outside = _newton(sh, gm, Ge[pe], X, ex.hold_inside(sh, xi))
        ins = conv & ex.inside(sh, xi, tol=1e-9)
        # Newton stalls on points beyond a prism's collapsed edge (outside: their residual stays
        # large); one that stalls with a tiny residual is in the element: kept, and counted
        stalled = np.nonzero(~conv & ~outside & ex.inside(sh, xi, tol=1e-9))[0]
        if stalled.size:
            Bs = ex.basis_matrix(sh, gm, xi[stalled])
            res = np.linalg.norm(X[stalled] - np.matmul(Bs[:, None, :], Ge[pe[stalled]])[:, 0, :], axis=1)
            hit = stalled[res < 1e-6 * h_g]
            ins[hit] = True
            kept = int(hit.size)
    e, xi, flat = e[ins], xi[ins], flat[ins]
    first = np.unique(flat, return_index=True)[1]  # a point on a shared face: one element
    e, xi, flat = e[first], xi[first], flat[first]
    vals = np.empty(e.size)
    step = max(1, J["eval_entries"] // k)
    for a in range(0, e.size, step):
        C = mesh.coeffs[mesh.coeff_offset[e[a:a + step]][:, None] + np.arange(k)[None, :]]
        vals[a:a + step] = (ex.basis_matrix(sh, m, xi[a:a + step]) * C).sum(axis=1)
    return flat, vals, kept


def resample(mesh: VolumeMesh, h_g: float, margin: float | None = None, pair_chunk: int = 1 << 18,
             eval_entries: int = 1 << 23, workers: int | None = None) -> GridField:
    """The mesh's field on the regular grid of spacing h_g over its bounding box (module doc).
    ``margin``: a curved element's candidate points are those whose vertex-affine reference
    coordinates lie within the reference element grown by this much; by default twice the
    largest deviation of the element block's maps from their vertex-affine maps, plus 0.05.
    ``workers``: processes (fork) over blocks of about pair_chunk candidate pairs; default
    all cores when there are over 4 million pairs, else 1. A point on a face shared by two
    elements takes the value of the element listed first."""
    t0 = time.perf_counter()
    lower, upper = mesh_bounds(mesh)
    n = np.array(grid_shape(lower, upper, h_g))
    vals = np.full(int(np.prod(n)), np.nan)
    owner = np.full(vals.size, np.iinfo(np.int64).max)
    blo, bhi = element_boxes(mesh)
    i0 = np.clip(np.ceil((blo - lower) / h_g - 1e-9).astype(np.int64), 0, n - 1)
    i1 = np.clip(np.floor((bhi - lower) / h_g + 1e-9).astype(np.int64), 0, n - 1)
    count = np.prod(np.maximum(i1 - i0 + 1, 0), axis=1)
    affine = np.ones(mesh.num_elements, bool) if mesh.affine is None else mesh.affine.astype(bool)
    gm_all = mesh.geom_modes if mesh.geom_modes is not None else np.full((mesh.num_elements, 3), 2)
    keys = np.concatenate([(~affine)[:, None].astype(int), mesh.shape[:, None], mesh.modes, gm_all], axis=1)
    tasks = []
    for key in np.unique(keys, axis=0):
        curved, sh = bool(key[0]), int(key[1])
        m, gm = tuple(int(v) for v in key[2:5]), tuple(int(v) for v in key[5:8])
        idx = np.nonzero((keys == key).all(axis=1) & (count > 0))[0]
        csum = np.cumsum(count[idx])
        start = 0
        while start < idx.size:  # element blocks of about pair_chunk candidate pairs
            base = csum[start - 1] if start else 0
            stop = max(start + 1, int(np.searchsorted(csum, base + pair_chunk, side="right")))
            tasks.append((curved, sh, m, gm, idx[start:stop]))
            start = stop
    _JOB.update(mesh=mesh, lower=lower, h_g=h_g, n=n, i0=i0, i1=i1, count=count, margin=margin,
                eval_entries=eval_entries)
    if workers is None:
        workers = (os.cpu_count() or 1) if count.sum() > 4e6 else 1
    kept = 0
    try:
        if workers > 1 and len(tasks) > 1:
            import multiprocessing as mp

            with mp.get_context("fork").Pool(min(workers, len(tasks))) as pool:
                results = pool.imap(_block, tasks)
                parts = [(task[4][0], r) for task, r in zip(tasks, results)]
        else:
            parts = [(task[4][0], _block(task)) for task in tasks]
    finally:
        _JOB.clear()
    for first_element, (flat, v, kp) in parts:
        kept += kp
        take = owner[flat] > first_element  # first-listed element wins on shared faces
        vals[flat[take]] = v[take]
        owner[flat[take]] = first_element
    values = vals.reshape(tuple(n)).astype(np.float32)
    return GridField(values, np.asarray(lower, float), float(h_g), time.perf_counter() - t0, kept)


# ------------------------------------------------------------------------------ the ray march

@wp.func
def slab(span: wp.vec2, o: float, d: float, lo: float, hi: float) -> wp.vec2:
    """The ray's t interval clipped to lo <= o + t d <= hi."""
    if wp.abs(d) < 1.0e-30:
        if o < lo or o > hi:
            return wp.vec2(span[0], -1.0e30)
        return span
    t1 = (lo - o) / d
    t2 = (hi - o) / d
    return wp.vec2(wp.max(span[0], wp.min(t1, t2)), wp.min(span[1], wp.max(t1, t2)))


@wp.func
def corner(g: wp.array3d(dtype=wp.float32), i: int, j: int, k: int) -> float:
    return g[i, j, k]

@wp.kernel
def march_kernel(g: wp.array3d(dtype=wp.float32), lo: wp.vec3, hg: float,
                 o0: wp.vec3, ou: wp.vec3, ov: wp.vec3, d0: wp.vec3, du: wp.vec3, dv: wp.vec3,
                 width: int, height: int, t_min: float, t_max: float, step: float,
                 cs: wp.array(dtype=wp.float32), crgb: wp.array(dtype=wp.vec3),
                 ds: wp.array(dtype=wp.float32), dtau: wp.array(dtype=wp.float32),
                 bg: wp.vec3, min_t: float, out: wp.array(dtype=wp.vec4), nsamp: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    i = tid % width
    j = tid / width
    u = (2.0 * (float(i) + 0.5) / float(width) - 1.0) * (float(width) / float(height))
    v = 1.0 - 2.0 * (float(j) + 0.5) / float(height)
    o = o0 + u * ou + v * ov
    d = wp.normalize(d0 + u * du + v * dv)
    nx = g.shape[0]
    ny = g.shape[1]
    nz = g.shape[2]
    hi = lo + hg * wp.vec3(float(nx - 1), float(ny - 1), float(nz - 1))
    span = wp.vec2(t_min, t_max)
    span = slab(span, o[0], d[0], lo[0], hi[0])
    span = slab(span, o[1], d[1], lo[1], hi[1])
    span = slab(span, o[2], d[2], lo[2], hi[2])
    ta = span[0]
    tb = span[1]
    col = wp.vec3(0.0, 0.0, 0.0)
    T = float(1.0)
    count = int(0)
    if tb > ta:
        nsteps = int(wp.ceil((tb - ta) / step))
        for s_i in range(nsteps):
            t0 = ta + float(s_i) * step
            dt = wp.min(step, tb - t0)
            if dt > 0.0 and T > min_t:
                p = (o + (t0 + 0.5 * dt) * d - lo) / hg
                fi = wp.clamp(wp.floor(p[0]), 0.0, float(nx - 2))
                fj = wp.clamp(wp.floor(p[1]), 0.0, float(ny - 2))
                fk = wp.clamp(wp.floor(p[2]), 0.0, float(nz - 2))
                ii = int(fi)
                jj = int(fj)
                kk = int(fk)
                x = wp.clamp(p[0] - fi, 0.0, 1.0)
                y = wp.clamp(p[1] - fj, 0.0, 1.0)
                z = wp.clamp(p[2] - fk, 0.0, 1.0)
                c000 = corner(g, ii, jj, kk)
                c100 = corner(g, ii + 1, jj, kk)
                c010 = corner(g, ii, jj + 1, kk)
                c110 = corner(g, ii + 1, jj + 1, kk)
                c001 = corner(g, ii, jj, kk + 1)
                c101 = corner(g, ii + 1, jj, kk + 1)
                c011 = corner(g, ii, jj + 1, kk + 1)
                c111 = corner(g, ii + 1, jj + 1, kk + 1)
                count += 1
                sv = ((c000 * (1.0 - x) + c100 * x) * (1.0 - y) + (c010 * (1.0 - x) + c110 * x) * y) * (1.0 - z) \
                    + ((c001 * (1.0 - x) + c101 * x) * (1.0 - y) + (c011 * (1.0 - x) + c111 * x) * y) * z
                if not wp.isnan(sv):
                    kw = ramp_segment(ds, sv, -1)
                    kd = int(kw[0])
                    tau = dtau[0]
                    if dtau.shape[0] > 1:
                        tau = dtau[kd] + kw[1] * (dtau[kd + 1] - dtau[kd])
                    kc = ramp_segment(cs, sv, -1)
                    kk2 = int(kc[0])
                    rgb = crgb[0]
                    if cs.shape[0] > 1:
                        rgb = crgb[kk2] + kc[1] * (crgb[kk2 + 1] - crgb[kk2])
                    alpha = 1.0 - wp.exp(-tau * dt)
                    col = col + (T * alpha) * rgb
                    T = T * (1.0 - alpha)
    res = col + T * bg
    out[tid] = wp.vec4(res[0], res[1], res[2], 1.0 - T)
    nsamp[tid] = count


def march(grid: GridField, camera, tf, background, step: float | None = None, device: str = "cpu",
          min_transmittance: float = 0.0):
    """(rgba (H, W, 4) float32, stats) of the trilinear ray march (module doc)."""
    wp.config.quiet = True
    wp.init()
    kern = march_kernel
    step = 0.5 * grid.spacing if step is None else float(step)
    W, H = int(camera.width), int(camera.height)
    bg = np.asarray(background, float).reshape(3)
    with wp.ScopedDevice(device):
        g = wp.array(np.ascontiguousarray(grid.values), dtype=wp.float32)
        args = [wp.vec3(*map(float, getattr(camera, a))) for a in ("o0", "ou", "ov", "d0", "du", "dv")]
        tfa = [wp.array(tf.color_s.astype(np.float32), dtype=wp.float32),
               wp.array(tf.color_rgb.astype(np.float32), dtype=wp.vec3),
               wp.array(tf.density_s.astype(np.float32), dtype=wp.float32),
               wp.array(tf.density_tau.astype(np.float32), dtype=wp.float32)]
        out = wp.zeros(W * H, dtype=wp.vec4)
        ns = wp.zeros(W * H, dtype=wp.int32)
        inputs = [g, wp.vec3(*map(float, grid.lower)), float(grid.spacing), *args, W, H, float(camera.t_min),
                  float(min(camera.t_max, 1e30)), step, *tfa, wp.vec3(*map(float, bg)), float(min_transmittance), out, ns]
        wp.load_module(kern.module, device=device)
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        wp.launch(kern, dim=W * H, inputs=inputs)
        wp.synchronize_device(device)
        secs = time.perf_counter() - t0
        img = out.numpy().reshape(H, W, 4)
        samples = int(ns.numpy().astype(np.int64).sum())
    return img, {"render_seconds": secs, "samples_per_ray": samples / (W * H), "step": step,
                 "grid_shape": list(grid.values.shape), "grid_bytes": grid.nbytes}


def mesh_memory_bytes(mesh: VolumeMesh) -> int:
    """Bytes of the high-order data as the renderer uploads it (float32 coefficients and
    geometry, per-element tables), for comparison with the grid."""
    n = mesh.num_elements
    per_element = 4 * (1 + 9 + 3 + 3 + 1 + 1 + 1 + 2 + 6 + 1)  # shape, map, modes, ..., boxes
    geo = 0 if mesh.geom_coeffs is None else 4 * mesh.geom_coeffs.size
    return int(4 * mesh.coeffs.size + geo + n * per_element)


def compare(mesh, camera, tf, background, h_values, reference, device="cpu", step_factor=0.5,
            max_pairs: float | None = None, log=print):
    """One row per h_g: grid build seconds, render seconds, grid bytes, max RGB error vs
    `reference` (H, W, >=3). With max_pairs, a grid whose point location would test more
    (point, element) pairs is skipped and recorded as such."""
    rows = []
    for h in h_values:
        est = estimate_pairs(mesh, h)
        lo, hi = mesh_bounds(mesh)
        row = {"h_g": float(h), "grid_shape": list(grid_shape(lo, hi, h)), "grid_bytes": grid_memory_bytes(lo, hi, h),
               "candidate_pairs": est}
        if max_pairs is not None and est > max_pairs:
            row["skipped"] = f"point location would test {est:.3g} pairs > budget {max_pairs:.3g}"
            log(f"  resample h_g={h:g}: skipped ({row['skipped']})")
            rows.append(row)
            continue
        grid = resample(mesh, h)
        img, st = march(grid, camera, tf, background, step=step_factor * h, device=device)
        diff = np.abs(img[..., :3].astype(np.float64) - reference[..., :3]).max(axis=-1)
        err = float(diff.max())
        row.update({"build_seconds": grid.build_seconds, "render_seconds": st["render_seconds"],
                    "samples_per_ray": st["samples_per_ray"], "step": st["step"], "max_error": err,
                    "p99_error": float(np.percentile(diff, 99)), "mean_error": float(diff.mean()),
                    "points_inside": int(np.isfinite(grid.values).sum()), "newton_unconverged": grid.newton_unconverged})
        log(f"  resample h_g={h:g} grid {row['grid_shape']} ({row['grid_bytes'] / 2**20:.2f} MiB): build "
            f"{grid.build_seconds:.2f} s, march {st['render_seconds'] * 1e3:.1f} ms, max error {err:.3e}")
        rows.append(row)
    return rows


def main(argv=None):
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.reference import reference_render
    from hovr_blender.engine.transfer_function import TransferFunction
    from hovr_blender.io.builtin import sphere

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--size", default="48x36")
    ap.add_argument("--h", default="0.4,0.2,0.1,0.05")
    args = ap.parse_args(argv)
    W, H = (int(v) for v in args.size.split("x"))
    cam = RayCamera.from_contract({"eye": [7.0, 5.5, 8.0], "target": [0.0, 0.0, 1.0], "up": [0, 0, 1],
                                   "fov_y_deg": 40.0}, W, H)
    tf = TransferFunction.from_contract({"color": [[1.0, 1.0, 0.9, 0.2], [16.0, 1.0, 0.2, 0.6]],
                                         "density": [[1.5, 0.0], [2.0, 2.0], [2.5, 0.0], [8.5, 0.0], [9.0, 1.0],
                                                     [9.5, 0.0]]})
    mesh = sphere()
    ref, _ = reference_render(mesh, cam, tf, [0.02, 0.02, 0.03])
    rows = compare(mesh, cam, tf, [0.02, 0.02, 0.03], [float(v) for v in args.h.split(",")], ref, args.device)
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
