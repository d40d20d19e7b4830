"""A plain Draco-compressed ``.glb`` (not 3D Tiles content) whose building is spread over primitives, each quantized by
Draco on its own grid: read through trimesh (:func:`meshsom.io.read_trimesh`), the node's primitives are joined and
welded within half a quantum of each (:func:`meshsom.tiles3d.weld_quantized`), as the 3D Tiles reader welds a batch's.

Expected values by hand: the box's 8 corners, its volume within the bounds half a quantum of each primitive allows;
the quanta from DracoPy's own quantization (the largest extent over 2^bits - 1).
"""

from __future__ import annotations

import DracoPy
import numpy as np
import pytest
import trimesh

from meshsom.gltf_compression import join_glb
from meshsom.io import RawMesh, read_file
from tests.test_tiles3d_batches import BOX, FLOOR_ROOF, WALLS

FLOAT, UINT = 5126, 5125
#: The box's corner (metres, z up) and each primitive's Draco position bits: floor and roof, walls.
CORNER = np.array([3.37, 1.91, 0.23])
BITS = (9, 11)


def _glb(parts, draco: bool = True) -> bytes:
    """A GLB of one node whose mesh has a primitive per part (z-up vertices, triangles, bits), Draco-compressed with
    positions only (``draco``) or written plain."""
    binary, views, accessors, primitives = b"", [], [], []
    for v, f, bits in parts:
        y_up = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]).astype(np.float32)
        first = len(accessors)
        accessors += [{"componentType": FLOAT, "count": len(v), "type": "VEC3", "min": y_up.min(0).tolist(),
                       "max": y_up.max(0).tolist()}, {"componentType": UINT, "count": f.size, "type": "SCALAR"}]
        primitive = {"attributes": {"POSITION": first}, "indices": first + 1, "mode": 4}
        if draco:
            blobs = [DracoPy.encode(y_up, f.astype(np.uint32), quantization_bits=bits)]
            primitive["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": len(views), "attributes": {"POSITION": 0}}}
        else:
            blobs = [y_up.tobytes(), f.astype(np.uint32).tobytes()]
            accessors[first]["bufferView"], accessors[first + 1]["bufferView"] = len(views), len(views) + 1
        for blob in blobs:
            binary += b"\0" * (-len(binary) % 4)
            views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(blob)})
            binary += blob
        primitives.append(primitive)
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"name": "house", "mesh": 0}], "meshes": [{"primitives": primitives}], "accessors": accessors,
           "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    if draco:
        doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    return join_glb(doc, binary)


def _parts():
    """The box and a small box 9 m below it (so that the range Draco quantizes over is not the box's alone), split into
    floors and roofs, and walls: one range, quantized at two bit depths."""
    both = np.vstack([BOX + CORNER, BOX * [0.2, 0.2, 0.5] + CORNER + [0, 0, -9.0]])
    return [(both, np.vstack([FLOOR_ROOF, FLOOR_ROOF + 8]), BITS[0]), (both, np.vstack([WALLS, WALLS + 8]), BITS[1])]


def test_draco_primitives_of_a_plain_glb_are_welded_at_their_quanta(tmp_path):
    """Before, the two primitives were joined without welding: 16 vertices, the box open along its 8 edges where
    floor and roof meet the walls (rejected by preprocessing, or rebuilt)."""
    parts = _parts()
    (tmp_path / "house.glb").write_bytes(_glb(parts))
    quanta = [float(np.ptp(v, axis=0).max()) / (2 ** bits - 1) for v, _, bits in parts]
    assert quanta[0] > 0.015 and quanta[1] > 0.005  # coarse enough to leave the corners apart
    items = list(read_file(tmp_path / "house.glb"))
    (m,) = [i for i in items if isinstance(i, RawMesh)]
    assert any("welded within half a quantum of each" in n for n in m.notes), m.notes
    whole = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert len(m.vertices) == 16 and whole.is_watertight  # both boxes closed again, 8 corners each
    main = max(whole.split(only_watertight=True), key=lambda b: abs(b.volume))  # the box, not the small one
    slack = sum(quanta) / 2  # each corner moved by at most half a quantum of each primitive, per axis
    extent = np.array([10.0, 8.0, 6.0])
    assert np.prod(extent - 2 * slack) <= abs(main.volume) <= np.prod(extent + 2 * slack)
    assert np.ptp(main.vertices, axis=0) == pytest.approx(extent, abs=2 * slack)


def test_an_uncompressed_glb_is_joined_as_before(tmp_path):
    """The same primitives written plain (no Draco): no quantum, no weld, no note; the node's primitives joined with
    each primitive's own vertices, as before (every corner twice)."""
    (tmp_path / "plain.glb").write_bytes(_glb(_parts(), draco=False))
    (m,) = [i for i in read_file(tmp_path / "plain.glb") if isinstance(i, RawMesh)]
    assert not any("welded" in n for n in m.notes)
    assert len(m.vertices) == 16 + 16 and len(m.faces) == 8 + 16
    # the raw accessors, read here with trimesh alone: the same points
    scene = trimesh.load(tmp_path / "plain.glb", process=False, force="scene")
    raw = np.vstack([g.vertices for g in scene.geometry.values()])
    z_up = np.column_stack([raw[:, 0], -raw[:, 2], raw[:, 1]])  # glTF is y up
    assert np.ptp(m.vertices, axis=0) == pytest.approx(np.ptp(z_up, axis=0), abs=1e-5)
