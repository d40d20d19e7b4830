"""Multi-LoD exports (cjio's OBJ and GLB of a 3D BAG CityJSON) read as one LoD of each building, not their union.

Independent values: each building's LoD volumes from the CityJSON's own Solids by the divergence theorem over
its polygons (Newell area vectors, computed here from the JSON, not by meshsom), and trimesh volumes of hand-built
boxes."""
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from meshsom.io import RawMesh, ReaderOptions, Rejection, read_file

DATA = Path(__file__).parent / "data" / "cjio-3dbag"


def _read(path, **opts):
    out = list(read_file(path, ReaderOptions(**opts)))
    return {r.id.split("#")[-1]: r for r in out if isinstance(r, RawMesh)}, [r for r in out if isinstance(r, Rejection)]


def _volume(m):
    return trimesh.Trimesh(m.vertices, m.faces, process=True).volume


def _cityjson_volumes():
    """{building id: {lod: volume}} from the CityJSON's Solids: V = 1/3 sum over polygons of (a point . Newell area vector)."""
    cj = json.loads((DATA / "multi_lod.city.json").read_text())
    verts = np.asarray(cj["vertices"], float) * cj["transform"]["scale"]
    out = {}
    for oid, obj in cj["CityObjects"].items():
        for geom in obj.get("geometry", []):
            total = 0.0
            for surface in geom["boundaries"][0]:
                ring = verts[surface[0]] - verts[0]
                area = 0.5 * np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0)
                total += ring[0] @ area / 3
            out.setdefault(oid, {})[geom["lod"]] = abs(total)
    return out


def _box(x0, y0, z0, x1, y1, z1, name, first):
    v = trimesh.creation.box(bounds=[[x0, y0, z0], [x1, y1, z1]])
    lines = [f"o {name}"] + [f"v {a} {b} {c}" for a, b, c in v.vertices]
    lines += [f"f {a + first} {b + first} {c + first}" for a, b, c in v.faces]
    return lines, first + len(v.vertices)


def _gable(name, first):
    """A 10 x 8 m house, walls 4 m, ridge 7 m along x (440 m3), closed."""
    verts = [(0, 0, 0), (10, 0, 0), (10, 8, 0), (0, 8, 0), (0, 0, 4), (10, 0, 4), (10, 8, 4), (0, 8, 4), (0, 4, 7), (10, 4, 7)]
    faces = [(1, 3, 2), (1, 4, 3), (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8),
             (5, 6, 10), (5, 10, 9), (7, 8, 9), (7, 9, 10), (6, 7, 10), (8, 5, 9)]
    lines = [f"o {name}"] + [f"v {a} {b} {c}" for a, b, c in verts]
    lines += [f"f {a + first - 1} {b + first - 1} {c + first - 1}" for a, b, c in faces]
    return lines, first + len(verts)


def test_two_lods_of_one_name_read_as_the_most_detailed_or_the_least(tmp_path):
    block, n = _box(0, 0, 0, 10, 8, 6, "6751773", 1)
    house, _ = _gable("6751773", n)
    path = tmp_path / "two_lods.obj"
    path.write_text("\n".join(block + house) + "\n")
    assert trimesh.load(path, process=False).volume == pytest.approx(480 + 440)  # both solids, as written
    ok, rej = _read(path)
    (m,) = ok.values()
    assert rej == [] and _volume(m) == pytest.approx(440.0) and len(m.faces) == 16
    assert "2 versions of the object in the file" in m.notes[-1] and "most detailed, version 2" in m.notes[-1]
    (m,) = _read(path, lod="lowest")[0].values()
    assert _volume(m) == pytest.approx(480.0)
    (m,) = _read(path, lod="2.2")[0].values()
    assert _volume(m) == pytest.approx(440.0) and "LoD 2.2 cannot be told" in m.notes[-1]


def test_parts_of_one_name_stay_joined(tmp_path):
    """A roof and walls written as objects of one name (each open), and a house with its detached garage (each closed,
    their boxes hardly overlapping): parts of one building, joined as before."""
    house, n = _box(0, 0, 0, 10, 8, 6, "B1", 1)
    garage, _ = _box(12, 0, 0, 16, 4, 3, "B1", n)
    path = tmp_path / "house_and_garage.obj"
    path.write_text("\n".join(house + garage) + "\n")
    (m,) = _read(path)[0].values()
    assert len(m.faces) == 24 and not any("versions" in note for note in m.notes)
    walls = ["o B2", "v 0 0 0", "v 4 0 0", "v 4 0 3", "v 0 0 3", "f 1 2 3", "f 1 3 4"]
    roof = ["o B2", "v 0 0 3", "v 4 0 3", "v 4 4 3", "f 5 6 7"]
    path = tmp_path / "parts.obj"
    path.write_text("\n".join(walls + roof) + "\n")
    out = list(read_file(path, ReaderOptions()))
    assert len(out) == 1 and not any("versions" in note for note in getattr(out[0], "notes", ()))


@pytest.mark.parametrize("name, tol", [("multi_lod.obj", 1e-6), ("multi_lod.glb", 5e-3)])
def test_cjio_exports_of_the_3dbag_read_as_lod_2_2(name, tol):
    """cjio writes LoD 1.2, 1.3 and 2.2 of each building under its id: read as LoD 2.2 (the most detailed, of equal
    triangle counts the last), not their union (6751773 was 566.3 m3). The GLB's ids are its meshes' names (the
    building ids), its nodes being unnamed. GLB coordinates are float32, whence its tolerance."""
    expected = _cityjson_volumes()
    ok, rej = _read(DATA / name)
    assert rej == [] and set(ok) == set(expected)
    for oid, m in ok.items():
        assert _volume(m) == pytest.approx(expected[oid]["2.2"], rel=tol), oid
        assert "3 versions of the object in the file" in m.notes[-1]
    assert _volume(ok["6751773"]) == pytest.approx(418.6, abs=0.5)
    low, _ = _read(DATA / name, lod="lowest")
    # of equal triangle counts the least detailed is the first: LoD 1.2
    assert _volume(low["6751773"]) == pytest.approx(expected["6751773"]["1.2"], rel=tol)
