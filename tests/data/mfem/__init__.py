"""The vendored MFEM cases (make_cases.py, MANIFEST.md): every mesh with each GridFunction made on
it, and a camera that sees each mesh whole (the test modules' shared view of them)."""

VENDORED = [("fichera.mesh", "fichera-u.gf"), ("fichera.mesh", "fichera-w.gf"), ("fichera.mesh", "fichera-vel.gf"),
            ("fichera-part0.mesh", "fichera-part0-u.gf"), ("zoo.mesh", "zoo-u.gf"), ("zoo.mesh", "zoo-w.gf"),
            ("zoo-sets.mesh", "zoo-u.gf"), ("var.mesh", "var.gf")]
FICHERA_CAMERA = {"eye": [3.9, -3.2, 3.3], "target": [0.0, 0.0, -0.1], "up": [0, 0, 1], "fov_y_deg": 36.0}
ZOO_CAMERA = {"eye": [3.4, -2.6, 2.4], "target": [1.0, 0.5, 0.5], "up": [0, 0, 1], "fov_y_deg": 36.0}


def camera_for(mesh_name: str) -> dict:
    return ZOO_CAMERA if mesh_name.startswith("zoo") else FICHERA_CAMERA
