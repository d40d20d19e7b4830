"""3D Tiles 1.1 implicit tiling, as pg2b3dm and Cesium's tilers write it: content named by templates,
tiles listed by subtree files (binary with an internal bitstream, JSON with a buffer file beside it,
constant availability), read through the tileset like listed tiles.

The fixture writes the subtrees by the specification with its own Morton order (x in the lowest
bit), independent of the reader's: a quadtree of 3 levels in subtrees of 2, a REPLACE root whose
coarse tiles are replaced by their children, and ADD where every content counts.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from meshsom.implicit_tiling import morton_decode, morton_encode
from meshsom.io import RawMesh, Rejection, read_file
from tests.test_tiles3d import _buildings, _same_building, b3dm


def _morton(x: int, y: int, z: int | None = None) -> int:
    coords = [x, y] if z is None else [x, y, z]
    out = 0
    for bit in range(16):
        for d, c in enumerate(coords):
            out |= ((c >> bit) & 1) << (bit * len(coords) + d)
    return out


def _bitstream(indices, count) -> bytes:
    data = bytearray((count + 7) // 8)
    for i in indices:
        data[i // 8] |= 1 << (i % 8)
    return bytes(data)


def _binary_subtree(doc: dict, binary: bytes) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 8)
    binary += b"\0" * (-len(binary) % 8)
    return b"subt" + struct.pack("<IQQ", 1, len(text), len(binary)) + text + binary


def _tileset(folder, scheme, subtree_levels, available_levels, content, subtrees, refine="REPLACE"):
    """``folder/tileset.json``: one implicit root tile of the scheme, its templates, in a local frame."""
    (folder / "tileset.json").write_text(json.dumps({
        "asset": {"version": "1.1"}, "geometricError": 100,
        "root": {"boundingVolume": {"box": [0, 0, 0, 500, 0, 0, 0, 500, 0, 0, 0, 50]}, "geometricError": 50,
                 "refine": refine, "content": {"uri": content},
                 "implicitTiling": {"subdivisionScheme": scheme, "subtreeLevels": subtree_levels,
                                    "availableLevels": available_levels, "subtrees": {"uri": subtrees}}}}))


#: Available tiles (level, x, y) and which hold content; level 0 and (1, 0, 0) are coarse (children below).
TILES = {(0, 0, 0), (1, 0, 0), (1, 1, 1), (2, 0, 0), (2, 1, 0)}
LEAVES = {(1, 1, 1), (2, 0, 0), (2, 1, 0)}


def write_implicit(folder, buildings, refine="REPLACE"):
    """The tileset, its three subtrees and a glb per available tile (building k in the k-th tile in
    (level, x, y) order), in a local frame (no transform)."""
    order = sorted(TILES)
    (folder / "content").mkdir()
    (folder / "subtrees").mkdir()
    for k, (level, x, y) in enumerate(order):
        (folder / "content" / f"{level}-{x}-{y}.glb").write_bytes(b3dm([buildings[k]], lambda v: v, glb_only=True))
    # root subtree: levels 0 and 1 (5 bits), child subtrees at level 2 (16 bits)
    bits = [0] + [1 + _morton(x, y) for (level, x, y) in order if level == 1]
    children = [_morton(x, y) for (level, x, y) in order if level == 2]
    tile_bits, child_bits = _bitstream(bits, 5), _bitstream(children, 16)
    binary = tile_bits + b"\0" * (8 - len(tile_bits)) + child_bits
    doc = {"buffers": [{"byteLength": len(binary)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(tile_bits)},
                           {"buffer": 0, "byteOffset": 8, "byteLength": len(child_bits)}],
           "tileAvailability": {"bitstream": 0, "availableCount": len(bits)},
           "contentAvailability": [{"bitstream": 0, "availableCount": len(bits)}],
           "childSubtreeAvailability": {"bitstream": 1, "availableCount": len(children)}}
    (folder / "subtrees" / "0.0.0.subtree").write_bytes(_binary_subtree(doc, binary))
    # subtree (2, 0, 0): JSON, its bitstream in a buffer file; subtree (2, 1, 0): binary, constants
    (folder / "subtrees" / "avail.bin").write_bytes(_bitstream([0], 5))
    (folder / "subtrees" / "2.0.0.subtree").write_text(json.dumps({
        "buffers": [{"uri": "avail.bin", "byteLength": 1}], "bufferViews": [{"buffer": 0, "byteLength": 1}],
        "tileAvailability": {"bitstream": 0}, "contentAvailability": [{"bitstream": 0}],
        "childSubtreeAvailability": {"constant": 0}}))
    (folder / "subtrees" / "2.1.0.subtree").write_bytes(_binary_subtree({
        "tileAvailability": {"constant": 1}, "contentAvailability": [{"constant": 1}],
        "childSubtreeAvailability": {"constant": 0}}, b""))
    _tileset(folder, "QUADTREE", 2, 3, "content/{level}-{x}-{y}.glb", "subtrees/{level}.{x}.{y}.subtree", refine)
    return order


def _as_extension(folder):
    """The tileset as 3D Tiles 1.0's ``3DTILES_implicit_tiling`` extension wrote it (CesiumGS' samples before 1.1):
    the same object in the root's ``extensions``, its last level as ``maximumLevel``."""
    doc = json.loads((folder / "tileset.json").read_text())
    spec = doc["root"].pop("implicitTiling")
    spec["maximumLevel"] = spec.pop("availableLevels") - 1
    doc["asset"]["version"] = "1.0"
    doc["root"]["extensions"] = {"3DTILES_implicit_tiling": spec}
    doc["extensionsUsed"] = doc["extensionsRequired"] = ["3DTILES_implicit_tiling"]
    (folder / "tileset.json").write_text(json.dumps(doc))


@pytest.mark.parametrize("refine,extension", [("REPLACE", False), ("ADD", False), ("REPLACE", True)])
def test_implicit_quadtree_reads_its_finest_contents(tmp_path, refine, extension):
    buildings = _buildings(len(TILES))
    order = write_implicit(tmp_path, buildings, refine)
    if extension:
        _as_extension(tmp_path)
    items = list(read_file(tmp_path / "tileset.json"))
    assert all(isinstance(m, RawMesh) for m in items), items
    read = {m.id.split("#")[1]: m for m in items}
    want = {f"content/{level}-{x}-{y}.glb": k for k, (level, x, y) in enumerate(order)
            if refine == "ADD" or (level, x, y) in LEAVES}
    assert set(read) == set(want)
    for content, k in want.items():
        _, v, f = buildings[k]
        _same_building(read[content], v, f)


def test_implicit_tiling_through_a_folder_and_broken_subtrees(tmp_path):
    """The folder reads as its tileset (subtrees, buffers and contents listed as read through it); a
    missing or damaged subtree is one rejection naming it."""
    from meshsom.io import expand_inputs

    buildings = _buildings(len(TILES))
    write_implicit(tmp_path, buildings)
    skipped = []
    inputs, rejected = expand_inputs([tmp_path], skipped=skipped)
    assert [f.path.name for f in inputs] == ["tileset.json"] and not rejected
    assert {p.rsplit("/", 1)[1] for p, _ in skipped} >= {"0.0.0.subtree", "avail.bin", "2-0-0.glb"}
    for damage, problem in ((lambda p: p.unlink(), "2.1.0.subtree, which cannot be read"),
                            (lambda p: p.write_bytes(b"subt" + struct.pack("<IQQ", 1, 900, 0)), "do not fit")):
        target = tmp_path / "subtrees" / "2.1.0.subtree"
        damage(target)
        (item,) = list(read_file(tmp_path / "tileset.json"))
        assert isinstance(item, Rejection) and item.id == "tileset.json#implicit tiling" and problem in item.reason, item
        target.write_text(json.dumps({"tileAvailability": {"constant": 1}, "contentAvailability": [{"constant": 1}],
                                      "childSubtreeAvailability": {"constant": 0}}))  # whole again
    assert len(list(read_file(tmp_path / "tileset.json"))) == len(LEAVES)


def test_morton_order_and_octree(tmp_path):
    """Morton indices against the plain bit interleave; an octree of one subtree level whose root has
    two of its eight children (at (1, 0, 1) and (0, 1, 1)), both leaves."""
    rng = np.random.default_rng(5)
    for dims in (2, 3):
        coords = rng.integers(0, 1 << 10, (200, dims))
        index = morton_encode(coords, dims)
        assert [int(i) for i in index] == [_morton(*map(int, c)) for c in coords]
        assert (morton_decode(index, dims) == coords).all()
    buildings = _buildings(2)
    (tmp_path / "c").mkdir()
    for k, (x, y, z) in enumerate([(1, 0, 1), (0, 1, 1)]):
        (tmp_path / "c" / f"1_{x}_{y}_{z}.glb").write_bytes(b3dm([buildings[k]], lambda v: v, glb_only=True))
    # subtrees named by the template "{level}{x}{y}{z}.subtree": the root's 0000, its children's 1xyz
    (tmp_path / "0000.subtree").write_bytes(_binary_subtree({
        "buffers": [{"byteLength": 8}], "bufferViews": [{"buffer": 0, "byteLength": 1}],
        "tileAvailability": {"constant": 1}, "contentAvailability": [{"constant": 0}],
        "childSubtreeAvailability": {"bitstream": 0}}, _bitstream([_morton(1, 0, 1), _morton(0, 1, 1)], 8)))
    for x, y, z in [(1, 0, 1), (0, 1, 1)]:
        (tmp_path / f"1{x}{y}{z}.subtree").write_bytes(_binary_subtree({
            "tileAvailability": {"constant": 1}, "contentAvailability": [{"constant": 1}],
            "childSubtreeAvailability": {"constant": 0}}, b""))
    _tileset(tmp_path, "OCTREE", 1, 2, "c/{level}_{x}_{y}_{z}.glb", "{level}{x}{y}{z}.subtree")
    got = sorted(m.id.split("#")[1] for m in read_file(tmp_path / "tileset.json"))
    assert got == ["c/1_0_1_1.glb", "c/1_1_0_1.glb"]


def test_subtrees_too_large_to_hold_are_refused(tmp_path):
    """subtreeLevels 20 (a quadtree subtree of 3.7e11 tiles, its bitstreams 46 GB): refused from the
    tileset's numbers, before any subtree is read."""
    _tileset(tmp_path, "QUADTREE", 20, 20, "{level}/{x}/{y}.glb", "{level}.{x}.{y}.subtree")
    (item,) = list(read_file(tmp_path / "tileset.json"))
    assert isinstance(item, Rejection) and "MAX_SUBTREE_TILES" in item.reason
