"""What the mesh (mesh.py), its validity check (validity.py) and its derived fields
(derived_fields.py) share, below all three so that none imports another in a circle: the errors
they raise and the Jacobian tolerance."""
from __future__ import annotations

TOLERANCE = 1e-8  # det J below this fraction of the element's scale counts as zero


class MeshError(ValueError):
    """An element the renderer cannot represent (degenerate, non-affine, bad order, NaN)."""


class DerivedFieldError(ValueError):
    """A derived field name that cannot be read, or data that cannot give it."""
