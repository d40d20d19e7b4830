"""Draco metadata read from the bitstream: what Google's encoder writes (through DracoPy), what
ArcGIS Pro writes (New York's DA12 package), and metadata written here that Google's decoder reads."""

from __future__ import annotations

import gzip
import struct
import zipfile

import numpy as np
import pytest

from conftest import DATA
from meshsom.draco_metadata import MetadataError, entry_double, entry_int32s, entry_text, read_metadata
from test_i3s import draco_with_metadata

DracoPy = pytest.importorskip("DracoPy")

TETRA = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


def test_the_names_googles_encoder_writes_are_read():
    """DracoPy names generic attributes through Draco's metadata (``name``) and records its
    quantisation in the geometry's: both read here, keyed as Google's decoder keys them."""
    data = DracoPy.encode(*TETRA, create_metadata=True, quantization_bits=13,
                          generic_attributes={"feature-index": np.arange(4, dtype=np.uint32)[:, None], "weight": np.ones((4, 1), np.float32)})
    metadata = read_metadata(data)
    decoded = {a["unique_id"]: a["name"] for a in DracoPy.decode(data).attributes if a["name"]}
    assert {k: entry_text(v, "name") for k, v in metadata.attributes.items()} == decoded
    assert sorted(decoded.values()) == ["feature-index", "weight"]
    assert entry_int32s(metadata.geometry, "quantization_bits").tolist() == [13]
    assert metadata.version >= (2, 2)


def test_metadata_written_here_is_what_googles_decoder_reads():
    """The test packages' writer puts metadata where Draco's encoder does: Google's decoder still
    decodes the mesh and finds the attribute's ``name`` among the entries; the reader finds all."""
    data = draco_with_metadata(*TETRA, {9: np.arange(4, dtype=np.uint32)[:, None]}, {"i3s-scale_x": struct.pack("<d", 0.5)},
                               {9: {"name": b"feature-index", "i3s-feature-ids": np.array([-3, 70000], "<i4").tobytes()}},
                               {"note": "h\u00f4tel".encode()})
    mesh = DracoPy.decode(data)
    assert len(mesh.faces) == 4 and [a["name"] for a in mesh.attributes if a["unique_id"] == 9] == ["feature-index"]
    metadata = read_metadata(data)
    (position,) = [a["unique_id"] for a in mesh.attributes if a["attribute_type"] == 0]
    assert entry_double(metadata.attributes[position], "i3s-scale_x") == 0.5
    assert entry_int32s(metadata.attributes[9], "i3s-feature-ids").tolist() == [-3, 70000]
    assert entry_text(metadata.geometry, "note") == "h\u00f4tel" and entry_double(metadata.geometry, "absent") is None


def test_arcgis_pro_metadata_of_new_york():
    """A DA12 node's Draco buffer: the position's scales are degrees per equatorial metre, the
    feature index's ids are those of the node's plain buffer."""
    with zipfile.ZipFile(DATA / "nyc-i3s-da12" / "DA12_subset.slpk") as z:
        compressed = gzip.decompress(z.read("nodes/11/geometries/1.bin.gz"))
        plain = gzip.decompress(z.read("nodes/11/geometries/0.bin.gz"))
    metadata = read_metadata(compressed)
    vertices, features = struct.unpack_from("<II", plain)
    ids = np.frombuffer(plain, "<u8", features, 8 + vertices * (12 + 12 + 8 + 4))
    position = next(v for v in metadata.attributes.values() if "i3s-scale_x" in v)
    assert entry_double(position, "i3s-scale_x") == pytest.approx(1 / 111319.49, rel=1e-6) == entry_double(position, "i3s-scale_y")
    index = next(v for v in metadata.attributes.values() if entry_text(v, "i3s-attribute-type") == "feature-index")
    assert entry_int32s(index, "i3s-feature-ids").tolist() == ids.tolist() and features == 3


def test_a_bitstream_without_metadata_and_broken_ones():
    assert read_metadata(DracoPy.encode(*TETRA)).attributes == {}
    with pytest.raises(MetadataError, match="is not a Draco bitstream"):
        read_metadata(b"DRAC")
    header = b"DRACO\x02\x02\x01\x01\x00\x80"
    with pytest.raises(MetadataError, match="ends inside"):
        read_metadata(header + b"\x01\x00\x01\x05ab")
    with pytest.raises(MetadataError, match="more than 5 bytes"):
        read_metadata(header + b"\xff" * 6)
    with pytest.raises(MetadataError, match="has no value"):
        read_metadata(header + b"\x00\x01\x01k\x00\x00")
    with pytest.raises(MetadataError, match="a double is 8"):
        entry_double({"x": b"\x00" * 4}, "x")
