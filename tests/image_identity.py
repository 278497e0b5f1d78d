"""The CPU images of the image tests' scenes, as .npy files, to compare two checkouts bit for bit
(a refactoring must not change one pixel).

    PYTHONPATH=CHECKOUT python -m tests.image_identity render OUT_DIR     (from CHECKOUT)
    python -m tests.image_identity compare DIR_A DIR_B

Scenes (small, CPU, float32 and float64 where the tests use both): the example view files
through the loader (the sphere, ElVis' sphere, hump3D), the F12 tests' sphere (tests.helpers.SPHERE,
both projections, classified and split), the curved mixed cube of the precision and benchmark
tests, and vendored real Nektar++ files (a curved face, a magnitude |u,v,w|, a mixed mesh, all
four shapes) with the framing camera and tents; and, through the door (engine/frame.render_frame),
the example sphere with its isosurface and plane, with an opaque plane (shaded and holdout), bands
of rows, and a segment cache traced and then shaded through another transfer function, and the
`hovr render` of that view. Both checkouts need the door (issue 35 on).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

W, H = 48, 36


def scenes():
    """{name: (mesh, transfer function, camera, background, RenderOptions kwargs)}."""
    from hovr_blender.engine.view import View
    from hovr_blender.io.sources import VolumeSource, load_view_data, load_volume
    from tests.helpers import BACKGROUND, COLORS, REPO, curved_mixed_scene, framing, tents

    out = {}
    for name in ("sphere", "elvis_sphere", "hump3d"):
        view = View.load(str(REPO / "examples" / f"{name}.json"))
        cam = type(view.camera)(**{**view.camera.__dict__, "width": W, "height": H})
        opts = {k: getattr(view.options, k) for k in ("method", "h", "tolerance")}
        out[f"example_{name}"] = (load_view_data(view), view.transfer_function, cam, view.background, opts)
    mesh, tf, camera = curved_mixed_scene(2)
    for method in ("classified", "split"):
        out[f"curved_mixed_{method}"] = (mesh, tf, camera(W, H), BACKGROUND, {"method": method})
    nektar = REPO / "tests" / "data" / "nektar"
    for name, solution, field in (("Hex_CurvedFace", "Hex_CurvedFace.fld", "u"),
                                  ("Tet_channel_m3", "Tet_channel_m3.fld", "|u,v,w|"),
                                  ("wss_3D_periodic", "", "rho"), ("CubeAllElements", "", ""),
                                  ("hump3D_GLL", "hump3D.rst", "rho")):
        mesh = load_volume(VolumeSource.resolve(str(nektar / f"{name}.xml"),
                                                str(nektar / solution) if solution else "", field))
        lo, hi = np.percentile(mesh.field_samples(3), [2, 98])
        if hi - lo <= 1e-12 * max(1.0, abs(lo)):
            lo, hi = lo - 1.0, hi + 1.0
        for method in ("classified", "split"):
            out[f"{name}_{method}"] = (mesh, tents(lo, hi, COLORS, 6.0), framing(mesh, W, H), BACKGROUND,
                                       {"method": method})
    return out


def render(folder: Path):
    from hovr_blender.engine.camera import RayCamera
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import RenderOptions
    from tests.helpers import SPHERE

    folder.mkdir(parents=True, exist_ok=True)
    for name, (mesh, tf, cam, bg, kw) in scenes().items():
        renderer = Renderer(mesh, "cpu")
        for precision in ("float32", "float64"):
            image = renderer.render(cam, tf, np.asarray(bg, float), RenderOptions(device="cpu", precision=precision,
                                                                                  **kw)).rgba
            np.save(folder / f"{name}_{precision}.npy", image)
    for projection, contract in (("perspective", SPHERE.PERSPECTIVE), ("orthographic", SPHERE.ORTHOGRAPHIC)):
        for method in ("classified", "split"):
            image = SPHERE.core_render(contract, method, False, camera=RayCamera.from_contract(contract, SPHERE.W,
                                                                                               SPHERE.H))
            np.save(folder / f"blender_sphere_{projection}_{method}.npy", image)
    render_frames(folder)
    print(f"{len(list(folder.glob('*.npy')))} images in {folder}")


def render_frames(folder: Path):
    """The example sphere's isosurface and plane, opaque meshes, bands and a segment cache, each
    through the door; and the CLI's image of the same view."""
    import json

    from hovr_blender import cli
    from hovr_blender.engine.frame import Frame, SegmentSlot, render_frame
    from hovr_blender.engine.opaque import OpaqueScene
    from hovr_blender.engine.renderer import Renderer
    from hovr_blender.engine.view import View
    from hovr_blender.io.sources import load_view_data
    from tests.engine.test_opaque import plane_mesh
    from tests.helpers import REPO

    view = View.load(str(REPO / "examples" / "sphere_isosurface.json"))
    cam = type(view.camera)(**{**view.camera.__dict__, "width": 40, "height": 30})
    r = Renderer(load_view_data(view), "cpu")
    tf = view.transfer_function
    edited = type(tf)(tf.color_s, tf.color_rgb[::-1].copy(), tf.density_s, tf.density_tau * 0.5)
    opaque = OpaqueScene([plane_mesh()])
    for precision in ("float32", "float64"):
        frame = Frame.from_view(view, options=view.options.with_(precision=precision))
        plain = frame.with_(surfaces=None)
        runs = {"iso": (frame, {}), "opaque": (plain.with_(opaque=opaque), {}),
                "opaque_holdout": (plain.with_(opaque=opaque, opaque_mode="HOLDOUT"), {}),
                "opaque_iso": (frame.with_(opaque=opaque), {}), "iso_band": (frame, {"rows": (7, 19)}),
                "opaque_band": (plain.with_(opaque=opaque), {"rows": (7, 19)})}
        for name, (f, how) in runs.items():
            np.save(folder / f"frame_{name}_{precision}.npy", render_frame(r, f, cam, **how).rgba)
        for name, f, rows in (("cached", frame.with_(opaque=opaque), None), ("cached_band", frame, (3, 22))):
            slot = SegmentSlot()
            traced = render_frame(r, f.with_(cache=slot), cam, rows=rows)
            shaded = render_frame(r, f.with_(cache=slot, transfer_function=edited), cam, rows=rows)
            np.save(folder / f"frame_{name}_trace_{precision}.npy", traced.rgba)
            np.save(folder / f"frame_{name}_shade_{precision}.npy", shaded.rgba)
    doc = json.loads((REPO / "examples" / "sphere_isosurface.json").read_text())
    doc["image"] = {"width": 40, "height": 30}
    (folder / "view.json").write_text(json.dumps(doc))
    assert cli.main(["render", str(folder / "view.json"), "-o", str(folder / "cli_sphere_isosurface.npy")]) == 0
    (folder / "view.json").unlink()


def compare(a: Path, b: Path) -> int:
    names = sorted({p.name for p in a.glob("*.npy")} | {p.name for p in b.glob("*.npy")})
    differ = [n for n in names if not ((a / n).exists() and (b / n).exists()
                                       and (a / n).read_bytes() == (b / n).read_bytes())]
    for n in differ:
        print("differs:", n)
    print(f"{len(names) - len(differ)} of {len(names)} images bit-identical")
    return 1 if differ else 0


if __name__ == "__main__":
    if sys.argv[1] == "render":
        render(Path(sys.argv[2]))
    else:
        raise SystemExit(compare(Path(sys.argv[2]), Path(sys.argv[3])))
