"""3MF packages read as the buildings they build (meshsom.threemf).

The packages are written here as 3MF writers lay them out (content types, the package relationship to the root
model part, ``<resources>`` of meshes and components, ``<build>`` items with 3 x 4 transforms, the Production
extension's ``p:path`` to another model part), in millimetres (named or by default), metres and inches. Every
expected coordinate is worked out here from the vertices and the transforms by hand, every volume from the
footprint's area.
"""

from __future__ import annotations

import gzip
import zipfile

import numpy as np
import pytest

from meshsom.io import RawMesh, Rejection, expand_inputs, input_kind, read_file
from mesh_checks import HEIGHT, L_AREA, L_SHAPE, rotation_z, same_points, signed_volume

CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
PRODUCTION = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
CONTENT_TYPES = ('<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxmlformats.org/package/2006/'
                 'content-types"><Default Extension="rels" ContentType="application/vnd.openxmlformats-package.'
                 'relationships+xml"/><Default Extension="model" ContentType="application/vnd.ms-package.'
                 '3dmanufacturing-3dmodel+xml"/></Types>')
RELS = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.openxmlformats.org/package/2006/'
        'relationships"><Relationship Target="/{target}" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing'
        '/2013/01/3dmodel"/></Relationships>')


def l_prism() -> tuple[np.ndarray, np.ndarray]:
    """The L-prism (metres): vertices (12, 3) and outward triangles (20, 3) (the L cut into two rectangles)."""
    n = len(L_SHAPE)
    vertices = np.array([(x, y, 0.0) for x, y in L_SHAPE] + [(x, y, HEIGHT) for x, y in L_SHAPE])
    # the ring is counter-clockwise seen from above: the floor's triangles reversed (facing down), the roof's as it
    # runs, each wall's two turned outwards
    floor = [(0, 1, 4), (0, 4, 5), (1, 2, 3), (1, 3, 4)]
    triangles = [(c, b, a) for a, b, c in floor] + [(a + n, b + n, c + n) for a, b, c in floor]
    for a in range(n):
        b = (a + 1) % n
        triangles += [(a, b, b + n), (a, b + n, a + n)]
    corners = vertices[np.array(triangles)]
    volume = np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6
    assert volume == pytest.approx(L_AREA * HEIGHT)  # the fixture itself: closed and outwards
    return vertices, np.array(triangles)


def mesh_xml(object_id: int, vertices: np.ndarray, triangles: np.ndarray, name: str | None = None,
             kind: str | None = None) -> str:
    attributes = f' id="{object_id}"' + (f' name="{name}"' if name else "") + (f' type="{kind}"' if kind else "")
    vs = "".join(f'<vertex x="{x:.9g}" y="{y:.9g}" z="{z:.9g}"/>' for x, y, z in vertices)
    ts = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in triangles)
    return f"<object{attributes}><mesh><vertices>{vs}</vertices><triangles>{ts}</triangles></mesh></object>"


def transform(linear: np.ndarray, shift) -> str:
    """3MF's 12 numbers of ``p -> linear @ p + shift`` (row vectors: the rows of linear's transpose, then the shift)."""
    return " ".join(f"{v:.12g}" for v in np.vstack([np.asarray(linear).T, shift]).reshape(-1))


def model_xml(resources: str, build: str, unit: str | None = "millimeter") -> str:
    unit_attr = f' unit="{unit}"' if unit else ""
    return (f'<?xml version="1.0" encoding="UTF-8"?><model{unit_attr} xml:lang="en-US" xmlns="{CORE}" '
            f'xmlns:p="{PRODUCTION}"><resources>{resources}</resources><build>{build}</build></model>')


def write_3mf(path, model: str, parts: dict | None = None, root: str = "3D/3dmodel.model") -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as package:
        package.writestr("[Content_Types].xml", CONTENT_TYPES)
        package.writestr("_rels/.rels", RELS.format(target=root))
        package.writestr(root, model)
        for name, text in (parts or {}).items():
            package.writestr(name, text)








@pytest.mark.parametrize("unit", ["millimeter", None, "meter", "inch"])
def test_build_items_placed_in_metres(tmp_path, unit):
    """Each build item is a building at its transform (rotated, scaled, translated; the object built twice gets
    ``(2)``), in metres by the model's unit (millimetres where it names none, noted); a mirroring item keeps its
    faces outwards (a positive volume)."""
    per_metre = 1.0 / {"millimeter": 0.001, None: 0.001, "meter": 1.0, "inch": 0.0254}[unit]
    vertices, triangles = l_prism()
    placements = [(2.0 * rotation_z(30), np.array([250.0, -40.0, 3.0])), (np.eye(3), np.zeros(3)),
                  (np.diag([-1.0, 1.0, 1.0]), np.array([60.0, 0, 0]))]
    build = "".join(f'<item objectid="1" transform="{transform(a, t * per_metre)}"/>' for a, t in placements)
    path = tmp_path / "city.3mf"
    write_3mf(path, model_xml(mesh_xml(1, vertices * per_metre, triangles, "house"), build, unit))
    assert input_kind(path) == "3mf"
    got = list(read_file(path))
    assert [m.id for m in got] == ["city.3mf#house", "city.3mf#house (2)", "city.3mf#house (3)"]
    for mesh, (a, t) in zip(got, placements):
        assert isinstance(mesh, RawMesh) and mesh.source == str(path)
        same_points(mesh, vertices @ a.T + t)
        assert signed_volume(mesh) == pytest.approx(L_AREA * HEIGHT * abs(np.linalg.det(a)), rel=1e-9)
        assert (mesh.notes != ()) == (unit is None)


def test_components_in_this_part_and_another_one_joined_into_their_item(tmp_path):
    """An item of an object of components is one building: each component at its transform, then the item's; a
    component may name an object of another model part (Production's p:path); a partnumber names the item."""
    vertices, triangles = l_prism()
    n = len(L_SHAPE)
    lower = vertices.copy()
    lower[n:, 2] = HEIGHT / 2  # the lower half of the prism
    other = model_xml(mesh_xml(7, lower * 1000, triangles, "half"), "")
    resources = (mesh_xml(1, lower * 1000, triangles, "half") +
                 f'<object id="2" name="tower"><components><component objectid="1"/>'
                 f'<component objectid="7" p:path="/3D/part.model" transform="{transform(np.eye(3), [0, 0, 3500])}"/>'
                 f'</components></object>')
    shift = np.array([10.0, 20.0, 0.0])
    build = f'<item objectid="2" partnumber="B-17" transform="{transform(rotation_z(90), shift * 1000)}"/>'
    path = tmp_path / "tower.3mf"
    write_3mf(path, model_xml(resources, build), {"3D/part.model": other})
    (got,) = read_file(path)
    assert isinstance(got, RawMesh) and got.id == "tower.3mf#B-17"
    same_points(got, np.concatenate([lower, lower + [0, 0, HEIGHT / 2]]) @ rotation_z(90).T + shift)
    assert signed_volume(got) == pytest.approx(L_AREA * HEIGHT, rel=1e-9)


def test_bad_items_rejected_alone_and_damaged_packages_named(tmp_path):
    """An item whose triangles name vertices its object has not, one of a support object and one of a missing
    object are rejections saying so, the good item read; a file that is no zip, a zip without a model part and a
    model part that is not XML are rejections of the file saying which."""
    vertices, triangles = l_prism()
    bad = triangles.copy()
    bad[3, 1] = 40
    resources = (mesh_xml(1, vertices, triangles, "good") + mesh_xml(2, vertices, bad, "broken") +
                 mesh_xml(3, vertices, triangles, "scaffold", kind="support"))
    build = "".join(f'<item objectid="{k}"/>' for k in (1, 2, 3, 9))
    path = tmp_path / "mixed.3mf"
    write_3mf(path, model_xml(resources, build, "meter"))
    got = {m.id: m for m in read_file(path)}
    assert isinstance(got["mixed.3mf#good"], RawMesh)
    assert "refers to vertex 40, and the object has 12 vertices" in got["mixed.3mf#broken"].reason
    assert "'support' object" in got["mixed.3mf#scaffold"].reason
    assert "names object 9" in got["mixed.3mf#object-9"].reason
    damaged = {"not-a-zip.3mf": b"PK\x03\x04 this is no zip", "empty.3mf": None, "broken-xml.3mf": "<model"}
    for name, content in damaged.items():
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        elif content is None:
            with zipfile.ZipFile(path, "w") as package:
                package.writestr("readme.txt", "nothing here")
        else:
            write_3mf(path, content)
        (got,) = read_file(path)
        assert isinstance(got, Rejection) and got.source == str(path)
    reasons = {name: r.reason for name in damaged for r in read_file(tmp_path / name)}
    assert "cannot be read as 3MF" in reasons["not-a-zip.3mf"]
    assert "holds no 3MF model part" in reasons["empty.3mf"]
    assert "model part /3D/3dmodel.model is not XML" in reasons["broken-xml.3mf"]


def test_gzipped_and_folder_walk(tmp_path):
    vertices, triangles = l_prism()
    path = tmp_path / "house.3mf"
    write_3mf(path, model_xml(mesh_xml(1, vertices, triangles, "house"), '<item objectid="1"/>', "meter"))
    (tmp_path / "house2.3mf.gz").write_bytes(gzip.compress(path.read_bytes()))
    files, rejected = expand_inputs([tmp_path])
    assert sorted(f.name for f in files) == ["house.3mf", "house2.3mf.gz"] and not rejected
    (got,) = read_file(tmp_path / "house2.3mf.gz")
    assert got.id == "house2.3mf.gz#house" and signed_volume(got) == pytest.approx(L_AREA * HEIGHT)


def test_split_components_cuts_an_item_into_its_pieces(tmp_path):
    """With split_components, an item of two prisms that do not touch is two buildings, ``#c1`` and ``#c2``."""
    from meshsom.io import ReaderOptions

    vertices, triangles = l_prism()
    resources = (mesh_xml(1, vertices, triangles, "house") +
                 f'<object id="2" name="pair"><components><component objectid="1"/><component objectid="1" '
                 f'transform="{transform(np.eye(3), [100, 0, 0])}"/></components></object>')
    path = tmp_path / "pair.3mf"
    write_3mf(path, model_xml(resources, '<item objectid="2"/>', "meter"))
    got = list(read_file(path, ReaderOptions(split_components=True)))
    assert [m.id for m in got] == ["pair.3mf#pair#c1", "pair.3mf#pair#c2"]
    same_points(got[1], vertices + [100, 0, 0])
    assert all(signed_volume(m) == pytest.approx(L_AREA * HEIGHT) for m in got)
