"""Measurements behind docs/traversal.md (issue 28): what a traversal by face crossings would cost,
counted on any device, before it is built.

Every element face (boundary and shared, each shared face once) is tessellated through its
element's geometry map (engine/walls.tessellate: a uniform k x k grid per face, k doubled until
the triangles are within the distance bound of the true face) into one Warp triangle mesh. For each
bound it reports the triangles per face and the bytes per element of the mesh and its BVH; every
pixel's ray of the audit's oblique view walks from crossing to crossing (wp.mesh_query_ray,
restarting just past each hit); a sample of the crossings is polished by float64 Newton on
(u, v, t) of the curved face from the triangle's barycentric point, and the iterations each takes
to a step below float32's and float64's Newton tolerances (kernels/geometry.py) are counted, with
the crossings whose polish leaves the face (a grazing ray: the triangle is hit, the face is not).

    python -m bench.face_crossings --datasets curved_mixed_cube_small,hump3D --size 96x54 --out face.json
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from hovr_blender.engine.kernels.tolerances import NEWTON_STEP_TOL, NEWTON_STEP_TOL_FLOAT64

STEP_TOL = {"float32": NEWTON_STEP_TOL, "float64": NEWTON_STEP_TOL_FLOAT64}  # the kernels' Newton stops
MAX_ITER = 30
BVH_NODE_BYTES = 32  # Warp's BVH: a node holds a box (2 x vec3) and two indices; about 2 nodes a triangle


def load(name):
    """A dataset by name: the audit's (hovr_blender/audit/datasets.py), and curved_mixed_cube_small,
    the tests' two-cell curved cube (tests/perf)."""
    from hovr_blender.audit import datasets

    if name == "curved_mixed_cube_small":
        from hovr_blender.io.synthetic import curved_cube

        return curved_cube(2)
    return datasets.load(name)[0]


def unique_faces(mesh):
    """(element, face) of every face once: a shared face from the lower-numbered element."""
    from hovr_blender.engine.adjacency import face_neighbours
    from hovr_blender.engine.shapes import FACE_PLANES, MAX_FACES

    nb = face_neighbours(mesh).reshape(-1, MAX_FACES)
    nfaces = np.array([len(FACE_PLANES[s]) for s in range(4)])[mesh.shape]
    real = np.arange(MAX_FACES)[None, :] < nfaces[:, None]
    keep = real & ((nb < 0) | (nb > np.arange(mesh.num_elements)[:, None]))
    elem, face = np.nonzero(keep)
    return elem.astype(np.int64), face.astype(np.int64)


def polish(mesh, walls, tri, bary, o, d, t_hit):
    """float64 Newton on (u, v, t) of the curved face of triangle `tri` from its barycentric point:
    (iterations to a step below STEP_TOL per precision, converged inside the face)."""
    from hovr_blender.engine import expansions as ex
    from hovr_blender.engine.walls import face_corners, face_reference_points, grid

    f = int(np.searchsorted(walls.triangle_offset, tri, side="right") - 1)
    e, face, k = int(walls.element[f]), int(walls.face[f]), int(walls.k[f])
    sh, gm = int(mesh.shape[e]), tuple(int(v) for v in mesh.geom_modes[e])
    G = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]
    corners = face_corners(sh, face)
    uv_grid, tris = grid(len(corners), k)
    local = tris[tri - walls.triangle_offset[f]]
    if walls.triangles[tri][0] - walls.vertex_offset[f] != local[0]:
        local = local[::-1]  # walls wound it the other way
    w = np.array([1.0 - bary[0] - bary[1], bary[0], bary[1]])
    uv = w @ uv_grid[local]
    t = float(t_hit)
    # xi(u, v) is affine on every reference face (a parallelogram or a triangle)
    xi0 = face_reference_points(corners, np.zeros(2))
    a = face_reference_points(corners, np.array([1.0, 0.0])) - xi0
    b = face_reference_points(corners, np.array([0.0, 1.0])) - xi0
    iters = {}
    for it in range(1, MAX_ITER + 1):
        xi = face_reference_points(corners, uv)
        x = ex.eval_modal(sh, gm, G, xi[None])[0]
        J = ex.eval_modal_grad(sh, gm, G, xi[None])[0]  # (3 coords, 3 xi)
        J = J.reshape(3, 3) if J.shape == (3, 3) else np.asarray(J).reshape(3, 3)
        M = np.stack([J @ a, J @ b, -d], axis=1)
        try:
            s = np.linalg.solve(M, x - o - t * d)
        except np.linalg.LinAlgError:
            break
        uv = uv - s[:2]
        t -= s[2]
        step = float(np.linalg.norm(a * s[0] + b * s[1]))  # reference-space step
        for p, tol in STEP_TOL.items():
            if p not in iters and step < tol:
                iters[p] = it
        if len(iters) == len(STEP_TOL):
            break
    inside = bool(np.all(uv >= -1 - 1e-9) and (uv.sum() <= 1e-9 if len(corners) == 3 else np.all(uv <= 1 + 1e-9)))
    return iters, inside


def crossings(mesh, walls, camera, device):
    """Per ray: its face crossings (mesh_query_ray from just past each hit), every hit's
    (ray, triangle, barycentric u, v, t), the walk's seconds, and the triangles whose box grown
    by the bound the ray crosses (a near-miss test's candidates: every true crossing lies within
    the bound of a triangle)."""
    import warp as wp

    from hovr_blender.engine.launch_args import camera_args
    from hovr_blender.engine.kernels import raycast
    from hovr_blender.engine.kernels.precision import Precision

    MAX_HITS = 256

    @wp.kernel
    def walk(m: wp.uint64, cam: raycast.CameraArgs, hits: wp.array(dtype=wp.int32), rec: wp.array2d(dtype=wp.vec4)):
        i = wp.tid()
        o, d = raycast.camera_ray(cam, i)
        t = float(0.0)
        n = int(0)
        for k in range(MAX_HITS):
            q = wp.mesh_query_ray(m, o + d * t, d, 1.0e30)
            if not q.result:
                break
            t = t + q.t
            rec[i, n] = wp.vec4(float(q.face), q.u, q.v, t)
            t = t + 1.0e-6 * (1.0 + t)
            n += 1
        hits[i] = n

    @wp.kernel
    def near(bvh: wp.uint64, cam: raycast.CameraArgs, count: wp.array(dtype=wp.int32)):
        i = wp.tid()
        o, d = raycast.camera_ray(cam, i)
        query = wp.bvh_query_ray(bvh, o, d)
        tri = int(0)
        n = int(0)
        while wp.bvh_query_next(query, tri, 1.0e30):
            n += 1
        count[i] = n

    with wp.ScopedDevice(device):
        wm = wp.Mesh(points=wp.array(walls.vertices.astype(np.float32), dtype=wp.vec3),
                     indices=wp.array(walls.triangles.astype(np.int32).ravel(), dtype=wp.int32))
        n = camera.width * camera.height
        hits = wp.zeros(n, dtype=wp.int32)
        rec = wp.zeros((n, MAX_HITS), dtype=wp.vec4)
        cam = camera_args(Precision.named("float32"), camera)
        wp.launch(walk, n, inputs=[wm.id, cam, hits, rec])
        wp.synchronize()
        t0 = time.perf_counter()
        wp.launch(walk, n, inputs=[wm.id, cam, hits, rec])
        wp.synchronize()
        seconds = time.perf_counter() - t0
        corners = walls.vertices[walls.triangles]
        pad = walls.tolerance
        lo = wp.array((corners.min(axis=1) - pad).astype(np.float32), dtype=wp.vec3)
        hi = wp.array((corners.max(axis=1) + pad).astype(np.float32), dtype=wp.vec3)
        bvh = wp.Bvh(lo, hi)
        count = wp.zeros(n, dtype=wp.int32)
        wp.launch(near, n, inputs=[bvh.id, cam, count])
        return hits.numpy(), rec.numpy(), seconds, count.numpy()


def run(name, args, out):
    from hovr_blender.audit.scenes import framing
    from hovr_blender.engine.mesh import with_geometry_expansion
    from hovr_blender.engine.walls import tessellate

    mesh = load(name)
    if mesh.geom_coeffs is None:
        mesh = with_geometry_expansion(mesh)
    W, H = map(int, args.size.split("x"))
    camera = framing(mesh, W, H)
    pts = mesh.vertices.reshape(-1, 3)
    diag = float(np.linalg.norm(pts.max(0) - pts.min(0)))
    elem, face = unique_faces(mesh)
    rows = []
    for rel in map(float, args.bounds.split(",")):
        t0 = time.perf_counter()
        walls = tessellate(mesh, rel * diag, faces=(elem, face))
        build = time.perf_counter() - t0
        ntri = len(walls.triangles)
        hits, rec, seconds, near = crossings(mesh, walls, camera, args.device)
        rng = np.random.default_rng(0)
        rays = np.repeat(np.arange(len(hits)), hits)
        slots = np.concatenate([np.arange(h) for h in hits]) if hits.sum() else np.zeros(0, int)
        pick = rng.choice(len(rays), min(args.polish, len(rays)), replace=False) if len(rays) else []
        its = {p: [] for p in STEP_TOL}
        outside = 0
        for j in pick:
            i, s = int(rays[j]), int(slots[j])
            o = np.asarray(camera.o0, float)  # framing cameras are perspective: one eye
            px, py = i % W, i // W
            u = (2.0 * (px + 0.5) / W - 1.0) * (W / H)
            v = 1.0 - 2.0 * (py + 0.5) / H
            o = np.asarray(camera.o0) + u * np.asarray(camera.ou) + v * np.asarray(camera.ov)
            d = np.asarray(camera.d0) + u * np.asarray(camera.du) + v * np.asarray(camera.dv)
            d = d / np.linalg.norm(d)
            tri, bu, bv, t = rec[i, s]
            got, inside = polish(mesh, walls, int(tri), (bu, bv), o, d, t)
            outside += not inside
            for p in STEP_TOL:
                its[p].append(got.get(p, MAX_ITER))
        row = {"relative_bound": rel, "bound": rel * diag, "faces": int(len(elem)), "triangles": ntri,
               "triangles_per_face": ntri / max(len(elem), 1), "k_max": int(walls.k.max()) if len(walls.k) else 0,
               "capped_faces": walls.capped,
               "mesh_bytes_per_element": (len(walls.vertices) * 12 + ntri * (12 + 2 * BVH_NODE_BYTES)) / mesh.num_elements,
               "crossings_per_ray": float(hits.mean()), "rays_hitting": float((hits > 0).mean()),
               "near_candidates_per_ray": float(near.mean()),
               "walk_seconds": seconds, "tessellate_seconds": build, "polished": len(pick),
               "polish_iterations": {p: {"mean": float(np.mean(v)) if v else None, "max": int(np.max(v)) if v else None}
                                     for p, v in its.items()},
               "polish_left_face": outside}
        rows.append(row)
        print(f"{name} bound {rel:g}: {ntri} triangles ({row['triangles_per_face']:.1f}/face, k <= {row['k_max']}), "
              f"{row['mesh_bytes_per_element']:.0f} B/element, {row['crossings_per_ray']:.2f} crossings/ray, "
              f"{row['near_candidates_per_ray']:.2f} grown-box candidates/ray, "
              f"Newton polish mean/max {row['polish_iterations']['float32']} (f32) "
              f"{row['polish_iterations']['float64']} (f64), left face {outside}/{len(pick)}", flush=True)
    out[name] = {"elements": int(mesh.num_elements), "size": [W, H], "rows": rows}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--datasets", default="curved_mixed_cube_small,hump3D")
    ap.add_argument("--size", default="96x54")
    ap.add_argument("--bounds", default="1e-2,1e-3,1e-4", help="distance bounds, relative to the data's diagonal")
    ap.add_argument("--polish", type=int, default=300, help="crossings polished by Newton per bound")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    out = {"device": args.device, "date": time.strftime("%Y-%m-%d")}
    for name in args.datasets.split(","):
        run(name, args, out)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
