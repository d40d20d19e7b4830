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
