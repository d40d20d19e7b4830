"""b3dm batches as tilers write them: py3dtiles' tiles without ``BATCH_LENGTH`` (ids from the batch table's columns),
and pg2b3dm's Draco tiles whose buildings are spread over one primitive per material, each primitive quantized by
Draco on its own grid (welded back within half a quantum of each, :func:`meshsom.tiles3d.weld_quantized`).

Expected values are computed apart from meshsom's reader: batch tables parsed here with ``struct`` and ``json``, glTF
volumes by trimesh from the raw accessors, boxes by hand, quanta from DracoPy's own quantization (range / (2^bits - 1)).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import DracoPy
import numpy as np
import pytest
import trimesh

from meshsom.gltf_compression import join_glb, position_quantum
from meshsom.io import RawMesh, read_file
from tests.test_tiles3d import _buildings, _pad, b3dm

PY3DTILERS = Path(__file__).parent / "data" / "py3dtilers" / "white_buildings_0.b3dm"
FLOAT, UINT = 5126, 5125


def _without_batch_length(tile: bytes, count: int) -> bytes:
    """The b3dm with its feature table emptied (as py3dtiles writes it), lengths unchanged."""
    old = json.dumps({"BATCH_LENGTH": count}).encode()
    return tile.replace(old, b"{}" + b" " * (len(old) - 2), 1)


def _signed_volume(v, f):
    a, b, c = (v[f[:, k]] - v.mean(axis=0) for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def test_batches_without_batch_length_take_their_ids_from_the_batch_table(tmp_path):
    buildings = _buildings(3)
    names = ["BATIMENT-A", "BATIMENT-B", "BATIMENT-C"]
    tile = _without_batch_length(b3dm(buildings, lambda v: v, batch_table={"id": names, "usage": ["x", "y", "z"]}), 3)
    assert b'"BATCH_LENGTH"' not in tile
    (tmp_path / "t.b3dm").write_bytes(tile)
    items = list(read_file(tmp_path / "t.b3dm"))
    assert [m.id for m in items] == [f"t.b3dm#{n}" for n in names]
    assert all(any("no BATCH_LENGTH" in n and "3 batches" in n for n in m.notes) for m in items)
    for m, (_, v, f) in zip(items, buildings):  # each batch is its building
        assert abs(_signed_volume(m.vertices, m.faces)) == pytest.approx(abs(_signed_volume(v, f)), rel=1e-5)
    # columns of other lengths than the ids reach: batches read by number, saying why
    short = _without_batch_length(b3dm(buildings, lambda v: v, batch_table={"id": names[:2]}), 3)
    (tmp_path / "short.b3dm").write_bytes(short)
    items = list(read_file(tmp_path / "short.b3dm"))
    assert [m.id for m in items] == ["short.b3dm#0", "short.b3dm#1", "short.b3dm#2"]
    assert any("beyond its batch table's 2 rows" in n for n in items[0].notes)


def _raw_batches(path: Path) -> tuple[dict, dict]:
    """(batch table, {batch: trimesh volume}) of a plain b3dm, read here with struct, json and trimesh."""
    data = path.read_bytes()
    _, _, _, ft_json, ft_bin, bt_json, bt_bin = struct.unpack_from("<4sIIIIII", data)
    table = json.loads(data[28 + ft_json + ft_bin:28 + ft_json + ft_bin + bt_json])
    scene = trimesh.load(trimesh.util.wrap_as_stream(data[28 + ft_json + ft_bin + bt_json + bt_bin:]), file_type="glb",
                         process=False, force="scene")
    mesh = next(iter(scene.geometry.values()))
    ids = np.rint(np.asarray(mesh.vertex_attributes["_BATCHID"]).reshape(len(mesh.vertices), -1)[:, 0]).astype(int)
    volumes = {}
    for batch in np.unique(ids):
        part = trimesh.Trimesh(mesh.vertices, mesh.faces[ids[mesh.faces[:, 0]] == batch], process=True)
        trimesh.repair.fix_normals(part)
        volumes[int(batch)] = abs(float(part.volume))
    assert volumes[0] == pytest.approx(6468.1, abs=0.05)  # the probe's independent reading (trimesh), as a guard
    return table, volumes


def test_py3dtilers_tile_without_batch_length_keeps_its_building_ids():
    table, volumes = _raw_batches(PY3DTILERS)
    items = list(read_file(PY3DTILERS))
    assert [m.id.split("#", 1)[1] for m in items] == table["id"] == ["BATIMENT0000000240853073",
                                                                     "BATIMENT0000000240853157"]
    for batch, m in enumerate(items):
        assert isinstance(m, RawMesh)
        got = trimesh.Trimesh(m.vertices, m.faces, process=True)  # its windings made consistent as the raw one's
        trimesh.repair.fix_normals(got)
        assert abs(got.volume) == pytest.approx(volumes[batch], rel=1e-6)


BOX = np.array([[0, 0, 0], [10, 0, 0], [10, 8, 0], [0, 8, 0], [0, 0, 6], [10, 0, 6], [10, 8, 6], [0, 8, 6]], float)
FLOOR_ROOF = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
WALLS = np.array([[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


def _draco_primitives(parts) -> bytes:
    """A GLB of one mesh whose primitives are each Draco-compressed on their own: ``parts`` are (z-up vertices,
    triangles, batch id per vertex, quantization bits)."""
    binary, views, accessors, primitives = b"", [], [], []
    for v, f, ids, bits in parts:
        y_up = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]).astype(np.float32)
        stream = DracoPy.encode(y_up, f.astype(np.uint32), quantization_bits=bits,
                                generic_attributes={0: ids.astype(np.float32).reshape(-1, 1)})
        uid = {a["attribute_type"]: a["unique_id"] for a in DracoPy.decode(stream).attributes}
        binary += b"\0" * (-len(binary) % 4)
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(stream)})
        binary += stream
        first = len(accessors)
        accessors += [{"componentType": FLOAT, "count": len(v), "type": "VEC3", "min": y_up.min(0).tolist(),
                       "max": y_up.max(0).tolist()},
                      {"componentType": FLOAT, "count": len(v), "type": "SCALAR"},
                      {"componentType": UINT, "count": f.size, "type": "SCALAR"}]
        primitives.append({"attributes": {"POSITION": first, "_BATCHID": first + 1}, "indices": first + 2, "mode": 4,
                           "extensions": {"KHR_draco_mesh_compression": {
                               "bufferView": len(views) - 1, "attributes": {"POSITION": uid[0], "_BATCHID": uid[4]}}}})
    doc = {"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_draco_mesh_compression"],
           "extensionsRequired": ["KHR_draco_mesh_compression"], "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}], "meshes": [{"primitives": primitives}], "accessors": accessors,
           "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    return join_glb(doc, binary)


def _b3dm(glb: bytes, feature_table: dict) -> bytes:
    ft, glb = _pad(json.dumps(feature_table).encode()), _pad(glb, b"\0")
    return b"b3dm" + struct.pack("<6I", 1, 28 + len(ft) + len(glb), len(ft), 0, 0, 0) + ft + glb


def test_draco_primitives_of_one_building_are_welded_at_their_quanta(tmp_path):
    """pg2b3dm's layout: BATCH_LENGTH 0, no batch table, one primitive per material (floor and roof; walls), each
    quantized by Draco on its own grid (here 9 and 11 bits over ranges of 31.3 and 27.6 m, a second box making them
    differ), so the box's corners are read up to half a quantum of each apart and share no vertex."""
    corner = np.array([3.37, 1.91, 0.23])
    house, shed = BOX + corner, BOX * [0.5, 0.5, 0.5] + corner + [20, 12, 0]
    floors = np.vstack([house, shed])
    walls = np.vstack([house, shed + [0, 0, 3.0]])  # the shed's walls on a plinth: another range
    ids = np.repeat([0.0, 1.0], 8)
    both = lambda f: np.vstack([f, f + 8])  # noqa: E731
    glb = _draco_primitives([(floors, both(FLOOR_ROOF), ids, 9), (walls, both(WALLS), ids, 11)])
    (tmp_path / "t.b3dm").write_bytes(_b3dm(glb, {"BATCH_LENGTH": 0}))
    quanta = []
    for v, bits in ((floors, 9), (walls, 11)):  # Draco's quantum: the largest extent over 2^bits - 1
        quanta.append(float(np.ptp(v, axis=0).max()) / (2 ** bits - 1))
    assert quanta[0] > 0.04 and quanta[1] > 0.01
    m = next(m for m in read_file(tmp_path / "t.b3dm") if m.id.endswith("#0"))
    assert isinstance(m, RawMesh) and any("welded within half a quantum" in n for n in m.notes)
    mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert len(m.vertices) == 8 and mesh.is_watertight  # one closed box again
    slack = sum(quanta) / 2
    lo, hi = 480.0, 480.0  # the box's volume moves by at most half a quantum of each primitive on each side
    for sign, bound in ((-1, "lo"), (1, "hi")):
        value = (10 + 2 * sign * slack) * (8 + 2 * sign * slack) * (6 + 2 * sign * slack)
        lo, hi = (value, hi) if bound == "lo" else (lo, value)
    assert lo <= abs(mesh.volume) <= hi
    assert np.ptp(m.vertices, axis=0) == pytest.approx([10, 8, 6], abs=2 * slack)


def test_position_quantum_is_dracos_range_over_its_steps():
    rng = np.random.default_rng(3)
    points = (rng.random((400, 3)) * [30.0, 20.0, 10.0] + [100, 200, 5]).astype(np.float32)
    for bits in (8, 11, 14):
        decoded = np.asarray(DracoPy.decode(DracoPy.encode(points, np.arange(399).reshape(-1, 3),
                                                           quantization_bits=bits)).points)
        assert position_quantum(decoded) == pytest.approx(float(np.ptp(decoded, axis=0).max()) / (2 ** bits - 1),
                                                          rel=1e-6)
    assert position_quantum(points.astype(np.float64) + 1e-4 * rng.random((400, 3))) is None  # not on a grid


def test_a_lone_tile_in_earth_centred_axes_is_read_east_north_up(tmp_path):
    """pg2b3dm's tiles hold offsets in earth-centred axes from their tileset's root translation (no RTC_CENTER), so a
    tile read alone is tilted (Delft, 52 deg N: z 38 deg from up). It is turned east-north-up about the up its walls and
    floors show; expected: the buildings' east-north-up coordinates by PROJ's topocentric conversion (tests.test_tiles3d
    ._ecef), to a millimetre."""
    from tests.test_tiles3d import CENTRE, _ecef

    buildings = _buildings(12)
    ecef = {id(v): _ecef(v) for _, v, _ in buildings}
    centre = _ecef(np.zeros((1, 3)))[0]
    (tmp_path / "t.b3dm").write_bytes(b3dm(buildings, lambda v: ecef[id(v)] - centre))
    got = {m.id.split("#", 1)[1]: m for m in read_file(tmp_path / "t.b3dm")}
    note = next(n for n in got[buildings[0][0]].notes if "z is not up" in n)
    tilt = float(note.split(" deg from its z")[0].rsplit(" ", 1)[1])
    assert tilt == pytest.approx(90 - CENTRE[0], abs=0.5)
    for bid, v, f in buildings:
        m = got[bid]
        assert "east-north-up" in m.notes[0]
        want, have = v - v.mean(axis=0), m.vertices - m.vertices.mean(axis=0)
        assert np.abs(have - want).max() < 1e-3  # LoD1: walls exactly vertical, so the up is found exactly


def test_a_batch_spanning_kilometres_is_refused_not_a_building(tmp_path):
    """3D Tiles are metres; a tile written in millimetres (cjio's b3dm export writes its integer millimetre
    vertices unscaled: 525 km for a 3D BAG block) or a whole district as one model is refused with the span, as a
    mesh file's building is (io.MAX_BUILDING_EXTENT_M), where it had been accepted at 3.4e12 m3; buildings beside it
    are read."""
    from meshsom.io import MAX_BUILDING_EXTENT_M, Rejection

    buildings = _buildings(2)
    scale = 1000.0  # millimetres, as written; the second building is kept in metres
    tile = b3dm([(i, v * scale if k == 0 else v, f) for k, (i, v, f) in enumerate(buildings)], lambda v: v)
    (tmp_path / "mm.b3dm").write_bytes(tile)
    items = {m.id: m for m in read_file(tmp_path / "mm.b3dm")}
    span = float(np.ptp(buildings[0][1] * scale, axis=0).max())
    assert span > MAX_BUILDING_EXTENT_M  # the fixture does reach beyond the bound
    (refused,) = [m for m in items.values() if isinstance(m, Rejection)]
    assert refused.reason.startswith(f"spans {span / 1000:,.3g} km: not one building")
    (kept,) = [m for m in items.values() if isinstance(m, RawMesh)]
    v, f = buildings[1][1], buildings[1][2]
    assert abs(_signed_volume(kept.vertices, kept.faces)) == pytest.approx(abs(_signed_volume(v, f)), rel=1e-5)
