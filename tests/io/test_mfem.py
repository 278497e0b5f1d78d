"""The MFEM reader (hovr_blender/io/mfem) on files MFEM 4.10 wrote through PyMFEM (tests/data/mfem,
MANIFEST.md, make_cases.py): a curved mixed mesh (v1.0) with H1, L2 and vector fields, a parallel
rank's piece (v1.2), pyramids in Bergot's space, and a variable-order field on a nonconforming mesh.
The reference is MFEM itself: its values of each file, read back as GLVis reads it, at points of
every element (the .npz files), and its ParaViewDataCollection's high-order export, which gives
the same pixels through the VTU reader."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.shapes import HEX, PRISM, PYR, TET
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io import formats
from hovr_blender.io.mfem import MFEMError, elements as el
from hovr_blender.io.mfem.format import list_fields, read_mfem  # the parser, in this process
from hovr_blender.io.mfem.files import parse_collection
from hovr_blender.io.vtu import read_vtu

from ..data.mfem import FICHERA_CAMERA, VENDORED, camera_for
from ..helpers import data_file

CAMERA = FICHERA_CAMERA
BG = [0.05, 0.05, 0.08]


def path(name):
    return data_file("mfem", name)


# ----------------------------------------------------------------------------- spaces

@pytest.mark.parametrize("geom", [4, 5, 6])
@pytest.mark.parametrize("kind,btype", [("H1", 1), ("H1", 4), ("L2", 0), ("L2", 1), ("L2", 5)])
@pytest.mark.parametrize("p", [1, 2, 3, 5])
def test_change_of_basis_is_exact(geom, kind, btype, p):
    """Values at an element's nodes -> modal coefficients whose expansion takes those values at the
    nodes again: an interpolation in the element's space, not a fit."""
    col = parse_collection(f"H1{'' if btype == 1 else '@U'}_3D_P{p}" if kind == "H1" else
                           f"L2{'' if btype == 0 else f'_T{btype}'}_3D_P{p}")
    from hovr_blender.io.mfem.dofs import nodes_of

    X = nodes_of(col, geom)
    values = np.random.default_rng(p).normal(size=len(X))
    C = el.conversion(geom, p, X) @ values
    back = ex.eval_modal(el.SHAPES[geom], el.modes(geom, p), C, el.to_engine(geom, X))
    assert np.abs(back - values).max() < 1e-10


def test_pyramids_the_engine_cannot_hold_are_refused():
    el.check_order("H1", 7, 1, el.FUENTES)
    el.check_order("H1", 7, 2, el.BERGOT)
    el.check_order("L2", 7, 0, el.FUENTES)
    for kind, p, pyr in (("H1", 2, el.FUENTES), ("H1", 3, el.BERGOT), ("L2", 1, el.FUENTES)):
        with pytest.raises(el.SpaceError, match="rational"):
            el.check_order(kind, 7, p, pyr)


def test_collections():
    assert parse_collection("H1_3D_P3") == parse_collection("H1_3D_P3")
    c = parse_collection("L2_T1_3D_P2_Pyr0")
    assert (c.kind, c.order, c.btype, c.pyramid) == ("L2", 2, 1, el.BERGOT)
    assert parse_collection("H1@U_3D_P4").btype == 4 and parse_collection("Quadratic").order == 2
    for name, why in (("H1Pos_3D_P2", "Bernstein"), ("ND_3D_P1", "Nedelec"), ("L2Int_3D_P1", "integral"),
                      ("H1_2D_P2", "2-D"), ("H1_3D_P15", "order 15"), ("L2_T2_3D_P1", "not a nodal"),
                      ("Cubic", "not an H1 or L2")):
        with pytest.raises(el.SpaceError, match=why):
            parse_collection(name)


# ----------------------------------------------------------------------------- against MFEM's own values

CASES = [("fichera.mesh", "fichera-u.gf", "fichera-values.npz"),
         ("fichera.mesh", "fichera-w.gf", "fichera-values.npz"),
         ("fichera.mesh", "fichera-vel.gf", "fichera-values.npz"),
         ("fichera-part0.mesh", "fichera-part0-u.gf", "fichera-part0-values.npz"),
         ("zoo.mesh", "zoo-u.gf", "zoo-values.npz"),
         ("zoo.mesh", "zoo-w.gf", "zoo-values.npz")]


def mfem_gap(mesh, reference, values):
    """The largest differences (geometry, field) between a VolumeMesh read here and MFEM's own
    evaluation at the reference points (element, MFEM reference coordinates)."""
    gx = gv = 0.0
    xs = reference["x"] if "x" in reference else [None] * len(values)
    for e, X, x, v in zip(reference["element"], reference["X"], xs, values):
        geom, sh = int(reference["geom"][e]), int(mesh.shape[e])
        xi = el.to_engine(geom, X)
        g = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, mesh.geom_modes[e])]
        f = mesh.coeffs[mesh.coeff_offset[e]: mesh.coeff_offset[e] + ex.num_coeffs(sh, mesh.modes[e])]
        if x is not None:
            gx = max(gx, float(np.abs(ex.eval_modal(sh, mesh.geom_modes[e], g, xi) - x).max()))
        gv = max(gv, abs(float(ex.eval_modal(sh, mesh.modes[e], f, xi)) - float(v)))
    return gx, gv


@pytest.mark.parametrize("mesh_name,gf_name,reference", CASES)
def test_the_values_are_mfems(mesh_name, gf_name, reference):
    """Geometry and field at MFEM's points of every element equal MFEM's own evaluation of the same
    files: the DOF numbering, the node sets and the change of basis are MFEM's."""
    ref = np.load(path(reference))
    values = ref[gf_name[:-3]]
    for c in range(values.shape[1]):
        m = read_mfem(path(mesh_name), path(gf_name), None, c if values.shape[1] > 1 else None)
        gx, gv = mfem_gap(m, ref, values[:, c])
        assert gx < 1e-12 and gv < 1e-12, (gf_name, c, gx, gv)


def test_the_cases_hold_what_they_say():
    m = read_mfem(path("fichera.mesh"), path("fichera-u.gf"))
    assert {s: int((m.shape == s).sum()) for s in (HEX, PRISM, TET, PYR)} == {HEX: 24, PRISM: 48, TET: 40, PYR: 0}
    assert not m.affine.all() and (m.geom_modes == 3).all() and (m.modes == 4).all()
    z = read_mfem(path("zoo.mesh"), path("zoo-w.gf"))
    assert (z.shape == PYR).sum() == 6 and (z.modes == 3).all()
    assert read_mfem(path("fichera-part0.mesh"), path("fichera-part0-u.gf")).num_elements == 34
    assert formats.format_of(path("fichera.mesh")).name == "mfem"
    assert list_fields(path("fichera-vel.gf")) == {"fichera-vel": 3}


def test_vector_fields():
    mesh, vel = path("fichera.mesh"), path("fichera-vel.gf")
    comps = [read_mfem(mesh, vel, None, i) for i in range(3)]
    magnitude = read_mfem(mesh, vel)
    assert magnitude.field_name == "|fichera-vel|" and comps[1].field_name == "fichera-vel[1]"
    q = read_mfem(mesh, vel, "Q(fichera-vel)")
    assert q.derived is not None
    with pytest.raises(MFEMError, match="no field 'u'"):
        read_mfem(mesh, vel, "u")


# ----------------------------------------------------------------------------- variable order

def test_a_variable_order_field_keeps_its_orders():
    """var.gf is the variable-order field raised to order 4 (MFEM writes no orders); each element
    comes back at the order MFEM gave it, holding MFEM's values of the variable-order field."""
    orders = json.loads(path("var-orders.json").read_text())["orders"]
    m = read_mfem(path("var.mesh"), path("var.gf"))
    assert m.modes[:, 0].tolist() == [o + 1 for o in orders] and len(set(orders)) == 4
    raised = read_mfem(path("var.mesh"), path("var.gf"), own_orders=False)
    assert (raised.modes == 5).all()
    ref = np.load(path("var-values.npz"))
    _, gv = mfem_gap(m, ref, ref["u"])
    assert gv < 1e-12, gv


def test_a_variable_order_field_saved_as_it_is_is_refused():
    """GridFunction::Save of a variable-order space writes its base order's header over every
    element's own values: refused in one line saying what to save instead."""
    with pytest.raises(MFEMError) as caught:
        read_mfem(path("var.mesh"), path("var-raw.gf"))
    message = str(caught.value)
    assert "\n" not in message and "var-raw.gf" in message and "ProlongateToMaxOrder" in message


# ----------------------------------------------------------------------------- images

TF_U = {"color": [[-0.6, 0.1, 0.2, 0.8], [0.0, 0.2, 0.9, 0.6], [0.6, 1.0, 0.8, 0.1], [1.2, 1.0, 0.2, 0.1]],
        "density": [[-0.6, 0.5], [0.0, 1.5], [0.6, 3.0], [1.2, 6.0]]}


def render(mesh, method, precision="float64", size=256, device="cpu", camera=None):
    cam = RayCamera.from_contract(camera or CAMERA, size, size)
    tf = TransferFunction.from_contract(TF_U)
    opts = RenderOptions(method=method, h=0.01, tolerance=1e-8, min_transmittance=0.0, precision=precision)
    return Renderer(mesh, device).render(cam, tf, BG, opts).rgba.astype(np.float64)


@pytest.fixture(scope="module")
def exports():
    return {"fichera": (read_mfem(path("fichera.mesh"), path("fichera-u.gf")),
                        read_vtu(path("fichera_lagrange_p3.vtu"), "u")),
            "var": (read_mfem(path("var.mesh"), path("var.gf")), read_vtu(path("var_lagrange_p4.vtu"), "u"))}


@pytest.mark.parametrize("case", ["fichera", "var"])
@pytest.mark.parametrize("method", ["split", "classified"])
def test_same_image_as_mfems_paraview_export(device, exports, case, method):
    """256 x 256, split and classified: the native files against MFEM's ParaViewDataCollection
    export at high order (Lagrange cells of order 3, 4: exact for fields of order 3 and up to 4 and
    geometry of order 2). The two hold each element's polynomial in different bases, so the kernels
    run in float64: in float32 their rounding alone moves pixels by ~1e-5."""
    native, export = exports[case]
    a, b = render(native, method, device=device), render(export, method, device=device)
    assert a[..., 3].max() > 0.2 and np.ptp(a[..., :3], axis=(0, 1)).max() > 0.1
    diff = float(np.abs(a - b).max())
    print(f"mfem {case} {method} {device}: max |native - export| = {diff:.2e}")
    assert diff <= 1e-6, (case, method, diff)


@pytest.mark.parametrize("method", ["split", "classified"])
def test_variable_orders_render_as_the_raised_field(device, method):
    """Each element at its own order against the same field at order 4 everywhere (as the file
    stores it): within the audit's 1e-3 (measured: round-off)."""
    own = read_mfem(path("var.mesh"), path("var.gf"))
    raised = read_mfem(path("var.mesh"), path("var.gf"), own_orders=False)
    assert (own.modes < raised.modes).any()
    diff = float(np.abs(render(own, method, device=device) - render(raised, method, device=device)).max())
    print(f"mfem var own orders vs raised {method} {device}: {diff:.2e}")
    assert diff <= 1e-3, diff


@pytest.mark.parametrize("mesh_name,gf_name", VENDORED)
def test_each_vendored_file_renders_in_the_cli(tmp_path, mesh_name, gf_name):
    view = {"data": {"path": str(path(mesh_name)), "solution": str(path(gf_name))}, "camera": camera_for(mesh_name),
            "image": {"width": 24, "height": 20}, "transfer_function": TF_U, "background": BG,
            "render": {"method": "split"}}
    (tmp_path / "v.json").write_text(json.dumps(view))
    out = subprocess.run([sys.executable, "-m", "hovr_blender.cli", "render", str(tmp_path / "v.json"),
                          "-o", str(tmp_path / "v.npy")], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    image = np.load(tmp_path / "v.npy")
    assert image.shape == (20, 24, 4) and image[..., 3].max() > 0.05


# ----------------------------------------------------------------------------- the GridFunction beside a mesh

def test_the_gridfunction_beside_a_mesh(tmp_path):
    from hovr_blender.io.mfem.format import pick_solution

    mesh = tmp_path / "beam.mesh"
    mesh.write_bytes(path("zoo.mesh").read_bytes())
    assert pick_solution(mesh)[0] is None
    (tmp_path / "other.gf").write_bytes(path("zoo-u.gf").read_bytes())
    assert pick_solution(mesh)[0].name == "other.gf"
    (tmp_path / "more.gf").write_bytes(path("zoo-u.gf").read_bytes())
    assert pick_solution(mesh)[0] is None
    (tmp_path / "beam-u.gf").write_bytes(path("zoo-u.gf").read_bytes())
    assert pick_solution(mesh)[0].name == "beam-u.gf"
    m = read_mfem(mesh)
    assert m.field_name == "beam-u" and m.num_elements == 34


# ----------------------------------------------------------------------------- what is refused, in one line

def test_mesh_v13_with_attribute_sets():
    """MFEM writes v1.3 when a mesh has named attribute sets (skipped: the numbering is v1.0's)."""
    a = read_mfem(path("zoo-sets.mesh"), path("zoo-u.gf"))
    b = read_mfem(path("zoo.mesh"), path("zoo-u.gf"))
    assert np.array_equal(a.coeffs, b.coeffs) and np.array_equal(a.geom_coeffs, b.geom_coeffs)


def edited(tmp_path, name, old, new, count=1):
    text = path(name).read_text()
    assert old in text, old
    out = tmp_path / name
    out.write_text(text.replace(old, new, count))
    return out


def refusal(mesh, gf, *words):
    with pytest.raises(MFEMError) as caught:
        read_mfem(mesh, gf)
    message = str(caught.value)
    assert "\n" not in message and all(w in message for w in words), message
    return message


def test_what_the_reader_does_not_read_is_refused_in_one_line(tmp_path):
    gf = path("zoo-u.gf")
    refusal(edited(tmp_path, "zoo.mesh", "dimension\n3", "dimension\n2"), gf, "zoo.mesh", "line", "2-D mesh")
    refusal(edited(tmp_path, "zoo.mesh", "MFEM mesh v1.0", "MFEM NURBS mesh v1.0"), gf, "a NURBS mesh")
    refusal(edited(tmp_path, "zoo.mesh", "MFEM mesh v1.0", "MFEM mesh v9.0"), gf, "not an MFEM mesh")
    refusal(edited(tmp_path, "var.mesh", "0 1 4 0 13 15 21 25", "0 1 4 1 13 15 21 25 1 2 3 4 5 6 7 8"),
            path("var.gf"), "refined", "hanging nodes")
    refusal(path("zoo.mesh"), edited(tmp_path, "zoo-u.gf", "H1_3D_P2_Pyr0", "H1_3D_P2"), "pyramids of order 2",
            "Fuentes", "rational")
    refusal(path("zoo.mesh"), edited(tmp_path, "zoo-u.gf", "VDim: 1", "VDim: 1000000"), "VDim", "outside")
    refusal(path("zoo.mesh"), edited(tmp_path, "zoo-u.gf", "H1_3D_P2_Pyr0", "H1_3D_P99_Pyr0"), "order 99")


def test_broken_topology_is_refused(tmp_path):
    text = path("zoo.mesh").read_text()
    lines = text.split("\n")
    at = lines.index("elements") + 2  # the first element's line
    gf = path("zoo-w.gf")
    # an element naming one vertex twice
    first = lines[at].split()
    twice = tmp_path / "twice.mesh"
    twice.write_text("\n".join(lines[:at] + [" ".join(first[:3] + [first[2]] + first[4:])] + lines[at + 1:]))
    refusal(twice, gf, "names a vertex twice")
    # a fourth element on a face: an element repeated
    count = int(lines[at - 1])
    three = tmp_path / "three.mesh"
    three.write_text("\n".join(lines[:at - 1] + [str(count + 2)] + lines[at:at + count] + [lines[at]] * 2
                               + lines[at + count:]))
    refusal(three, gf, "shared by")


def test_absurd_counts_are_refused_before_anything_is_allocated(tmp_path):
    gf = path("zoo-u.gf")
    n = path("zoo.mesh").read_text().split("elements\n")[1].split("\n")[0]
    refusal(edited(tmp_path, "zoo.mesh", f"elements\n{n}\n", "elements\n1000000000000\n"), gf, "element count",
            "outside")
    refusal(edited(tmp_path, "zoo.mesh", "vertices\n", "vertices\n999999999999999999999\n#"), gf, "vertex count")
