"""The <CURVED> section: the points of curved edges and faces, plain or as B64Z records with a
shared point pool (docs/spec/formats.md §2.2, §2.3)."""
from __future__ import annotations

import numpy as np

from ...engine.shapes import MAX_MODES
from .entities import check_coordinates
from .errors import NektarError
from .points import POINTS_ENUM
from .xmlfile import check_count, endianness, entity_id, parse_floats, parse_int, records

# The renderer's limit on modes per direction also bounds curve points (one mode per point).
MAX_CURVE_POINTS = MAX_MODES


def read_curves(geometry, path, edges, faces, scale, move, budget):
    """({edge id: (points type, (n, 3) points)}, {face id: (points type, (N, 3) points)}); compressed
    blocks within the file's inflation budget and what the edges and faces can use."""
    curved_edges, curved_faces = {}, {}
    curved = geometry.find("CURVED")
    if curved is None or not len(curved):
        return curved_edges, curved_faces
    endian = endianness(curved, path, "CURVED")
    if endian:
        entries = _compressed_entries(curved, path, endian, scale, move, budget, len(edges), len(faces))
    else:
        check_count(sum(node.tag in ("E", "F") for node in curved), len(edges) + len(faces), path, "CURVED",
                    "edges and faces")
        entries = _plain_entries(curved, path, scale, move)
    for tag, curve_id, entity, points_type, xyz in entries:
        what = f"curved {'edge' if tag == 'E' else 'face'} {curve_id}"
        check_coordinates(xyz, path, what)
        if tag == "E":
            if entity not in edges:
                raise NektarError(f"{path}: {what} refers to missing edge {entity}")
            if entity in curved_edges:
                raise NektarError(f"{path}: edge {entity} is curved twice")
            curved_edges[entity] = (points_type, xyz)
        else:
            if entity not in faces:
                raise NektarError(f"{path}: {what} refers to missing face {entity}")
            if entity in curved_faces:
                raise NektarError(f"{path}: face {entity} is curved twice")
            curved_faces[entity] = (points_type, xyz)
    return curved_edges, curved_faces


def _compressed_entries(curved, path, endian, scale, move, budget, num_edges, num_faces):
    """(tag 'E'/'F', curve id, entity id, points type, points) of each record; the points come
    from the DATAPOINTS pool through its INDEX. Each edge and face is curved once at most, with at
    most MAX_CURVE_POINTS (squared for a face) points."""
    most_points = num_edges * MAX_CURVE_POINTS + num_faces * MAX_CURVE_POINTS**2
    pools = curved.findall("DATAPOINTS")
    if len(pools) > 1:
        raise NektarError(f"{path}: CURVED has {len(pools)} DATAPOINTS blocks; one is expected")
    index = pool = None
    if pools:
        index_node, points_node = pools[0].find("INDEX"), pools[0].find("POINTS")
        if index_node is None or points_node is None:
            raise NektarError(f"{path}: CURVED/DATAPOINTS lacks INDEX or POINTS")
        index = records(index_node, path, "CURVED INDEX", [("i", "i8", None)], endian, budget, most_points,
                        "curved edges and faces")["i"]
        pool = records(points_node, path, "CURVED POINTS", [("id", "i8", None), ("x", "f8", (3,))], endian, budget,
                       most_points, "curved edges and faces")["x"]
        if not np.all(np.isfinite(pool)):
            raise NektarError(f"{path}: CURVED POINTS: coordinates are not finite")
        pool = pool * scale + move  # the compressed reader scales every curve point (docs/spec/formats.md §2.2)
    entries = []
    for node in curved:
        if node.tag not in ("E", "F"):
            continue
        rec = records(node, path, f"CURVED {node.tag}",
                      [(k, "i8", None) for k in ("id", "entity", "npoints", "ptid", "offset", "ptype")], endian,
                      budget, num_edges if node.tag == "E" else num_faces, "edges" if node.tag == "E" else "faces")
        for row in rec:
            curve_id, entity, count, offset, points_type = (
                int(row[k]) for k in ("id", "entity", "npoints", "offset", "ptype"))
            what = (f"curved {'edge' if node.tag == 'E' else 'face'} record {curve_id} "
                    f"({'EDGEID' if node.tag == 'E' else 'FACEID'} {entity})")
            if not 0 <= points_type < len(POINTS_ENUM):
                raise NektarError(f"{path}: {what}: unknown points type {points_type}")
            _check_count(count, node.tag, path, what)
            if index is None:
                raise NektarError(f"{path}: {what}: CURVED has no DATAPOINTS")
            if offset < 0 or offset + count > len(index):
                raise NektarError(f"{path}: {what}: points {offset}..{offset + count - 1} lie outside INDEX "
                                  f"({len(index)} entries)")
            pool_index = index[offset : offset + count]
            if np.any(pool_index < 0) or np.any(pool_index >= len(pool)):
                raise NektarError(f"{path}: {what}: INDEX refers to a point outside POINTS ({len(pool)} points)")
            entries.append((node.tag, curve_id, entity, POINTS_ENUM[points_type], pool[pool_index]))
    return entries


def _plain_entries(curved, path, scale, move):
    """(tag 'E'/'F', curve id, entity id, points type, points) of each <E> and <F>."""
    entries = []
    for node in curved:
        if node.tag not in ("E", "F"):
            continue
        curve_id = entity_id(node, path, "CURVED")
        key = "EDGEID" if node.tag == "E" else "FACEID"
        what = f"curved {'edge' if node.tag == 'E' else 'face'} {curve_id} ({key} {node.attrib.get(key)})"
        entity = parse_int(node.attrib.get(key), path, f"{what}: {key}")
        count = parse_int(node.attrib.get("NUMPOINTS"), path, f"{what}: NUMPOINTS")
        _check_count(count, node.tag, path, what)
        points_type = node.attrib.get("TYPE", "").strip()
        if points_type not in POINTS_ENUM:
            raise NektarError(f"{path}: {what}: unknown points TYPE {points_type!r}")
        xyz = parse_floats(node.text, 3 * count, path, what).reshape(count, 3)
        if node.tag == "E":  # the uncompressed reader scales edge points only (docs/spec/formats.md §2.2)
            xyz = xyz * scale + move
        entries.append((node.tag, curve_id, entity, points_type, xyz))
    return entries


def _check_count(count, tag, path, what):
    cap = MAX_CURVE_POINTS if tag == "E" else MAX_CURVE_POINTS**2
    if not 1 <= count <= cap:
        raise NektarError(f"{path}: {what}: NUMPOINTS={count}; 1..{cap} are supported")
