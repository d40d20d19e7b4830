"""Small hand-written CityJSON documents for the reader tests."""

from __future__ import annotations

import copy
import json

# A unit cube's 8 corners on a 1 mm grid, far from the origin (Swiss LV95-like translate).
CUBE_VERTS = [[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0],
              [0, 0, 1000], [1000, 0, 1000], [1000, 1000, 1000], [0, 1000, 1000]]
# Quads, counter-clockwise seen from outside.
CUBE_QUADS = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


def cube_solid(offset=0, lod="1"):
    return {"type": "Solid", "lod": lod, "boundaries": [[[[i + offset for i in q]] for q in CUBE_QUADS]]}


def doc(objects, vertices, version="2.0", transform=True):
    d = {"type": "CityJSON", "version": version, "CityObjects": objects, "vertices": vertices}
    if transform:
        d["transform"] = {"scale": [0.001, 0.001, 0.001], "translate": [2600000.0, 1200000.0, 400.0]}
    return d


def two_buildings():
    """Building A: a cube (LoD1) and a taller box at LoD2; building B: two parts, each a cube."""
    verts = copy.deepcopy(CUBE_VERTS)
    verts += [[x + 3000, y, z] for x, y, z in CUBE_VERTS]  # part 1
    verts += [[x + 4000, y, z] for x, y, z in CUBE_VERTS]  # part 2 (touching part 1)
    verts += [[x, y, z * 2] for x, y, z in CUBE_VERTS]  # A at LoD2: 2 m tall
    objects = {
        "A": {"type": "Building", "attributes": {"family": "cube"}, "geometry": [cube_solid(0, "1"), cube_solid(24, "2")]},
        "B": {"type": "Building", "children": ["B1", "B2"], "attributes": {"family": "pair"}},
        "B1": {"type": "BuildingPart", "parents": ["B"], "geometry": [cube_solid(8, "1")]},
        "B2": {"type": "BuildingPart", "parents": ["B"], "geometry": [cube_solid(16, "1")]},
        "R": {"type": "Road", "geometry": [{"type": "MultiSurface", "lod": "1", "boundaries": [[[0, 1, 2]]]}]},
    }
    return doc(objects, verts)


def write(path, document):
    path.write_text(json.dumps(document))
    return path


# ----------------------------------------------------------------------------- buildings of parts


def box_solid(lo, hi, offset, lod="2"):
    """An axis-aligned box from ``lo`` to ``hi`` (integer millimetres) as CityJSON vertices + Solid.

    Returns
    -------
    vertices : list of [x, y, z]
        Its 8 corners (append them to the file's vertices at index ``offset``).
    solid : dict
        A Solid whose six quads are counter-clockwise seen from outside.
    """
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    corners = [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
               [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
    return corners, {"type": "Solid", "lod": lod, "boundaries": [[[[i + offset for i in q]] for q in CUBE_QUADS]]}


def building_of_parts(boxes, lod="2"):
    """One Building "B" whose BuildingParts "P0", "P1", ... are the given boxes (mm, lo/hi pairs)."""
    verts, objects = [], {"B": {"type": "Building", "children": [f"P{k}" for k in range(len(boxes))]}}
    for k, (lo, hi) in enumerate(boxes):
        corners, solid = box_solid(lo, hi, len(verts), lod)
        verts += corners
        objects[f"P{k}"] = {"type": "BuildingPart", "parents": ["B"], "geometry": [solid]}
    return doc(objects, verts)


def prism_surfaces(ring, z0, z1, offset=0, floor=True, roof=True):
    """A vertical prism over a ring (integer mm, made counter-clockwise seen from above) as polygons.

    Returns
    -------
    vertices : list of [x, y, z]
        The ring at ``z0`` then at ``z1``.
    polygons : list
        CityJSON polygons (one ring each): floor (optional), roof (optional), one quad per wall.
    """
    ring = list(ring)
    if sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(ring, ring[1:] + ring[:1])) < 0:
        ring = ring[::-1]
    n = len(ring)
    verts = [[x, y, z0] for x, y in ring] + [[x, y, z1] for x, y in ring]
    polys = []
    if floor:
        polys.append([[offset + i for i in range(n - 1, -1, -1)]])
    if roof:
        polys.append([[offset + n + i for i in range(n)]])
    polys += [[[offset + i, offset + (i + 1) % n, offset + n + (i + 1) % n, offset + n + i]] for i in range(n)]
    return verts, polys


#: A real footprint (Zürich, LV95 mm) of 83.6 m²: the old buffer trick of --extrude-lod1 emptied it.
HEXAGON_MM = [[3798148, 514420], [3802684, 515176], [3802485, 516191], [3806120, 516813],
              [3807915, 506553], [3799688, 505181]]


# ----------------------------------------------------------------------------- other containers of the same objects


def _renumbered(node, new_index: dict):
    """A geometry's ``boundaries`` with every vertex index replaced through ``new_index`` (assigned in
    order of first appearance)."""
    if isinstance(node, list):
        return [_renumbered(x, new_index) for x in node]
    return new_index.setdefault(node, len(new_index))


def to_cityjsonseq(document: dict, keep_order: bool = False) -> list[dict]:
    """A CityJSON document as CityJSONSeq lines (what ``cjseq cat`` writes, written independently
    of the reader): a header with the transform and no objects, then one CityJSONFeature per
    object without parents, holding it and its descendants with their own vertices, numbered as
    they first appear in the boundaries (``keep_order``: in the document's order)."""
    header = {k: v for k, v in document.items() if k not in ("CityObjects", "vertices")}
    header.update({"version": "2.0", "CityObjects": {}, "vertices": []})
    objects, vertices = document["CityObjects"], document["vertices"]
    lines = [header]
    for oid, obj in objects.items():
        if obj.get("parents"):
            continue
        members, stack = [], [oid]
        while stack:
            m = stack.pop(0)
            if m not in members and m in objects:
                members.append(m)
                stack += objects[m].get("children", [])
        new_index: dict = {}
        feature_objects = {}
        for m in members:
            copy = dict(objects[m])
            copy["geometry"] = [{**g, "boundaries": _renumbered(g["boundaries"], new_index)} for g in objects[m].get("geometry", [])]
            feature_objects[m] = copy
        old = sorted(new_index, key=new_index.get)
        if keep_order:
            new_index = {v: k for k, v in enumerate(sorted(old))}
            for m in members:
                feature_objects[m]["geometry"] = [{**g, "boundaries": _renumbered(g["boundaries"], new_index)}
                                                  for g in objects[m].get("geometry", [])]
            old = sorted(old)
        lines.append({"type": "CityJSONFeature", "id": oid, "CityObjects": feature_objects,
                      "vertices": [vertices[i] for i in old]})
    return lines


def write_lines(path, lines: list[dict], compress: bool = False):
    """Write JSON objects one per line (gzip-compressed with ``compress``)."""
    import gzip

    data = "".join(json.dumps(line, separators=(",", ":")) + "\n" for line in lines).encode()
    path.write_bytes(gzip.compress(data, mtime=0) if compress else data)
    return path


def to_3dbag_layout(document: dict) -> dict:
    """A CityJSON document of Buildings with solids rearranged as the 3D BAG publishes them: each
    Building keeps only a LoD 0 MultiSurface (its lowest solid's floor polygons) and its solids
    move to a BuildingPart child ``<id>-0``."""
    out = json.loads(json.dumps(document))
    objects = {}
    vz = [v[2] for v in out["vertices"]]
    for oid, obj in out["CityObjects"].items():
        solids = [g for g in obj.get("geometry", []) if g["type"] == "Solid"]
        if obj["type"] != "Building" or not solids:
            objects[oid] = obj
            continue
        lowest = min(solids, key=lambda g: float(g["lod"]))
        shell = lowest["boundaries"][0]
        bottom = min(vz[i] for poly in shell for ring in poly for i in ring)
        floor = [poly for poly in shell if all(vz[i] == bottom for ring in poly for i in ring)]
        objects[oid] = {**obj, "geometry": [{"type": "MultiSurface", "lod": "0", "boundaries": floor}],
                        "children": [f"{oid}-0"]}
        objects[f"{oid}-0"] = {"type": "BuildingPart", "parents": [oid], "geometry": solids}
    out["CityObjects"] = objects
    return out


def instanced_box_doc(instance: dict, with_templates: bool = True) -> dict:
    """Building T, an instance of a 1 m cube template; building S, the same box written out as a Solid."""
    import numpy as np

    cube = [[float(x) / 1000 for x in v] for v in CUBE_VERTS]  # CUBE_VERTS are 0 / 1000 on the mm grid
    angle = np.pi / 2
    m = np.array([[2 * np.cos(angle), -2 * np.sin(angle), 0, 0.25], [2 * np.sin(angle), 2 * np.cos(angle), 0, 0.5],
                  [0, 0, 3, 0], [0, 0, 0, 1]])
    ref = [5000, 7000, 1000]  # the reference point, on the file's grid (mm)
    # independently: world = M t + p, then to the mm grid of the transform (translate 2600000, 1200000, 400)
    world = np.array(cube) @ m[:3, :3].T + m[:3, 3] + (np.array(ref) * 0.001 + [2600000.0, 1200000.0, 400.0])
    grid = np.round((world - [2600000.0, 1200000.0, 400.0]) / 0.001).astype(int).tolist()
    solid = cube_solid(offset=1, lod="2")
    instance = {"type": "GeometryInstance", "template": 0, "boundaries": [0], "transformationMatrix": m.reshape(-1).tolist(),
                **instance}
    d = doc({"T": {"type": "Building", "geometry": [instance]}, "S": {"type": "Building", "geometry": [solid]}},
            [ref] + grid)
    if with_templates:
        d["geometry-templates"] = {"templates": [{"type": "Solid", "lod": "2", "boundaries": cube_solid()["boundaries"]}],
                                   "vertices-templates": cube}
    return d
