"""The metadata of a Draco bitstream: the key-value entries a Draco file carries before its geometry.

Draco's decoders (and DracoPy, which wraps Google's) give back the geometry and each attribute's
``name`` but no other metadata, and formats built on Draco keep what they need there: an I3S
geometry buffer (:mod:`meshsom.i3s`) stores its feature ids (``i3s-feature-ids``), which generic
attribute holds each vertex's feature (``i3s-attribute-type``) and the scale of its positions
(``i3s-scale_x``, ``i3s-scale_y``) as metadata. This module reads that section, which lies right
after the header and before anything compressed, as Draco's ``MetadataDecoder`` does:

- the header: ``DRACO``, the bitstream's major and minor version, the encoder type and method, and
  16 bits of flags; metadata follows where the flags hold ``0x8000`` (bitstreams 1.3 and later);
- the attributes' metadata: a count (varint), then for each the attribute's unique id (varint) and
  its metadata; then the geometry's own metadata;
- a metadata: a count of entries (varint), each a name (one byte of length, then the bytes) and a
  value (a varint of length, then the bytes, little-endian as written), then a count of
  sub-metadata (varint), each a name and a metadata (read here depth first, as Draco's stack does).

Values are kept as bytes; :func:`entry_double`, :func:`entry_int32s` and :func:`entry_text` read
them as Draco's ``GetEntryDouble``, ``GetEntryIntArray`` and ``GetEntryString`` do.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["DracoMetadata", "MetadataError", "entry_double", "entry_int32s", "entry_text", "read_metadata"]

#: The bytes every Draco bitstream starts with.
MAGIC = b"DRACO"
#: The header: magic, major and minor version, encoder type, encoder method (one byte each), flags (uint16).
HEADER_BYTES = len(MAGIC) + 4 + 2
#: The flag saying that metadata follows the header.
METADATA_FLAG = 0x8000
#: The first bitstream version with metadata.
FIRST_METADATA_VERSION = (1, 3)
#: Bytes a varint of 32 bits takes at most.
VARINT_BYTES = 5
#: Sub-metadata nesting read at most (Draco's own limit).
MAX_DEPTH = 1000


class MetadataError(ValueError):
    """The bytes are not a Draco bitstream, or its metadata section ends early or is malformed."""


@dataclasses.dataclass(frozen=True)
class DracoMetadata:
    """The metadata of one Draco bitstream.

    Attributes
    ----------
    version : (major, minor)
        The bitstream's version.
    attributes : dict[int, dict[str, bytes]]
        Each attribute's entries, by the attribute's unique id (DracoPy's ``unique_id``).
    geometry : dict[str, bytes]
        The geometry's own entries.
    sub : dict[str, dict]
        The geometry's sub-metadata, by name, each ``{"entries": ..., "sub": ...}``.
    """

    version: tuple[int, int]
    attributes: dict[int, dict[str, bytes]]
    geometry: dict[str, bytes]
    sub: dict[str, dict]


class _Reader:
    def __init__(self, data: bytes):
        self.data, self.at = data, 0

    def take(self, n: int, what: str) -> bytes:
        if self.at + n > len(self.data):
            raise MetadataError(f"the metadata ends inside {what} (byte {self.at} of {len(self.data)}, {n} more wanted)")
        out = self.data[self.at:self.at + n]
        self.at += n
        return out

    def varint(self, what: str) -> int:
        value = 0
        for shift in range(0, 7 * VARINT_BYTES, 7):
            (byte,) = self.take(1, what)
            value |= (byte & 0x7F) << shift
            if not byte & 0x80:
                return value
        raise MetadataError(f"{what} is a varint of more than {VARINT_BYTES} bytes (byte {self.at})")

    def name(self, what: str) -> str:
        (length,) = self.take(1, f"the length of {what}")
        return self.take(length, what).decode("utf-8", "replace")

    def metadata(self, depth: int = 0) -> dict:
        if depth > MAX_DEPTH:
            raise MetadataError(f"sub-metadata nested more than {MAX_DEPTH} deep")
        entries = {}
        for _ in range(self.varint("a count of entries")):
            key = self.name("an entry's name")
            size = self.varint(f"the size of entry {key!r}")
            if size == 0:
                raise MetadataError(f"entry {key!r} has no value (Draco writes none such)")
            entries[key] = self.take(size, f"the value of entry {key!r}")
        count = self.varint("a count of sub-metadata")
        if count > len(self.data) - self.at:
            raise MetadataError(f"{count} sub-metadata in the {len(self.data) - self.at} bytes left")
        sub = {}
        for _ in range(count):
            name = self.name("a sub-metadata's name")
            sub[name] = self.metadata(depth + 1)
        return {"entries": entries, "sub": sub}


def read_metadata(data: bytes) -> DracoMetadata:
    """The metadata of a Draco bitstream (as the module says); empty where it has none.

    Parameters
    ----------
    data : bytes
        The whole bitstream (only its header and metadata are read).

    Raises
    ------
    MetadataError
        ``data`` does not start with ``DRACO``, or its metadata section is cut short or malformed.
    """
    data = bytes(data)
    if len(data) < HEADER_BYTES or not data.startswith(MAGIC):
        raise MetadataError(f"is not a Draco bitstream (starts {data[:8]!r}, expected {MAGIC!r} and a header of "
                            f"{HEADER_BYTES} bytes)")
    version = (data[5], data[6])
    flags = int.from_bytes(data[9:11], "little")
    if not flags & METADATA_FLAG or version < FIRST_METADATA_VERSION:
        return DracoMetadata(version, {}, {}, {})
    reader = _Reader(data)
    reader.at = HEADER_BYTES
    attributes = {}
    for _ in range(reader.varint("the count of attribute metadata")):
        unique_id = reader.varint("an attribute's unique id")
        attributes[unique_id] = reader.metadata()["entries"]
    geometry = reader.metadata()
    return DracoMetadata(version, attributes, geometry["entries"], geometry["sub"])


def entry_double(entries: dict[str, bytes], key: str) -> float | None:
    """The entry ``key`` as one float64 (Draco's ``GetEntryDouble``); None where absent.

    Raises
    ------
    MetadataError
        The entry is not 8 bytes.
    """
    value = entries.get(key)
    if value is None:
        return None
    if len(value) != 8:
        raise MetadataError(f"entry {key!r} holds {len(value)} bytes; a double is 8")
    return float(np.frombuffer(value, "<f8")[0])


def entry_int32s(entries: dict[str, bytes], key: str) -> np.ndarray | None:
    """The entry ``key`` as int32 values, (K,) int64 (Draco's ``GetEntryIntArray``); None where absent.

    Raises
    ------
    MetadataError
        The entry's size is not a multiple of 4 bytes.
    """
    value = entries.get(key)
    if value is None:
        return None
    if len(value) % 4:
        raise MetadataError(f"entry {key!r} holds {len(value)} bytes, not a whole number of int32 values")
    return np.frombuffer(value, "<i4").astype(np.int64)


def entry_text(entries: dict[str, bytes], key: str) -> str | None:
    """The entry ``key`` as text (Draco's ``GetEntryString``: its bytes, UTF-8); None where absent."""
    value = entries.get(key)
    return None if value is None else value.decode("utf-8", "replace")
