"""The entry points: read_vtu (a .vtu file's point-data field and geometry -> VolumeMesh) and
list_fields. Reading goes piece by piece: the points, cells and field arrays are decoded to the
sizes the piece's counts give them, each cell is checked (type, degrees, node count, finite
values), and cells of one kind and degree are converted together."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...engine import limits, validity
from ...engine.mesh import MeshError, VolumeMesh
from ...engine.shapes import HEX, MAX_MODES, PRISM, TET
from .cells import CELL_TYPES, PYRAMIDS, infer_degrees, node_count
from .conversion import conversion_matrix, modes_for
from .decoding import LoadedFile, decode
from .errors import VtuError
from .vtkfile import load, pieces, point_arrays, point_fields, version


def list_fields(path) -> dict[str, int]:
    """Point-data arrays present in every piece: {name: number of components}, file order.
    Reads the XML only (no array is decoded)."""
    path = Path(path)
    try:
        root, _ = load(path)
        return point_fields(path, pieces(path, root))
    except VtuError:
        raise
    except Exception as exc:  # anything a malformed file provokes in the XML layer
        raise VtuError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


def read_vtu(path, field=None, component=None) -> VolumeMesh:
    """Read a .vtu file into a VolumeMesh (field and geometry as modal expansions).

    field: a point-data array name (default: the first one). component: for multi-component
    arrays an index, or "magnitude" (the default for vectors; the magnitude is taken at the
    nodes and interpolated like any nodal field). Every problem raises VtuError."""
    path = Path(path)
    try:
        return _read(path, field, component)
    except VtuError:
        raise
    except limits.ResourceLimitError as exc:
        raise VtuError(f"{path}: {exc}") from exc
    except MeshError as exc:
        raise VtuError(f"{path}: {exc}".replace("element ", "cell ", 1)) from exc
    except Exception as exc:  # a malformed file must never surface as anything but VtuError
        raise VtuError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


def _read(path: Path, field, component):
    root, file = load(path)
    all_pieces = pieces(path, root)
    field, num_components = _choose_field(path, all_pieces, field)
    vtk8 = version(path, root) < (2, 1)
    cells = []  # (shape, family, degrees, node coordinates, node values) of every cell
    field_name = None
    for index, piece in enumerate(all_pieces):
        # len(cells): the global index of the piece's first cell, for error messages
        piece_cells, piece_field_name = _read_piece(file, piece, f"piece {index}", len(cells), field,
                                                    num_components, component)
        if piece_cells:
            cells.extend(piece_cells)
            field_name = piece_field_name
    if not cells:
        raise VtuError(f"{path}: the file has no cells")
    return _volume_mesh(path, cells, vtk8, field_name)


def _choose_field(path, all_pieces, field):
    """(field, its number of components): the one asked for, or the first point array."""
    available = point_fields(path, all_pieces)
    if field is None:
        if not available:
            raise VtuError(f"{path}: no point-data array to render")
        field = next(iter(available))
    elif field not in available:
        cell_names = {a.attrib.get("Name") for p in all_pieces for cd in p.findall("CellData") for a in cd}
        hint = " (it is cell data: only point data is a polynomial field)" if field in cell_names else ""
        raise VtuError(f"{path}: no point-data field {field!r}{hint}; available: {sorted(available) or 'none'}")
    return field, available[field]


def _count(path, element, key, where):
    try:
        value = int(element.attrib[key])
    except (KeyError, ValueError):
        raise VtuError(f"{path}: {where}: missing or bad {key}") from None
    if value < 0:
        raise VtuError(f"{path}: {where}: {key} = {value}")
    return value


def _read_piece(file: LoadedFile, piece, where, first_cell, field, num_components, component):
    """(the piece's cells, the field's name with the component: e.g. "|u|" or "u[1]"); an
    empty piece gives ([], None)."""
    path = file.path
    num_points = _count(path, piece, "NumberOfPoints", where)
    num_cells = _count(path, piece, "NumberOfCells", where)
    if num_cells == 0:
        return [], None
    points_element = piece.find("Points")
    if points_element is None or len(points_element) != 1:
        raise VtuError(f"{path}: {where}: <Points> must hold one DataArray")
    points = decode(file, points_element[0], f"{where} points", 3 * num_points, f"{num_points} points x 3")
    points = points.astype(np.float64, copy=False).reshape(num_points, 3)
    ends, starts, types, connectivity = _piece_cells(file, piece, where, num_points, num_cells, first_cell)
    array = [a for a in point_arrays(piece) if a.attrib.get("Name") == field][0]
    values = decode(file, array, f"{where} field {field!r}", num_points * num_components,
                    f"{num_points} points x {num_components}")
    values, field_name = _select_component(path, values.astype(np.float64, copy=False), field, num_components,
                                           component)
    weights = _rational_weights(file, piece, where, num_points)
    degrees = _higher_order_degrees(file, piece, where, num_cells)
    cells = []
    for c in range(num_cells):
        cell = first_cell + c
        cell_type = int(types[c])
        nodes = connectivity[starts[c]:ends[c]]
        if cell_type in PYRAMIDS:
            raise VtuError(f"{path}: cell {cell}: {PYRAMIDS[cell_type]} is not supported (VTK's pyramid space "
                           "differs from the Nektar++ pyramid expansion this renderer evaluates)")
        if cell_type not in CELL_TYPES:
            raise VtuError(f"{path}: cell {cell}: VTK cell type {cell_type} is not supported "
                           "(3-D Lagrange/Bézier tetrahedra, hexahedra and wedges are)")
        type_name, shape, family = CELL_TYPES[cell_type]
        cell_degrees = _cell_degrees(path, cell, type_name, shape, family, nodes.size,
                                     None if degrees is None else degrees[c])
        node_points = points[nodes]
        node_values = values[nodes]
        if not np.all(np.isfinite(node_points)):
            raise VtuError(f"{path}: cell {cell}: node coordinates are NaN or Inf")
        if not np.all(np.isfinite(node_values)):
            raise VtuError(f"{path}: cell {cell}: field {field_name!r} is NaN or Inf at a node")
        if family == "bezier" and weights is not None and np.any(weights[nodes] != 1.0):
            raise VtuError(f"{path}: cell {cell}: rational Bézier cells (RationalWeights != 1) are not polynomial")
        cells.append((shape, "lagrange" if family == "linear" else family, cell_degrees, node_points, node_values))
    return cells, field_name


def _piece_cells(file: LoadedFile, piece, where, num_points, num_cells, first_cell):
    """(ends, starts, types, connectivity) of the piece's <Cells>: cell c's nodes are
    connectivity[starts[c]:ends[c]], each a valid point index."""
    path = file.path
    cells_element = piece.find("Cells")
    if cells_element is None:
        raise VtuError(f"{path}: {where}: no <Cells>")
    arrays = {a.attrib.get("Name"): a for a in cells_element}
    if "faces" in arrays:
        raise VtuError(f"{path}: {where}: polyhedral cells are not supported")
    for key in ("connectivity", "offsets", "types"):
        if key not in arrays:
            raise VtuError(f"{path}: {where}: <Cells> lacks the {key} array")
    ends = decode(file, arrays["offsets"], f"{where} offsets", num_cells, f"{num_cells} cells")
    types = decode(file, arrays["types"], f"{where} types", num_cells, f"{num_cells} cells")
    for name, array in (("offsets", ends), ("types", types)):
        if array.dtype.kind not in "iu":
            raise VtuError(f"{path}: {where}: {name} array is {array.dtype}, not integer")
    ends = ends.astype(np.int64)
    starts = np.concatenate([[0], ends[:-1]])
    bad = np.flatnonzero(ends <= starts)
    if bad.size:
        raise VtuError(f"{path}: cell {first_cell + bad[0]}: offsets are not increasing")
    connectivity = decode(file, arrays["connectivity"], f"{where} connectivity", int(ends[-1]),
                          f"offsets end at {ends[-1]}")
    if connectivity.dtype.kind not in "iu":
        raise VtuError(f"{path}: {where}: connectivity array is {connectivity.dtype}, not integer")
    # each connectivity entry becomes a node's coordinates and value, copied twice later
    limits.check_bytes(connectivity.size * 64, f"{where}: the cells' node coordinates and values")
    connectivity = connectivity.astype(np.int64)
    if connectivity.size and (connectivity.min() < 0 or connectivity.max() >= num_points):
        bad_entry = int(np.flatnonzero((connectivity < 0) | (connectivity >= num_points))[0])
        c = int(np.searchsorted(ends, bad_entry, side="right"))
        raise VtuError(f"{path}: cell {first_cell + c}: point index out of range (piece has {num_points} points)")
    return ends, starts, types, connectivity


def _select_component(path, values, name, num_components, component):
    """(one value per point, the field's name) of a scalar or of a vector's component or magnitude."""
    if num_components == 1:
        if component not in (None, 0, "magnitude"):
            raise VtuError(f"{path}: field {name!r} is a scalar; component {component!r} does not exist")
        return values.reshape(-1), name
    values = values.reshape(-1, num_components)
    if component is None or component == "magnitude":
        return np.sqrt(np.einsum("ij,ij->i", values, values)), f"|{name}|"
    if (isinstance(component, (int, np.integer)) and not isinstance(component, bool)
            and 0 <= component < num_components):
        return values[:, int(component)], f"{name}[{int(component)}]"
    raise VtuError(f"{path}: field {name!r} has {num_components} components; component must be "
                   f"0..{num_components - 1} or 'magnitude', not {component!r}")


def _rational_weights(file: LoadedFile, piece, where, num_points):
    """The point array PointData's RationalWeights attribute names, or None."""
    point_data = piece.find("PointData")
    name = point_data.attrib.get("RationalWeights") if point_data is not None else None
    if not name:
        return None
    found = [a for a in point_arrays(piece) if a.attrib.get("Name") == name]
    if not found:
        return None
    return decode(file, found[0], f"{where} rational weights", num_points, f"{num_points} points")


def _higher_order_degrees(file: LoadedFile, piece, where, num_cells):
    """(num_cells, 3) degrees from the cell array CellData's HigherOrderDegrees attribute
    names (default: HigherOrderDegrees), or None."""
    cell_data = piece.find("CellData")
    if cell_data is None:
        return None
    name = cell_data.attrib.get("HigherOrderDegrees", "HigherOrderDegrees")
    found = [a for a in cell_data if a.attrib.get("Name") == name]
    if not found:
        return None
    degrees = decode(file, found[0], f"{where} HigherOrderDegrees", 3 * num_cells, f"{num_cells} cells x 3")
    if not np.all(np.isfinite(degrees)) or np.any(degrees != np.round(degrees)):
        raise VtuError(f"{file.path}: {where}: HigherOrderDegrees are not all integers")
    return degrees.reshape(num_cells, 3).astype(np.int64)


def _cell_degrees(path, cell, type_name, shape, family, num_nodes, declared):
    """The cell's (p, q, r): 1 for linear cells, else HigherOrderDegrees (declared) where VTK
    uses them, else inferred from the node count; checked against the renderer's limit and the
    node count."""
    if family == "linear":
        degrees = (1, 1, 1)
    elif declared is not None and shape != TET:
        degrees = tuple(int(x) for x in declared)
        if shape == PRISM and degrees[0] != degrees[1]:
            raise VtuError(f"{path}: cell {cell}: {type_name} HigherOrderDegrees {degrees}: the triangle "
                           "degrees must agree")
    else:  # VTK's tetrahedra ignore HigherOrderDegrees too
        degrees = infer_degrees(shape, num_nodes)
        if degrees is None:
            raise VtuError(f"{path}: cell {cell}: {type_name} with {num_nodes} nodes matches no complete degree")
    if min(degrees) < 1 or max(degrees) > MAX_MODES - 1:
        raise VtuError(f"{path}: cell {cell}: {type_name} degrees {degrees}; 1..{MAX_MODES - 1} are supported")
    if node_count(shape, degrees) != num_nodes:
        raise VtuError(f"{path}: cell {cell}: {type_name} of degrees {degrees} needs "
                       f"{node_count(shape, degrees)} nodes, has {num_nodes}")
    return degrees


def _volume_mesh(path, cells, vtk8, field_name):
    """The cells converted to modal expansions, a conversion matrix per (shape, family, degrees),
    each cell read mirrored where it is left-handed."""
    n = len(cells)
    coeffs, geometry_coeffs, modes = [None] * n, [None] * n, [None] * n
    groups = {}
    for e, (shape, family, degrees, _, _) in enumerate(cells):
        groups.setdefault((shape, family, degrees), []).append(e)
    for (shape, family, degrees), members in groups.items():
        old_hex_order = vtk8 and shape == HEX
        group_modes = modes_for(shape, degrees)
        X = np.stack([cells[e][3] for e in members])  # (n, N, 3)
        V = np.stack([cells[e][4] for e in members])  # (n, N)
        T = conversion_matrix(shape, family, degrees, old_hex_order)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is diagnosed below
            G = np.matmul(T, X)  # (n, K, 3)
            C = V @ T.T
        flip = validity.orientation(shape, group_modes, G) < 0  # left-handed: read mirrored
        if flip.any():
            T_mirrored = conversion_matrix(shape, family, degrees, old_hex_order, True)
            G[flip] = np.matmul(T_mirrored, X[flip])
            C[flip] = V[flip] @ T_mirrored.T
        validity.check_elements(shape, group_modes, G, members)
        for i, e in enumerate(members):
            coeffs[e], geometry_coeffs[e], modes[e] = C[i], G[i], group_modes
    shapes = [cell[0] for cell in cells]
    return VolumeMesh.from_elements(shapes, modes, coeffs, modes, geometry_coeffs, field_name=field_name,
                                    source=str(path))
