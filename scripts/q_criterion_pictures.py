"""The CFD picture of issue 31 (docs/user-guide.md): per dataset, PyFR's Taylor-Green vortex and
hump3D, a Q-criterion isosurface coloured by the speed

- rendered by hovr from the expansion: Q(Velocity) / Q(rhou,rhov,rhow/rho) sampled exactly at each
  sample point along each ray (contract §8), its level found on the segments' series (§7);
- beside VTK's contour of the same level as ParaView computes it: the Lagrange cells split into
  linear tetrahedra on their node lattice (vtkDataSetTriangleFilter), the velocity's gradient as
  point data (vtkGradientFilter: each cell's derivatives averaged at the shared points, Q from
  them), contoured (vtkContourFilter), the speed interpolated onto the triangles; cast with the
  same camera and the same shading (the ramp's colour of the speed times 0.25 + 0.75 |n . d|,
  the triangle's own normal);
- and their difference (the largest RGB difference per pixel).

    python -m scripts.q_criterion_pictures --size 320x240 --out docs   (CPU; a few minutes a dataset)

The level is the audit's (hovr_blender/audit/datasets.q_level: a fraction of Q's 99th
percentile), the ramp the audit's speed ramp (speed_ramp), the view the oblique one framing
where Q exceeds the level (q_view). Writes
q-criterion-DATASET.png (the three pictures with titles) and prints the coverage and colour
differences.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from hovr_blender.audit import datasets

VTK_COMPONENTS = {"pyfr_tgv": None, "hump3D": ("rhou", "rhov", "rhow", "rho")}  # None: the VTU's Velocity array


def vtk_velocity_grid(name: str):
    """A vtkUnstructuredGrid of Lagrange cells with the point array Velocity: PyFR's own file as
    VTK reads it; hump3D's momenta and density converted exactly (audit/vtk_volume.from_mesh),
    u = m / rho at the nodes."""
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    from hovr_blender.audit import vtk_volume

    if VTK_COMPONENTS[name] is None:
        r = vtk.vtkXMLUnstructuredGridReader()
        r.SetFileName(datasets.view_data(name)["path"])
        r.Update()
        return r.GetOutput()
    grids = [vtk_volume.from_mesh(datasets.load_field(name, f)) for f in VTK_COMPONENTS[name]]
    m = np.stack([vtk_to_numpy(g.GetPointData().GetArray(vtk_volume.FIELD)) for g in grids[:3]], axis=1)
    rho = vtk_to_numpy(grids[3].GetPointData().GetArray(vtk_volume.FIELD))
    arr = numpy_to_vtk(np.ascontiguousarray(m / rho[:, None]), deep=True)
    arr.SetName("Velocity")
    grid = grids[0]
    grid.GetPointData().AddArray(arr)
    return grid


def vtk_q_contour(grid, level: float):
    """(points (n, 3), triangles (m, 3), speed at the points) of VTK's Q = level on the linearised cells."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    tets = vtk.vtkDataSetTriangleFilter()
    tets.SetInputData(grid)
    grad = vtk.vtkGradientFilter()
    grad.SetInputConnection(tets.GetOutputPort())
    grad.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_POINTS, "Velocity")
    grad.ComputeQCriterionOn()
    grad.SetQCriterionArrayName("Q")
    contour = vtk.vtkContourFilter()
    contour.SetInputConnection(grad.GetOutputPort())
    contour.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_POINTS, "Q")
    contour.SetValue(0, level)
    tri = vtk.vtkTriangleFilter()
    tri.SetInputConnection(contour.GetOutputPort())
    tri.Update()
    poly = tri.GetOutput()
    points = vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64)
    cells = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    speed = np.linalg.norm(vtk_to_numpy(poly.GetPointData().GetArray("Velocity")), axis=1)
    return points, cells, speed


def cast(points, triangles, values, camera, ramp, background):
    """(H, W, 3) RGB of opaque triangles coloured by ramp(values interpolated), headlight-shaded
    as hovr shades an isosurface, over `background`."""
    import warp as wp

    @wp.kernel
    def first_hit(mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
                  face: wp.array(dtype=wp.int32), uv: wp.array(dtype=wp.vec2)):
        i = wp.tid()
        face[i] = -1
        hit = wp.mesh_query_ray(mesh, o[i], d[i], 1.0e30)
        if hit.result:
            face[i] = hit.face
            uv[i] = wp.vec2(hit.u, hit.v)

    o, d = (a.reshape(-1, 3) for a in camera.rays())
    n = o.shape[0]
    mesh = wp.Mesh(points=wp.array(points.astype(np.float32), dtype=wp.vec3),
                   indices=wp.array(triangles.astype(np.int32).ravel(), dtype=wp.int32))
    face, uv = wp.zeros(n, dtype=wp.int32), wp.zeros(n, dtype=wp.vec2)
    wp.launch(first_hit, n, [mesh.id, wp.array(o.astype(np.float32), dtype=wp.vec3),
                             wp.array(d.astype(np.float32), dtype=wp.vec3), face, uv])
    face, uv = face.numpy(), uv.numpy()
    rgb = np.tile(np.asarray(background, float), (n, 1))
    hit = face >= 0
    t = triangles[face[hit]]
    u, v = uv[hit, 0], uv[hit, 1]
    value = u * values[t[:, 0]] + v * values[t[:, 1]] + (1 - u - v) * values[t[:, 2]]
    ramp = np.asarray(ramp)
    colour = np.stack([np.interp(value, ramp[:, 0], ramp[:, k]) for k in (1, 2, 3)], axis=1)
    normal = np.cross(points[t[:, 1]] - points[t[:, 0]], points[t[:, 2]] - points[t[:, 0]])
    cosine = np.abs(np.einsum("ij,ij->i", normal, d[hit])) / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)
    rgb[hit] = colour * (0.25 + 0.75 * cosine)[:, None]
    return rgb.reshape(camera.height, camera.width, 3), hit.reshape(camera.height, camera.width)


def ours(mesh, camera, level, ramp, background):
    """(H, W, 3) RGB and coverage of hovr's Q isosurface coloured by the speed, no volume."""
    from hovr_blender.engine.isosurfaces import Isosurface, Surfaces
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.transfer_function import TransferFunction
    from hovr_blender.engine.view import RenderOptions

    tf = datasets.transfer_function(mesh)
    clear = TransferFunction(tf.color_s, tf.color_rgb, tf.density_s, np.zeros_like(tf.density_tau))
    iso = Surfaces((Isosurface(level, (1.0, 1.0, 1.0), 1.0, color_by="speed", color_ramp=ramp),))
    res = Renderer(mesh, "cpu").render(camera, clear, np.asarray(background), RenderOptions(), surfaces=iso)
    return res.rgba[..., :3].astype(np.float64), res.rgba[..., 3] > 0.5, res.stats


def figure(path, title, pictures, notes):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.3))
    for ax, (name, img) in zip(axes, pictures):
        ax.imshow(np.clip(img, 0, 1) ** (1 / 2.2) if img.ndim == 3 else img, cmap="magma",
                  interpolation="nearest", vmin=0, vmax=1)
        ax.set_title(name, fontsize=10)
        ax.axis("off")
    fig.suptitle(title, fontsize=11)
    fig.text(0.5, 0.02, notes, ha="center", fontsize=8)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--datasets", default="pyfr_tgv,hump3D")
    ap.add_argument("--out", default="docs")
    args = ap.parse_args(argv)
    from hovr_blender.audit.scenes import BACKGROUND
    from hovr_blender.engine.camera import RayCamera

    W, H = (int(v) for v in args.size.lower().split("x"))
    for name in args.datasets.split(","):
        t0 = time.perf_counter()
        mesh = datasets.load_field(name, datasets.Q_FIELDS[name])
        level, ramp = datasets.q_level(mesh, name), datasets.speed_ramp(mesh)
        camera = RayCamera.from_contract(datasets.q_view(mesh, level), W, H)
        t1 = time.perf_counter()
        mine, mine_hit, stats = ours(mesh, camera, level, ramp, BACKGROUND)
        t2 = time.perf_counter()
        points, triangles, speed = vtk_q_contour(vtk_velocity_grid(name), level)
        theirs, theirs_hit = cast(points, triangles, speed, camera, ramp, BACKGROUND)
        t3 = time.perf_counter()
        diff = np.abs(mine - theirs).max(axis=-1)
        either = mine_hit | theirs_hit
        notes = (f"{W}x{H}, Q = {level:.4g} ({datasets.Q_FIELDS[name]}), speed ramp 0..{ramp[-1][0]:.3g}; "
                 f"pixels covered: hovr {mine_hit.mean():.1%}, VTK {theirs_hit.mean():.1%}, by one only "
                 f"{(mine_hit != theirs_hit).mean():.1%}; mean |difference| where either {diff[either].mean():.3f}; "
                 f"VTK: {len(triangles)} triangles")
        print(f"{name}: {notes}; load {t1 - t0:.0f} s, hovr render {t2 - t1:.0f} s "
              f"({stats['render_seconds']:.1f} s in the kernels), VTK {t3 - t2:.0f} s", flush=True)
        figure(Path(args.out) / f"q-criterion-{name.replace('_', '-')}.png",
               f"{name}: Q-criterion isosurface coloured by speed",
               [("hovr: Q sampled exactly from the expansion", mine),
                ("VTK: point gradients on the linearised cells, contoured", theirs),
                ("difference (largest RGB difference per pixel)", diff)], notes)


if __name__ == "__main__":
    main()
