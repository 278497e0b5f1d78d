"""VTK as a ParaView user drives it: the same view, the same transfer function, VTK's own mappers.

Used by bench/peers.py (issue 19) and bench/test_peers_calibration.py. Needs the `vtk`
package (a test dependency) and an offscreen OpenGL context (EGL or OSMesa; VTK picks one
at run time when there is no X display). Nothing in the product imports this file.

What a VTK image means here, mapped onto the render contract:

- Camera: VTK's camera at the contract's eye, target and up; perspective view angle = the
  contract's vertical fov_y (VTK's default, a vertical angle); orthographic parallel scale =
  height / 2. VTK's OpenGL mappers draw pixel centres, as contract §4 does; its rows run
  bottom to top and are flipped. vtkUnstructuredGridVolumeRayCastMapper casts its rays half a
  pixel off (measured on the calibration cube: its image sits half a pixel down and left),
  so for it the camera's window centre moves by half a pixel (vtkCamera.SetWindowCenter(1/W,
  1/H)): its rays are then the contract's (cube error 0.21 -> 0.07 at the silhouette).
- Colour: vtkColorTransferFunction with the contract's colour breakpoints (linear RGB,
  clamped outside, as contract §2).
- Density tau(s) (extinction per world unit) onto VTK's scalar opacity alpha(s) and its
  "scalar opacity unit distance" u. VTK's mappers read them two ways:
  * the unstructured-grid mappers (vtkUnstructuredGridVolumeRayCastMapper's ray integrators,
    vtkProjectedTetrahedraMapper) take alpha(s) / u as the attenuation coefficient, so
    alpha(s) = tau(s) u on the same breakpoints is exact (piecewise linear stays piecewise
    linear); u = 1 / max tau keeps alpha <= 1 (`unstructured_functions`);
  * the image mappers (vtkGPUVolumeRayCastMapper, vtkFixedPointVolumeRayCastMapper, through
    vtkSmartVolumeMapper) correct alpha for their sample distance dt as
    1 - (1 - alpha)^(dt / u), so alpha(s) = 1 - exp(-tau(s) u); that is not linear between
    breakpoints, so the opacity function gets DENSIFY points per density segment, and u is
    again 1 / max tau (`image_functions`).
  bench/test_peers_calibration.py checks both on a cube of constant density, where
  the exact image is C = kappa (1 - exp(-tau L)) with L the ray's chord.
- Output: the render window's 8-bit RGBA framebuffer (what ParaView shows and saves), so every
  VTK pixel carries a rounding of up to 0.5/255 = 2.0e-3 (QUANT); the background is black, so
  RGB is the contract's C.
"""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np

FIELD = "f"  # the point array name of hovr_blender/audit/vtk_volume.py
DENSIFY = 64  # opacity points per density segment for the image mappers
QUANT = 0.5 / 255  # rounding of the 8-bit framebuffer


def _vtk():
    import vtk  # a test and benchmark dependency only

    return vtk


# ------------------------------------------------------------------------- availability

_PROBE = r"""
import vtk
rw = vtk.vtkRenderWindow()
rw.SetOffScreenRendering(1)
rw.SetSize(8, 8)
ren = vtk.vtkRenderer()
rw.AddRenderer(ren)
rw.Render()
ok = rw.SupportsOpenGL() if hasattr(rw, "SupportsOpenGL") else 1
caps = rw.ReportCapabilities() or ""
lines = [l.strip() for l in caps.splitlines() if "renderer string" in l or "version string" in l]
print("OK" if ok else "NOGL", type(rw).__name__, "|", " ; ".join(lines))
"""


def offscreen_status(timeout=120):
    """(ok, text): whether VTK can open an offscreen OpenGL window here, asked in a child
    process (a missing EGL/OSMesa library can abort the process); text names the window class
    and the OpenGL renderer, or says why not."""
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.SubprocessError) as exc:
        return False, f"probe failed: {exc}"
    out = [line for line in r.stdout.splitlines() if line.startswith(("OK", "NOGL"))]
    if r.returncode == 0 and out and out[-1].startswith("OK"):
        return True, out[-1][3:].strip()
    if r.returncode != 0 and "No module named" in r.stderr:
        return False, "the vtk package is not installed"
    tail = (r.stderr.strip().splitlines() or ["(no message)"])[-1]
    return False, f"no offscreen OpenGL context for VTK (exit {r.returncode}): {tail[:300]}"


# ------------------------------------------------------------------------- transfer function

def _color_function(tf):
    """(vtkColorTransferFunction on the transfer function's colour breakpoints, u = 1 / max tau)."""
    ctf = _vtk().vtkColorTransferFunction()
    for s, c in zip(tf.color_s, tf.color_rgb):
        ctf.AddRGBPoint(float(s), *map(float, c))
    tmax = float(np.max(tf.density_tau))
    return ctf, (1.0 / tmax if tmax > 0 else 1.0)


def unstructured_functions(tf):
    """(vtkColorTransferFunction, vtkPiecewiseFunction, u) for the unstructured-grid mappers:
    alpha = tau u, exact on the same breakpoints."""
    vtk = _vtk()
    ctf, u = _color_function(tf)
    otf = vtk.vtkPiecewiseFunction()
    for s, t in zip(tf.density_s, tf.density_tau):
        otf.AddPoint(float(s), float(t) * u)
    return ctf, otf, u


def image_functions(tf, densify=DENSIFY):
    """(ctf, otf, u) for the image mappers: alpha = 1 - exp(-tau u), sampled `densify` times per
    density segment (tau is linear there, alpha is not)."""
    vtk = _vtk()
    ctf, u = _color_function(tf)
    s = tf.density_s
    pts = [s[:1]] + [np.linspace(a, b, densify + 1)[1:] for a, b in zip(s[:-1], s[1:])]
    pts = np.concatenate(pts)
    otf = vtk.vtkPiecewiseFunction()
    for x in pts:
        otf.AddPoint(float(x), float(1.0 - np.exp(-tf.density(x) * u)))
    return ctf, otf, u


def volume_property(ctf, otf, u):
    vtk = _vtk()
    p = vtk.vtkVolumeProperty()
    p.SetColor(ctf)
    p.SetScalarOpacity(otf)
    p.SetScalarOpacityUnitDistance(u)
    p.SetInterpolationTypeToLinear()
    p.ShadeOff()
    return p


# ------------------------------------------------------------------------- the data, as users prepare it

def with_scalars(data):
    data.GetPointData().SetActiveScalars(FIELD)
    return data


def lattice(grid):
    """ParaView's volume representation of higher-order cells: vtkDataSetTriangleFilter splits
    each Lagrange cell into linear tetrahedra on its own node lattice (a cell of order p: p^3
    sub-hexahedra, 5 or 6 tetrahedra each)."""
    vtk = _vtk()
    f = vtk.vtkDataSetTriangleFilter()
    f.SetInputData(grid)
    f.Update()
    return with_scalars(f.GetOutput())


def tessellate(grid, level):
    """vtkTessellatorFilter: each cell into linear tetrahedra, every edge halved `level` times
    (its chord and field criteria set to zero so the subdivision is uniform, as ParaView's
    Nonlinear Subdivision Level is for surfaces); new points get VTK's interpolation of the cell.
    Level 0 is the cell's corners only."""
    vtk = _vtk()
    f = vtk.vtkTessellatorFilter()
    f.SetInputData(grid)
    f.SetOutputDimension(3)
    f.SetMaximumNumberOfSubdivisions(int(level))
    f.SetChordError(1e-300)
    f.MergePointsOn()
    sub = f.GetSubdivider()
    if sub is not None and hasattr(sub, "SetFieldError2"):
        sub.SetFieldError2(0, 1e-300)
    f.Update()
    return with_scalars(f.GetOutput())


def tessellated_tets(cells, level):
    """Tetrahedra vtkTessellatorFilter makes of `cells` cells at `level` (48 per hexahedron at
    level 0, each tetrahedron into 8 per level): for budgets."""
    return int(cells) * 48 * 8 ** int(level)


def resample(grid, n, bounds=None):
    """vtkResampleToImage: n points along the longest side of the box, the same spacing along
    the others; points outside every cell get 0 and are masked (vtkValidPointMask, blanked)."""
    vtk = _vtk()
    b = np.asarray(bounds if bounds is not None else grid.GetBounds(), float)
    L = b[1::2] - b[0::2]
    h = L.max() / (n - 1)
    dims = [max(2, int(np.ceil(x / h - 1e-9)) + 1) for x in L]
    f = vtk.vtkResampleToImage()
    f.SetInputDataObject(grid)
    f.SetUseInputBounds(False)
    f.SetSamplingBounds(*map(float, b))
    f.SetSamplingDimensions(*dims)
    f.Update()
    return with_scalars(f.GetOutput())


# ------------------------------------------------------------------------- rendering

MAPPERS = {
    "raycast": "vtkUnstructuredGridVolumeRayCastMapper",  # CPU ray casting of tetrahedra
    "projected": "vtkOpenGLProjectedTetrahedraMapper",  # OpenGL cell projection
    "smart": "vtkSmartVolumeMapper",  # image data: GPU ray casting where OpenGL allows
    "gpu": "vtkGPUVolumeRayCastMapper",
    "fixedpoint": "vtkFixedPointVolumeRayCastMapper",  # image data, CPU (its image is cut short under EGL)
}


def make_mapper(kind, data):
    vtk = _vtk()
    if kind == "raycast":
        m = vtk.vtkUnstructuredGridVolumeRayCastMapper()
        # Its default integrator (partial pre-integration), and the linear and pre-integration
        # ones, gave an all-black image (VTK 9.7.2) for the audit's transfer functions (tents
        # with zero density between them) on Hex_CurvedFace, while they agree with the
        # homogeneous one on the calibration cube; the homogeneous integrator renders both.
        m.SetRayIntegrator(vtk.vtkUnstructuredGridHomogeneousRayIntegrator())
    elif kind == "projected":
        m = vtk.vtkProjectedTetrahedraMapper()  # the object factory gives the OpenGL one
    elif kind == "smart":
        m = vtk.vtkSmartVolumeMapper()
    elif kind == "gpu":
        m = vtk.vtkGPUVolumeRayCastMapper()
    elif kind == "fixedpoint":
        m = vtk.vtkFixedPointVolumeRayCastMapper()
    else:
        raise ValueError(kind)
    m.SetInputData(data)
    if hasattr(m, "SetScalarModeToUsePointFieldData"):
        m.SetScalarModeToUsePointFieldData()
        m.SelectScalarArray(FIELD)
    return m


class Scene:
    """One offscreen render window of W x H pixels looking through a contract camera."""

    def __init__(self, camera: dict, width: int, height: int):
        vtk = _vtk()
        self.W, self.H = int(width), int(height)
        self.rw = vtk.vtkRenderWindow()
        self.rw.SetOffScreenRendering(1)
        self.rw.SetMultiSamples(0)
        self.rw.SetSize(self.W, self.H)
        self.ren = vtk.vtkRenderer()
        self.ren.SetBackground(0.0, 0.0, 0.0)
        self.rw.AddRenderer(self.ren)
        self.camera = camera
        self.volume = None

    def set_camera(self):
        c = self.camera
        cam = self.ren.GetActiveCamera()
        cam.SetPosition(*map(float, c["eye"]))
        cam.SetFocalPoint(*map(float, c["target"]))
        cam.SetViewUp(*map(float, c["up"]))
        if c.get("projection", "perspective") == "orthographic":
            cam.ParallelProjectionOn()
            cam.SetParallelScale(0.5 * float(c["height"]))
        else:
            cam.ParallelProjectionOff()
            cam.SetViewAngle(float(c["fov_y_deg"]))
        self.ren.ResetCameraClippingRange()

    def show(self, mapper, prop):
        """Put the volume of `mapper` in the scene (the only one)."""
        vtk = _vtk()
        if self.volume is not None:
            self.ren.RemoveVolume(self.volume)
        self.volume = vtk.vtkVolume()
        self.volume.SetMapper(mapper)
        self.volume.SetProperty(prop)
        self.ren.AddVolume(self.volume)
        self.set_camera()
        half = isinstance(mapper, vtk.vtkUnstructuredGridVolumeRayCastMapper)
        self.ren.GetActiveCamera().SetWindowCenter(1.0 / self.W if half else 0.0, 1.0 / self.H if half else 0.0)

    def render(self):
        """(rgba (H, W, 4) float64 with row 0 at the top, seconds of the Render call)."""
        vtk = _vtk()
        from vtk.util.numpy_support import vtk_to_numpy

        self.ren.GetActiveCamera().Modified()
        t0 = time.perf_counter()
        self.rw.Render()
        secs = time.perf_counter() - t0
        w2i = vtk.vtkWindowToImageFilter()
        w2i.SetInput(self.rw)
        w2i.SetInputBufferTypeToRGBA()
        w2i.ReadFrontBufferOff()
        w2i.Update()
        img = vtk_to_numpy(w2i.GetOutput().GetPointData().GetScalars()).reshape(self.H, self.W, 4)
        return img[::-1].astype(np.float64) / 255.0, secs

    def close(self):
        if self.volume is not None:
            self.ren.RemoveVolume(self.volume)
        self.rw.Finalize()


def chord_lengths(camera: dict, width: int, height: int, lo, hi):
    """(H, W) length of each contract pixel ray inside the box [lo, hi] (slab method)."""
    from hovr_blender.audit.vtk_reference import contract_ray

    out = np.zeros((height, width))
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    for j in range(height):
        for i in range(width):
            o, d = contract_ray(camera, width, height, i, j)
            with np.errstate(divide="ignore", invalid="ignore"):
                ta, tb = (lo - o) / d, (hi - o) / d
            t0 = np.nanmax(np.minimum(ta, tb))
            t1 = np.nanmin(np.maximum(ta, tb))
            out[j, i] = max(0.0, t1 - max(t0, 0.0))
    return out
